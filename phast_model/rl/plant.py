"""The plant side of the model-based RL loop: the machine, the task, closed-loop episodes and their cost.

The loop touches the plant only through ``reset(state)`` / ``step(u)`` of a phast_gym env that returns q-only, noisy
measurements (what an encoder gives).  The plant is a registered env id or a rig of the user's own, named as for
``phast-mismatch --sim``: ``path/to/rig.py:Class`` or ``module:Class``, a :class:`phast_gym.systems.base.System`
subclass (docs/describe_your_rig.md), stepped at the control rate ``dt`` (0.01 s by default, the control protocol's).
Every
plant episode is an :class:`Episode` (:func:`record_episode`): the measurements, the applied inputs and (simulation
only, for the success metrics and never for learning) the true states.  :func:`to_recordings` turns episodes into the
``phast-train
--recordings`` format at the decision rate, which is what the world model is fitted to.

Success is the quiet criterion of docs/control.md: over the last ``settle_s`` seconds every true angle error is below
``tol`` and the RMS applied input is below ``u_tol`` (:func:`quiet_metrics`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from phast_gym.control import sample_start_states
from phast_gym.env import PortHamiltonianEnv
from phast_gym.systems.base import System, wrap

from .types import Controller, Plant

#: the tasks of ``phast-rl --task``: start regime of the pendulum and the target (pi on every angle: upright)
TASKS = ("swingup", "upright")
#: env-level keyword arguments of a phast_gym env (the rest are the system's physical parameters)
ENV_LEVEL_KWARGS = ("actuated_dofs",)


@dataclass(frozen=True)
class PlantSpec:
    """The plant: a phast_gym env id with its kwargs (physical parameters and ``actuated_dofs``), stepped every ``dt``
    seconds, measured with q-noise ``sigma``, inputs clipped at ``max_action``; the agent decides (and the world model
    steps) every ``decision_steps`` plant steps.  With ``machine`` (a factory, :func:`.sources.load_machine`, called
    with ``machine_kwargs``) the plant is that machine and ``env_id`` only describes it (its coordinates, the LQG
    floor of the quiet criterion); ``sigma`` is then the machine's own measurement noise, as far as it is known."""

    env_id: str = "PHAST/Pendulum-v0"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    dt: float = 0.01
    decision_steps: int = 5
    sigma: float = 0.01
    max_action: float = 10.0
    machine: str | None = None
    machine_kwargs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not (self.dt > 0 and math.isfinite(self.dt)):
            raise ValueError(f"dt must be a positive number of seconds, got {self.dt!r}")
        if int(self.decision_steps) != self.decision_steps or self.decision_steps < 1:
            raise ValueError(f"decision_steps must be a positive integer, got {self.decision_steps!r}")
        if not (self.sigma >= 0 and math.isfinite(self.sigma)):
            raise ValueError(f"sigma must be a finite number >= 0, got {self.sigma!r}")
        if not (self.max_action > 0 and math.isfinite(self.max_action)):
            raise ValueError(f"max_action must be a positive number, got {self.max_action!r}")

    @property
    def decision_dt(self) -> float:
        """Seconds between two decisions (the world model's step, the recordings' sampling interval)."""
        return self.dt * self.decision_steps

    @property
    def physical_kwargs(self) -> dict[str, Any]:
        return {k: v for k, v in self.env_kwargs.items() if k not in ENV_LEVEL_KWARGS}


def plant_system(spec: PlantSpec) -> System:
    """The plant's physics (an env id or a user's rig class, :func:`phast_model.identify.simulators.load_simulator`)
    sampled at ``spec.dt`` (RK4 substeps scaled so the substep does not grow)."""
    from ..identify.simulators import load_simulator

    system = load_simulator(spec.env_id, spec.physical_kwargs).build()
    base_dt, base_sub = type(system).dt, type(system).substeps
    system.dt = float(spec.dt)
    system.substeps = max(1, math.ceil(base_sub * spec.dt / base_dt - 1e-9))
    return system


def make_plant(spec: PlantSpec) -> Plant:
    """The plant env: q-only measurements with noise ``sigma``, float64, no time limit (episodes are counted here);
    a machine's (:class:`.sources.MachinePlant`) when ``spec.machine`` names one, its step checked against ``dt``."""
    system = plant_system(spec)
    if spec.machine is not None:
        from .sources import MachinePlant, load_machine, machine_dt

        machine = load_machine(spec.machine, spec.machine_kwargs)
        dt = float(machine_dt(machine))
        if not math.isclose(dt, spec.dt, rel_tol=1e-6):
            raise ValueError(f"machine {spec.machine!r} steps every {dt:g} s, the loop every {spec.dt:g} s: give --dt "
                             f"{dt:g}")
        return MachinePlant(machine, system, spec.env_kwargs.get("actuated_dofs"), spec.max_action, spec.machine)
    return PortHamiltonianEnv(system, actuated_dofs=spec.env_kwargs.get("actuated_dofs"), max_action=spec.max_action,
                              obs_noise_std=spec.sigma, dtype=np.float64, substeps=system.substeps)


