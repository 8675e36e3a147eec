"""Fast tests of Energy-Casimir control: passivity, Casimir, estimators, wrapper, CLI, errors."""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pytest

import phast_gym  # noqa: F401  (registers the ids)
from phast_gym.control import (
    ControlProtocol,
    EnergyCasimirController,
    EnergyCasimirWrapper,
    MAPSmootherEstimator,
    evaluate_estimators,
    make_control_env,
    make_estimator,
    map_smoother_weights,
    run_episode,
)


def _loop(env_id: str, k_xi: float, steps: int = 300, x0=(2.5, 1.0), sigma: float = 0.0, estimator: str = "oracle",
          k_c: float = 2.0, d_inj: float = 0.5, q_star: float = 0.0, xi_feedback: str = "meas", max_action: float = 50.0):
    protocol = ControlProtocol(env_id=env_id, horizon=steps, q_star=q_star, k_c=k_c, d_inj=d_inj, k_xi=k_xi, settle_steps=10,
                               xi_feedback=xi_feedback, max_action=max_action)
    env = make_control_env(protocol, sigma)
    system = env.unwrapped.system
    ctrl = EnergyCasimirController(make_estimator(estimator, system, protocol.dt, sigma=sigma), q_star, k_c, d_inj, k_xi,
                                   dt=protocol.dt, max_action=max_action, system=system, xi_feedback=xi_feedback)
    return run_episode(env, ctrl, np.array(x0), seed=3, protocol=protocol), protocol


@pytest.mark.parametrize("env_id", ["PHAST/Pendulum-v0", "PHAST/DampedPendulum-v0"])
def test_closed_loop_storage_non_increasing_with_oracle(env_id: str) -> None:
    # Eq. 27 with v_ext = 0 and y_hat = y_p: dH_cl/dt = -(D + d_inj) qdot^2 <= 0; the discrete loop
    # (zero-order-hold torque, Euler xi) may only add O(dt^2) per step.
    ep, _ = _loop(env_id, k_xi=0.0)
    h = ep.storage
    inc = np.diff(h)
    assert inc.max() < 1e-3 * h[0], f"storage increased by {inc.max():.3g} (H_cl0 = {h[0]:.3g})"
    assert h[-1] < 0.5 * h[0]  # and it actually dissipates


@pytest.mark.parametrize("env_id", ["PHAST/Pendulum-v0", "PHAST/WindyPendulum-v0"])
@pytest.mark.parametrize("xi_feedback", ["meas", "filtered"])
@pytest.mark.parametrize("k_xi", [0.0, 5.0])
def test_upright_storage_non_increasing_with_oracle(env_id: str, xi_feedback: str, k_xi: float) -> None:
    # Upright (q_star = pi, k_c > m g l), swing-up from near hanging, oracle port, noiseless, v_ext = 0:
    # H_cl = H + k_c/2 wrap(xi - pi)^2 may only grow by the sampled loop's O(dt^2) per step, also with the
    # xi correction (k_xi > 0; xi stays on the Casimir leaf xi = q) and with filtered xi feedback (oracle q_hat = q).
    # The argument is for the unsaturated loop: a torque bound (clipping) can add energy, so the bound is lifted here.
    # Integrator tolerance: per step the torque is held while xi moves by Euler (dt * qdot_t), so H_cl can grow by
    # |u| |Delta q - dt qdot_t| + k_c/2 (Delta xi)^2 <= dt^2 (max|u| max|qddot| / 2 + k_c max|qdot|^2): O(dt^2) per step.
    ep, protocol = _loop(env_id, k_xi=k_xi, steps=800, x0=(0.3, 0.0), k_c=20.0, d_inj=3.0, q_star=math.pi,
                         xi_feedback=xi_feedback, max_action=1e3)
    dt = protocol.dt
    h = ep.storage
    inc = np.diff(h)
    qddot = np.abs(np.diff(ep.qdot[:, 0])).max() / dt
    tol = dt**2 * (np.abs(ep.u).max() * qddot / 2 + 20.0 * np.abs(ep.qdot).max() ** 2)
    assert inc.max() <= tol, f"storage increased by {inc.max():.3g} > integrator tolerance {tol:.3g}"
    assert tol < 2e-2 * (h[0] - h.min())  # the tolerance is small against the energy the loop removes
    assert abs(phast_gym.wrap(ep.q[-1, 0] - math.pi)) < 1e-3  # and it reaches the upright


