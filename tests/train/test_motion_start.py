"""UNKNOWN's start from the recorded motion (phast_model.train.motion_start): the force balance fitted by the model's
own neural potential, mass and friction, before the multiple-shooting fit."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch

from phast_model.train.motion_start import MotionStartConfig, force_residual, motion_samples, motion_start
from phast_model.train.rig_fit import RigTrainConfig, build, load_rig_data, lr_mult, rig_config, window_rmse

SIM = "PHAST/DampedPendulum-v0"
G, B = 9.81, 0.1  # the recordings' pendulum: qddot = -G sin q - B qdot + u (unit inertia)


def _recordings(driven: bool, n_traj: int = 6, T: int = 400, dt: float = 0.01, seed: int = 0) -> dict[str, Any]:
    """A damped pendulum (RK4 at dt / 10) from random states, driven by smooth random torques or free; q with noise
    1e-4 rad."""
    rng = np.random.default_rng(seed)
    knots = rng.normal(0.0, 3.0, (n_traj, T // 20 + 2)) if driven else np.zeros((n_traj, T // 20 + 2))
    u = np.stack([np.interp(np.arange(T - 1) / 20, np.arange(knots.shape[1]), k) for k in knots])
    x = np.stack([rng.uniform(-2, 2, n_traj), rng.uniform(-2, 2, n_traj)], -1)
    f = lambda x, a: np.stack([x[:, 1], -G * np.sin(x[:, 0]) - B * x[:, 1] + a], -1)  # noqa: E731
    q, h = [x[:, 0].copy()], dt / 10
    for k in range(T - 1):
        for _ in range(10):
            k1 = f(x, u[:, k])
            k2 = f(x + h / 2 * k1, u[:, k])
            k3 = f(x + h / 2 * k2, u[:, k])
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + f(x + h * k3, u[:, k]))
        q.append(x[:, 0].copy())
    rec = {"q": np.stack(q, 1)[..., None] + rng.normal(0.0, 1e-4, (n_traj, T, 1)), "dt": dt, "angle_dims": np.array([0])}
    if driven:
        rec["u"] = u[..., None]
    return rec


@pytest.fixture(scope="module", params=[True, False], ids=["driven", "free"])
def started(request: pytest.FixtureRequest) -> tuple[Any, Any, dict[str, float], float]:
    torch.set_num_threads(1)
    data = load_rig_data(_recordings(request.param), SIM, {}, [5])
    model = build(rig_config(SIM, {}, "unknown", data)).double()
    raw = window_rmse(model, data, RigTrainConfig(window_s=1.0))
    info = motion_start(model, data.train, lambda m: window_rmse(m, data, RigTrainConfig(window_s=1.0)),
                        MotionStartConfig(steps=600, polish_iters=100, window_taus=(0.5, 1.0)))
    return model, data, info, raw


def test_unknown_starts_from_the_recorded_motion() -> None:
    data = load_rig_data(_recordings(True, n_traj=2, T=100), SIM, {}, None)
    assert rig_config(SIM, {}, "unknown", data).init_from == "motion"
    model = build(rig_config(SIM, {}, "unknown", data))
    assert lr_mult(model, RigTrainConfig()) < 1.0  # a fitted network is refined, not relearned
    assert lr_mult(model, RigTrainConfig(lr_mult=1.0)) == 1.0
    assert lr_mult(build(rig_config(SIM, {}, "partial", data)), RigTrainConfig()) == 1.0


def test_the_start_explains_the_force_balance_and_keeps_the_best_window(started: tuple) -> None:
    model, data, info, _ = started
    residuals = [info[f"window_{k:g}tau_force_residual"] for k in (0.5, 1.0)]
    rmses = [info[f"window_{k:g}tau_rmse"] for k in (0.5, 1.0)]
    assert min(residuals) < 0.05  # of the typical force (a wide window smooths a driven motion: more)
    assert info["start_rmse"] == min(rmses)
    assert info["window_s"] == pytest.approx((0.5, 1.0)[rmses.index(min(rmses))] * info["time_scale_s"])
    assert window_rmse(model, data, RigTrainConfig(window_s=1.0)) == pytest.approx(info["start_rmse"])


def test_the_started_model_predicts_open_loop_windows(started: tuple) -> None:
    model, data, _, raw = started
    after = window_rmse(model, data, RigTrainConfig(window_s=1.0))
    assert after < 0.05 * raw
    assert after < 0.05  # rad, 1-s open-loop windows of swings up to 2 rad


def test_the_learned_physics_is_the_pendulum_s_up_to_the_free_scale(started: tuple) -> None:
    """dV/dq over M is G sin q whatever the scale; with a port input the scale itself (unit inertia) is found."""
    model, data, _, _ = started
    q = torch.linspace(-1.5, 1.5, 31, dtype=torch.float64)[:, None]
    with torch.no_grad():
        m = float(model.mass.matrix(q[:1])[0, 0, 0])
        ratio = model.potential.grad(q)[:, 0] / m
    assert torch.allclose(ratio, G * torch.sin(q[:, 0]), atol=0.05 * G)
    if data.driven:  # the friction: the true viscous law within 0.08 N m (2% of the typical force, the residual's
        # scale) over the recorded speeds; Coulomb and viscous trade off a little, the shooting fit refines them
        assert m == pytest.approx(1.0, rel=0.05)
        v = torch.linspace(0.5, 3.0, 11, dtype=torch.float64)[:, None]
        with torch.no_grad():
            assert torch.allclose(model.friction.force(v), B * v, atol=0.08)


def test_samples_are_interior_and_aligned_with_the_held_input() -> None:
    data = load_rig_data(_recordings(True, n_traj=2, T=100), SIM, {}, None)
    s = motion_samples(data.train, 0.1)
    assert s.f is not None and s.q.shape == s.v.shape == s.a.shape == s.f.shape
    assert len(s) <= 2 * 100
    model = build(rig_config(SIM, {}, "unknown", data)).double()
    assert force_residual(model, s).shape == s.q.shape


def test_the_start_is_kept_when_training_does_not_beat_it_on_held_in_windows(monkeypatch: pytest.MonkeyPatch) -> None:
    """fit_recordings scores the start and the trained model on the same held-in validation windows and keeps the
    better: a training at 50x the rates wrecks the model, and the start's weights come back (best epoch 0)."""
    import phast_model.train.motion_start as ms
    from phast_model.train.rig_fit import fit_recordings

    torch.set_num_threads(1)
    monkeypatch.setattr(ms, "MotionStartConfig", lambda: MotionStartConfig(steps=400, polish_iters=50, window_taus=(1.0,)))
    data = load_rig_data(_recordings(False, n_traj=4, T=300), SIM, {}, [3])
    cfg = RigTrainConfig(window_s=1.0, epochs=2, lr_mult=50.0, patience=None, progress=False)
    fit = fit_recordings(build(rig_config(SIM, {}, "unknown", data)), data, cfg)
    assert fit.init["trained_rmse"] > fit.init["start_rmse"]
    assert fit.best_epoch == 0 and fit.best_val == fit.init["start_rmse"]
    assert window_rmse(fit.model, data, cfg) == pytest.approx(fit.init["start_rmse"], rel=1e-6)
