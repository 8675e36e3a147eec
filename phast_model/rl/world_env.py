"""The agent's training env inside the learned world model, started where the plant has been.

:class:`WorldTaskEnv` wraps :class:`phast_model.world.gym_env.PHASTWorldModelEnv` (a model of recordings: no
simulator behind it) for an SB3 agent: actions in [-1, 1] scaled to the input bound, the world env's reward (the
suite's regulation reward to the target, with the model's velocity estimate), observations as on the plant ((sin q,
cos q) of the last ``frames`` measurements, noise ``sigma`` added to the model's noise-free q).  On an underactuated
plant the agent drives the ``actuated`` columns of the model's port only.

Every episode starts from a burn-in window of *recorded* measurements: ``pool`` holds windows cut from the
recordings the model was fitted to, so starting there costs no plant time beyond what the recordings already counted
(the one-shot world model of issue 29 took a fresh real burn-in per episode: 1,110 of its 4,310 real samples).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from ..world.gym_env import PHASTWorldModelEnv
from ..world.model import PHAST
from .envs import ObsBuilder


def burn_in_pool(q: np.ndarray, window: int, stride: int = 1) -> np.ndarray:
    """(P, window, n) burn-in windows of recordings ``q`` (N, T, n): every start ``0, stride, ...`` that leaves room
    for a full window, all trajectories, one strided view (no copy loop)."""
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 3 or q.shape[1] < window:
        raise ValueError(f"recordings q must be (N, T >= {window}, n), got {q.shape}")
    views = np.lib.stride_tricks.sliding_window_view(q, window, axis=1)[:, ::stride]  # (N, S, n, window)
    return np.ascontiguousarray(np.moveaxis(views, -1, 2).reshape(-1, window, q.shape[2]))


class WorldTaskEnv(gym.Env):
    """The world-model env of one task (module docstring); ``decisions`` steps per episode."""

    metadata = {"render_modes": []}

    def __init__(self, model: PHAST, pool: np.ndarray, q_star: np.ndarray, max_action: float, sigma: float,
                 decisions: int, frames: int = 3, seed: int | None = None, actuated: Sequence[int] | None = None) -> None:
        super().__init__()
        pool = np.asarray(pool, dtype=np.float64)
        if pool.ndim != 3 or len(pool) == 0:
            raise ValueError(f"pool must be (P >= 1, K, n) burn-in windows, got shape {pool.shape}")
        self.world = PHASTWorldModelEnv(model, burn_in=pool.shape[1], max_episode_steps=decisions,
                                        target=np.asarray(q_star, dtype=np.float64))
        self.pool, self.sigma, self.max_action, self.frames = pool, float(sigma), float(max_action), int(frames)
        self.builder = ObsBuilder(self.frames)
        m = self.world.action_space.shape[0]
        # the agent's inputs: the actuated columns of the model's port (a rig's recordings give n-wide forces)
        self.actuated = list(range(m)) if actuated is None else [int(i) for i in actuated]
        self._u = np.zeros(m)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(len(self.actuated),), dtype=np.float32)
        self.observation_space = gym.spaces.Box(-1.0, 1.0, shape=(self.builder.size * pool.shape[2],), dtype=np.float32)
        self._rng = np.random.default_rng(seed)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        window = self.pool[int(self._rng.integers(len(self.pool)))]
        _, info = self.world.reset(seed=int(self._rng.integers(2**31)), options={"q_burn": window})
        k = min(self.frames, len(window))
        obs = self.builder.reset(window[-k])
        for q in window[len(window) - k + 1:]:
            obs = self.builder.push(q)
        return obs, info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict]:
        self._u[self.actuated] = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1, 1) * self.max_action
        q, r, term, trunc, info = self.world.step(self._u)
        noisy = np.asarray(q, dtype=np.float64) + self.sigma * self._rng.standard_normal(np.shape(q))
        return self.builder.push(noisy), float(r), term, trunc, info