@dataclass(frozen=True)
class Task:
    """What to learn: ``name`` of :data:`TASKS`; the target is the upright (pi) on every angle, 0 elsewhere.  Success
    is the quiet criterion over the last ``settle_s`` seconds (angle ``tol`` rad, RMS input ``u_tol``)."""

    name: str = "swingup"
    tol: float = 0.05
    u_tol: float = 0.25
    settle_s: float = 1.0

    def __post_init__(self) -> None:
        if self.name not in TASKS:
            raise ValueError(f"task must be one of {TASKS}, got {self.name!r}")
        for k in ("tol", "u_tol", "settle_s"):
            v = getattr(self, k)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{k} must be a positive number, got {v!r}")

    def target(self, system: System) -> np.ndarray:
        """q* (n,): pi on the angles (the pole or pendulum upright), 0 on the other coordinates."""
        return np.array([math.pi if i in system.angle_dims else 0.0 for i in range(system.n)])

    def start_states(self, system: System, rng: np.random.Generator, size: int) -> np.ndarray:
        """(size, 2n) initial states: hanging (``swingup``) or near the upright (``upright``); the pendulum start
        regimes of the control protocol (near_stable / near_unstable), the same spreads for a pole on a cart."""
        if system.n == 1:
            return sample_start_states(system, "near_stable" if self.name == "swingup" else "near_unstable", rng, size)
        spread = 0.5 if self.name == "swingup" else 0.3
        base = np.zeros(system.n) if self.name == "swingup" else self.target(system)
        q = base + rng.uniform(-spread, spread,
                               (size, system.n)) * np.array([i in system.angle_dims for i in range(system.n)])
        v = rng.uniform(-spread, spread, (size, system.n))
        p = np.stack([np.asarray(c, dtype=np.float64) for c in system.momentum(tuple(q.T), tuple(v.T))], -1)
        return np.concatenate([q, np.broadcast_to(p, q.shape)], -1)


#: the quiet criterion's RMS input of the pendulum (the control protocol's, N m)
PENDULUM_U_TOL = 0.25
#: elsewhere the quiet criterion allows this multiple of the plant's own LQG floor (docs/control.md)
FLOOR_FACTOR = 2.0


def quiet_u_tol(spec: PlantSpec, factor: float = FLOOR_FACTOR) -> float:
    """The default RMS-input limit of the quiet criterion on ``spec``'s plant: the protocol's 0.25 N m for a 1-dof
    pendulum, else ``factor`` x the plant's LQG floor at its upright and noise ``sigma``
    (:func:`phast_model.control.lqg_bound.lqg_floor`: the least stationary RMS input of any causal q-only controller;
    the cart-pole with the force on the cart, sigma 0.01: 0.194 N, so 0.387 N)."""
    system = plant_system(spec)
    if system.n == 1:
        return PENDULUM_U_TOL
    from ..control.lqg_bound import system_lqg_floor

    floor = system_lqg_floor(system, max(spec.sigma, 1e-6), math.pi, spec.dt, spec.env_kwargs.get("actuated_dofs"))
    return factor * float(floor["rms_torque"])


@dataclass
class Episode:
    """One plant episode: ``q`` (T+1, n) noisy measurements, ``u`` (T, m) applied inputs, ``x`` (T+1, 2n) true states
    (metrics only; on a machine the measured q and NaN momenta), ``dt`` the plant step, ``kind`` (``excitation`` /
    ``policy`` / ``evaluation``), ``handoffs``."""

    q: np.ndarray
    u: np.ndarray
    x: np.ndarray
    dt: float
    kind: str
    handoffs: int = 0  # entries into the hold (HybridPolicy), for the record
    act_s: np.ndarray | None = None  # (T,) seconds the controller took per step (a real machine's dt must allow it)

    @property
    def seconds(self) -> float:
        """Plant time used: the interval covered by the measurements."""
        return float(self.u.shape[0] * self.dt)


