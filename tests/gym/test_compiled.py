"""The compiled batched simulator (phast_gym.compiled) agrees with the NumPy one, kinks and overflow included."""

from __future__ import annotations

import numpy as np
import pytest

import phast_gym
import phast_gym.compiled as compiled
from phast_gym.integrate import simulate

pytest.importorskip("torch")


def test_smooth_system_with_port_matches_numpy_simulate() -> None:
    system = phast_gym.make_env_system("PHAST/Pendulum-v0")
    rng = np.random.default_rng(0)
    x0 = system.sample_initial(rng, 16)
    u = rng.uniform(-2.0, 2.0, (16, 12, 1))
    got = compiled.simulate_compiled(system, x0, 12, u)
    ref = simulate(system, x0, 12, u)
    assert got.shape == ref.shape == (16, 13, 2)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-11)


def test_kinked_damping_gathered_split_and_overflow_match_numpy(monkeypatch: pytest.MonkeyPatch) -> None:
    """Windy pendulum, whirling: the kink |sin q| is crossed often.  Intervals whose crossings fit the gather
    are split in the compiled graph; the others overflow to the NumPy path.  Both must equal ``simulate``."""
    system = phast_gym.make_env_system("PHAST/WindyPendulum-v0")
    b = 40
    assert compiled._crossing_capacity(b) < b
    x0 = np.stack([np.linspace(-3.0, 3.0, b), np.linspace(14.0, 24.0, b)], 1)
    calls = []
    numpy_step = compiled.step
    monkeypatch.setattr(compiled, "step", lambda *a, **k: calls.append(1) or numpy_step(*a, **k))
    n_steps = 30
    got = compiled.simulate_compiled(system, x0, n_steps, substeps=1)
    ref = simulate(system, x0, n_steps, substeps=1)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-11)
    assert 0 < len(calls) < n_steps, f"{len(calls)} of {n_steps} intervals overflowed: both paths must be exercised"


def test_make_dataset_compiled_backend() -> None:
    kw = dict(n_traj=6, T=8, seed=3, cache=False)
    a = phast_gym.make_dataset("PHAST/DampedOscillator-v0", backend="compiled", **kw)
    b = phast_gym.make_dataset("PHAST/DampedOscillator-v0", **kw)
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-12)
    assert a.config["backend"] == "compiled" and "backend" not in b.config
    with pytest.raises(ValueError, match="backend"):
        phast_gym.make_dataset("PHAST/DampedOscillator-v0", backend="jax", **kw)


def test_bad_input_is_rejected() -> None:
    system = phast_gym.make_env_system("PHAST/Pendulum-v0")
    with pytest.raises(ValueError, match="x0 must have shape"):
        compiled.simulate_compiled(system, np.zeros((4, 3)), 5)
    with pytest.raises(ValueError, match="finite"):
        compiled.simulate_compiled(system, np.full((4, 2), np.nan), 5)
    with pytest.raises(ValueError, match="u must have shape"):
        compiled.simulate_compiled(system, np.zeros((4, 2)), 5, u=np.zeros((4, 4, 1)))


@pytest.mark.slow
def test_langevin_kick_draws_match_numpy_simulate() -> None:
    system = phast_gym.make_env_system("PHAST/LennardJones3-v0", temperature=0.05)
    x0 = system.sample_initial(np.random.default_rng(1), 8)
    got = compiled.simulate_compiled(system, x0, 10, rng=np.random.default_rng(7))
    ref = simulate(system, x0, 10, rng=np.random.default_rng(7))
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-11)


def test_a_failing_compile_names_the_backend_and_the_way_out(monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(*_a, **_k):
        raise OSError("g++: command not found")

    system = phast_gym.make_env_system("PHAST/DampedPendulum-v0")
    monkeypatch.setattr(compiled, "_interval_fn", lambda *a, **k: broken)
    with pytest.raises(RuntimeError, match="backend='numpy' needs neither"):
        compiled.simulate_compiled(system, np.zeros((3, 2)), 4)
