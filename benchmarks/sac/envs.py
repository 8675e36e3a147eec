"""The SAC agents' training environments: decisions every ``repeat`` plant steps with the torque held, resets from
the start regimes of :mod:`phast_gym.control`, the world-model env with real burn-ins, and the policy observation
(:class:`FrameObs`: the :class:`phast_model.rl.observation.ObsBuilder` that the evaluation on the plant uses too).

``sac-gym``'s env counts its steps with SB3's ``Monitor`` (:func:`benchmarks.sac.agents.make_agent_env`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, SupportsFloat, cast

import gymnasium as gym
import numpy as np

from phast_gym.control import START_REGIMES, ControlProtocol, make_control_env, sample_start_states
from phast_gym.env import PortHamiltonianEnv
from phast_gym.systems.base import SCALAR, System, wrap
from phast_model.rl.observation import ObsBuilder

from .rewards import Reward


def plant_system(env: gym.Env) -> System:
    """The system of a phast_gym env (under any wrappers)."""
    return cast(PortHamiltonianEnv, env.unwrapped).system


class FrameObs(gym.Wrapper):
    """q-only observation -> (sin q, cos q) of the last ``frames`` measurements (velocity is implicit), or another
    :data:`phast_model.rl.observation.OBS_MODES` observation (ablations that read the true state from
    ``info['state']``).

    At reset the buffer is cleared and filled with ``frames`` copies of the first measurement.  Not Gymnasium's
    ``FrameStackObservation`` (+ ``TransformObservation``): the plant evaluation steps the plant at its own rate and
    builds the same observation with the same :class:`ObsBuilder` (one code for both); the ablations read
    ``info['state']``, which an observation wrapper does not see; and ``FrameStackObservation`` stacks into an array
    of the inner space's dtype, float32 for the world model, whose noisy measurements are float64.
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

    def step(self, action: np.ndarray) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict]:
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
    plant steps (real-env samples) consumed.  Episodes have no end of their own: Gymnasium's ``TimeLimit`` ends
    them after the episode's decisions (:func:`benchmarks.sac.agents.make_agent_env`).
    """

    def __init__(self, env: gym.Env, repeat: int, max_action: float, q_star: float = 0.0, reward: str | Reward = "zoo",
                 seed: int | None = None, regimes: Sequence[str] = tuple(START_REGIMES)) -> None:
        super().__init__(env)
        self.regimes = check_regimes(regimes)
        self.q_star, self.reward_fn = q_star, reward if isinstance(reward, Reward) else Reward(reward)
        self.repeat = repeat
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=env.action_space.shape, dtype=np.float32)
        self.max_action = max_action
        self._rng = np.random.default_rng(seed)
        self.plant_steps = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        options = dict(options or {})
        if options.get("state") is None:
            regime = self.regimes[int(self._rng.integers(len(self.regimes)))]
            options["state"] = sample_start_states(plant_system(self.env), regime, self._rng, 1)[0]
        return self.env.reset(seed=int(self._rng.integers(2**31)), options=options)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict]:
        u = np.clip(np.asarray(action, dtype=np.float64), -1, 1) * self.max_action
        total = 0.0
        system = plant_system(self.env)
        us, errs = [], []
        for _ in range(self.repeat):
            obs, _, term, trunc, info = self.env.step(u)
            x = info["state"]
            (v,) = system.velocity([float(x[0])], [float(x[1])], SCALAR)
            err = float(wrap(x[0] - self.q_star))
            total += self.reward_fn(err, v, float(u[0]))
            us.append(float(u[0]))
            errs.append(abs(err))
            self.plant_steps += 1
            if term:
                break
        info = {**info, "plant_u": us, "plant_err": errs}
        return obs, total / len(us), term, trunc, info


class RegimeWorldEnv(gym.Wrapper):
    """World-model env: actions in [-1, 1] scaled to the torque bound, the chosen reward recomputed from the model's
    q and velocity estimate, observations with ``sigma`` measurement noise added (as on the plant), and every episode
    started from ``burn_in`` real noisy zero-torque measurements (run dt) from a start-regime state.

    ``real_samples`` counts the real measurements consumed by burn-ins.
    """

    def __init__(self, env: gym.Env, max_action: float, q_star: float, reward: str | Reward, sigma: float, burn_in: int,
                 seed: int | None = None, regimes: Sequence[str] = tuple(START_REGIMES),
                 plant_env_id: str = ControlProtocol.env_id) -> None:
        super().__init__(env)
        self.regimes = check_regimes(regimes)
        self.reward_fn = reward if isinstance(reward, Reward) else Reward(reward)
        self.max_action, self.q_star, self.sigma, self.burn_in = max_action, q_star, sigma, burn_in
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=env.action_space.shape, dtype=np.float32)
        self._rng = np.random.default_rng(seed)
        self._plant = make_control_env(ControlProtocol(plant_env_id, dt=float(cast(Any, env.unwrapped).real.dt), horizon=10**9), sigma)
        self.real_samples = 0

    def burn_in_window(self, rng: np.random.Generator) -> np.ndarray:
        """``burn_in`` noisy zero-torque measurements of the real plant from a random start-regime state."""
        regime = self.regimes[int(rng.integers(len(self.regimes)))]
        x0 = sample_start_states(plant_system(self._plant), regime, rng, 1)[0]
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

    def step(self, action: np.ndarray) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict]:
        u = np.clip(np.asarray(action, dtype=np.float64), -1, 1) * self.max_action
        obs, r, term, trunc, info = self.env.step(u.astype(np.float32))
        if not term:
            err = float(wrap(float(obs[0]) - self.q_star))
            r = self.reward_fn(err, float(info["velocity"][0]), float(u[0]))
        return self._noisy(obs), float(r), term, trunc, info
