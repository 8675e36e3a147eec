"""SB3 SAC vs Energy-Casimir on the torque-port damped pendulum (q-only, noisy), same regimes and metrics.

Agents (CPU, one torch thread):

* ``sac-real``: SAC trained on the real plant (the control env of :class:`ControlProtocol`, decisions
  every ``repeat`` plant steps with the torque held), observation = (sin q, cos q) of the last
  ``frames`` noisy measurements taken at the decision rate;
* ``sac-world`` (with ``--phast-run``): SAC trained inside :class:`phast_model.world.gym_env.PHASTWorldModelEnv`
  (the learned PHAST model, dt = the run's env dt = ``repeat`` plant steps; every episode starts from a
  burn-in window of ``burn_in`` real noisy measurements from a start-regime state) and deployed on the real plant.

Hyperparameters: the RL zoo's tuned Pendulum-v1 SAC (``learning_rate 1e-3``, everything else SB3's SAC
defaults; the zoo's 20k-step budget is replaced by ``--until-flat``).  With ``--until-flat`` training
runs in chunks of ``--eval-every`` decisions; after each chunk the deterministic policy is evaluated on
fixed seeded episodes of its training env (the real plant for ``sac-real``, the world model for
``sac-world``) and training stops when the learning curve is flat (:func:`is_flat`) or at ``--max-steps``.
A monitoring curve on the real plant (not used for stopping, not counted as training samples) is
plotted too.  Both agents are then evaluated like ``phast-control-eval`` (five regimes, success =
settled and quiet, effort ``sum_t u_t^2`` over plant steps) and compared with Energy-Casimir rows
(``--ec-estimators``) on success, effort and real-env samples.  Rows are merged into
``OUT/control_sac.json`` / ``OUT/control_sac.md`` (one process per agent is fine); learning curves go to
``OUT/curve_<agent>.json`` and ``OUT/curve_<agent>.png``.

* ``sac-gym`` (alone): the same SAC construction and training loop on a Gymnasium env (``--gym-env``, default
  ``Pendulum-v1``) as a harness check (rows in ``OUT/gym_sac.json`` / ``OUT/gym_sac.md``).

Ablations: ``--obs`` (true-velocity / true-state observations), ``--quiet-weight`` (0.5 at ``q* = 0``; 0.05 at the
upright, below :func:`max_quiet_weight`), ``--reward precise``, ``--curve`` (fixed budget with a learning curve);
see docs/control_results/sac/DIAGNOSIS.md.

    python benchmarks/control_sac.py --out OUT --agents sac-real --until-flat --reward quiet --q-star 0
    python benchmarks/control_sac.py --out OUT --agents sac-gym --steps 20000 --curve --seed 0
"""

from __future__ import annotations

import argparse
import json
import math
import re
import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
import torch

from phast_gym.control import (
    START_REGIMES,
    ControlProtocol,
    evaluate_estimators,
    make_control_env,
    resolve_estimator_name,
    sample_start_states,
    start_states,
)
from phast_gym.fileio import atomic_write_text
from phast_gym.reward import regulation_reward
from phast_gym.systems.base import SCALAR, wrap

#: the RL zoo's tuned SAC hyperparameters for Pendulum-v1 (rl-baselines3-zoo hyperparams/sac.yml: ``policy MlpPolicy,
#: learning_rate 1e-3, n_timesteps 20000``); the rest are SB3's SAC defaults, written out so the JSON records them.
ZOO_PENDULUM_SAC: dict[str, Any] = {
    "learning_rate": 1e-3, "buffer_size": 1_000_000, "learning_starts": 100, "batch_size": 256, "tau": 0.005,
    "gamma": 0.99, "train_freq": 1, "gradient_steps": 1, "ent_coef": "auto", "use_sde": False,
    "policy_kwargs": {"net_arch": [256, 256]},
}

REWARDS = ("zoo", "quiet", "precise")
#: the quiet reward's extra torque weight and the angle scale of the region where it applies
QUIET_WEIGHT, QUIET_SCALE = 0.5, 0.3
#: the precise reward's extra angle well: depth and width (the success rule's 0.05 rad tolerance)
PRECISE_WEIGHT, PRECISE_SCALE = 0.1, 0.05


class Well(NamedTuple):
    """An angle well of the ``precise`` reward: ``-depth (1 - exp(-(err / width)^2))`` per step."""

    depth: float
    width: float


#: the ``precise`` reward's default wells (``--wells``): one, as wide as the success tolerance
PRECISE_WELLS: tuple[Well, ...] = (Well(PRECISE_WEIGHT, PRECISE_SCALE),)


def parse_wells(text: str) -> tuple[Well, ...]:
    """``"DEPTH:WIDTH[,DEPTH:WIDTH...]"`` -> wells; depths >= 0 and widths > 0, or a ValueError naming the bad item."""
    wells = []
    for item in text.split(","):
        try:
            depth, width = (float(x) for x in item.split(":"))
        except ValueError:
            raise ValueError(f"well {item!r} is not DEPTH:WIDTH (e.g. 0.1:0.05)") from None
        if not (depth >= 0 and width > 0 and math.isfinite(depth) and math.isfinite(width)):
            raise ValueError(f"well {item!r} needs depth >= 0 and width > 0")
        wells.append(Well(depth, width))
    return tuple(wells)


def format_wells(wells: Sequence[Well]) -> str:
    return ",".join(f"{w.depth:g}:{w.width:g}" for w in wells)


def pendulum_reward(err: float, v: float, u: float, kind: str = "zoo", quiet_weight: float = QUIET_WEIGHT,
                    wells: Sequence[Well] = PRECISE_WELLS) -> float:
    """Per-step reward from the wrapped angle error ``err`` (rad), velocity ``v`` and torque ``u`` (N m).

    ``zoo``: the suite's standard reward (:func:`phast_gym.reward.regulation_reward`), the Gymnasium Pendulum shape
    ``-(err^2 + 0.1 v^2 + 0.001 u^2)``.
    ``quiet``: that minus ``quiet_weight u^2 exp(-(err / QUIET_SCALE)^2)``: a torque penalty that is 500x larger
    (``quiet_weight`` 0.5) near the target, so holding the target with a quiet actuator (the success rule's RMS
    torque) pays.  At an unstable target the weight must stay below :func:`max_quiet_weight` (see there).
    ``precise``: ``quiet`` minus ``PRECISE_WEIGHT (1 - exp(-(err / PRECISE_SCALE)^2))``: a narrow angle well as wide as
    the success tolerance, whose slope at a few 0.01 rad is ~30x that of ``err^2``, so a steady offset of the held angle
    costs (at the upright a 0.03 rad offset needs 0.3 N m of holding torque, over the 0.25 N m RMS limit).
    ``wells`` replaces that one well by others (``--wells``), e.g. a second, wider one whose pull reaches the offsets
    of 0.1-0.3 rad where the narrow well is flat and ``err^2`` is weak.
    """
    r = regulation_reward(err * err, v * v, u * u)
    if kind in ("quiet", "precise"):
        r -= quiet_weight * u * u * math.exp(-((err / QUIET_SCALE) ** 2))
    if kind == "precise":
        r -= sum(w.depth * (1.0 - math.exp(-((err / w.width) ** 2))) for w in wells)
    elif kind not in ("zoo", "quiet"):
        raise ValueError(f"reward must be one of {REWARDS}, got {kind!r}")
    return r