def test_q_estimates_and_filtered_xi_feedback() -> None:
    system = phast_gym.make_env_system("PHAST/Pendulum-v0")
    dt = 0.01
    assert make_estimator("fd", system, dt).q_estimate() is None
    # MAP: the smoothed newest angle is exact on a ramp (the acceleration prior is inactive)
    est = MAPSmootherEstimator(system, dt, sigma=0.05, window=10)
    for i in range(20):
        est.update(np.array([0.3 + 1.7 * i * dt]))
    np.testing.assert_allclose(est.q_estimate(), [0.3 + 1.7 * 19 * dt], atol=1e-9)
    # UKF: the posterior q is much closer to the truth than the noisy measurement
    ep, _ = _loop("PHAST/DampedPendulum-v0", k_xi=5.0, steps=300, sigma=0.05, estimator="ukf", xi_feedback="filtered")
    meas_err = np.std(phast_gym.wrap(ep.q_meas[100:, 0] - ep.q[100:-1, 0]))
    xi_err = np.std(ep.xi[101:, 0] - ep.q[101:, 0])
    assert xi_err < 0.3 * meas_err, (xi_err, meas_err)
    # estimators without a q estimate fall back to the measurement: filtered == meas for FD
    a, _ = _loop("PHAST/DampedPendulum-v0", k_xi=5.0, steps=100, sigma=0.05, estimator="fd", xi_feedback="filtered")
    b, _ = _loop("PHAST/DampedPendulum-v0", k_xi=5.0, steps=100, sigma=0.05, estimator="fd", xi_feedback="meas")
    np.testing.assert_array_equal(a.u, b.u)
    with pytest.raises(ValueError, match="xi_feedback"):
        EnergyCasimirController(make_estimator("oracle", system, dt), 0.0, 1.0, 0.5, xi_feedback="smoothed")
    with pytest.raises(ValueError, match="xi_feedback"):
        ControlProtocol(xi_feedback="q_hat")


def test_casimir_invariant_without_correction() -> None:
    # k_xi = 0, exact port: xi integrates qdot, so C = q - xi stays constant up to the Euler error
    # of xi (bounded by dt * |delta qdot| / 2 over the run).
    ep, protocol = _loop("PHAST/Pendulum-v0", k_xi=0.0, d_inj=0.0, steps=200)
    c = ep.q[:, 0] - ep.xi[:, 0]
    drift = np.abs(c - c[0]).max()
    bound = protocol.dt * (np.abs(ep.qdot).max() + 1.0)
    assert drift < bound, (drift, bound)


def test_casimir_broken_by_correction_but_tracks() -> None:
    ep, _ = _loop("PHAST/DampedPendulum-v0", k_xi=5.0, steps=400)
    assert abs(ep.q[-1, 0] - ep.xi[-1, 0]) < 1e-2  # k_xi pulls xi onto q


def test_map_smoother_exact_on_polynomials() -> None:
    dt = 0.01
    t = np.arange(40) * dt
    system = phast_gym.make_env_system("PHAST/Pendulum-v0")
    # linear: the acceleration prior is inactive, the MAP solution is the data -> exact slope, any sigma
    est = MAPSmootherEstimator(system, dt, sigma=0.05, window=10)
    out = [est.update(np.array([0.3 + 1.7 * ti])) for ti in t]
    np.testing.assert_allclose(np.array(out)[1:, 0], 1.7, atol=1e-9)
    # noiseless (sigma = 0): exact backward difference of a quadratic, = derivative at t - dt/2
    est0 = MAPSmootherEstimator(system, dt, sigma=0.0, window=10)
    qq = 0.5 * t**2
    out0 = np.array([est0.update(np.array([v])) for v in qq])[:, 0]
    np.testing.assert_allclose(out0[1:], t[1:] - dt / 2, atol=1e-9)
    # the closed form is one dot product whose weights annihilate constants and read slopes exactly
    c = map_smoother_weights(10, dt, 0.05, 10.0)
    assert abs(c.sum()) < 1e-9 and abs(c @ np.arange(10) * dt - 1.0) < 1e-9