def record_episode(plant: Plant, controller: Controller, x0: np.ndarray, steps: int, seed: int, kind: str) -> Episode:
    """Run ``controller`` on the plant for ``steps`` steps from the true state ``x0`` (a real rig: its own start) and
    record the episode: measurements, applied inputs, true states and the controller's time per step (the loop's
    learning data and evaluations; ``phast_gym.control.run_episode`` is the control protocol's episode of an
    Energy-Casimir controller, with its metrics)."""
    obs, info = plant.reset(seed=seed, options={"state": np.asarray(x0, dtype=np.float64)})
    controller.reset(np.asarray(obs, dtype=np.float64))
    qs, us, xs = [np.asarray(obs, dtype=np.float64)], [], [np.asarray(info["state"], dtype=np.float64)]
    act_s = np.zeros(steps)
    for i in range(steps):
        t0 = time.perf_counter()
        u = np.clip(np.asarray(controller.act(qs[-1]), dtype=np.float64).reshape(plant.m), -plant.max_action,
                    plant.max_action)
        act_s[i] = time.perf_counter() - t0
        obs, _, _, _, info = plant.step(u)
        qs.append(np.asarray(obs, dtype=np.float64))
        us.append(u)
        xs.append(np.asarray(info["state"], dtype=np.float64))
    return Episode(np.array(qs), np.array(us), np.array(xs), float(plant.dt), kind, act_s=act_s)


class HeldTorques:
    """Open-loop excitation: a precomputed input sequence (T, m), e.g. random torques held for a few decisions."""

    def __init__(self, u: np.ndarray) -> None:
        self.u = np.asarray(u, dtype=np.float64)
        self._t = 0

    def reset(self, q_meas: np.ndarray) -> None:
        self._t = 0

    def act(self, q_meas: np.ndarray) -> np.ndarray:
        u = self.u[min(self._t, len(self.u) - 1)]
        self._t += 1
        return u


def excitation_inputs(rng: np.random.Generator, steps: int, m: int, hold_steps: int, std: float,
                      bound: float) -> np.ndarray:
    """(steps, m) random inputs ~ N(0, std) clipped at ``bound``, each held ``hold_steps`` plant steps."""
    n_hold = -(-steps // hold_steps)
    u = np.clip(rng.normal(0.0, std, (n_hold, m)), -bound, bound)
    return np.repeat(u, hold_steps, axis=0)[:steps]


def to_recordings(episodes: Sequence[Episode], decision_steps: int, angle_dims: Sequence[int],
                  actuated_dofs: Sequence[int] | None = None) -> dict[str, Any]:
    """The episodes in the ``phast-train --recordings`` format at the decision rate: ``q`` (N, T, n) every
    ``decision_steps``-th measurement, ``u`` (N, T-1, m) the mean input over each interval (exact while the input is
    held, the zero-order-hold average while the hold controller acts every plant step), ``dt``, ``angle_dims``.
    ``actuated_dofs`` (the coordinates the m inputs drive) is recorded when given.  Every episode must have the same
    length."""
    lengths = {e.u.shape[0] for e in episodes}
    if len(lengths) != 1:
        raise ValueError(f"recorded episodes must share one length, got {sorted(lengths)} plant steps")
    (steps,) = lengths
    if steps % decision_steps:
        raise ValueError(f"episode length {steps} is not a multiple of decision_steps={decision_steps}")
    k = decision_steps
    q = np.stack([e.q[::k] for e in episodes])
    u = np.stack([e.u.reshape(steps // k, k, -1).mean(axis=1) for e in episodes])
    rec = {"q": q, "u": u, "dt": episodes[0].dt * k, "angle_dims": np.array(list(angle_dims), dtype=np.int64)}
    if actuated_dofs is not None:
        rec["actuated_dofs"] = np.array(list(actuated_dofs), dtype=np.int64)
    return rec


@dataclass(frozen=True)
class QuietMetrics:
    """The quiet criterion of one episode: ``settled`` (angle only), ``rms_input`` over the last second, ``success``
    (both), the final angle error."""

    settled: bool
    rms_input: float
    success: bool
    final_error: float


def quiet_metrics(ep: Episode, q_star: np.ndarray, angle_dims: Sequence[int], task: Task) -> QuietMetrics:
    """The quiet criterion on the true angles of ``ep`` (on a machine: the measured ones, :class:`Episode` ``x``;
    the protocol of docs/control.md): all angle errors below
    ``task.tol`` over the last ``task.settle_s`` seconds and the RMS input (all inputs) below ``task.u_tol``."""
    n_tail = max(1, int(round(task.settle_s / ep.dt)))
    dims = list(angle_dims)
    err = np.abs(wrap(ep.x[-n_tail:, dims] - q_star[dims]))
    rms = float(np.sqrt(np.mean(ep.u[-n_tail:] ** 2)))
    settled = bool(np.all(err < task.tol))
    return QuietMetrics(settled, rms, settled and rms <= task.u_tol,
                        float(np.max(np.abs(wrap(ep.x[-1, dims] - q_star[dims])))))