def max_quiet_weight(mgl: float) -> float:
    """The largest ``quiet_weight`` for which holding a pendulum still at an angle error ``e`` from an *unstable* target
    costs more the larger ``e`` is.

    Holding still at ``e`` needs the gravity torque ``u = m g l sin e`` (zero only at the target), so the quiet
    reward's static cost is ``h(e) = e^2 + w (m g l sin e)^2 exp(-(e / s)^2)``.  For small ``e`` that is
    ``e^2 (1 + c exp(-x))`` with ``c = w (m g l)^2``, ``x = (e / s)^2``, whose derivative ``2 e (1 + c exp(-x) (1 - x))``
    stays positive for every ``x`` iff ``c < e^2 = 7.39`` (the minimum of ``exp(-x) (1 - x)`` is ``-exp(-2)``, at
    ``x = 2``), whatever the scale ``s``.  Above it ``h`` has a spurious minimum away from the target (with
    ``w = 0.5``, ``m g l = 9.81``: at ``e = 0.7`` rad, cost 0.62 per step behind a barrier of 1.64 at ``e = 0.3``).
    At a stable target (hanging) no holding torque is needed and the bound does not apply.
    """
    return math.exp(2.0) / mgl**2


def upright_quiet_weight(mgl: float) -> float:
    """The quiet weight used at the upright by default: ``0.05 (9.81 / m g l)^2`` (0.05 for our plant, 0.65 of
    :func:`max_quiet_weight`, 10x below :data:`QUIET_WEIGHT`).  The reward only reads ``m g l`` to set this weight."""
    return 0.05 * (9.81 / mgl) ** 2


def is_flat(curve: Sequence[float], window: int = 4, rel_tol: float = 0.05, abs_tol: float = 0.05) -> bool:
    """Flatness rule: at least ``2 window`` points and the mean of the last ``window`` evaluation returns
    improves on the mean of the ``window`` before by less than ``max(rel_tol |mean_prev|, abs_tol)``."""
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    if len(curve) < 2 * window:
        return False
    last, prev = float(np.mean(curve[-window:])), float(np.mean(curve[-2 * window:-window]))
    return last - prev < max(rel_tol * abs(prev), abs_tol)


def stack_frames(buf: Sequence[np.ndarray]) -> np.ndarray:
    """(sin q, cos q) of the buffered measurements, oldest first."""
    q = np.concatenate([np.asarray(b, dtype=np.float64).reshape(-1) for b in buf])
    return np.concatenate([np.sin(q), np.cos(q)]).astype(np.float32)


#: policy observations: ``frames`` (the default, q-only): (sin q, cos q) of the last ``frames`` noisy measurements;
#: ``frames+qdot``: that plus the true velocity (oracle-velocity ablation); ``state``: (sin q, cos q, qdot) of the true,
#: noise-free state (Gymnasium Pendulum-v1's observation, measured from our q; ablation).
OBS_MODES = ("frames", "frames+qdot", "state")


class ObsBuilder:
    """The policy observation of :data:`OBS_MODES` from the noisy measurement and the true state; one instance per
    episode stream, used by training (:class:`FrameObs`) and by :func:`evaluate_policy_on_plant` alike."""

    def __init__(self, frames: int = 3, mode: str = "frames", inertia: float = 1.0) -> None:
        if mode not in OBS_MODES:
            raise ValueError(f"obs must be one of {OBS_MODES}, got {mode!r}")
        self.frames, self.mode, self.inertia = frames, mode, inertia
        self._buf: deque[np.ndarray] = deque(maxlen=frames)

    @property
    def size(self) -> int:
        return {"frames": 2 * self.frames, "frames+qdot": 2 * self.frames + 1, "state": 3}[self.mode]

    def reset(self, meas: np.ndarray, state: np.ndarray | None = None) -> np.ndarray:
        """Clear the buffer and fill it with ``frames`` copies of the first measurement."""
        self._buf.clear()
        self._buf.extend([np.asarray(meas, dtype=np.float64)] * self.frames)
        return self._obs(state)

    def push(self, meas: np.ndarray, state: np.ndarray | None = None) -> np.ndarray:
        self._buf.append(np.asarray(meas, dtype=np.float64))
        return self._obs(state)

    def _obs(self, state: np.ndarray | None) -> np.ndarray:
        if self.mode == "frames":
            return stack_frames(self._buf)
        if state is None:
            raise ValueError(f"obs {self.mode!r} needs the true state (info['state'])")
        q, p = float(state[0]), float(state[1])
        qdot = p / self.inertia  # the pendulum's velocity (p = I qdot)
        if self.mode == "state":
            return np.array([math.sin(q), math.cos(q), qdot], dtype=np.float32)
        return np.concatenate([stack_frames(self._buf), np.array([qdot], dtype=np.float32)])


class FrameObs(gym.Wrapper):
    """q-only observation -> (sin q, cos q) of the last ``frames`` measurements (velocity is implicit), or another
    :data:`OBS_MODES` observation (ablations that read the true state from ``info['state']``).

    At reset the buffer is cleared and filled with ``frames`` copies of the first measurement.
    """

    def __init__(self, env: gym.Env, frames: int = 3, obs: str = "frames") -> None:
        super().__init__(env)
        self.frames = frames
        system = getattr(env.unwrapped, "system", None)
        self.builder = ObsBuilder(frames, obs, float(getattr(system, "inertia", 1.0) or 1.0))
        lim = 1.0 if obs == "frames" else np.inf
        self.observation_space = gym.spaces.Box(-lim, lim, shape=(self.builder.size,), dtype=np.float32)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(**kwargs)
        return self.builder.reset(obs, info.get("state")), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        obs, r, term, trunc, info = self.env.step(action)
        return self.builder.push(obs, info.get("state")), r, term, trunc, info


