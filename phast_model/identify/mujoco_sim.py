"""MuJoCo as the simulator of a model file: open-loop rollouts with its own timestep and integrator.

Used to record bench "reality" from a model file and to evaluate a written ``calibrated.xml`` as MuJoCo simulates
it.  ``q`` columns are the model's ``qpos`` (hinge / slide joints), ``ctrl`` columns its actuators; each control is
held over one recording interval ``dt``, which MuJoCo covers in ``k = ceil(dt / timestep)`` steps (the timestep is
shortened to ``dt / k`` when it does not divide ``dt``).

Two settings serve the fits (:class:`~phast_model.identify.shooting.Shooter`): ``max_substeps`` caps k at the fits'
own RK4 substeps (a 1-ms RK4 file under 10-ms samples: 10 steps an interval cut to 2, the same RK4 at the step the
fits use on every other simulator; a file with another integrator keeps its step; the rollouts a held-out score
compares are always at the file's), and :func:`engine_threads` spreads a batch over MuJoCo's native threads
(``mujoco.rollout``'s thread pool).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .shooting import Shooter, Windows

if TYPE_CHECKING:
    import mujoco  # untyped to mypy (pyproject.toml): the annotations name MuJoCo's classes for the reader

    from phast_gym.systems.base import System
    from phast_gym.systems.mjcf import MJCFSystem


#: MuJoCo threads a rollout may use (:func:`engine_threads`); 1: the calling thread alone
_THREADS = [1]
#: windows per thread below which a batch runs on the calling thread (the pool's hand-off costs more than it saves)
MIN_PER_THREAD = 4


@contextmanager
def engine_threads(n: int) -> Iterator[None]:
    """Within the block, MuJoCo rollouts of at least ``MIN_PER_THREAD * n`` trajectories run on ``n`` native threads
    (the numbers do not depend on it: every trajectory is integrated on its own)."""
    if n < 1:
        raise ValueError(f"threads must be at least 1, got {n}")
    before = _THREADS[0]
    _THREADS[0] = int(n)
    try:
        yield
    finally:
        _THREADS[0] = before


def steps_per_interval(dt: float, timestep: float, max_substeps: int | None = None) -> int:
    """MuJoCo steps per recording interval: ``ceil(dt / timestep)``, at most ``max_substeps`` when given."""
    k = max(1, int(math.ceil(dt / timestep - 1e-9)))
    return k if max_substeps is None else max(1, min(k, int(max_substeps)))


def load_mjmodel(model: str | Path | mujoco.MjModel) -> mujoco.MjModel:
    """An ``MjModel`` from a path (MJCF / URDF, through :func:`phast_gym.systems.mjcf_tree.compile_model`) or a
    model."""
    if isinstance(model, (str, Path)):
        from phast_gym.systems.mjcf_tree import compile_model

        return compile_model(model)
    return model


def rollout_q(model: str | Path | mujoco.MjModel, q0: np.ndarray, v0: np.ndarray, ctrl: np.ndarray | None, dt: float,
              n_steps: int, timestep: float | None = None, max_substeps: int | None = None,
              qfrc: np.ndarray | None = None) -> np.ndarray:
    """Simulate B trajectories with MuJoCo from ``(q0, v0)`` (B, n) for ``n_steps`` intervals of ``dt`` with ``ctrl``
    (B, n_steps, m) held per interval (None: zero) -> q (B, n_steps + 1, n).  ``timestep``: the model's own (default:
    as compiled; give it when the same model is rolled out again, since the step is set to ``dt / k`` here).
    ``max_substeps``: at most this many steps per interval (:func:`steps_per_interval`).  ``qfrc`` (n,): a constant
    generalized force applied at every step (``qfrc_applied``)."""
    import mujoco
    from mujoco import rollout

    m = load_mjmodel(model)
    if m.nq != m.nv:
        raise ValueError("rollout_q takes models of hinge and slide joints only (nq == nv)")
    q0, v0 = np.atleast_2d(np.asarray(q0, dtype=float)), np.atleast_2d(np.asarray(v0, dtype=float))
    B = q0.shape[0]
    k = steps_per_interval(dt, timestep or m.opt.timestep, max_substeps)
    m.opt.timestep = dt / k
    threads = _THREADS[0] if B >= MIN_PER_THREAD * _THREADS[0] else 1
    datas = [mujoco.MjData(m) for _ in range(threads)]
    d = datas[0]
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    rest = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, rest, spec)  # the model's rest state; FULLPHYSICS lays out time, qpos, qvel, ...
    state0 = np.tile(rest, (B, 1))
    state0[:, 1: 1 + m.nq], state0[:, 1 + m.nq: 1 + m.nq + m.nv] = q0, v0
    c = np.zeros((B, n_steps, m.nu)) if ctrl is None else np.asarray(ctrl, dtype=float).reshape(B, n_steps, m.nu)
    control, control_spec = np.repeat(c, k, axis=1), int(mujoco.mjtState.mjSTATE_CTRL)
    if qfrc is not None:  # the control vector is (ctrl, qfrc_applied), in mjtState's order
        applied = np.broadcast_to(np.asarray(qfrc, dtype=float), (B, n_steps * k, m.nv))
        control, control_spec = np.concatenate([control, applied], axis=-1), control_spec | int(
            mujoco.mjtState.mjSTATE_QFRC_APPLIED)
    state, _ = rollout.rollout(m, datas if threads > 1 else d, state0, control, control_spec=control_spec,
                               nstep=n_steps * k, persistent_pool=threads > 1)
    q = state[:, k - 1:: k, 1: 1 + m.nq]
    return np.concatenate([q0[:, None, :], q], axis=1)


def mujoco_simulated(path: str | Path) -> MJCFSystem:
    """The model file's :class:`phast_gym.systems.mjcf.MJCFSystem` whose rollouts (:func:`phast_model.identify.shooting.
    simulate_qv`, so initial-state fits and held-out scores alike) are MuJoCo's own: its timestep, integrator and
    constraint-based frictionloss (an RK4 file: at most ``max_substeps`` steps an interval where a fit asks for its own
    step; any other integrator always at the file's)."""
    from phast_gym.systems.mjcf import mjcf_system

    return simulated_by(mjcf_system(path)(), load_mjmodel(path))


def simulated_by(system: MJCFSystem, model: mujoco.MjModel) -> MJCFSystem:
    """``system`` (set up in place: give a copy) whose rollouts are ``model``'s in MuJoCo, as
    :func:`mujoco_simulated` says; ``model`` is the file's structure with ``system``'s values (a calibrated model)."""
    import mujoco

    cols = list(system.actuated_dofs)
    timestep = float(model.opt.timestep)
    # a coarser step only for RK4, whose error at the fits' step is O(h^4) (Euler's would grow with h)
    coarsens = int(model.opt.integrator) == int(mujoco.mjtIntegrator.mjINT_RK4)

    def external_rollout(q0: np.ndarray, v0: np.ndarray, n_steps: int, u: np.ndarray | None,
                         dt: float | np.ndarray, max_substeps: int | None = None,
                         qfrc: np.ndarray | None = None) -> np.ndarray:
        step = float(np.mean(dt))  # recorded jitter: MuJoCo steps at one rate
        ctrl = None if u is None or not cols else np.broadcast_to(u, (q0.shape[0], n_steps, u.shape[-1]))[..., cols]
        return rollout_q(model, q0, v0, ctrl, step, n_steps, timestep, max_substeps if coarsens else None, qfrc)

    system.external_rollout = external_rollout  # type: ignore[attr-defined]
    system.engine_timestep = timestep  # type: ignore[attr-defined]
    system.engine_coarsens = coarsens  # type: ignore[attr-defined]
    return system


#: shooting windows a comparison of MuJoCo's steps simulates (evenly spaced)
STEP_SAMPLE = 32


def departure(at_coarse: np.ndarray, at_file: np.ndarray, relative: bool = False) -> float:
    """RMS, in noise units, of standardized residuals at a coarser MuJoCo step against the same at the file's step.
    ``relative``: in units of the larger of the noise and the residual's own RMS at the file's step instead (a fit
    that leaves model error of s noise units has intervals s times wider, so its departure is judged on that scale;
    at the noise the two agree).  Samples where the file's step itself diverges (clipped residuals) are no test; inf
    when none is left."""
    ok = np.abs(at_file) < 1e5
    d = (at_coarse - at_file)[ok]
    if not d.size:
        return math.inf
    scale = max(1.0, math.sqrt(float(np.mean(at_file[ok] ** 2)))) if relative else 1.0
    return math.sqrt(float(np.mean(d**2))) / scale


class StepProbe:
    """A MuJoCo-simulated ``system`` on up to :data:`STEP_SAMPLE` of a shooter's windows (states ``X``), simulated at
    the file's step once: :meth:`departure` compares a coarser step with it."""

    def __init__(self, system: System, windows: Windows, X: np.ndarray, substeps: int, sigma: np.ndarray,
                 x_scale: np.ndarray) -> None:
        self.idx = np.unique(np.linspace(0, windows.count - 1, min(STEP_SAMPLE, windows.count)).astype(int))
        self.system, self.X = system, X[self.idx]
        self.shooter = Shooter(windows.select(self.idx), sigma, substeps, x_scale)
        self.at_file = self.shooter.residual(system, self.X)

    def departure(self, engine_substeps: int, relative: bool = False) -> float:
        """How far ``engine_substeps`` steps a sample depart from the file's step (:func:`departure`)."""
        self.shooter.engine_substeps = engine_substeps
        try:
            return departure(self.shooter.residual(self.system, self.X), self.at_file, relative)
        finally:
            self.shooter.engine_substeps = None


@dataclass
class StepCheck:
    """The largest departure (:func:`departure`, relative to the fit's own residual) of a fit's final model at a
    coarser MuJoCo step (a shooter's ``engine_substeps``) from the same model at the file's step, on a sample of its
    windows: every fit of an analysis reports here (but the short-window starts of a state fit, whose full-window fit
    reports), so a step that held for the nominal model but not for a fitted friction is caught."""

    worst: float = 0.0

    def measure(self, shooter: Shooter, system: System, X: np.ndarray, r: np.ndarray) -> None:
        """Compare the fit's final residual ``r`` (at its coarser step) with the file's step on a sample."""
        probe = StepProbe(system, shooter.w, X, shooter.substeps, shooter.sigma, shooter.x_scale)
        d = departure(r[probe.idx], probe.at_file, relative=True)
        if math.isfinite(d):  # (inf: the file's step diverged on every sample, a model no fit accepted: no test)
            self.worst = max(self.worst, d)