def test_map_smoother_unwraps_inside_window() -> None:
    dt = 0.01
    system = phast_gym.make_env_system("PHAST/Pendulum-v0")
    est = MAPSmootherEstimator(system, dt, sigma=0.01, window=8)
    q = np.pi - 0.2 + 3.0 * np.arange(30) * dt  # crosses +pi
    out = [est.update(np.array([phast_gym.wrap(v)])) for v in q]
    np.testing.assert_allclose(np.array(out)[1:, 0], 3.0, atol=1e-8)


def test_finite_difference_wrap_aware() -> None:
    system = phast_gym.make_env_system("PHAST/Pendulum-v0")
    fd = make_estimator("fd", system, 0.01)
    fd.update(np.array([math.pi - 0.01]))
    assert fd.update(np.array([-math.pi + 0.01]))[0] == pytest.approx(2.0, abs=1e-9)


def test_ukf_tracks_velocity_under_noise() -> None:
    ep, _ = _loop("PHAST/DampedPendulum-v0", k_xi=5.0, steps=300, sigma=0.05, estimator="ukf")
    assert np.mean(np.abs(ep.y_hat[50:, 0] - ep.qdot[50:, 0])) < 0.1


def test_ekf_is_a_deprecated_alias_of_ukf() -> None:
    """The estimator registered as "ekf" was always an unscented Kalman filter: "ukf" is its name, "ekf" still builds
    it, with a DeprecationWarning, and is no longer listed."""
    from phast_gym import make_env_system
    from phast_gym.control import UKFEstimator, estimator_names, make_estimator

    system = make_env_system("PHAST/DampedPendulum-v0")
    assert make_estimator("ukf", system, 0.05).name == "ukf" and "ekf" not in estimator_names()
    with pytest.warns(DeprecationWarning, match="'ekf' is deprecated.*'ukf'"):
        est = make_estimator("ekf", system, 0.05, sigma=0.01)
    assert isinstance(est, UKFEstimator)


def test_fd_noise_vs_ukf_in_evaluation() -> None:
    protocol = ControlProtocol(horizon=600, settle_steps=100)
    rows, _ = evaluate_estimators(protocol, ["fd", "ukf"], [0.05], trials_per_regime=1, progress=False)
    by = {(r["estimator"], r["regime"]): r for r in rows}
    assert len(rows) == 12 and by[("fd", "all")]["n_trials"] == 5
    assert by[("fd", "all")]["velocity_error"] > 10 * by[("ukf", "all")]["velocity_error"]
    assert by[("fd", "all")]["effort"] > by[("ukf", "all")]["effort"]


def test_wrapper_passes_env_checker_and_runs() -> None:
    from gymnasium.utils.env_checker import check_env

    env = EnergyCasimirWrapper(gym.make("PHAST/DampedPendulum-v0", obs_noise_std=0.01), estimator="map", k_c=2.0, d_inj=0.5)
    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=0, options={"state": np.array([1.0, 0.0])})
    for _ in range(200):
        obs, _, _, _, info = env.step(np.zeros(1, dtype=np.float32))
    assert {"u", "xi", "y_hat", "v_ext"} <= set(info)
    assert abs(phast_gym.wrap(info["state"][0])) < 1.0


def test_bad_gains_and_targets_are_refused() -> None:
    system = phast_gym.make_env_system("PHAST/Pendulum-v0")
    est = make_estimator("oracle", system, 0.01)
    with pytest.raises(ValueError, match="negative"):
        EnergyCasimirController(est, 0.0, k_c=-1.0, d_inj=0.5)
    with pytest.raises(ValueError, match="negative"):
        EnergyCasimirController(est, 0.0, k_c=1.0, d_inj=-0.5)
    with pytest.raises(ValueError, match="m g l"):
        EnergyCasimirController(est, math.pi, k_c=5.0, d_inj=0.5)  # m g l = 9.81
    EnergyCasimirController(est, math.pi, k_c=15.0, d_inj=0.5)  # upright is fine above m g l
    with pytest.raises(ValueError, match="not an equilibrium"):
        EnergyCasimirController(est, 1.0, k_c=5.0, d_inj=0.5)
    with pytest.raises(ValueError, match="k_xi"):
        EnergyCasimirController(est, 0.0, k_c=1.0, d_inj=0.5, k_xi=500.0)
    with pytest.raises(ValueError, match="finite"):
        EnergyCasimirController(est, 0.0, k_c=float("nan"), d_inj=0.5)