def check_regimes(regimes: Sequence[str]) -> tuple[str, ...]:
    """The start regimes as a tuple in :data:`START_REGIMES` order; ValueError naming an unknown or missing one."""
    bad = [r for r in regimes if r not in START_REGIMES]
    if bad or not regimes:
        raise ValueError(f"start regimes must be a non-empty subset of {list(START_REGIMES)}, got {list(regimes)}")
    return tuple(r for r in START_REGIMES if r in regimes)


class RepeatRegimeEnv(gym.Wrapper):
    """Hold each action for ``repeat`` plant steps (mean reward over them); reset from the start-regime mix.

    Resets draw from an own generator (seeded by ``seed`` or the first ``reset(seed=...)``), so a training
    run is reproducible; ``reset(options={"state": x0})`` starts from ``x0``.  ``plant_steps`` counts the
    plant steps (real-env samples) consumed.
    """

    def __init__(self, env: gym.Env, repeat: int, episode_decisions: int, max_action: float, q_star: float = 0.0,
                 reward: str = "zoo", seed: int | None = None, quiet_weight: float = QUIET_WEIGHT,
                 wells: Sequence[Well] = PRECISE_WELLS, regimes: Sequence[str] = tuple(START_REGIMES)) -> None:
        super().__init__(env)
        self.regimes = check_regimes(regimes)
        if reward not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {reward!r}")
        self.q_star, self.reward_kind, self.quiet_weight, self.wells = q_star, reward, quiet_weight, tuple(wells)
        self.repeat, self.episode_decisions = repeat, episode_decisions
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=env.action_space.shape, dtype=np.float32)
        self.max_action = max_action
        self._rng = np.random.default_rng(seed)
        self._k = 0
        self.plant_steps = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        options = dict(options or {})
        if options.get("state") is None:
            regime = self.regimes[int(self._rng.integers(len(self.regimes)))]
            options["state"] = sample_start_states(self.env.unwrapped.system, regime, self._rng, 1)[0]
        self._k = 0
        return self.env.reset(seed=int(self._rng.integers(2**31)), options=options)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        u = np.clip(np.asarray(action, dtype=np.float64), -1, 1) * self.max_action
        total = 0.0
        system = self.env.unwrapped.system
        us, errs = [], []
        for _ in range(self.repeat):
            obs, _, term, trunc, info = self.env.step(u)
            x = info["state"]
            (v,) = system.velocity([float(x[0])], [float(x[1])], SCALAR)
            err = float(wrap(x[0] - self.q_star))
            total += pendulum_reward(err, v, float(u[0]), self.reward_kind, self.quiet_weight, self.wells)
            us.append(float(u[0]))
            errs.append(abs(err))
            self.plant_steps += 1
            if term:
                break
        self._k += 1
        info = {**info, "plant_u": us, "plant_err": errs}
        return obs, total / len(us), term, trunc or self._k >= self.episode_decisions, info


class RegimeWorldEnv(gym.Wrapper):
    """World-model env: actions in [-1, 1] scaled to the torque bound, the chosen reward recomputed from the model's
    q and velocity estimate, observations with ``sigma`` measurement noise added (as on the plant), and every episode
    started from ``burn_in`` real noisy zero-torque measurements (run dt) from a start-regime state.

    ``real_samples`` counts the real measurements consumed by burn-ins.
    """

    def __init__(self, env: gym.Env, max_action: float, q_star: float, reward: str, sigma: float, burn_in: int,
                 seed: int | None = None, quiet_weight: float = QUIET_WEIGHT, wells: Sequence[Well] = PRECISE_WELLS,
                 regimes: Sequence[str] = tuple(START_REGIMES), plant_env_id: str = ControlProtocol.env_id) -> None:
        super().__init__(env)
        self.regimes = check_regimes(regimes)
        if reward not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {reward!r}")
        self.max_action, self.q_star, self.reward_kind, self.sigma, self.burn_in = max_action, q_star, reward, sigma, burn_in
        self.quiet_weight, self.wells = quiet_weight, tuple(wells)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=env.action_space.shape, dtype=np.float32)
        self._rng = np.random.default_rng(seed)
        self._plant = make_control_env(ControlProtocol(plant_env_id, dt=float(env.unwrapped.real.dt), horizon=10**9), sigma)
        self.real_samples = 0

    def burn_in_window(self, rng: np.random.Generator) -> np.ndarray:
        """``burn_in`` noisy zero-torque measurements of the real plant from a random start-regime state."""
        regime = self.regimes[int(rng.integers(len(self.regimes)))]
        x0 = sample_start_states(self._plant.unwrapped.system, regime, rng, 1)[0]
        obs, _ = self._plant.reset(seed=int(rng.integers(2**31)), options={"state": x0})
        qs = [np.asarray(obs, dtype=np.float64)]
        for _ in range(self.burn_in - 1):
            obs, *_ = self._plant.step(np.zeros(1))
            qs.append(np.asarray(obs, dtype=np.float64))
        self.real_samples += self.burn_in
        return np.array(qs)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        options = dict(options or {})
        if options.get("q_burn") is None:
            options["q_burn"] = self.burn_in_window(self._rng)
        obs, info = self.env.reset(seed=int(self._rng.integers(2**31)), options=options)
        return self._noisy(obs), info

    def _noisy(self, obs: np.ndarray) -> np.ndarray:
        return np.asarray(obs, dtype=np.float64) + self.sigma * self._rng.standard_normal(np.shape(obs))

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        u = np.clip(np.asarray(action, dtype=np.float64), -1, 1) * self.max_action
        obs, r, term, trunc, info = self.env.step(u.astype(np.float32))
        if not term:
            err = float(wrap(float(obs[0]) - self.q_star))
            r = pendulum_reward(err, float(info["velocity"][0]), float(u[0]), self.reward_kind, self.quiet_weight, self.wells)
        return self._noisy(obs), float(r), term, trunc, info


def episode_return(model: Any, env: gym.Env, seed: int, options: dict | None = None) -> float:
    """Return of one deterministic episode of ``model`` in ``env`` (a FrameObs-wrapped env)."""
    obs, _ = env.reset(seed=seed, options=options)
    total, done = 0.0, False
    while not done:
        a, _ = model.predict(obs, deterministic=True)
        obs, r, term, trunc, _ = env.step(a)
        total += float(r)
        done = term or trunc
    return total


