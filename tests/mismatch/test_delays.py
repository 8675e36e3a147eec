"""Delays in the vocabulary (issue 41): ``input_delay`` (the port delivers u(t - d)) and ``sensor_delay`` (the sensor
reports q_i(t - d)), in seconds, fractions of a sample by linear interpolation, applied around the simulation."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from phast_gym.registry import make_env_system
from phast_gym.systems.pendulum import Pendulum
from phast_model.bench.reality import make_reality
from phast_model.identify.delays import HISTORY, MAX_DELAY_SAMPLES
from phast_model.identify.recordings import Recordings
from phast_model.identify.shooting import Shooter, Windows, simulate_qv
from phast_model.mismatch import AugmentedSystem, Term, analyze
from phast_model.mismatch.vocabulary.registry import VOCABULARY, ScaleContext

DT = 0.01


class Pendulum100Hz(Pendulum):
    """The env pendulum sampled at 100 Hz (the reality of the input-delay case; the tool is given PHAST/Pendulum-v0)."""

    dt, substeps = 0.01, 1


def _inputs(B: int, K: int, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(B, K + HISTORY, n))
    return u[:, HISTORY:], u[:, :HISTORY]


def test_the_delays_are_registered_terms():
    for name, component in (("input_delay", "port"), ("sensor_delay", "sensor")):
        kind = VOCABULARY[name]
        assert kind.component == component and kind.delay and kind.mjcf is None and "MuJoCo has no" in kind.mjcf_advice
        assert kind.regression_column(np.zeros(3), np.zeros(3), np.ones(3), 1.0) is None  # not in the PySINDy library
        with pytest.raises(ValueError, match=">= 0"):
            Term(name, 0, -0.01)
    assert Term("input_delay", 0, 0.03).expression() == "port delivers u0(t - 0.03 s)"
    ctx = ScaleContext(np.zeros(5), np.ones(5), 1.0, 1.0, 1e-3, 1e-2, np.ones(5), True, DT, 1)
    assert [s.scale for s in VOCABULARY["input_delay"].scales(ctx)] == [DT]  # z = 1 is one sample
    assert VOCABULARY["sensor_delay"].scales(ctx) == []  # one coordinate: a sensor delay is an input delay
    assert VOCABULARY["input_delay"].scales(replace(ctx, u=None)) == []  # no input, no input delay


@pytest.mark.parametrize("delay_samples", [3.0, 2.4, 0.5])
def test_an_input_delay_simulates_the_shifted_input(delay_samples):
    """Whole samples: the recorded u shifted by that many samples; a fraction f of a sample: the interval average of the
    delayed zero-order hold, (1 - f) u[k - m] + f u[k - m - 1]."""
    base = make_env_system("PHAST/Pendulum-v0")
    B, K = 4, 60
    u, before = _inputs(B, K, 1)
    rng = np.random.default_rng(1)
    q0, v0 = rng.normal(size=(B, 1)), rng.normal(size=(B, 1))
    delayed = AugmentedSystem(base, [Term("input_delay", 0, delay_samples * DT)])
    got = simulate_qv(delayed, q0, v0, K, u, DT, 2, before)
    ext = np.concatenate([before, u], axis=1)
    m, f = int(np.floor(delay_samples)), delay_samples - np.floor(delay_samples)
    k = np.arange(K) + HISTORY
    shifted = (1 - f) * ext[:, k - m] + f * ext[:, k - m - 1]
    want = simulate_qv(AugmentedSystem(base, []), q0, v0, K, shifted, DT, 2)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_a_sensor_delay_reports_the_earlier_state_of_its_coordinate_only():
    base = make_env_system("PHAST/DoublePendulum-v0")
    B, K = 3, 80
    u, before = _inputs(B, K, 2, seed=2)
    rng = np.random.default_rng(3)
    q0, v0 = 0.5 * rng.normal(size=(B, 2)), rng.normal(size=(B, 2))
    true = simulate_qv(AugmentedSystem(base, []), q0, v0, K, u, DT, 3, before)
    got = simulate_qv(AugmentedSystem(base, [Term("sensor_delay", 1, 2 * DT)]), q0, v0, K, u, DT, 3, before)
    np.testing.assert_array_equal(got[..., 0], true[..., 0])
    np.testing.assert_allclose(got[:, 2:, 1], true[:, :-2, 1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[:, :2, 1], q0[:, 1:] - v0[:, 1:] * np.array([2 * DT, DT]), atol=1e-12)  # extrapolated back
    half = simulate_qv(AugmentedSystem(base, [Term("sensor_delay", 1, 0.5 * DT)]), q0, v0, K, u, DT, 3, before)
    np.testing.assert_allclose(half[:, 1:, 1], 0.5 * (true[:, 1:, 1] + true[:, :-1, 1]), atol=1e-12)


def test_a_delay_is_bounded_by_the_history():
    base = make_env_system("PHAST/Pendulum-v0")
    u, before = _inputs(2, 30, 1)
    q0, v0 = np.zeros((2, 1)), np.zeros((2, 1))
    at_bound = simulate_qv(AugmentedSystem(base, [Term("input_delay", 0, MAX_DELAY_SAMPLES * DT)]), q0, v0, 30, u, DT, 2, before)
    beyond = simulate_qv(AugmentedSystem(base, [Term("input_delay", 0, 3 * MAX_DELAY_SAMPLES * DT)]), q0, v0, 30, u, DT, 2, before)
    assert np.all(np.isfinite(beyond))
    np.testing.assert_allclose(beyond[:, :-1], at_bound[:, :-1], atol=1e-12)  # clipped to HISTORY samples at most


def test_the_windows_carry_the_recorded_inputs_before_them():
    rng = np.random.default_rng(4)
    q, u = rng.normal(size=(2, 50, 1)), rng.normal(size=(2, 49, 1))
    w = Windows.cut(Recordings(q=q, dt=DT, u=u), 20)
    assert w.u_before is not None and w.u_before.shape == (w.count, HISTORY, 1)
    np.testing.assert_array_equal(w.u_before[0], np.repeat(u[0, :1], HISTORY, axis=0))  # before the recording: u[0] held
    np.testing.assert_array_equal(w.u_before[1], u[0, 20 - HISTORY:20])


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), sensor=st.booleans(), n_windows=st.integers(1, 4))
def test_a_zero_delay_reproduces_the_undelayed_residual_exactly(seed, sensor, n_windows):
    base = make_env_system("PHAST/DoublePendulum-v0")
    rng = np.random.default_rng(seed)
    L = 25
    T = n_windows * L
    q = 0.3 * rng.normal(size=(2, T, 2))
    u = rng.normal(size=(2, T - 1, 2))
    w = Windows.cut(Recordings(q=q, dt=DT, u=u), L)
    shooter = Shooter(w, np.full(2, 0.01), 3, np.ones(4))
    X = np.concatenate([w.q[:, 0], rng.normal(size=(w.count, 2))], axis=1)
    zero = [Term("input_delay", 0, 0.0), Term("input_delay", 1, 0.0)] + ([Term("sensor_delay", 1, 0.0)] if sensor else [])
    np.testing.assert_array_equal(shooter.residual(AugmentedSystem(base, zero), X), shooter.residual(AugmentedSystem(base, []), X))
    # merged with a delayed system (per-sample delay arrays), the zero-delay samples are still the undelayed ones
    both = shooter.residuals_of([AugmentedSystem(base, zero), AugmentedSystem(base, [Term("input_delay", 0, 0.02), *zero[1:]])], X)
    np.testing.assert_array_equal(both[0], shooter.residual(AugmentedSystem(base, []), X))


def test_the_tool_names_a_30ms_actuator_delay_at_100hz():
    """The bench's pendulum_input_delay case, smaller: the delay named, within 20%, and nothing else."""
    rec = make_reality(Pendulum100Hz, [Term("input_delay", 0, 0.03)], n_traj=16, T=300, noise_std=0.002, seed=3, u_std=1.0)
    rep = analyze("PHAST/Pendulum-v0", rec)
    found = {(m["term"], m["coordinate"]): m for m in rep.missing_physics}
    assert set(found) == {("input_delay", 0)}
    row = found[("input_delay", 0)]
    assert abs(row["coefficient"] - 0.03) <= 0.2 * 0.03
    assert row["ci95"][0] <= row["coefficient"] <= row["ci95"][1]
    assert rep.fit["augmented"]["rollout_rmse"] < 0.5 * rep.fit["calibrated"]["rollout_rmse"]
