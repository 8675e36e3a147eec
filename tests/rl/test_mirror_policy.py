"""phast_model.rl.mirror_policy: the reflection-equivariant SAC policy is exactly odd / invariant."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

pytest.importorskip("stable_baselines3")
from stable_baselines3 import SAC  # noqa: E402

from phast_model.rl.mirror_policy import MirrorSACPolicy, mirror_signs  # noqa: E402


class _Frames(gym.Env):
    """A stand-in env with the benchmark's frame observation (sin q x3, cos q x3) and a [-1, 1] torque."""

    observation_space = gym.spaces.Box(-1.0, 1.0, shape=(6,), dtype=np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.q = self.np_random.uniform(-np.pi, np.pi, 3)
        return self._obs(), {}

    def _obs(self) -> np.ndarray:
        return np.concatenate([np.sin(self.q), np.cos(self.q)]).astype(np.float32)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.q = np.roll(self.q, -1)
        self.q[-1] += 0.1 * float(action[0])
        return self._obs(), -float(np.cos(self.q[-1]) + 1), False, False, {}


def test_mirror_policy_is_odd_and_its_critics_invariant(tmp_path) -> None:
    assert mirror_signs(3) == [-1, -1, -1, 1, 1, 1] and mirror_signs(2, velocity=True) == [-1, -1, 1, 1, -1]
    assert mirror_signs(3, state=True) == [-1, 1, -1]
    model = SAC(MirrorSACPolicy, _Frames(), seed=0, learning_starts=20, batch_size=16,
                policy_kwargs={"mirror": mirror_signs(3), "net_arch": [16, 16]})
    model.learn(60)  # trained weights, not only the initial ones
    rng = np.random.default_rng(0)
    q = rng.uniform(-np.pi, np.pi, (32, 3))
    obs = torch.as_tensor(np.concatenate([np.sin(q), np.cos(q)], 1), dtype=torch.float32)
    mirrored = obs * torch.tensor(mirror_signs(3))
    actor, critic = model.policy.actor, model.policy.critic
    with torch.no_grad():
        assert torch.allclose(actor(obs, deterministic=True), -actor(mirrored, deterministic=True), atol=1e-6)
        a = torch.as_tensor(rng.uniform(-1, 1, (32, 1)), dtype=torch.float32)
        for q1, q2 in zip(critic(obs, a), critic(mirrored, -a)):
            assert torch.allclose(q1, q2, atol=1e-5)
        # at a symmetric observation (the upright, at rest) the action is exactly zero
        top = torch.tensor([[0.0, 0.0, 0.0, -1.0, -1.0, -1.0]])
        assert float(actor(top, deterministic=True).abs()) < 1e-7
    model.save(tmp_path / "p.zip")
    loaded = SAC.load(tmp_path / "p.zip")
    assert isinstance(loaded.policy, MirrorSACPolicy)
    np.testing.assert_allclose(loaded.predict(obs.numpy(), deterministic=True)[0],
                               model.predict(obs.numpy(), deterministic=True)[0], atol=1e-6)
    with pytest.raises(ValueError, match="signs"):
        SAC(MirrorSACPolicy, _Frames(), policy_kwargs={"mirror": [1, -1]})