def evaluate_policy_on_plant(model: Any, protocol: ControlProtocol, sigma: float, trials: int, repeat: int, frames: int,
                             max_action: float, seed: int = 0, obs_mode: str = "frames",
                             regimes: Sequence[str] = tuple(START_REGIMES)) -> dict[str, float]:
    """The phast-control-eval metrics for an SB3 policy on the real plant (same initial states and noise seeds).

    The frame buffer holds measurements at the decision rate (every ``repeat`` plant steps, as in training) and is
    filled with copies of the first measurement at every start.
    """
    from phast_gym.control.evaluation import stable_seed

    env = make_control_env(protocol, sigma)
    builder = ObsBuilder(frames, obs_mode, float(getattr(env.unwrapped.system, "inertia", 1.0) or 1.0))
    chosen = check_regimes(regimes)
    states = {r: x for r, x in start_states(protocol, trials, seed).items() if r in chosen}
    succ, succ_angle, eff, fin, rms = [], [], [], [], []
    for regime, x0s in states.items():
        for i, x0 in enumerate(x0s):
            obs, info = env.reset(seed=stable_seed(seed, "noise", regime, i), options={"state": x0})
            pobs = builder.reset(obs, info["state"])
            us, errs = [], []
            u = np.zeros(1)
            for t in range(protocol.horizon):
                if t % repeat == 0:
                    if t > 0:
                        pobs = builder.push(obs, info["state"])
                    a, _ = model.predict(pobs, deterministic=True)
                    u = np.clip(a, -1, 1) * max_action
                obs, _, _, _, info = env.step(u)
                us.append(float(u[0]))
                errs.append(abs(float(wrap(info["state"][0] - protocol.q_star))))
            us_a, errs_a = np.array(us), np.array(errs)
            tail = slice(-protocol.settle_steps, None)
            settled = bool(np.all(errs_a[tail] < protocol.tol))
            u_rms = float(np.sqrt(np.mean(us_a[tail] ** 2)))
            succ.append(settled and u_rms < protocol.u_tol)
            succ_angle.append(settled)
            rms.append(u_rms)
            eff.append(float(np.sum(us_a**2)))
            fin.append(errs_a[-1])
    return {"success_rate": float(np.mean(succ)), "success_angle_rate": float(np.mean(succ_angle)), "effort": float(np.mean(eff)),
            "final_error": float(np.mean(fin)), "u_rms_final": float(np.mean(rms)),
            "trial_final_errors": [round(float(e), 5) for e in fin], "trial_u_rms_final": [round(float(r), 4) for r in rms]}


#: angle offsets (rad) from the target at which :func:`torque_at_rest` reads a policy
REST_OFFSETS = (-0.1, 0.0, 0.1)


def torque_at_rest(model: Any, q_star: float, frames: int, max_action: float, obs_mode: str = "frames",
                   offsets: Sequence[float] = REST_OFFSETS) -> list[float]:
    """The deterministic torque (N m) a policy applies with the pendulum at rest at ``q_star + e`` for each ``e``
    of ``offsets`` (noise-free frames).  A symmetric policy applies 0 at the target; a nonzero value there is a bias,
    and the policy then holds still where that bias balances gravity (``-m g l sin e``; DIAGNOSIS.md item 7)."""
    out = []
    for e in offsets:
        q = np.array([q_star + e])
        obs = ObsBuilder(frames, obs_mode).reset(q, np.array([q_star + e, 0.0]))
        a, _ = model.predict(obs, deterministic=True)
        out.append(round(float(np.clip(a, -1, 1)[0]) * max_action, 3))
    return out


def plot_curve(curve: dict[str, Any], path: Path) -> None:
    """Learning curve PNG: eval return on the training env (stopping rule) and on the real plant (monitoring)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    x = np.array(curve["decisions"])
    rule = curve.get("until_flat", True)
    ax.plot(x, curve["train_env_return"], "o-", ms=3, label=curve["train_env"] + (" (stopping rule)" if rule else ""))
    if curve["agent"] == "sac-world":
        ax.plot(x, curve["plant_return"], "s--", ms=3, label="real plant (monitoring)")
    ax.set_xlabel("SAC decisions (env steps)")
    ax.set_ylabel(f"mean eval return ({curve['n_eval_episodes']} episodes)")
    stop = (f"flat at {x[-1]}" if curve["flat"] else f"cap {x[-1]} (not flat)") if rule else f"fixed budget {x[-1]}"
    if curve["agent"] == "sac-gym":
        ax.set_title(f"sac-gym on {curve['train_env']}, seed {curve.get('seed', 0)}: {x[-1]} steps", fontsize=9)
    else:
        extra = "" if curve.get("obs", "frames") == "frames" else f", obs {curve['obs']}"
        if curve["reward"] != "zoo" and curve.get("quiet_weight", QUIET_WEIGHT) != QUIET_WEIGHT:
            extra += f", w {curve['quiet_weight']:g}"
        if curve.get("wells"):
            extra += f", wells {curve['wells']}"
        ax.set_title(f"{curve['agent']}, q* = {curve['q_star']:.3g}, reward {curve['reward']}{extra}: {stop}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


class StepCounter(gym.Wrapper):
    """Counts the env steps taken (``plant_steps``, as :class:`RepeatRegimeEnv`): the sample counter of ``sac-gym``."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.plant_steps = 0

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.plant_steps += 1
        return self.env.step(action)


def evaluate_gym_policy(model: Any, env_id: str, episodes: int, seed: int = 0, window: int = 20,
                        tol: float = 0.05) -> dict[str, float]:
    """Deterministic returns of ``model`` on ``episodes`` seeded episodes of a Gymnasium env (the zoo's metric), and for
    ``Pendulum-v1`` (observation cos, sin, thetadot; theta = 0 upright) the analogue of our success rule over the last
    ``window`` steps (1 s): the share of episodes with ``|theta| < tol`` throughout, mean final ``|theta|`` and the
    mean RMS torque over the window."""
    env = gym.make(env_id)
    rets, settled, fin, rms = [], [], [], []
    for i in range(episodes):
        obs, _ = env.reset(seed=seed * 1000 + 50_000 + i)
        total, done, ths, us = 0.0, False, [], []
        while not done:
            a, _ = model.predict(obs, deterministic=True)
            obs, r, term, trunc, _ = env.step(a)
            total += float(r)
            ths.append(abs(math.atan2(float(obs[1]), float(obs[0]))) if len(obs) == 3 else float("nan"))
            us.append(float(np.clip(a, env.action_space.low, env.action_space.high)[0]))
            done = term or trunc
        rets.append(total)
        settled.append(bool(np.all(np.array(ths[-window:]) < tol)))
        fin.append(ths[-1])
        rms.append(float(np.sqrt(np.mean(np.square(us[-window:])))))
    return {"mean_return": float(np.mean(rets)), "std_return": float(np.std(rets)), "episodes": episodes,
            "settled_rate": float(np.mean(settled)), "final_abs_theta": float(np.mean(fin)), "u_rms_final": float(np.mean(rms))}


