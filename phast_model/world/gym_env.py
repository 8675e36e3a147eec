"""``PHASTWorldModelEnv``: a Gymnasium env that steps a learned PHAST model instead of the physics.

Same observation and action spaces as the real env (``gym.make(env_id)``); each episode starts
from a burn-in window of real observations: ``reset(options={"q_burn": (K, n)})``, else a random
trajectory of the ``dataset`` given at construction, else K real-env steps with zero input from a
sampled initial state.  Steps are the model's autoregressive next-step predictions (observer in the
loop) with the action as the port input, so SB3 agents can train inside the world model.
Reward: the real env's, :func:`phast_gym.reward.regulation_reward`,
``-(|wrap(q - target)|^2 + 0.1 |qdot|^2 + 0.001 |u|^2)`` with qdot the model's velocity estimate.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np
import numpy.typing as npt
import torch

import phast_gym  # noqa: F401  (registers the ids)
from phast_gym.reward import regulation_reward
from phast_gym.systems import wrap

from ..api import load_run
from .interfaces import Trajectories
from .model import PHAST


@runtime_checkable
class _SizedEnv(Protocol):
    """A phast_gym env's sizes: ``n`` coordinates, ``m`` port inputs."""

    n: int
    m: int


class PHASTWorldModelEnv(gym.Env):
    """Gymnasium env backed by a trained PHAST model (see module docstring)."""

    metadata = {"render_modes": []}
    observation_space: gym.spaces.Box
    action_space: gym.spaces.Box
    real: gym.Env | None  # the real env (unwrapped) the burn-in windows come from; None for a model of recordings

    def __init__(self, model: PHAST | str | Path, env_id: str | None = None, burn_in: int = 10,
                 dataset: Trajectories | None = None, max_episode_steps: int = 200, target: np.ndarray | None = None,
                 **env_kwargs: Any) -> None:
        super().__init__()
        self.model = load_run(model) if isinstance(model, (str, Path)) else model
        self.model.eval()
        self.env_id = env_id or self.model.config.env_id
        if int(burn_in) < 1:
            raise ValueError(f"burn_in must be >= 1, got {burn_in!r}")
        self.burn_in, self.max_episode_steps = int(burn_in), int(max_episode_steps)
        if getattr(self.model.config, "sim", None) is not None and env_id is None:
            self._rig_spaces()  # a model of a rig's recordings: no simulator to reset from
        else:
            real = gym.make(self.env_id, **env_kwargs).unwrapped
            if not isinstance(real, _SizedEnv):
                raise TypeError(f"{self.env_id} is not a phast_gym env: its unwrapped env has no sizes n and m")
            if real.n != self.model.n or real.m != self.model.m:
                raise ValueError(f"model (n={self.model.n}, m={self.model.m}) does not match {self.env_id} "
                                 f"(n={real.n}, m={real.m})")
            obs_space, act_space = real.observation_space, real.action_space
            if not (isinstance(obs_space, gym.spaces.Box) and isinstance(act_space, gym.spaces.Box)):
                raise TypeError(f"{self.env_id}: the world model needs Box observation and action spaces")
            self.real = real
            self.observation_space = obs_space
            self.action_space = act_space
        self.dataset = dataset
        self.target = np.zeros(self.model.n) if target is None else np.asarray(target, dtype=np.float64)
        self._dtype = next(self.model.parameters()).dtype
        self._hist: torch.Tensor | None = None
        self._t = 0

    def _rig_spaces(self) -> None:
        """Spaces of a recordings model: q unbounded (angles wrapped), u within the config's ``action_bound`` (the
        largest recorded |u| per input, or the user's bound); episodes start from ``options["q_burn"]`` or the
        ``dataset``."""
        m = self.model.m
        bound = np.asarray(self.model.config.action_bound or [np.inf] * m, dtype=np.float32).reshape(-1)
        if bound.size != m:
            bound = np.full(m, float(bound.max()), dtype=np.float32)
        self.real = None
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (self.model.n,), np.float32)
        self.action_space = gym.spaces.Box(-bound, bound, (m,), np.float32)

    def _obs(self) -> np.ndarray:
        if self._hist is None:
            raise RuntimeError("call reset() first")
        q = self._hist[0, -1].numpy().astype(self.observation_space.dtype)
        return np.clip(q, self.observation_space.low, self.observation_space.high)

    def _burn_in_window(self, options: Mapping[str, object] | None) -> np.ndarray:
        if options and options.get("q_burn") is not None:
            qb = np.asarray(options["q_burn"], dtype=np.float64)
            if qb.ndim != 2 or qb.shape[1] != self.model.n or qb.shape[0] < 1:
                raise ValueError(f"options['q_burn'] must be (K, {self.model.n}), got {qb.shape}")
            if not np.isfinite(qb).all():
                raise ValueError("options['q_burn'] must be finite")
            return qb
        if self.dataset is not None:
            i = int(self.np_random.integers(len(self.dataset.q)))
            return np.asarray(self.dataset.q[i, : self.burn_in], dtype=np.float64)
        if self.real is None:
            raise ValueError("a world model of recordings has no simulator to start from: pass "
                             "reset(options={'q_burn': (K, n) measured q}) or a dataset")
        obs, _ = self.real.reset(seed=int(self.np_random.integers(2**31)))
        qs = [obs[: self.model.n]]
        zero = np.zeros(self.model.m, dtype=self.real.action_space.dtype)  # the real env's m (checked at construction)
        for _ in range(self.burn_in - 1):
            obs, *_ = self.real.step(zero)
            qs.append(obs[: self.model.n])
        return np.asarray(qs, dtype=np.float64)

    def reset(self, *, seed: int | None = None, options: Mapping[str, object] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        qb = self._burn_in_window(options)
        self._hist = torch.as_tensor(qb[None, -self.model.observer.window:], dtype=self._dtype)
        self._t = 0
        return self._obs(), {"burn_in": np.array(qb, copy=True)}

    def step(self, action: npt.ArrayLike) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self._hist is None:
            raise RuntimeError("call reset() before step()")
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        if a.shape != (self.model.m,) or not np.isfinite(a).all():
            raise ValueError(f"action must be finite with shape ({self.model.m},), got {np.shape(action)}")
        a = np.clip(a, self.action_space.low, self.action_space.high)
        u = torch.as_tensor(a[None], dtype=self._dtype)
        with torch.no_grad():
            q1 = self.model.predict_next(self._hist, u)
            self._hist = torch.cat([self._hist, q1.unsqueeze(1)], 1)[:, -self.model.observer.window:]
            v = self.model.observer(self._hist)[0, -1].numpy()
        self._t += 1
        q = self._hist[0, -1].numpy().astype(np.float64)
        finite = bool(np.isfinite(q).all() and np.isfinite(v).all())
        e = q - self.target
        for i in self.model.angle_dims:
            e[i] = wrap(e[i])
        reward = regulation_reward(float(e @ e), float(v @ v), float(a @ a)) if finite else -1e3
        truncated = self._t >= self.max_episode_steps
        info = {"t": self._t * self.model.dt, "velocity": v}
        if not finite:
            self._hist = torch.nan_to_num(self._hist)
        return self._obs(), float(reward), not finite, truncated, info
