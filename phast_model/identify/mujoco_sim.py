"""MuJoCo as the simulator of a model file: open-loop rollouts with its own timestep and integrator.

Used to record bench "reality" from a model file and to evaluate a written ``calibrated.xml`` as MuJoCo simulates
it.  ``q`` columns are the model's ``qpos`` (hinge / slide joints), ``ctrl`` columns its actuators; each control is
held over one recording interval ``dt``, which MuJoCo covers in ``k = ceil(dt / timestep)`` steps (the timestep is
shortened to ``dt / k`` when it does not divide ``dt``).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import mujoco  # untyped to mypy (pyproject.toml): the annotations name MuJoCo's classes for the reader

    from phast_gym.systems.mjcf import MJCFSystem


def load_mjmodel(model: str | Path | mujoco.MjModel) -> mujoco.MjModel:
    """An ``MjModel`` from a path (MJCF / URDF, through :func:`phast_gym.systems.mjcf_tree.compile_model`) or a
    model."""
    if isinstance(model, (str, Path)):
        from phast_gym.systems.mjcf_tree import compile_model

        return compile_model(model)
    return model


def rollout_q(model: str | Path | mujoco.MjModel, q0: np.ndarray, v0: np.ndarray, ctrl: np.ndarray | None, dt: float,
              n_steps: int, timestep: float | None = None) -> np.ndarray:
    """Simulate B trajectories with MuJoCo from ``(q0, v0)`` (B, n) for ``n_steps`` intervals of ``dt`` with ``ctrl``
    (B, n_steps, m) held per interval (None: zero) -> q (B, n_steps + 1, n).  ``timestep``: the model's own (default:
    as compiled; give it when the same model is rolled out again, since the step is set to ``dt / k`` here)."""
    import mujoco
    from mujoco import rollout

    m = load_mjmodel(model)
    if m.nq != m.nv:
        raise ValueError("rollout_q takes models of hinge and slide joints only (nq == nv)")
    q0, v0 = np.atleast_2d(np.asarray(q0, dtype=float)), np.atleast_2d(np.asarray(v0, dtype=float))
    B = q0.shape[0]
    k = max(1, int(math.ceil(dt / (timestep or m.opt.timestep) - 1e-9)))
    m.opt.timestep = dt / k
    d = mujoco.MjData(m)
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    rest = np.empty(mujoco.mj_stateSize(m, spec))
    mujoco.mj_getState(m, d, rest, spec)  # the model's rest state; FULLPHYSICS lays out time, qpos, qvel, ...
    state0 = np.tile(rest, (B, 1))
    state0[:, 1: 1 + m.nq], state0[:, 1 + m.nq: 1 + m.nq + m.nv] = q0, v0
    c = np.zeros((B, n_steps, m.nu)) if ctrl is None else np.asarray(ctrl, dtype=float).reshape(B, n_steps, m.nu)
    control = np.repeat(c, k, axis=1)
    state, _ = rollout.rollout(m, d, state0, control, nstep=n_steps * k)
    q = state[:, k - 1:: k, 1: 1 + m.nq]
    return np.concatenate([q0[:, None, :], q], axis=1)


def mujoco_simulated(path: str | Path) -> MJCFSystem:
    """The model file's :class:`phast_gym.systems.mjcf.MJCFSystem` whose rollouts (:func:`phast_model.identify.shooting.
    simulate_qv`, so initial-state fits and held-out scores alike) are MuJoCo's own: its timestep, integrator and
    constraint-based frictionloss."""
    from phast_gym.systems.mjcf import mjcf_system

    system = mjcf_system(path)()
    model = load_mjmodel(path)
    cols = list(system.actuated_dofs)
    timestep = float(model.opt.timestep)

    def external_rollout(q0: np.ndarray, v0: np.ndarray, n_steps: int, u: np.ndarray | None,
                         dt: float | np.ndarray) -> np.ndarray:
        step = float(np.mean(dt))  # recorded jitter: MuJoCo steps at one rate
        ctrl = None if u is None or not cols else np.broadcast_to(u, (q0.shape[0], n_steps, u.shape[-1]))[..., cols]
        return rollout_q(model, q0, v0, ctrl, step, n_steps, timestep)

    system.external_rollout = external_rollout  # type: ignore[attr-defined]
    return system