def sac_hyperparameters(args: argparse.Namespace) -> dict[str, Any]:
    """:data:`ZOO_PENDULUM_SAC` with ``--net`` (hidden layer sizes) in place of its ``net_arch``."""
    hp = dict(ZOO_PENDULUM_SAC)
    if getattr(args, "net", None):
        hp["policy_kwargs"] = {**hp["policy_kwargs"], "net_arch": [int(h) for h in args.net.split(",")]}
    return hp


class LinearDecay:
    """A learning rate going linearly from ``start`` to ``final`` over ``budget`` decisions of ``model`` (counted by
    its ``num_timesteps``, so training in chunks of ``learn`` calls follows one schedule), then held."""

    def __init__(self, start: float, final: float, budget: int, model: Any) -> None:
        self.start, self.final, self.budget, self.model = start, final, max(int(budget), 1), model

    def __call__(self, _progress_remaining: float) -> float:
        frac = min(self.model.num_timesteps / self.budget, 1.0)
        return self.start + (self.final - self.start) * frac


def make_agent_env(name: str, args: argparse.Namespace, seed: int) -> tuple[gym.Env, gym.Env]:
    """(observation env, inner env with the sample counter) of an agent's training environment."""
    if name == "sac-gym":
        env = StepCounter(gym.make(args.gym_env))
        return env, env
    if name == "sac-real":
        inner: gym.Env = RepeatRegimeEnv(make_control_env(ControlProtocol(args.env, horizon=10**9), args.sigma), args.repeat,
                                         args.episode_decisions, args.max_action, args.q_star, args.reward, seed=seed,
                                         quiet_weight=quiet_weight_of(args), wells=wells_of(args),
                                         regimes=regimes_of(args))
        return FrameObs(inner, args.frames, args.obs), inner
    from phast_model.world.gym_env import PHASTWorldModelEnv

    # env_id: the plant, which also serves a model of its recordings (sac_world_data.py) that names no simulator
    wm = PHASTWorldModelEnv(args.phast_run, env_id=args.env, burn_in=args.burn_in,
                            max_episode_steps=args.episode_decisions, target=np.array([args.q_star]))
    if abs(wm.real.dt - ControlProtocol.dt * args.repeat) > 1e-9:
        raise ValueError(f"world model dt {wm.real.dt} != repeat * plant dt {ControlProtocol.dt * args.repeat}")
    inner = RegimeWorldEnv(wm, args.max_action, args.q_star, args.reward, args.sigma, args.burn_in, seed=seed,
                           quiet_weight=quiet_weight_of(args), wells=wells_of(args), regimes=regimes_of(args),
                           plant_env_id=args.env)
    return FrameObs(inner, args.frames), inner


def quiet_weight_of(args: argparse.Namespace) -> float:
    """``--quiet-weight``, or its default: :data:`QUIET_WEIGHT` at the hanging target ``q_star = 0`` (no holding torque
    needed), :func:`upright_quiet_weight` of the plant's ``m g l`` at any other target (see :func:`max_quiet_weight`)."""
    w = getattr(args, "quiet_weight", None)
    if w is not None:
        return float(w)
    if abs(float(wrap(float(args.q_star)))) < 1e-9:
        return QUIET_WEIGHT
    from phast_gym.control.evaluation import control_system

    return upright_quiet_weight(float(control_system(ControlProtocol(getattr(args, "env", ControlProtocol.env_id))).mgl))


def regimes_of(args: argparse.Namespace) -> tuple[str, ...]:
    """``--regimes`` (start regimes of training, burn-ins and evaluation), or all of :data:`START_REGIMES`."""
    text = getattr(args, "regimes", None)
    return tuple(START_REGIMES) if text is None else check_regimes(text.split(","))


def wells_of(args: argparse.Namespace) -> tuple[Well, ...]:
    """``--wells`` (the ``precise`` reward's angle wells), or :data:`PRECISE_WELLS`."""
    text = getattr(args, "wells", None)
    return PRECISE_WELLS if text is None else parse_wells(text)


def method_tag(name: str, args: argparse.Namespace) -> str:
    """Row name: ``agent/reward``, plus the non-default observation and quiet weight; ``sac-gym/<env id>``."""
    if name == "sac-gym":
        return f"sac-gym/{args.gym_env}"
    tag = f"{name}/{args.reward}"
    if args.reward != "zoo" and quiet_weight_of(args) != QUIET_WEIGHT:
        tag += f"/w{quiet_weight_of(args):g}"
    if args.reward == "precise" and wells_of(args) != PRECISE_WELLS:
        tag += f"/wells={format_wells(wells_of(args))}"
    if args.obs != "frames":
        tag += f"/obs={args.obs}"
    if getattr(args, "net", None):
        tag += "/net" + "x".join(h.strip() for h in args.net.split(","))
    if getattr(args, "lr_final", None) is not None:
        tag += f"/lrf{args.lr_final:g}"
    if getattr(args, "mirror", False):
        tag += "/mirror"
    return tag


def curve_stem(name: str, args: argparse.Namespace) -> str:
    """File stem of an agent's learning curve (``curve_<agent>_<reward>`` as before for the default options)."""
    if name == "sac-gym":
        return f"curve_sac-gym_{args.gym_env}_s{args.seed}"
    tag = method_tag(name, args).replace("/", "_").replace("=", "-")
    return "curve_" + re.sub(r"[^A-Za-z0-9._+-]", "-", tag.replace(",", "+"))  # portable file names