def test_unknown_estimator_and_missing_info() -> None:
    system = phast_gym.make_env_system("PHAST/Pendulum-v0")
    with pytest.raises(ValueError, match="unknown port estimator 'kalman'.*valid names"):
        make_estimator("kalman", system, 0.01)
    with pytest.raises(ValueError, match="info"):
        make_estimator("oracle", system, 0.01).update(np.zeros(1), None)
    with pytest.raises(ValueError, match="sigma"):
        make_estimator("map", system, 0.01, sigma=-1.0)
    with pytest.raises(ValueError, match="unknown port estimator 'nope'"):
        EnergyCasimirWrapper(gym.make("PHAST/Pendulum-v0"), estimator="nope")
    with pytest.raises(gym.error.ResetNeeded):
        EnergyCasimirWrapper(gym.make("PHAST/Pendulum-v0"), estimator="fd").step(np.zeros(1, dtype=np.float32))


def test_upright_stabilisation() -> None:
    protocol = ControlProtocol(env_id="PHAST/DampedPendulum-v0", horizon=1000, q_star=math.pi, k_c=20.0, d_inj=3.0,
                               settle_steps=100)
    rows, _ = evaluate_estimators(protocol, ["oracle"], [0.0], trials_per_regime=1, progress=False)
    assert next(r for r in rows if r["regime"] == "all")["success_rate"] == 1.0


def test_tcn_numpy_inference_matches_torch() -> None:
    torch = pytest.importorskip("torch")
    from phast_model.control import TCNEstimator, TCNObserverConfig, train_tcn_observer

    protocol = ControlProtocol()
    cfg = TCNObserverConfig(noise_mode="conditioned", n_traj=5, traj_steps=200, crop=80, iters=3, batch_size=4)
    model, report = train_tcn_observer(protocol, cfg)
    assert math.isfinite(report["final_loss"])
    system = make_control_env(protocol).unwrapped.system
    est = TCNEstimator(system, protocol.dt, model, sigma=0.02)
    q = phast_gym.wrap(np.cumsum(np.random.default_rng(0).normal(0, 0.05, (70, 1)), 0) + 3.0)
    out = np.array([est.update(v) for v in q])
    with torch.no_grad():
        ref = model(torch.as_tensor(q)[None], torch.tensor([0.02], dtype=torch.float64))[0].numpy()
    w = model.window
    np.testing.assert_allclose(out[w:], ref[w:], atol=1e-9)


def test_cli_writes_results(tmp_path) -> None:
    from phast_model.cli.control_eval import main

    out = tmp_path / "ce"
    rc = main(["--estimators", "oracle,fd", "--sigma", "0,0.05", "--trials-per-regime", "1", "--horizon", "300",
               "--out", str(out), "--no-progress"])
    assert rc == 0
    rows = json.loads((out / "results.json").read_text())
    assert len(rows) == 2 * 2 * 6
    assert {"sigma", "estimator", "regime", "n_trials", "success_rate", "final_error", "effort", "velocity_error"} <= set(rows[0])
    assert (out / "results.md").read_text().count("| 0.05 |") >= 2
    assert (out / "success_by_regime.png").is_file() and (out / "traces_sigma0.05.png").is_file()
    assert main(["--estimators", "oracle,bogus", "--out", str(out)]) == 2
    assert main(["--estimators", "oracle", "--sigma", "-1", "--out", str(out)]) == 2


def test_phast_estimators_with_untrained_model() -> None:
    torch = pytest.importorskip("torch")
    from phast_model.control import PHASTModelEstimator, PHASTObserverEstimator
    from phast_model.world.regimes import build_model

    model = build_model("PHAST/DampedPendulum-v0", "known").eval()
    system = make_control_env(ControlProtocol()).unwrapped.system
    obs_est = PHASTObserverEstimator(system, 0.01, model)
    assert obs_est.stride == round(model.observer.dt / 0.01)
    q = 0.5 + 1.2 * np.arange(60) * 0.01
    outs = np.array([obs_est.update(np.array([v])) for v in q])
    assert np.all(np.isfinite(outs))
    with torch.no_grad():
        ref = model.observer(torch.as_tensor(q[::-obs_est.stride][::-1].copy(), dtype=next(model.parameters()).dtype)[None, :, None])
    np.testing.assert_allclose(outs[-1, 0], float(ref[0, -1, 0]), rtol=1e-5, atol=1e-6)
    full = PHASTModelEstimator(system, 0.01, model)
    v = full.update(np.zeros(1), {"state": np.array([0.3, 1.5])})
    with torch.no_grad():
        dt_ = next(model.parameters()).dtype
        v_ref = model.velocity(torch.tensor([[0.3]], dtype=dt_), torch.tensor([[1.5]], dtype=dt_))
    np.testing.assert_allclose(v, v_ref[0].double().numpy(), rtol=1e-6)
    with pytest.raises(ValueError, match="divide"):
        PHASTObserverEstimator(make_control_env(ControlProtocol(dt=0.03)).unwrapped.system, 0.03, model)
    with pytest.raises(ValueError, match="phast-run"):
        make_estimator("phast-model", system, 0.01)


