"""The contract every forecasting model (PHAST and the baselines) implements.

Time alignment, shared by datasets, training and rollouts:

* ``q``: (B, T, n) observed positions (angles wrapped), float32/float64 tensor;
* ``u``: (B, T-1, m) or (B, T, m) port input, ``u[:, t]`` held over [t, t+1];
* ``forward(q, u)`` returns (B, T, n): ``out[:, t]`` predicts ``q[:, t+1]`` from
  ``q[:, :t+1]`` and ``u[:, :t+1]`` only (causal, teacher-forced over the whole
  trajectory at once; the last entry predicts beyond the data).
* ``rollout(q_burn, u, H)``: burn-in ``q_burn`` (B, K, n) of ground truth, then
  ``H`` open-loop steps with the model's own predictions fed back
  (autoregressive); ``u`` (B, K-1+H, m) or None.  Returns (B, H, n): the
  predictions of ``q_K ... q_{K+H-1}``.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np
import torch
from torch import nn

from phast_gym.systems import wrap


def wrap_angles(x: torch.Tensor, angle_dims: tuple[int, ...]) -> torch.Tensor:
    """Wrap the angular coordinates (last axis) of ``x`` into [-pi, pi)."""
    if not angle_dims:
        return x
    out = x.clone()
    idx = list(angle_dims)
    out[..., idx] = wrap(x[..., idx])
    return out


def coordinate_error(pred: torch.Tensor, target: torch.Tensor, angle_dims: tuple[int, ...]) -> torch.Tensor:
    """pred - target with wrapped differences on angular coordinates."""
    return wrap_angles(pred - target, angle_dims)


class ForecastModel(nn.Module):
    """Base class of all next-step forecasters ``q_{0:t}, u_{0:t} -> q_{t+1}``."""

    def __init__(self, n: int, m: int, angle_dims: tuple[int, ...] = ()) -> None:
        super().__init__()
        self.n, self.m = int(n), int(m)
        self.angle_dims = tuple(int(i) for i in angle_dims)

    def forward(self, q: torch.Tensor, u: torch.Tensor | None = None) -> torch.Tensor:  # pragma: no cover
        raise NotImplementedError

    @staticmethod
    def pad_u(u: torch.Tensor | None, T: int) -> torch.Tensor | None:
        """Pad/crop ``u`` along time to length ``T`` (zeros beyond the data)."""
        if u is None:
            return None
        if u.shape[1] >= T:
            return u[:, :T]
        pad = u.new_zeros(u.shape[0], T - u.shape[1], u.shape[2])
        return torch.cat([u, pad], dim=1)

    @torch.no_grad()
    def rollout(self, q_burn: torch.Tensor, u: torch.Tensor | None, H: int) -> torch.Tensor:
        """Autoregressive open-loop rollout (generic O(H^2) version; models may override)."""
        q = q_burn
        preds = []
        for _ in range(H):
            out = self.forward(q, self.pad_u(u, q.shape[1]))[:, -1:]
            out = wrap_angles(out, self.angle_dims)
            preds.append(out)
            q = torch.cat([q, out], dim=1)
        return torch.cat(preds, dim=1)

    def n_parameters(self) -> int:
        """Trainable parameter count (reported in tables)."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)


# ---- optional hooks a model may have (runtime-checkable: ``isinstance`` is the ``hasattr`` test, typed) ----------
@runtime_checkable
class TakeoverModel(Protocol):
    """A model with a takeover rollout (Eq. 8: one inferred state, then the core alone)."""

    def rollout_takeover(self, q_burn: torch.Tensor, u: torch.Tensor | None, H: int) -> torch.Tensor: ...


@runtime_checkable
class LossForwardModel(Protocol):
    """A model whose training loss compares other teacher-forced predictions than ``forward``'s (PHAST with a
    non-causal training velocity, ``PHASTConfig.train_velocity``); the trainer's next-step loss calls it."""

    def loss_forward(self, q: torch.Tensor, u: torch.Tensor | None = None) -> torch.Tensor: ...


@runtime_checkable
class DampingModel(Protocol):
    """A model with a learned damping field whose diagonal can be scored (``damping_r2``, ``damping_mae``)."""

    def damping_diag(self, q: torch.Tensor) -> torch.Tensor: ...


class Trajectories(Protocol):
    """A batch of trajectories: a :class:`phast_gym.datasets.Dataset`, its full-state view, a rig's recordings.  Only
    ``q`` (N, T, n) is asked of all; readers take ``u``, ``dt``, ``system``, ``config`` with ``getattr`` where
    present."""

    @property
    def q(self) -> np.ndarray: ...


class TimedTrajectories(Trajectories, Protocol):
    """:class:`Trajectories` with their sampling interval ``dt``."""

    @property
    def dt(self) -> float: ...


@runtime_checkable
class ParamGroupsModel(Protocol):
    """A model that chooses its own optimizer parameter groups."""

    def param_groups(self, lr: float) -> list[dict[str, Any]]: ...


@runtime_checkable
class DataInitModel(Protocol):
    """A model whose learned physics starts from a least squares on the training set."""

    def initialize_from_data(self, q: torch.Tensor, u: torch.Tensor | None) -> dict[str, float]: ...


@runtime_checkable
class NormalizedModel(Protocol):
    """A model that fits its input normalization to the training data before training."""

    def fit_normalizer(self, q: np.ndarray | torch.Tensor, u: np.ndarray | torch.Tensor | None) -> None: ...

