"""MuJoCo as the fits' engine: the fits' own step, native threads, and how far the fits' integration departs from
the file's (phast_model.identify.mujoco_sim: StepProbe, StepCheck; Shooter.engine_substeps)."""

from __future__ import annotations

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from phast_model.bench.mjcf_cases import MODELS_DIR  # noqa: E402
from phast_model.identify.mujoco_sim import (  # noqa: E402
    engine_threads,
    mujoco_simulated,
    rollout_q,
    steps_per_interval,
)
from phast_model.identify.recordings import Recordings  # noqa: E402
from phast_model.identify.shooting import Shooter, Windows, simulate_qv  # noqa: E402

ARM3 = MODELS_DIR / "arm3.xml"  # RK4 at 1 ms


def _batch(B: int, L: int = 30, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.normal(0, 0.5, (B, 3)), rng.normal(0, 0.5, (B, 3)), rng.normal(0, 0.3, (B, L, 3))


def test_steps_per_interval():
    assert steps_per_interval(0.01, 0.001) == 10
    assert steps_per_interval(0.01, 0.001, 2) == 2
    assert steps_per_interval(0.01, 0.003) == 4  # 0.0025 s steps: never longer than the file's
    assert steps_per_interval(0.01, 0.02, 2) == 1
    assert steps_per_interval(0.01, 0.001, 0) == 1


def test_threads_give_the_same_numbers():
    q0, v0, u = _batch(40)
    one = rollout_q(str(ARM3), q0, v0, u, 0.01, 30)
    with engine_threads(2):
        two = rollout_q(str(ARM3), q0, v0, u, 0.01, 30)
    np.testing.assert_array_equal(one, two)  # every trajectory is integrated on its own
    with pytest.raises(ValueError, match="threads"):
        with engine_threads(0):
            pass


def test_fit_step_is_the_fits_rk4_step_and_close_to_the_files():
    system = mujoco_simulated(ARM3)
    q0, v0, u = _batch(8)
    file_q = simulate_qv(system, q0, v0, 30, u, 0.01, 2)
    fit_q = simulate_qv(system, q0, v0, 30, u, 0.01, 2, engine_substeps=2)
    direct = rollout_q(str(ARM3), q0, v0, u, 0.01, 30, max_substeps=2)
    np.testing.assert_array_equal(fit_q, direct)  # MuJoCo's RK4 at dt / 2
    np.testing.assert_array_equal(file_q, rollout_q(str(ARM3), q0, v0, u, 0.01, 30))  # the file's 1 ms
    gap = np.max(np.abs(fit_q - file_q))
    assert 0 < gap < 1e-3  # RK4 at 5 ms against 1 ms over 0.3 s: well under a sensor's noise
    # asking for more substeps than the file's step needs gives the file's own rollout
    np.testing.assert_array_equal(simulate_qv(system, q0, v0, 30, u, 0.01, 2, engine_substeps=50), file_q)


def test_shooter_engine_substeps_only_where_asked():
    system = mujoco_simulated(ARM3)
    q0, v0, u = _batch(4, L=20)
    q = rollout_q(str(ARM3), q0, v0, u, 0.01, 20)
    rec = Recordings(q=q, u=u, dt=0.01, angle_dims=(0, 1, 2))
    w = Windows.cut(rec, 21)
    X = np.concatenate([q0, v0], axis=1)
    shooter = Shooter(w, np.full(3, 1e-3), 2, np.ones(6))
    at_file = shooter.residual(system, X)
    assert np.max(np.abs(at_file)) < 1e-9  # the recordings are the file's own rollouts
    shooter.engine_substeps = 2
    at_fit = shooter.residual(system, X)
    assert 0 < np.max(np.abs(at_fit)) < 1.0  # under the noise of 1e-3 rad


def test_a_file_with_another_integrator_keeps_its_step(tmp_path):
    euler = tmp_path / "arm3_euler.xml"
    euler.write_text(ARM3.read_text().replace('integrator="RK4"', 'integrator="Euler"'))
    system = mujoco_simulated(euler)
    q0, v0, u = _batch(4)
    np.testing.assert_array_equal(simulate_qv(system, q0, v0, 30, u, 0.01, 2, engine_substeps=2),
                                  simulate_qv(system, q0, v0, 30, u, 0.01, 2))


def _nominal_problem(path, n_traj: int = 4, T: int = 120):
    from phast_model.identify.simulators import load_simulator
    from phast_model.mismatch.fitting.problem import prepare
    from phast_model.mismatch.options import Options, Progress
    from phast_model.mismatch.written import with_coarse_step

    q0, v0, u = _batch(n_traj, L=T - 1, seed=1)
    q = rollout_q(str(path), q0, v0, u, 0.01, T - 1) + np.random.default_rng(2).normal(0, 1e-3, (n_traj, T, 3))
    sim = load_simulator(str(path))
    return with_coarse_step(prepare(sim, sim.build(), Recordings(q=q, u=u, dt=0.01, angle_dims=(0, 1, 2)), Options(),
                                    Progress(False)))


def test_a_coarser_step_only_where_the_nominal_model_follows_the_files(tmp_path):
    assert _nominal_problem(ARM3).shooting.engine_substeps == 2
    for stiffness, steps in ((1000, 8), (10000, None)):  # elbow modes of about 700 and 2200 rad/s
        stiff = tmp_path / f"arm3_stiff{stiffness}.xml"
        stiff.write_text(ARM3.read_text().replace('<joint name="elbow"', f'<joint name="elbow" stiffness="{stiffness}"'))
        assert _nominal_problem(stiff).shooting.engine_substeps == steps


def test_a_departure_is_judged_against_the_residual_it_leaves():
    """In noise units at the noise; where model error leaves a residual of s noise units, in units of s (the scale of
    that fit's intervals); samples where the file's step itself diverged are no test."""
    from phast_model.identify.mujoco_sim import departure

    at_file = np.full((4, 10), 10.0)
    assert departure(at_file + 1.0, at_file) == pytest.approx(1.0)
    assert departure(at_file + 1.0, at_file, relative=True) == pytest.approx(0.1)
    small = np.full((4, 10), 0.5)  # below the noise: noise units either way
    assert departure(small + 0.2, small, relative=True) == pytest.approx(0.2)
    assert departure(np.zeros(3), np.full(3, 2e5)) == np.inf


def test_the_fits_run_on_muJoCo_unless_the_vocabulary_holds_a_force_it_lacks():
    """A model file's families build MuJoCo-simulated systems when every term of the vocabulary is one MuJoCo
    simulates (the model-file default); with a cubic stiffness in it every fit keeps the tool's own integrator."""
    from dataclasses import replace

    from phast_model.mismatch.vocabulary.registry import mujoco_vocabulary
    from phast_model.mismatch.written import family_engine, fits_in_mujoco

    problem = _nominal_problem(ARM3)
    with_cubic = replace(problem, opts=replace(problem.opts, terms=("viscous_damping", "cubic_stiffness")))
    assert fits_in_mujoco(with_cubic).nominal_family.engine is None
    on_mujoco = fits_in_mujoco(replace(problem, opts=replace(problem.opts, terms=mujoco_vocabulary())))
    assert on_mujoco.nominal_family.engine is family_engine
    assert getattr(on_mujoco.nominal_family.build(np.zeros(0)), "external_rollout", None) is not None