def test_phast_ukf_process_model_is_the_learned_core() -> None:
    """phast-ukf predicts with the PHAST run: at the run's dt one interval is the model's own step; at the control
    rate, on an exact (frictionless KNOWN) model, it agrees with the plant physics and the closed loop tracks qdot."""
    torch = pytest.importorskip("torch")
    from phast_gym.control.estimators import PlantPhysics
    from phast_model.control import PHASTProcess, phast_ukf
    from phast_model.world.regimes import build_model

    model = build_model("PHAST/Pendulum-v0", "known", damping="none").eval()
    dtype = next(model.parameters()).dtype
    X = np.array([[0.3, 1.5], [-2.0, -0.4], [3.0, 2.0]])
    u = np.array([0.7])
    coarse = PHASTProcess(model, model.dt)
    with torch.no_grad():
        q1, p1 = model.step(torch.as_tensor(X[:, :1], dtype=dtype), torch.as_tensor(X[:, 1:], dtype=dtype),
                            torch.full((3, 1), 0.7, dtype=dtype))
    np.testing.assert_allclose(coarse.propagate(X, u), torch.cat([q1, p1], -1).double().numpy(), rtol=1e-6, atol=1e-6)
    protocol = ControlProtocol(env_id="PHAST/Pendulum-v0", horizon=400, k_c=0.7, d_inj=0.5, settle_steps=10)
    system = make_control_env(protocol).unwrapped.system
    fine = PHASTProcess(model, protocol.dt)
    assert fine.substeps >= 1 and fine.dt == protocol.dt
    np.testing.assert_allclose(fine.propagate(X, u), PlantPhysics(system, protocol.dt).propagate(X, u), atol=2e-5)
    np.testing.assert_allclose(fine.velocity(X[0]), system.velocity([0.3], [1.5], __import__("phast_gym").systems.SCALAR),
                               rtol=1e-6)
    env = make_control_env(protocol, 0.05)
    est = make_estimator("phast-ukf", system, protocol.dt, sigma=0.05, run=model)
    assert est.name == "phast-ukf" and isinstance(est.process, PHASTProcess)
    ctrl = EnergyCasimirController(est, 0.0, 0.7, 0.5, 5.0, dt=protocol.dt, max_action=protocol.max_action, system=system)
    ep = run_episode(env, ctrl, np.array([2.5, 1.0]), seed=3, protocol=protocol)
    assert np.mean(np.abs(ep.y_hat[50:, 0] - ep.qdot[50:, 0])) < 0.1
    with pytest.raises(ValueError, match="n = 2"):
        phast_ukf(system, protocol.dt, build_model("PHAST/DoublePendulum-v0", "known").eval())
    with pytest.raises(ValueError, match="PHASTCore"):
        PHASTProcess(build_model("PHAST/PredatorPrey-v0", "known").eval(), 0.01)


