"""Reflection-equivariant SAC for systems with a mirror symmetry (an SB3 policy class).

A pendulum, damped or not, is symmetric under the reflection ``q -> -q, p -> -p, u -> -u`` about the vertical: the
mirror image of a trajectory is a trajectory, and a reward of ``|wrap(q - q*)|``, ``qdot^2`` and ``u^2`` with
``q* = 0`` or ``pi`` is unchanged by it.  The optimal policy is then odd: ``pi(M o) = -pi(o)``.  An unconstrained
SAC actor need not be, and on the upright it typically is not: its action at the target at rest is biased (e.g.
+4 N m), so it holds the pendulum still at the offset where that bias balances gravity (see
docs/control_results/sac/DIAGNOSIS.md).  Exploration around such an offset never visits the target, so the critic
cannot learn better.

:class:`MirrorSACPolicy` builds the symmetry in, exactly: the actor's mean is the odd part of the network's,
``(mu(o) - mu(M o)) / 2``, its log-std the even part, and each critic is invariant,
``(Q(o, a) + Q(M o, -a)) / 2``; so the policy's action at a symmetric observation (at the target, at rest) is
zero.  ``M`` is a per-coordinate sign vector on the observation (``mirror``): -1 on odd features (``sin q``,
velocities), +1 on even ones (``cos q``).  Actions are mirrored by negation (a symmetric action box).

    SAC(MirrorSACPolicy, env, policy_kwargs={"mirror": mirror_signs(frames=3)})
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch
from stable_baselines3.common.policies import ContinuousCritic
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.sac.policies import Actor, SACPolicy


def mirror_signs(frames: int, velocity: bool = False, state: bool = False) -> list[float]:
    """The reflection's signs on the benchmark's pendulum observations: ``frames`` values of ``sin q`` (odd) then as
    many of ``cos q`` (even), then an odd velocity if ``velocity``; ``state``: ``(sin q, cos q, qdot)``."""
    if state:
        return [-1.0, 1.0, -1.0]
    return [-1.0] * frames + [1.0] * frames + ([-1.0] if velocity else [])


def _obs_size(space: object) -> int:
    shape = getattr(space, "shape", None)
    if not shape or len(shape) != 1:
        raise ValueError(f"a mirrored policy needs a flat Box observation, got shape {shape}")
    return int(shape[0])


def _signs(mirror: Sequence[float], size: int) -> torch.Tensor:
    m = torch.as_tensor([float(s) for s in mirror], dtype=torch.float32)
    if m.shape != (size,) or not bool(torch.all(m.abs() == 1)):
        raise ValueError(f"mirror must be {size} signs (+1 or -1), one per observation feature, got {list(mirror)}")
    return m


class MirrorActor(Actor):
    """SAC actor whose Gaussian mean is odd and log-std even under the observation reflection ``mirror``."""

    def __init__(self, *args: Any, mirror: Sequence[float], **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if self.use_sde:
            raise ValueError("MirrorActor does not support gSDE")
        self.mirror: torch.Tensor
        self.register_buffer("mirror", _signs(mirror, _obs_size(self.observation_space)))

    def get_action_dist_params(self, obs: Any) -> tuple[torch.Tensor, torch.Tensor, dict[str, torch.Tensor]]:
        mean, log_std, kw = super().get_action_dist_params(obs)
        mean_m, log_std_m, _ = super().get_action_dist_params(obs * self.mirror)
        return (mean - mean_m) / 2, (log_std + log_std_m) / 2, kw


class MirrorCritic(ContinuousCritic):
    """Twin critics, each invariant under ``(o, a) -> (M o, -a)``."""

    def __init__(self, *args: Any, mirror: Sequence[float], **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.mirror: torch.Tensor
        self.register_buffer("mirror", _signs(mirror, _obs_size(self.observation_space)))

    def forward(self, obs: torch.Tensor, actions: torch.Tensor) -> tuple[torch.Tensor, ...]:
        direct = super().forward(obs, actions)
        mirrored = super().forward(obs * self.mirror, -actions)
        return tuple((a + b) / 2 for a, b in zip(direct, mirrored))

    def q1_forward(self, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        return self.forward(obs, actions)[0]


class MirrorSACPolicy(SACPolicy):
    """:class:`SACPolicy` with :class:`MirrorActor` and :class:`MirrorCritic`; ``policy_kwargs={"mirror": signs}``."""

    def __init__(self, *args: Any, mirror: Sequence[float], **kwargs: Any) -> None:
        self.mirror_signs = [float(s) for s in mirror]  # read by make_actor / make_critic during SACPolicy's build
        super().__init__(*args, **kwargs)

    def make_actor(self, features_extractor: BaseFeaturesExtractor | None = None) -> Actor:
        actor_kwargs = self._update_features_extractor(self.actor_kwargs, features_extractor)
        return MirrorActor(**actor_kwargs, mirror=self.mirror_signs).to(self.device)

    def make_critic(self, features_extractor: BaseFeaturesExtractor | None = None) -> ContinuousCritic:
        critic_kwargs = self._update_features_extractor(self.critic_kwargs, features_extractor)
        return MirrorCritic(**critic_kwargs, mirror=self.mirror_signs).to(self.device)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "mirror": self.mirror_signs}