def train_agent(name: str, args: argparse.Namespace, out: Path) -> dict[str, Any]:
    """Train one agent (until flat or a fixed budget), write its learning curve, return its result row."""
    from stable_baselines3 import SAC
    from tqdm.auto import tqdm

    t0 = time.time()
    train_env, counter = make_agent_env(name, args, args.seed)
    eval_env, eval_inner = make_agent_env(name, args, args.seed + 1)
    plant_eval = None if name != "sac-world" else make_agent_env("sac-real", args, args.seed + 2)[0]
    n_eval = args.eval_episodes
    eval_seeds = [args.seed * 1000 + 10_000 + i for i in range(n_eval)]
    world = name == "sac-world"
    world_data = world_data_samples(args.phast_run) if world else 0  # the world model's own training recordings
    # fixed evaluation starts: the same seeded states (plant, Gymnasium env) or burn-ins (world model, drawn once:
    # real samples)
    if not world:
        eval_opts: list[dict | None] = [None] * n_eval
    else:
        eval_opts = [{"q_burn": eval_inner.burn_in_window(np.random.default_rng(s))} for s in eval_seeds]
    hp = sac_hyperparameters(args)
    policy_cls: Any = "MlpPolicy"
    if getattr(args, "mirror", False):
        from phast_model.world.mirror_policy import MirrorSACPolicy, mirror_signs

        policy_cls = MirrorSACPolicy
        hp["policy_kwargs"] = {**hp["policy_kwargs"], "mirror": mirror_signs(args.frames, velocity=args.obs == "frames+qdot",
                                                                            state=args.obs == "state")}
    model = SAC(policy_cls, train_env, seed=args.seed, verbose=0, **hp)
    budget = args.max_steps if args.until_flat else args.steps
    if args.lr_final is not None:
        model.lr_schedule = LinearDecay(float(hp["learning_rate"]), args.lr_final, budget, model)
    record = args.until_flat or args.curve  # --curve: a learning curve at a fixed budget (no stopping rule)
    chunk = args.eval_every if record else budget
    stem = curve_stem(name, args)
    train_env_name = {"sac-real": "real plant", "sac-world": "PHAST world model"}.get(name, args.gym_env)
    curve: dict[str, Any] = {"agent": name, "q_star": args.q_star, "reward": args.reward, "sigma": args.sigma,
                             "obs": args.obs, "quiet_weight": quiet_weight_of(args), "seed": args.seed,
                             "wells": format_wells(wells_of(args)) if args.reward == "precise" else None,
                             "until_flat": bool(args.until_flat),
                             "train_env": train_env_name,
                             "n_eval_episodes": n_eval, "rule": {"window": args.flat_window, "rel_tol": args.flat_rel_tol,
                                                                 "abs_tol": args.flat_abs_tol},
                             "decisions": [], "train_env_return": [], "plant_return": [], "real_env_samples": [],
                             "seconds": [], "flat": False}
    bar = tqdm(total=budget, desc=f"{name} decisions", disable=args.no_progress)
    done = 0
    while done < budget:
        n = min(chunk, budget - done)
        model.learn(total_timesteps=n, reset_num_timesteps=done == 0, progress_bar=False)
        done += n
        bar.update(n)
        if not record:
            break
        ret = float(np.mean([episode_return(model, eval_env, s, o) for s, o in zip(eval_seeds, eval_opts)]))
        plant = ret if not world else float(np.mean([episode_return(model, plant_eval, s) for s in eval_seeds]))
        real = counter.plant_steps if not world else counter.real_samples + eval_inner.real_samples + world_data
        for k, v in (("decisions", done), ("train_env_return", ret), ("plant_return", plant), ("real_env_samples", int(real)),
                     ("seconds", round(time.time() - t0, 1))):
            curve[k].append(v)
        bar.set_postfix(ret=f"{ret:.2f}", plant=f"{plant:.2f}")
        atomic_write_text(out / f"{stem}.json", json.dumps(curve, indent=1))  # partial curve
        if args.until_flat and is_flat(curve["train_env_return"], args.flat_window, args.flat_rel_tol, args.flat_abs_tol):
            curve["flat"] = True
            break
    bar.close()
    secs = time.time() - t0
    real = counter.plant_steps if not world else counter.real_samples + eval_inner.real_samples + world_data
    if name == "sac-gym":
        m = evaluate_gym_policy(model, args.gym_env, args.gym_eval_episodes, args.seed)
    else:
        m = evaluate_policy_on_plant(model, make_protocol(args.q_star, args.env), args.sigma, args.trials_per_regime,
                                     args.repeat, args.frames, args.max_action, args.seed, args.obs, regimes_of(args))
        m["torque_at_rest"] = dict(zip((f"{e:+g}" for e in REST_OFFSETS),
                                       torque_at_rest(model, args.q_star, args.frames, args.max_action, args.obs)))
    row = {"method": method_tag(name, args), **m, "real_env_samples": int(real), "world_model_samples": world_data,
           "hyperparameters": {**hp, "learning_rate_final": args.lr_final},
           "decisions": done,
           "flat": curve["flat"] if args.until_flat else None, "train_seconds": round(secs, 1), "seed": args.seed,
           "command": command_line(args, [name])}
    if record:
        atomic_write_text(out / f"{stem}.json", json.dumps(curve, indent=1))
        plot_curve(curve, out / f"{stem}.png")
    if name != "sac-gym":
        if args.lr_final is not None:  # the schedule holds the model: save the final rate instead
            from stable_baselines3.common.utils import FloatSchedule

            model.learning_rate, model.lr_schedule = args.lr_final, FloatSchedule(args.lr_final)
        policy = out / f"policy_{stem.removeprefix('curve_')}_s{args.seed}.zip"
        model.save(policy)  # the trained agent, deployable with SAC.load (no replay buffer)
        row["policy"] = str(policy)
    return row


