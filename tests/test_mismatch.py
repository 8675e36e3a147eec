"""Tests of the simulation-vs-reality mismatch tool (small synthetic cases, fast)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from phast_gym.registry import make_env_system
from phast_model.mismatch import AugmentedSystem, Term, analyze, make_reality, validate
from phast_model.mismatch.shooting import estimate_noise


@pytest.fixture(scope="module")
def coulomb_data() -> dict:
    return make_reality("PHAST/Pendulum-v0", [Term("coulomb_friction", 0, 0.1)], n_traj=12, T=300, noise_std=0.01, seed=3)


@pytest.fixture(scope="module")
def coulomb_report(coulomb_data):
    return analyze("PHAST/Pendulum-v0", coulomb_data)


def test_clean_recordings_give_no_missing_physics():
    rec = make_reality("PHAST/DampedPendulum-v0", [], n_traj=12, T=300, noise_std=0.01, seed=5)
    rep = analyze("PHAST/DampedPendulum-v0", rec)
    assert rep.missing_physics == []
    assert "No missing physics" in rep.summary
    assert rep.located == []
    # the calibrated parameters stay at the truth
    assert abs(rep.sim["calibrated"]["gamma"]["fitted"] - 0.5) / 0.5 < 0.05


def test_parameter_error_is_calibrated_not_missing_physics():
    rec = make_reality("PHAST/DampedPendulum-v0", [], true_kwargs={"gamma": 0.42}, n_traj=12, T=300, noise_std=0.01, seed=6)
    rep = analyze("PHAST/DampedPendulum-v0", rec)
    assert rep.missing_physics == []
    cal = rep.sim["calibrated"]["gamma"]
    assert abs(cal["fitted"] - 0.42) / 0.42 < 0.05
    assert cal["ci95"][0] < cal["fitted"] < cal["ci95"][1]


def test_concealed_coulomb_friction_is_found(coulomb_report):
    rep = coulomb_report
    assert [(m["term"], m["coordinate"]) for m in rep.missing_physics] == [("coulomb_friction", 0)]
    m = rep.missing_physics[0]
    assert m["component"] == "dissipation"
    assert abs(m["coefficient"] - 0.1) / 0.1 < 0.15
    assert m["ci95"][0] < m["coefficient"] < m["ci95"][1] and m["ci95"][0] > 0
    # the augmented model predicts held-out recordings better than the calibrated one
    assert rep.fit["augmented"]["rollout_rmse"] < 0.7 * rep.fit["calibrated"]["rollout_rmse"]
    assert rep.located and rep.located[0]["component"] == "dissipation" and rep.located[0]["removes_energy"]
    # noise level reported
    assert abs(rep.data["noise_std"] - 0.01) < 0.002


def test_answer_is_stable_across_smoothing_choices(coulomb_data, coulomb_report):
    """Smoothing only seeds the shooting fit: term set and coefficient do not move with the filter or window."""
    ref = coulomb_report.missing_physics[0]["coefficient"]
    for sg, L in ((5, 20), (21, 40), (41, 60)):
        rep = analyze("PHAST/Pendulum-v0", coulomb_data, smoothing_window=sg, shoot_window=L)
        assert [(m["term"], m["coordinate"]) for m in rep.missing_physics] == [("coulomb_friction", 0)], (sg, L)
        assert abs(rep.missing_physics[0]["coefficient"] - ref) / ref < 0.1, (sg, L)


def test_constant_force_on_linear_oscillator_names_sensor_offset_alternative():
    rec = make_reality("PHAST/DampedOscillator-v0", [Term("constant_force", 0, 0.15)], n_traj=10, T=250, noise_std=0.01, seed=2)
    rep = analyze("PHAST/DampedOscillator-v0", rec, terms=("constant_force", "sensor_offset", "viscous_damping"))
    assert len(rep.missing_physics) == 1
    m = rep.missing_physics[0]
    assert m["coordinate"] == 0 and m["term"] in ("constant_force", "sensor_offset")
    other = "sensor_offset" if m["term"] == "constant_force" else "constant_force"
    assert any(a.get("term") == other for a in m["alternatives"])
    assert "cannot tell" in rep.summary


def test_report_schema_and_files(coulomb_report, tmp_path):
    d = coulomb_report.to_dict()
    assert set(d) >= {"sim", "data", "located", "missing_physics", "fit", "summary"}
    assert set(d["sim"]) >= {"env_id", "kwargs", "calibrated"}
    assert set(d["data"]) >= {"n_traj", "T", "dt", "noise_std"}
    for loc in d["located"]:
        assert set(loc) >= {"coordinate", "component", "where", "share"}
    for m in d["missing_physics"]:
        assert set(m) >= {"term", "coordinate", "component", "coefficient", "ci95", "expression", "explains"}
    for name in ("nominal", "calibrated", "augmented"):
        assert set(d["fit"][name]) == {"one_step_mse", "rollout_rmse"}
        assert all(math.isfinite(v) for v in d["fit"][name].values())
    assert d["fit"]["evaluated_on"]
    out = coulomb_report.write(tmp_path / "rep")
    loaded = json.loads((out / "report.json").read_text())
    assert loaded["missing_physics"][0]["term"] == "coulomb_friction"
    for f in ("report.md", "residual_map.png", "heldout_fit.png", "decay.png"):
        assert (out / f).stat().st_size > 0
    # rewriting replaces the directory atomically, nothing left behind
    coulomb_report.write(out, plots=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep"]


def test_augmented_system_stays_passive():
    base = make_env_system("PHAST/Pendulum-v0")
    aug = AugmentedSystem(base, [Term("coulomb_friction", 0, 0.2), Term("quadratic_drag", 0, 0.1),
                                 Term("position_dependent_damping", 0, 0.3), Term("linear_stiffness", 0, 0.5),
                                 Term("stribeck_friction", 0, 0.1, velocity=0.3)])
    rng = np.random.default_rng(0)
    q, p = rng.normal(size=(1, 500)), rng.normal(size=(1, 500)) * 3
    diss, _ = aug.power_balance((q[0],), (p[0],), None)
    assert np.all(diss >= 0)
    # dH/dt along the vector field equals minus the dissipated power (conservative part in H)
    qd, pd = aug.rhs((q[0],), (p[0],), None)
    dq = aug.dH_dq((q[0],), (p[0],))
    dH = dq[0] * qd[0] + aug.velocity((q[0],), (p[0],))[0] * pd[0]
    np.testing.assert_allclose(dH, -diss, rtol=1e-10, atol=1e-10)


def test_noise_estimate():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 20, 2000)
    q = np.sin(t)[None, :, None] + rng.normal(0, 0.003, size=(3, 2000, 1))
    assert abs(estimate_noise(q)[0] - 0.003) < 0.0005


# --------------------------------------------------------------------------- bad input
def _ok() -> dict:
    return make_reality("PHAST/Pendulum-v0", [], n_traj=3, T=100, noise_std=0.01, seed=1)


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.pop("q"), "missing key 'q'"),
    (lambda d: d.pop("dt"), "time base"),
    (lambda d: d.__setitem__("q", np.where(np.arange(100)[None, :, None] == 50, np.nan, d["q"])), "NaN"),
    (lambda d: d.__setitem__("q", d["q"][:, :10]), "too short"),
    (lambda d: d.__setitem__("q", np.concatenate([d["q"], d["q"]], -1)), "n=2"),
    (lambda d: d.__setitem__("q", d["q"][..., 0][..., None, None]), "shape"),
    (lambda d: (d.pop("dt"), d.__setitem__("t", np.r_[np.arange(99) * 0.05, 4.9])), "not strictly increasing"),
    (lambda d: d.__setitem__("u", np.zeros((3, 50, 1))), "'u' must have shape"),
])
def test_bad_recordings_raise_clear_errors(mutate, match):
    d = _ok()
    mutate(d)
    with pytest.raises(ValueError, match=match):
        analyze("PHAST/Pendulum-v0", d)


def test_unknown_env_and_bad_kwargs():
    with pytest.raises(ValueError, match="unknown simulator"):
        analyze("PHAST/NoSuchThing-v0", _ok())
    with pytest.raises(ValueError, match="sim-kwargs"):
        analyze("PHAST/Pendulum-v0", _ok(), sim_kwargs={"lenght": 1.0})
    with pytest.raises(ValueError, match="not a port-Hamiltonian"):
        analyze("PHAST/PredatorPrey-v0", _ok())


def test_cli_bad_input_leaves_nothing(tmp_path, capsys):
    from phast_model.cli.mismatch import main

    d = _ok()
    d["q"][0, 3, 0] = np.nan
    np.savez(tmp_path / "bad.npz", **d)
    rc = main(["--sim", "PHAST/Pendulum-v0", "--recordings", str(tmp_path / "bad.npz"), "--out", str(tmp_path / "out"), "--quiet"])
    assert rc == 2
    assert "NaN" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npz"]
    rc = main(["--sim", "PHAST/Pendulum-v0", "--recordings", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "out")])
    assert rc == 2


def test_csv_recordings_roundtrip(tmp_path):
    d = _ok()
    q = d["q"]
    rows = ["traj,t,q0"] + [f"{k},{i * d['dt']:.6f},{q[k, i, 0]:.10f}" for k in range(q.shape[0]) for i in range(q.shape[1])]
    (tmp_path / "r.csv").write_text("\n".join(rows) + "\n")
    from phast_model.mismatch import load_raw

    raw, _ = load_raw(tmp_path / "r.csv")
    rec = validate(raw, 1, (0,))
    assert rec.q.shape == q.shape and abs(rec.dt - d["dt"]) < 1e-9
    np.testing.assert_allclose(np.sin(rec.q), np.sin(q), atol=1e-8)


def test_angle_offset_convention():
    d = _ok()
    shifted = dict(d, q=d["q"] - math.pi, angle_offset=math.pi)  # recorded with 0 upright, pi hanging
    a = validate(d, 1, (0,))
    b = validate(shifted, 1, (0,))
    np.testing.assert_allclose(np.sin(a.q), np.sin(b.q), atol=1e-12)


def test_unexplained_residual_is_located_when_no_term_fits():
    """A bias torque with only friction terms allowed: nothing passes, the residual is located as a potential force."""
    rec = make_reality("PHAST/DampedPendulum-v0", [Term("constant_force", 0, 0.4)], n_traj=10, T=250, noise_std=0.01, seed=8)
    rep = analyze("PHAST/DampedPendulum-v0", rec, terms=("viscous_damping", "coulomb_friction"))
    assert rep.missing_physics == []
    assert "Unexplained residual" in rep.summary
    assert rep.located and rep.located[0]["coordinate"] == 0 and rep.located[0]["component"] == "potential"


def _energy_balance_on_pendulum_reality(truth: list) -> dict:
    """Terms the energy balance finds on 8 pendulum recordings (encoder-grade noise) with ``truth`` hidden in them."""
    from phast_model.mismatch.energy import energy_balance

    raw = make_reality("PHAST/Pendulum-v0", truth, n_traj=8, T=600, noise_std=1e-3, seed=1, x0_scale=0.7)
    eb = energy_balance(make_env_system("PHAST/Pendulum-v0"), validate(raw, 1, (0,)), 7, 0.01)
    return {t["term"]: t for t in eb.terms}


def test_energy_balance_recovers_dissipation_despite_sensor_errors():
    """The weak-form energy balance picks Coulomb + quadratic drag (right coefficients) under an encoder offset and eccentricity."""
    found = _energy_balance_on_pendulum_reality([Term("coulomb_friction", 0, 0.05), Term("quadratic_drag", 0, 0.005),
                                                 Term("sensor_eccentricity", 0, 0.02), Term("sensor_offset", 0, 0.02)])
    assert set(found) == {"coulomb_friction", "quadratic_drag"}
    assert abs(found["coulomb_friction"]["coefficient"] - 0.05) / 0.05 < 0.1
    assert abs(found["quadratic_drag"]["coefficient"] - 0.005) / 0.005 < 0.1
    for t in found.values():
        assert t["ci95"][0] > 0


def test_stribeck_term_needs_its_velocity():
    with pytest.raises(ValueError, match="Stribeck velocity"):
        Term("stribeck_friction", 0, 0.1)
    assert "exp(-(qdot0/0.3)**2)" in Term("stribeck_friction", 0, 0.1, velocity=0.3).expression()


def test_energy_balance_finds_stribeck_friction():
    """Extra static friction near velocity reversals is told apart from plain Coulomb friction, with its v_s profiled."""
    found = _energy_balance_on_pendulum_reality([Term("coulomb_friction", 0, 0.03), Term("stribeck_friction", 0, 0.06, velocity=0.4)])
    assert set(found) == {"coulomb_friction", "stribeck_friction"}
    assert abs(found["coulomb_friction"]["coefficient"] - 0.03) / 0.03 < 0.1
    assert abs(found["stribeck_friction"]["coefficient"] - 0.06) / 0.06 < 0.3
    assert 0.4 / 1.5 < found["stribeck_friction"]["velocity"] < 0.4 * 1.5


def test_stribeck_friction_found_by_shooting():
    """Noise-dominated regime (shooting selection): Coulomb plus Stribeck friction, v_s refined from the grid."""
    raw = make_reality("PHAST/DampedOscillator-v0", [Term("coulomb_friction", 0, 0.02), Term("stribeck_friction", 0, 0.04, 0.5)],
                       n_traj=24, T=400, noise_std=0.01, seed=1)
    rep = analyze("PHAST/DampedOscillator-v0", raw)
    found = {m["term"]: m for m in rep.missing_physics}
    assert set(found) == {"coulomb_friction", "stribeck_friction"}
    assert abs(found["coulomb_friction"]["coefficient"] - 0.02) / 0.02 < 0.3
    assert abs(found["stribeck_friction"]["coefficient"] - 0.04) / 0.04 < 0.3
    assert 0.5 / 1.3 < found["stribeck_friction"]["stribeck_velocity"] < 0.5 * 1.3
    assert "exp(-(qdot0/" in found["stribeck_friction"]["expression"]


def test_energy_check_measures_missing_dissipation():
    """measured / predicted energy loss is 1 for the true model and 1/0.8 when its friction is 80% of the truth."""
    from phast_model.mismatch.energy import energy_check

    truth = [Term("coulomb_friction", 0, 0.03), Term("quadratic_drag", 0, 0.005)]
    rec = validate(make_reality("PHAST/Pendulum-v0", truth, n_traj=6, T=600, noise_std=1e-3, seed=4, x0_scale=0.7), 1, (0,))
    base = make_env_system("PHAST/Pendulum-v0")
    exact = energy_check(AugmentedSystem(base, truth, 0.01), rec, 7)
    low = energy_check(AugmentedSystem(base, [Term(t.name, 0, 0.8 * t.coefficient) for t in truth], 0.01), rec, 7)
    assert abs(exact["measured_over_predicted"] - 1.0) < 0.01 and exact["ci95"][0] < 1.0 < exact["ci95"][1] + 0.005
    assert abs(low["measured_over_predicted"] - 1.25) < 0.015 and low["ci95"][0] > 1.2
    assert energy_check(base, rec, 7) is None  # the undamped model dissipates nothing: no ratio


def test_energy_balance_finds_nothing_when_dissipation_is_right():
    from phast_model.mismatch.energy import energy_balance

    raw = make_reality("PHAST/DampedPendulum-v0", [Term("sensor_offset", 0, 0.03)], n_traj=8, T=600, noise_std=1e-3, seed=2, x0_scale=0.7)
    eb = energy_balance(make_env_system("PHAST/DampedPendulum-v0"), validate(raw, 1, (0,)), 7, 0.01)
    assert eb.terms == []
    assert abs(eb.damping_scale - 1.0) < 0.01


def test_systematic_regime_uses_energy_balance(coulomb_data):
    """Forcing the model-error regime: the energy balance finds the same friction, the better open-loop model is kept."""
    rep = analyze("PHAST/Pendulum-v0", coulomb_data, systematic_chi2=0.0)
    eb = rep.details["energy_balance"]
    assert [t["term"] for t in eb["terms"]] == ["coulomb_friction"]
    assert abs(eb["terms"][0]["coefficient"] - 0.1) / 0.1 < 0.1
    assert set(eb["training_rollout_rmse"]) >= {"energy-balance model", "shooting selection"}
    assert [m["term"] for m in rep.missing_physics] == ["coulomb_friction"]
    m = rep.missing_physics[0]
    assert abs(m["coefficient"] - 0.1) / 0.1 < 0.1 and m["ci95"][0] > 0
    assert rep.fit["augmented"]["rollout_rmse"] < 0.5 * rep.fit["calibrated"]["rollout_rmse"]
    assert rep.fit["rollout_window_samples"] == coulomb_data["q"].shape[1]


@pytest.mark.slow
@pytest.mark.parametrize("with_eccentricity", [False, True])
def test_encoder_grade_noise_friction_and_drag(with_eccentricity):
    """Encoder-grade noise (2e-5): Coulomb + quadratic drag (+ eccentricity) are found by the shooting selection,
    and forcing the model-error regime keeps that answer (its training rollout is not worse)."""
    terms = [Term("coulomb_friction", 0, 0.02), Term("quadratic_drag", 0, 0.002)]
    if with_eccentricity:
        terms.append(Term("sensor_eccentricity", 0, 0.01))
    d = make_reality("PHAST/DampedPendulum-v0", terms, n_traj=40, T=400, noise_std=2e-5, seed=0)
    want = {t.name for t in terms}
    for forced in (False, True):
        rep = analyze("PHAST/DampedPendulum-v0", d, **({"systematic_chi2": 0.0} if forced else {}))
        assert {m["term"] for m in rep.missing_physics} == want
        assert not rep.details["energy_balance"]["used"]
        for m in rep.missing_physics:
            true = next(t.coefficient for t in terms if t.name == m["term"])
            assert abs(m["coefficient"] - true) / true < 0.15


def test_rollout_window_cuts_heldout_into_consecutive_windows(coulomb_data):
    rep = analyze("PHAST/Pendulum-v0", coulomb_data, rollout_window=4.0)  # dt 0.05: 81-sample windows, 3 per 300-sample trajectory
    assert rep.fit["rollout_window_samples"] == 81
    assert rep.fit["rollout_n_windows"] == 4 * 3
    assert "consecutive windows" in rep.fit["rollout"]
    assert rep.fit["augmented"]["rollout_rmse"] < rep.fit["calibrated"]["rollout_rmse"]
    with pytest.raises(ValueError, match="rollout_window"):
        analyze("PHAST/Pendulum-v0", coulomb_data, rollout_window=0.1)
