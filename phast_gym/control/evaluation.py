"""Closed-loop evaluation protocol (paper Sec. 4.2, Tables 7-11): regimes, episodes, metrics.

Protocol (documented in docs/control.md; defaults of :class:`ControlProtocol`):

* plant: a ``PHAST/Pendulum-v0``-family :class:`~phast_gym.PortHamiltonianEnv` sampled at
  ``dt = 0.01`` s (the paper's control rate: its finite-difference velocity error at
  sigma = 0.01, 1.117 rad/s, is the mean |N(0, 2 sigma^2 / dt^2)| = 1.13 of a dt = 0.01 sampler),
  q-only observations with ``obs_noise_std = sigma``;
* five initial-condition regimes x ``trials_per_regime`` trials (:data:`START_REGIMES`), the same
  initial states and noise streams for every estimator (common random numbers);
* metrics per trial: success = settled and quiet: ``|wrap(q - q_star)| < tol`` (true q) at
  every step of the last ``settle_steps`` steps AND the RMS applied torque over those steps
  ``< u_tol`` (a loop that keeps chattering the actuator with estimator noise has not converged;
  ``success_angle`` reports the angle-only criterion alongside), final error ``|wrap(q_T - q_star)|`` (true q), effort
  ``sum_t |u_t|^2`` (applied torque), velocity error ``mean_t |qdot_hat_t - qdot_t|``, and the RMS torque over
  the final window (``u_rms_final``; rows give its mean and 90th percentile).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, TypedDict

import gymnasium as gym
import numpy as np

from ..env import PortHamiltonianEnv
from ..registry import make_env_system
from ..systems.base import NUMPY, SCALAR, System, wrap
from .controller import XI_FEEDBACK, EnergyCasimirController, PortPlant
from .estimators import PortEstimator, make_estimator

#: initial-condition ("start") regime of a closed-loop trial -> how its start states are drawn (sampled by
#: :func:`sample_start_states`)
START_REGIMES: dict[str, str] = {
    "near_stable": "theta ~ U(-0.5, 0.5), thetadot ~ U(-0.5, 0.5)",
    "far_stable": "|theta| ~ U(1.0, 2.0) (random sign), thetadot ~ U(-1, 1)",
    "near_unstable": "theta = pi + U(-0.3, 0.3), thetadot ~ U(-0.3, 0.3)",
    "far_unstable": "theta = pi +- U(0.3, 0.8), thetadot ~ U(-1, 1)",
    "high_energy": "theta ~ U(-pi, pi), |thetadot| ~ U(7, 10) (above the separatrix: the pendulum spins)",
}


@dataclass
class ControlProtocol:
    """Plant, gains and success criterion shared by every estimator of a study."""

    env_id: str = "PHAST/DampedPendulum-v0"
    dt: float = 0.01
    horizon: int = 3000
    q_star: float = 0.0
    k_c: float = 0.7
    d_inj: float = 0.11
    k_xi: float = 5.0
    tol: float = 0.05
    settle_steps: int = 100
    u_tol: float = 0.25
    max_action: float | None = None
    xi_feedback: str = "meas"
    env_kwargs: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if int(self.horizon) != self.horizon or self.horizon < 2:
            raise ValueError(f"horizon must be an integer >= 2 steps, got {self.horizon!r}")
        if not 1 <= self.settle_steps <= self.horizon:
            raise ValueError(f"settle_steps must be in [1, horizon={self.horizon}], got {self.settle_steps}")
        if not (self.tol > 0 and self.u_tol > 0):
            raise ValueError(f"tol and u_tol must be > 0, got tol={self.tol}, u_tol={self.u_tol}")
        if not (self.dt > 0 and math.isfinite(self.dt)):
            raise ValueError(f"dt must be positive, got {self.dt}")
        if self.xi_feedback not in XI_FEEDBACK:
            raise ValueError(f"xi_feedback must be one of {XI_FEEDBACK}, got {self.xi_feedback!r}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def control_system(protocol: ControlProtocol) -> System:
    """The plant's physics for ``protocol.env_id``, sampled at the control rate ``protocol.dt``.

    The system's own dt is overridden on the instance (the env has no dt kwarg); RK4 substeps
    scale so the substep length stays at most that of the registered env.
    """
    system = make_env_system(protocol.env_id, **protocol.env_kwargs)
    base_dt, base_sub = type(system).dt, type(system).substeps
    system.dt = float(protocol.dt)
    system.substeps = max(1, math.ceil(base_sub * protocol.dt / base_dt - 1e-9))
    return system


def make_control_env(protocol: ControlProtocol, sigma: float = 0.0) -> gym.Env:
    """The plant env: q-only, ``obs_noise_std = sigma``, episodes of ``protocol.horizon`` steps."""
    system = control_system(protocol)
    env = PortHamiltonianEnv(system, obs_noise_std=sigma, max_action=protocol.max_action, dtype=np.float64,
                             substeps=system.substeps)
    return gym.wrappers.TimeLimit(env, max_episode_steps=protocol.horizon)


def sample_start_states(system: System, regime: str, rng: np.random.Generator, size: int) -> np.ndarray:
    """Initial states (size, 2) of a pendulum start regime (:data:`START_REGIMES`); p = M(q) qdot."""
    if regime not in START_REGIMES:
        raise ValueError(f"unknown regime {regime!r}; valid regimes are {list(START_REGIMES)}")
    if system.n != 1 or system.angle_dims != (0,):
        raise ValueError(f"the control regimes are defined for 1-dof pendulum plants, got {system.name} (n={system.n})")
    u = rng.uniform
    sign = np.where(rng.uniform(size=size) < 0.5, -1.0, 1.0)
    if regime == "near_stable":
        q, qd = u(-0.5, 0.5, size), u(-0.5, 0.5, size)
    elif regime == "far_stable":
        q, qd = sign * u(1.0, 2.0, size), u(-1.0, 1.0, size)
    elif regime == "near_unstable":
        q, qd = math.pi + u(-0.3, 0.3, size), u(-0.3, 0.3, size)
    elif regime == "far_unstable":
        q, qd = math.pi + sign * u(0.3, 0.8, size), u(-1.0, 1.0, size)
    else:  # high_energy
        q, qd = u(-math.pi, math.pi, size), sign * u(7.0, 10.0, size)
    q = wrap(q)
    (p,) = system.momentum((q,), (qd,), NUMPY)
    return np.stack(np.broadcast_arrays(q, p), -1)


@dataclass
class Episode:
    """One closed-loop run: per-step arrays (T steps) and its metrics."""

    q: np.ndarray  # (T+1, n) true q (unwrapped)
    qdot: np.ndarray  # (T, n) true qdot at the time of each control step
    q_meas: np.ndarray  # (T, n)
    y_hat: np.ndarray  # (T, n)
    u: np.ndarray  # (T, n) applied torque
    xi: np.ndarray  # (T+1, n)
    storage: np.ndarray  # (T+1,) H_cl along the run
    success: bool
    success_angle: bool
    final_error: float
    effort: float
    velocity_error: float
    u_rms_final: float = float("nan")

    def metrics(self) -> dict[str, float]:
        return {"success": float(self.success), "success_angle": float(self.success_angle),
                "final_error": self.final_error, "effort": self.effort,
                "velocity_error": self.velocity_error, "u_rms_final": self.u_rms_final}


def run_episode(env: gym.Env, controller: EnergyCasimirController, x0: np.ndarray, seed: int, protocol: ControlProtocol,
                v_ext: Callable[[int], np.ndarray] | None = None) -> Episode:
    """Run one closed loop through ``env.reset``/``env.step`` only; returns traces and metrics."""
    system = controller.system
    n = system.n
    action_space = env.action_space
    if not isinstance(action_space, gym.spaces.Box):
        raise TypeError(f"run_episode needs a Box action space (the applied u is clipped to it), got {action_space}")
    obs, info = env.reset(seed=int(seed), options={"state": np.asarray(x0, dtype=np.float64)})
    controller.reset(obs, info)
    T = protocol.horizon
    qs, qdots, qm, yh, us, xis, hs = [], [], [], [], [], [controller.xi.copy()], []
    for t in range(T):
        x = np.asarray(info["state"], dtype=np.float64)
        qs.append(x[:n])
        hs.append(controller.storage(x[:n], x[n:]))
        qdots.append([float(v) for v in system.velocity(list(x[:n]), list(x[n:]), SCALAR)])
        qm.append(np.asarray(obs, dtype=np.float64))
        u = controller.act(obs, info, 0.0 if v_ext is None else v_ext(t))
        yh.append(controller.y_hat.copy())
        xis.append(controller.xi.copy())
        obs, _, terminated, truncated, info = env.step(u)
        us.append(np.clip(u, action_space.low, action_space.high))
        if terminated or (truncated and t < T - 1):
            break
    x = np.asarray(info["state"], dtype=np.float64)
    qs.append(x[:n])
    hs.append(controller.storage(x[:n], x[n:]))
    q = np.array(qs)
    qdot, y_hat, u_arr = np.array(qdots), np.array(yh), np.array(us)
    err = np.linalg.norm(np.where([i in system.angle_dims for i in range(n)], wrap(q - controller.q_star),
                                  q - controller.q_star), axis=-1)
    finite = bool(np.all(np.isfinite(q)))
    settled = finite and len(q) == T + 1 and bool(np.all(err[-protocol.settle_steps:] < protocol.tol))
    u_rms = float(np.sqrt(np.mean(np.sum(u_arr[-protocol.settle_steps:] ** 2, axis=-1))))
    quiet = bool(u_rms < protocol.u_tol)
    return Episode(
        q=q, qdot=qdot, q_meas=np.array(qm), y_hat=y_hat, u=u_arr, xi=np.array(xis), storage=np.array(hs),
        success=settled and quiet, success_angle=settled,
        final_error=float(err[-1]) if finite else float("nan"),
        effort=float(np.sum(u_arr**2)),
        velocity_error=float(np.mean(np.linalg.norm(y_hat - qdot, axis=-1))),
        u_rms_final=u_rms,
    )


def stable_seed(*parts: object) -> int:
    return zlib.crc32("/".join(str(p) for p in parts).encode()) & 0x7FFFFFFF


def start_states(protocol: ControlProtocol, trials_per_regime: int, seed: int = 0) -> dict[str, np.ndarray]:
    """The initial states of every start regime (same for every estimator and noise level)."""
    system = control_system(protocol)
    return {r: sample_start_states(system, r, np.random.default_rng(stable_seed(seed, r)), trials_per_regime)
            for r in START_REGIMES}


EstimatorFactory = Callable[[str, System, float, float], PortEstimator]


class ControlRow(TypedDict):
    """One row of :func:`evaluate_estimators`: the trials of one (sigma, estimator, start regime), pooled (``regime``
    ``"all"``: every regime)."""

    sigma: float
    estimator: str
    regime: str
    n_trials: int
    success_rate: float
    success_angle_rate: float
    final_error: float
    effort: float
    velocity_error: float
    u_rms_final: float
    u_rms_final_p90: float


def evaluate_estimators(
    protocol: ControlProtocol,
    estimators: Sequence[str],
    sigmas: Sequence[float],
    trials_per_regime: int = 20,
    seed: int = 0,
    factory: EstimatorFactory | None = None,
    progress: bool = True,
    keep_episodes: Callable[[float, str, str, int], bool] | None = None,
) -> tuple[list[ControlRow], dict[tuple[float, str, str, int], Episode]]:
    """Closed-loop trials of every port estimator at every noise level: one row per (sigma, estimator, start regime)
    plus an ``all`` row per (sigma, estimator).

    ``factory(name, system, dt, sigma)`` builds an estimator (default :func:`make_estimator`);
    ``keep_episodes(sigma, estimator, regime, trial)`` selects episodes whose traces are returned.
    """
    if trials_per_regime < 1:
        raise ValueError(f"trials_per_regime must be >= 1, got {trials_per_regime}")
    factory = factory or (lambda name, system, dt, sigma: make_estimator(name, system, dt, sigma=sigma))
    states = start_states(protocol, trials_per_regime, seed)
    rows: list[ControlRow] = []
    kept: dict[tuple[float, str, str, int], Episode] = {}
    total = len(sigmas) * len(estimators) * len(START_REGIMES) * trials_per_regime
    from tqdm.auto import tqdm

    bar = tqdm(total=total, desc="closed-loop trials", disable=not progress)
    for sigma in sigmas:
        env = make_control_env(protocol, sigma)
        plant = env.unwrapped
        if not isinstance(plant, PortPlant):  # make_control_env wraps a PortHamiltonianEnv
            raise TypeError(f"make_control_env must build a phast_gym PortHamiltonianEnv, got {type(plant).__name__}")
        system = plant.system
        for name in estimators:
            est = factory(name, system, protocol.dt, float(sigma))
            ctrl = EnergyCasimirController(est, protocol.q_star, protocol.k_c, protocol.d_inj, protocol.k_xi,
                                           dt=protocol.dt, max_action=float(plant.max_action), system=system,
                                           xi_feedback=protocol.xi_feedback)
            per_all: list[dict[str, float]] = []
            for regime, x0s in states.items():
                per: list[dict[str, float]] = []
                for i, x0 in enumerate(x0s):
                    ep = run_episode(env, ctrl, x0, stable_seed(seed, "noise", regime, i), protocol)
                    per.append(ep.metrics())
                    if keep_episodes is not None and keep_episodes(float(sigma), name, regime, i):
                        kept[(float(sigma), name, regime, i)] = ep
                    bar.update(1)
                rows.append(_aggregate(float(sigma), name, regime, per))
                per_all += per
            rows.append(_aggregate(float(sigma), name, "all", per_all))
    bar.close()
    return rows, kept


def _aggregate(sigma: float, name: str, regime: str, per: list[dict[str, float]]) -> ControlRow:
    arr = {k: np.array([m[k] for m in per]) for k in per[0]}
    return {
        "sigma": sigma, "estimator": name, "regime": regime, "n_trials": len(per),
        "success_rate": float(arr["success"].mean()),
        "success_angle_rate": float(arr["success_angle"].mean()),
        "final_error": float(np.nanmean(arr["final_error"])) if np.isfinite(arr["final_error"]).any() else float("nan"),
        "effort": float(arr["effort"].mean()),
        "velocity_error": float(arr["velocity_error"].mean()),
        "u_rms_final": float(arr["u_rms_final"].mean()),
        "u_rms_final_p90": float(np.percentile(arr["u_rms_final"], 90)),
    }