def world_data_samples(run: str | Path) -> int:
    """Real samples behind a world-model run: ``real_samples`` of the ``world_data.json`` that
    ``benchmarks/sac_world_data.py`` writes beside a model of plant recordings; 0 without one (a model trained on
    simulated data, ``phast-train --env``: its samples are simulator outputs, reported separately)."""
    path = Path(run) / "world_data.json"
    if not path.exists():
        return 0
    try:
        return int(json.loads(path.read_text())["real_samples"])
    except (ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{path}: no integer 'real_samples' ({e})") from None


def make_protocol(q_star: float, env_id: str = ControlProtocol.env_id) -> ControlProtocol:
    """The evaluation protocol of plant ``env_id``; upright (q_star = pi) uses the upright Energy-Casimir gains
    k_c = 20, d_inj = 3."""
    upright = abs(math.cos(q_star) + 1) < 1e-9
    return ControlProtocol(env_id, q_star=q_star, k_c=20.0 if upright else ControlProtocol.k_c,
                           d_inj=3.0 if upright else ControlProtocol.d_inj)


#: options that only the plant agents (sac-real / sac-world) and the Energy-Casimir rows read
SAC_PLANT_ONLY = ("env", "regimes", "wells", "obs", "reward", "quiet_weight", "sigma", "trials_per_regime", "repeat",
                  "episode_decisions", "frames", "burn_in",
                  "max_action", "phast_run", "ec_estimators", "q_star")


def command_line(args: argparse.Namespace, agents: Sequence[str] | None = None) -> str:
    """The command that reproduces ``args`` (with ``agents`` in place of ``--agents``)."""
    parts = ["python benchmarks/control_sac.py"]
    for k, v in vars(args).items():
        if k == "agents" and agents is not None:
            v = ",".join(agents) or "none"
        if v is None or v is False or k in ("no_progress", "tables_only"):
            continue
        gym_only = agents is not None and list(agents) == ["sac-gym"]
        if agents is not None and ((k in ("gym_env", "gym_eval_episodes") and not gym_only) or (k in SAC_PLANT_ONLY and gym_only)):
            continue  # options the command's agents do not read
        parts.append(f"--{k.replace('_', '-')}" + ("" if v is True else f" {v}"))
    return " ".join(parts)


def write_tables(out: Path, meta: dict[str, Any]) -> None:
    """``control_sac.md`` from the merged rows of ``control_sac.json``."""
    regimes = meta.get("regimes", list(START_REGIMES))
    plant = meta.get("protocol", {}).get("env_id", ControlProtocol.env_id)
    where = "" if len(regimes) == len(START_REGIMES) else f" from {', '.join(regimes)}"
    lines = [f"SAC vs Energy-Casimir on {plant}, q_star = {meta['q_star']:.6g}, sigma = {meta['sigma']:g}, "
             f"{len(regimes) * meta['trials_per_regime']} trials{where} "
             "(success: |wrap(q - q*)| < 0.05 rad and RMS torque < 0.25 N m over the last 100 plant steps)", "",
             "| Method | Success | Success (angle only) | Effort | RMS torque, last 100 | Final error | Real-env samples "
             "| SAC decisions | Flat | Train s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in meta["results"]:
        flat = "-" if r.get("flat") is None else ("yes" if r["flat"] else "no (cap)")
        lines.append(f"| {r['method']} | {r['success_rate']:.2f} | {r['success_angle_rate']:.2f} | {r['effort']:.1f} | "
                     f"{r['u_rms_final']:.3f} | {r['final_error']:.2e} | {r['real_env_samples']} | {r.get('decisions', 0)} | {flat} | "
                     f"{r['train_seconds']} |")
    lines += ["", "Real-env samples: plant measurements consumed in training (sac-real: plant steps, 0.01 s apart; "
              "sac-world: burn-in measurements, 0.05 s apart, plus the recordings its world model was trained on when "
              "it comes from benchmarks/sac_world_data.py).", "", "Commands:", ""]
    lines += [f"* `{r['method']}`: `{r['command']}`" for r in meta["results"]]
    atomic_write_text(out / "control_sac.md", "\n".join(lines) + "\n")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--agents", default="sac-real,sac-world",
                    help="comma list of sac-real, sac-world (needs --phast-run); none: Energy-Casimir rows only; "
                         "sac-gym (alone): the same SAC on the Gymnasium env --gym-env (harness check, rows in OUT/gym_sac.json)")
    ap.add_argument("--gym-env", default="Pendulum-v1", help="Gymnasium env id of sac-gym")
    ap.add_argument("--gym-eval-episodes", type=int, default=20, help="seeded episodes of sac-gym's final evaluation")
    ap.add_argument("--curve", action="store_true", help="fixed budget --steps, with a learning curve every --eval-every")
    ap.add_argument("--obs", choices=OBS_MODES, default="frames",
                    help="policy observation: frames (q-only, default); frames+qdot / state: true-velocity ablations (sac-real)")
    ap.add_argument("--quiet-weight", type=float, default=None,
                    help=f"weight of the quiet reward's torque term (default {QUIET_WEIGHT} at q* = 0, 0.05 otherwise: "
                         "upright_quiet_weight)")
    ap.add_argument("--wells", default=None,
                    help="the precise reward's angle wells DEPTH:WIDTH[,...] (rad; default "
                         f"{format_wells(PRECISE_WELLS)})")
    ap.add_argument("--mirror", action="store_true",
                    help="reflection-equivariant SAC (odd actor, invariant critics: the pendulum's q -> -q symmetry; "
                         "phast_model.world.mirror_policy)")
    ap.add_argument("--net", default=None, help="SAC hidden layer sizes, e.g. 64,64 (default: the zoo's 256,256)")
    ap.add_argument("--lr-final", type=float, default=None,
                    help="decay the learning rate linearly from the zoo's 1e-3 to this over the budget (default: constant)")
    ap.add_argument("--steps", type=int, default=20000, help="SAC decisions per agent without --until-flat (zoo: 20k)")
    ap.add_argument("--until-flat", action="store_true", help="train until the learning curve is flat (is_flat) or --max-steps")
    ap.add_argument("--max-steps", type=int, default=150000, help="cap on SAC decisions with --until-flat")
    ap.add_argument("--eval-every", type=int, default=2500, help="decisions between learning-curve evaluations")
    ap.add_argument("--eval-episodes", type=int, default=10, help="fixed seeded episodes per learning-curve point")
    ap.add_argument("--flat-window", type=int, default=4, help="K: compare the mean of the last K points with the K before")
    ap.add_argument("--flat-rel-tol", type=float, default=0.05)
    ap.add_argument("--flat-abs-tol", type=float, default=0.05)
    ap.add_argument("--reward", choices=REWARDS, default="zoo")
    ap.add_argument("--env", default=ControlProtocol.env_id,
                    help="the plant (a phast_gym pendulum id; PHAST/Pendulum-v0: undamped, the swing-up task)")
    ap.add_argument("--regimes", default=None,
                    help=f"comma list of start regimes for training, burn-ins and evaluation (default all: {','.join(START_REGIMES)}); "
                         "near_stable: swing-up from hanging")
    ap.add_argument("--sigma", type=float, default=0.01)
    ap.add_argument("--trials-per-regime", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=5, help="plant steps per SAC decision (dt 0.01 -> 0.05)")
    ap.add_argument("--episode-decisions", type=int, default=200, help="training episode length in decisions (10 s)")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--burn-in", type=int, default=10, help="real measurements per world-model episode")
    ap.add_argument("--max-action", type=float, default=10.0, help="SAC torque bound (N m)")
    ap.add_argument("--phast-run", default=None, help="PHAST run for SAC inside PHASTWorldModelEnv")
    ap.add_argument("--ec-estimators", default="oracle,map,ukf")
    ap.add_argument("--q-star", type=float, default=0.0, help="target angle (pi: upright; EC gains k_c = 20, d_inj = 3)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--tables-only", action="store_true", help="only rewrite OUT/control_sac.md from OUT/control_sac.json")
    args = ap.parse_args(argv)
    agents = agents_of(args)
    for a in agents:
        if a not in ("sac-real", "sac-world", "sac-gym"):
            ap.error(f"unknown agent {a!r}")
        if a == "sac-world" and not args.phast_run:
            ap.error("sac-world needs --phast-run")
        if a == "sac-world" and args.obs != "frames":
            ap.error("sac-world observes frames only (the world model has no true state)")
    try:
        regimes_of(args)
    except ValueError as e:
        ap.error(str(e))
    if args.mirror and abs(math.sin(args.q_star)) > 1e-9:
        ap.error("--mirror needs a target the reflection q -> -q keeps: q_star 0 or pi")
    if args.net is not None and not all(h.strip().isdigit() and int(h) > 0 for h in args.net.split(",")):
        ap.error(f"--net must be positive layer sizes like 64,64, got {args.net!r}")
    if args.lr_final is not None and not (args.lr_final > 0 and math.isfinite(args.lr_final)):
        ap.error(f"--lr-final must be a positive learning rate, got {args.lr_final!r}")
    if args.wells is not None:
        if args.reward != "precise":
            ap.error("--wells shapes the precise reward only (add --reward precise)")
        try:
            parse_wells(args.wells)
        except ValueError as e:
            ap.error(str(e))
    if args.mirror and "sac-gym" in agents:
        ap.error("--mirror knows the plant agents' observations only (sac-real, sac-world)")
    if "sac-gym" in agents and len(agents) > 1:
        ap.error("sac-gym runs alone")
    return args


def agents_of(args: argparse.Namespace) -> list[str]:
    return [a for a in args.agents.split(",") if a and a != "none"]


def energy_casimir_rows(protocol: Any, args: argparse.Namespace) -> dict[str, dict[str, Any]]:
    """The Energy-Casimir reference rows, one per estimator (no real-env samples for training; the gains use the
    plant's m g l only)."""
    rows, _ = evaluate_estimators(protocol, args.ec_estimators.split(","), [args.sigma], args.trials_per_regime,
                                  seed=args.seed, progress=not args.no_progress)
    cmd = command_line(args, [])
    keys = ("success_rate", "success_angle_rate", "effort", "final_error", "u_rms_final")
    regimes = regimes_of(args)
    chosen = ("all",) if regimes == tuple(START_REGIMES) else regimes
    out: dict[str, dict[str, Any]] = {}
    for est in args.ec_estimators.split(","):
        mine = [r for r in rows if r["regime"] in chosen and r["estimator"] == resolve_estimator_name(est)]
        # equal trials per regime: the pooled mean over the chosen regimes is the mean of their means
        out[f"energy-casimir/{mine[0]['estimator']}"] = {
            "method": f"energy-casimir/{mine[0]['estimator']}",
            **{k: float(np.mean([r.get(k, float("nan")) for r in mine])) for k in keys},
            "real_env_samples": 0, "decisions": 0, "flat": None, "train_seconds": 0.0, "command": cmd}
    return out


def run_gym(args: argparse.Namespace, out: Path) -> None:
    """sac-gym: train, merge the row (one per env and seed) into ``OUT/gym_sac.json``, write ``OUT/gym_sac.md``."""
    path = out / "gym_sac.json"
    meta: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {"hyperparameters": ZOO_PENDULUM_SAC, "results": []}
    row = train_agent("sac-gym", args, out)
    print({k: v for k, v in row.items() if k != "command"}, flush=True)
    rows = [r for r in meta["results"] if (r["method"], r["seed"]) != (row["method"], row["seed"])] + [row]
    meta["results"] = sorted(rows, key=lambda r: (r["method"], r["seed"]))
    atomic_write_text(path, json.dumps(meta, indent=1))
    lines = ["SB3 SAC (zoo Pendulum-v1 hyperparameters) on Gymnasium envs: deterministic return on "
             f"{row['episodes']} seeded episodes; settled: |theta| < 0.05 rad over the last 20 steps (1 s)", "",
             "| Method | Seed | Steps | Mean return | Std | Settled | Final abs(theta) | RMS torque, last 20 | Train s |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in meta["results"]:
        lines.append(f"| {r['method']} | {r['seed']} | {r['decisions']} | {r['mean_return']:.1f} | {r['std_return']:.1f} | "
                     f"{r['settled_rate']:.2f} | {r['final_abs_theta']:.3g} | {r['u_rms_final']:.3f} | {r['train_seconds']} |")
    by: dict[str, list[float]] = {}
    for r in meta["results"]:
        by.setdefault(r["method"], []).append(r["mean_return"])
    lines += [""] + [f"{m}: mean over {len(v)} seeds {np.mean(v):.1f} (min {min(v):.1f}, max {max(v):.1f})" for m, v in by.items()]
    lines += ["", "Commands:", ""] + [f"* seed {r['seed']}: `{r['command']}`" for r in meta["results"]]
    atomic_write_text(out / "gym_sac.md", "\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.tables_only:
        write_tables(Path(args.out), json.loads((Path(args.out) / "control_sac.json").read_text()))
        return
    torch.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if agents_of(args) == ["sac-gym"]:
        run_gym(args, out)
        return
    protocol = make_protocol(args.q_star, args.env)
    path = out / "control_sac.json"
    meta: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    regimes = list(regimes_of(args))
    if meta and (meta.get("q_star") != args.q_star or meta.get("sigma") != args.sigma
                 or meta.get("trials_per_regime") != args.trials_per_regime
                 or meta.get("regimes", list(START_REGIMES)) != regimes
                 or meta.get("protocol", {}).get("env_id", ControlProtocol.env_id) != args.env):
        raise SystemExit(f"{path} holds another setting (plant/q_star/sigma/trials/regimes); use another --out")
    results: dict[str, dict[str, Any]] = {r["method"]: r for r in meta.get("results", [])}
    results.update(energy_casimir_rows(protocol, args))

    def save() -> None:
        order = sorted(results.values(), key=lambda r: (not r["method"].startswith("energy"), r["method"]))
        meta.update({"q_star": args.q_star, "sigma": args.sigma, "trials_per_regime": args.trials_per_regime,
                     "regimes": regimes, "protocol": protocol.to_dict(), "hyperparameters": ZOO_PENDULUM_SAC, "results": order})
        atomic_write_text(path, json.dumps(meta, indent=1))
        write_tables(out, meta)

    save()
    for name in agents_of(args):
        row = train_agent(name, args, out)
        results[row["method"]] = row
        print({k: v for k, v in row.items() if k != "command"}, flush=True)
        save()
    print((out / "control_sac.md").read_text())


if __name__ == "__main__":
    main()