def test_cli_bad_estimators_and_unwritable_out_fail_before_evaluating(tmp_path, capsys, monkeypatch) -> None:
    import phast_model.cli.control_eval as ce

    monkeypatch.setattr(ce, "evaluate_estimators", lambda *a, **k: pytest.fail("evaluation started"))
    assert ce.main(["--estimators", "", "--out", str(tmp_path / "a")]) == 2
    assert "--estimators is empty" in capsys.readouterr().err
    assert ce.main(["--estimators", " , ", "--out", str(tmp_path / "a")]) == 2
    (tmp_path / "file").write_text("x")
    assert ce.main(["--estimators", "oracle", "--out", str(tmp_path / "file" / "sub")]) == 2
    assert "cannot write to --out" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_lqg_torque_floor_upright(monkeypatch) -> None:
    # phast_model.control.lqg_bound (benchmarks/control_lqg_bound.py): no causal q-only controller holds the upright
    # with less stationary RMS torque than the LQG limit; it scales with sigma, and Energy-Casimir gains on the Kalman
    # estimate sit above it.
    from phast_model.control import lqg_bound as mod

    a, b = mod.linearise("PHAST/DampedPendulum-v0", math.pi, 0.01)
    lo1, lo5 = mod.torque_floor(a, b, 0.01), mod.torque_floor(a, b, 0.05)
    assert lo5["rms_torque"] == pytest.approx(5 * lo1["rms_torque"], rel=1e-3)
    assert 0.4 < lo5["rms_torque"] < 0.5  # above the protocol's u_tol = 0.25 at sigma = 0.05
    for gains in [(20.0, 3.0), (45.0, 3.0), (12.0, 1.0)]:
        assert mod.torque_floor(a, b, 0.05, gains=gains)["rms_torque"] >= lo5["rms_torque"] - 1e-9
    a0, b0 = mod.linearise("PHAST/DampedPendulum-v0", 0.0, 0.01)  # stable equilibrium: no floor
    assert mod.torque_floor(a0, b0, 0.05)["rms_torque"] < 1e-3
    # the floor caps the success rule: at sigma = 0.05 the minimum-torque loop passes few 1-s windows, at 0.01 all
    lqg1, lqg5 = mod.closed_loop(a, b, 0.01), mod.closed_loop(a, b, 0.05)
    assert mod.window_pass_rate(lqg1, n=2000)["pass"] > 0.98
    rate5 = mod.window_pass_rate(lqg5, n=2000)
    assert rate5["pass"] < 0.25 and rate5["pass"] <= min(rate5["pass_torque"], rate5["pass_angle"])
    unstable = mod.closed_loop(a, b, 0.05, gains=(1.0, 0.1))  # k_q below m g l: no stationary loop
    assert unstable.s is None and mod.window_pass_rate(unstable)["pass"] == 0.0


def test_learned_model_summary_reads_the_eval_directories(tmp_path) -> None:
    # phast_model.control.learned_model (benchmarks/control_learned_model.py): one row per (target, sigma, process
    # model), the plant UKF once per target, run labels from the directory names, and a linearisation of a run that
    # matches the plant for the KNOWN model
    import json

    from phast_model.control import learned_model as mod

    assert mod.label("partial_excited") == "PHAST PARTIAL, excited port"
    assert mod.label("unknown") == "PHAST UNKNOWN"

    def row(est: str, success: float) -> dict:
        return {"regime": "all", "estimator": est, "sigma": 0.05, "n_trials": 50, "success_rate": success,
                "success_angle_rate": 1.0, "u_rms_final": 0.1, "effort": 1.0, "velocity_error": 0.01}

    for name, q_star, rows in [("windy_q0_known", 0.0, [row("ekf", 1.0), row("phast-ukf", 0.9), row("map", 1.0)]),
                               ("windy_up_partial_excited", math.pi, [row("ukf", 0.7), row("phast-ukf", 0.5)])]:
        (tmp_path / name).mkdir()
        (tmp_path / name / "protocol.json").write_text(json.dumps({"q_star": q_star}))
        (tmp_path / name / "results.json").write_text(json.dumps(rows))
    got = {(r.target, r.process_model): r.success for r in mod.summarize_runs(tmp_path, {})[0]}
    assert got == {("hanging (q* = 0)", "plant physics"): 1.0, ("hanging (q* = 0)", "PHAST KNOWN"): 0.9,
                   ("upright (q* = pi)", "plant physics"): 0.7,  # stored results name it "ekf" (before) or "ukf"
                   ("upright (q* = pi)", "PHAST PARTIAL, excited port"): 0.5}
    from phast_model.train.checkpoint import save_run
    from phast_model.world.regimes import build_model

    save_run(build_model("PHAST/WindyPendulum-v0", "known"), tmp_path / "run")
    lin = mod.linearised(tmp_path / "run")  # KNOWN's V and M are the plant's
    for k in ("stiffness_0", "stiffness_pi", "port_gain"):
        assert lin[k] == pytest.approx(lin[f"true_{k}"], rel=1e-4)
