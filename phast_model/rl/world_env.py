"""The agent's training env inside the learned world model, started where the plant has been.

:class:`WorldTaskEnv` wraps :class:`phast_model.world.gym_env.PHASTWorldModelEnv` (a model of recordings: no
simulator behind it) for an SB3 agent: actions in [-1, 1] scaled to the input bound, the world env's reward (the
suite's regulation reward to the target, with the model's velocity estimate), observations as on the plant ((sin q,
cos q) of the last ``frames`` measurements, a cart's position as ``tanh(x / 2)``, noise ``sigma`` added to the model's
noise-free q).  The reward is the suite's regulation reward with the task's weights: ``velocity_weight`` on |qdot|^2
(the suite's 0.1 by default) and ``position_weight`` on the squared Euclidean errors (1 by default).  On an
underactuated
plant the agent drives the ``actuated`` columns of the model's port only.

A model rollout that leaves the region the model can speak for (a Euclidean coordinate beyond ``x_max``, a velocity
estimate beyond ``v_max``, or a non-finite state: a learned model driven far from its data can diverge) ends the
episode with the worst per-step reward for every decision left, so leaving is never cheaper than staying; per-step
rewards are clipped at ``-reward_floor`` (SB3 buffers are float32).

With ``recenter`` the burn-in window's Euclidean coordinates are shifted to end at 0 (where the task starts the cart):
valid when the model's dynamics do not depend on them, as for a cart's position (V_hat and M_hat of the cart-pole
description are functions of the pole angle only).  Without it, windows of the excitation (the cart drifting up to
12 m under random forces) start most episodes far away, and the cart's position term dominates the reward.

With a ``goal`` (the deployed hold's :class:`phast_model.rl.hold.HoldConfig`) the agent's task ends where the hold
takes over: an episode whose model state enters the hold's handoff region (``HoldConfig.enters``: the angles and
their rates) ends there, the decisions left counted at the best per-step reward (0).  The agent then learns to bring
the plant into the hold's region (its handoff, :class:`phast_model.rl.hold.HybridPolicy`), not to balance by itself,
which it does not do on the plant anyway; on the cart-pole a seed whose agent pumped without reaching the top in the
world model
(returns stuck at -420 where others reach -250) is the case this is for.

Every episode starts from a burn-in window of *recorded* measurements: ``pool`` holds windows cut from the
recordings the model was fitted to, so starting there costs no plant time beyond what the recordings already counted
(a fresh real burn-in per episode would spend plant time on every episode: docs/control.md).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import SupportsFloat

import gymnasium as gym
import numpy as np

from phast_gym.reward import ACTION_WEIGHT, VELOCITY_WEIGHT
from phast_gym.systems.base import angle_diff

from ..world.gym_env import PHASTWorldModelEnv
from ..world.model import PHAST
from .hold import HoldConfig
from .observation import ObsBuilder


def burn_in_pool(q: np.ndarray, window: int, stride: int = 1) -> np.ndarray:
    """(P, window, n) burn-in windows of recordings ``q`` (N, T, n): every start ``0, stride, ...`` that leaves room
    for a full window, all trajectories, one strided view (no copy loop)."""
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 3 or q.shape[1] < window:
        raise ValueError(f"recordings q must be (N, T >= {window}, n), got {q.shape}")
    views = np.lib.stride_tricks.sliding_window_view(q, window, axis=1)[:, ::stride]  # (N, S, n, window)
    return np.ascontiguousarray(np.moveaxis(views, -1, 2).reshape(-1, window, q.shape[2]))


@dataclass(frozen=True)
class WorldTask:
    """What one task asks of :class:`WorldTaskEnv`: the target ``q_star``, the input bound, the measurement noise
    ``sigma``, the episode length in decisions, the observation frames, the reward's weights (module docstring) and
    whether episodes start with the Euclidean coordinates moved to 0 (``recenter``)."""

    q_star: np.ndarray
    max_action: float
    sigma: float
    decisions: int
    frames: int = 3
    velocity_weight: float = VELOCITY_WEIGHT
    position_weight: float = 1.0
    recenter: bool = False
    goal: HoldConfig | None = None


class WorldTaskEnv(gym.Env):
    """The world-model env of one task (module docstring); ``decisions`` steps per episode."""

    metadata = {"render_modes": []}
    #: the region of a rollout (module docstring): |Euclidean q| (m), |velocity estimate| per coordinate, reward floor
    x_max = 10.0
    v_max = 40.0
    reward_floor = 50.0

    def __init__(self, model: PHAST, pool: np.ndarray, task: WorldTask, seed: int | None = None,
                 actuated: Sequence[int] | None = None) -> None:
        super().__init__()
        q_star, decisions = task.q_star, task.decisions
        self.recenter, self.goal = bool(task.recenter), task.goal
        self.velocity_weight, self.position_weight = float(task.velocity_weight), float(task.position_weight)
        pool = np.asarray(pool, dtype=np.float64)
        if pool.ndim != 3 or len(pool) == 0:
            raise ValueError(f"pool must be (P >= 1, K, n) burn-in windows, got shape {pool.shape}")
        self.world = PHASTWorldModelEnv(model, burn_in=pool.shape[1], max_episode_steps=decisions,
                                        target=np.asarray(q_star, dtype=np.float64))
        self.pool, self.sigma, self.max_action, self.frames = (pool, float(task.sigma), float(task.max_action),
                                                               int(task.frames))
        self.angle_dims = tuple(int(i) for i in model.angle_dims)
        self.euclid = [i for i in range(pool.shape[2]) if i not in self.angle_dims]
        self.decisions = int(decisions)
        self.builder = ObsBuilder(self.frames, angle_dims=self.angle_dims)
        m = self.world.action_space.shape[0]
        # the agent's inputs: the actuated columns of the model's port (a rig's recordings give n-wide forces)
        self.actuated = list(range(m)) if actuated is None else [int(i) for i in actuated]
        self._u = np.zeros(m)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(len(self.actuated),), dtype=np.float32)
        self.observation_space = gym.spaces.Box(-1.0, 1.0, shape=(self.builder.size * pool.shape[2],), dtype=np.float32)
        self._rng = np.random.default_rng(seed)

    def reset(self, *, seed: int | None = None,
              options: Mapping[str, object] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        window = self.pool[int(self._rng.integers(len(self.pool)))]
        if self.recenter and self.euclid:  # the window moved so that its Euclidean coordinates end at 0
            window = window.copy()
            window[:, self.euclid] -= window[-1, self.euclid]
        _, info = self.world.reset(seed=int(self._rng.integers(2**31)), options={"q_burn": window})
        k = min(self.frames, len(window))
        obs = self.builder.reset(window[-k])
        for q in window[len(window) - k + 1:]:
            obs = self.builder.push(q)
        return obs, info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict]:
        self._u[self.actuated] = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1, 1) * self.max_action
        q, r, term, trunc, info = self.world.step(self._u)
        q = np.asarray(q, dtype=np.float64)
        v = np.asarray(info["velocity"], dtype=np.float64)
        left = (term or not np.isfinite(q).all() or not np.isfinite(v).all() or bool(np.any(np.abs(v) > self.v_max))
                or bool(np.any(np.abs(q[self.euclid]) > self.x_max)))
        if np.isfinite(r) and np.isfinite(q).all() and np.isfinite(v).all():  # the task's weights on the same terms
            e = angle_diff(q, self.world.target, self.angle_dims)
            w = np.where(np.isin(np.arange(len(q)), self.angle_dims), 1.0, self.position_weight)
            a = self._u[self.actuated]
            r = -(float(w @ e**2) + self.velocity_weight * float(v @ v) + ACTION_WEIGHT * float(a @ a))
        r = max(float(r), -self.reward_floor) if np.isfinite(r) else -self.reward_floor
        if left:  # the worst reward for every decision left, this one included
            r, term = -self.reward_floor * (self.decisions - self.world._t + 1), True
            q = np.nan_to_num(np.clip(q, -1e6, 1e6))
        elif self._at_goal(q, v):  # the hold takes over: the decisions left at the best reward, 0
            term = True
        noisy = q + self.sigma * self._rng.standard_normal(np.shape(q))
        return self.builder.push(noisy), float(r), term, trunc, info

    def _at_goal(self, q: np.ndarray, v: np.ndarray) -> bool:
        """The model's state is in the hold's handoff region (module docstring)."""
        if self.goal is None or not self.angle_dims:
            return False
        dims = list(self.angle_dims)
        return self.goal.enters(angle_diff(q, self.world.target, self.angle_dims)[dims], v[dims])
