"""Shared plumbing of the sequence baselines: input features, increment head, stateful rollout.

Every baseline is a causal seq2seq next-step predictor ``q_{0:t}, u_{0:t} -> q_{t+1}``
(paper Sec. 4.1.1, Table 14).  They share

* input features: angular coordinates as ``(sin, cos)``, the other coordinates
  standardized, the port input ``u_t`` (held over ``[t, t+1]``) appended;
* an increment head: ``q_{t+1} = wrap(q_t + s * head(h_t))`` with ``s`` the
  per-coordinate scale of the training increments (a buffer, not a parameter);
* an incremental ``rollout`` for models that carry a state (RNNs, SSMs) or a cache
  of the past (Transformer: keys and values, VPT: attention inputs): the burn-in is
  encoded once and each open-loop step only computes the new position instead of
  re-running the whole prefix (the base class's definition, which it reproduces).

Normalization statistics are buffers set by :meth:`SeqBaseline.fit_normalizer`
from the training set (the harness calls it before training); they travel with the
``state_dict`` and do not count as trainable parameters.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import torch
from torch import nn

from ..world.interfaces import ForecastModel, wrap_angles


def _as_tensor(x: npt.ArrayLike | torch.Tensor) -> torch.Tensor:
    return x if isinstance(x, torch.Tensor) else torch.as_tensor(np.asarray(x), dtype=torch.float64)


class SeqBaseline(ForecastModel):
    """Base class of the q-only sequence baselines (features + increment head).

    Subclasses implement :meth:`encode` ((B, T, F) features -> (B, T, d) causal
    hidden states).  Stateful subclasses also implement :meth:`encode_state`
    and :meth:`step` and set ``stateful = True`` to get the incremental rollout.
    """

    stateful: bool = False
    q_mean: torch.Tensor  # buffers: input normalization and the increment scale (fit_normalizer)
    q_std: torch.Tensor
    u_std: torch.Tensor
    dq_scale: torch.Tensor

    def __init__(self, n: int, m: int, angle_dims: tuple[int, ...] = (), d_model: int = 64) -> None:
        super().__init__(n, m, angle_dims)
        if n < 1:
            raise ValueError(f"n must be >= 1, got {n}")
        if m < 0:
            raise ValueError(f"m must be >= 0, got {m}")
        if any(not 0 <= i < n for i in self.angle_dims):
            raise ValueError(f"angle_dims {self.angle_dims} out of range for n = {n}")
        self.d_model = int(d_model)
        self.lin_dims = tuple(i for i in range(n) if i not in self.angle_dims)
        self.in_dim = len(self.lin_dims) + 2 * len(self.angle_dims) + self.m
        self.register_buffer("q_mean", torch.zeros(n))
        self.register_buffer("q_std", torch.ones(n))
        self.register_buffer("u_std", torch.ones(max(self.m, 1)))
        self.register_buffer("dq_scale", torch.ones(n))
        self.head = nn.Linear(self.d_model, n)

    # ------------------------------------------------------------------ normalization
    @torch.no_grad()
    def fit_normalizer(self, q: np.ndarray | torch.Tensor, u: np.ndarray | torch.Tensor | None = None) -> None:
        """Set the input/increment scales from training data ``q`` (N, T, n), ``u`` (N, T-1, m)."""
        q = _as_tensor(q).to(self.q_mean.dtype)
        if q.ndim != 3 or q.shape[-1] != self.n:
            raise ValueError(f"q must have shape (N, T, {self.n}), got {tuple(q.shape)}")
        flat = q.reshape(-1, self.n)
        self.q_mean.copy_(flat.mean(0))
        self.q_std.copy_(flat.std(0).clamp_min(1e-6))
        dq = wrap_angles(q[:, 1:] - q[:, :-1], self.angle_dims).reshape(-1, self.n)
        self.dq_scale.copy_(dq.std(0).clamp_min(1e-8))
        if u is not None and self.m > 0:
            u = _as_tensor(u).to(self.q_mean.dtype).reshape(-1, self.m)
            if u.numel():
                self.u_std.copy_(u.std(0).nan_to_num(1.0).clamp_min(1e-3))

    # ------------------------------------------------------------------ features / head
    def features(self, q: torch.Tensor, u: torch.Tensor | None) -> torch.Tensor:
        """(B, T, n) positions + (B, T, m) inputs -> (B, T, F) network inputs."""
        parts = []
        if self.lin_dims:
            idx = list(self.lin_dims)
            parts.append((q[..., idx] - self.q_mean[idx]) / self.q_std[idx])
        if self.angle_dims:
            a = q[..., list(self.angle_dims)]
            parts += [torch.sin(a), torch.cos(a)]
        if self.m > 0:
            if u is None:
                u = q.new_zeros(*q.shape[:-1], self.m)
            parts.append(u.to(q.dtype) / self.u_std[: self.m])
        return torch.cat(parts, dim=-1)

    def readout(self, h: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        """Hidden state(s) + current q -> next q (wrapped increment)."""
        return wrap_angles(q + self.dq_scale * self.head(h), self.angle_dims)

    def _prep(self, q: torch.Tensor, u: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        if q.ndim != 3 or q.shape[-1] != self.n:
            raise ValueError(f"q must have shape (B, T, {self.n}), got {tuple(q.shape)}")
        q = q.to(self.q_mean.dtype)
        if u is not None:
            if u.ndim != 3 or u.shape[-1] != self.m:
                raise ValueError(f"u must have shape (B, T or T-1, {self.m}), got {tuple(u.shape)}")
            u = self.pad_u(u.to(q.dtype), q.shape[1])
        return q, u

    def forward(self, q: torch.Tensor, u: torch.Tensor | None = None) -> torch.Tensor:
        q, u = self._prep(q, u)
        return self.readout(self.encode(self.features(q, u)), q)

    # ------------------------------------------------------------------ subclass hooks
    def encode(self, x: torch.Tensor) -> torch.Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    def encode_state(self, x: torch.Tensor) -> tuple[torch.Tensor, Any]:  # pragma: no cover - abstract
        """Like :meth:`encode`, also returning the recurrent state after the last step."""
        raise NotImplementedError

    def step(self, x: torch.Tensor, state: Any) -> tuple[torch.Tensor, Any]:  # pragma: no cover - abstract
        """One recurrent step: features (B, F) + state -> hidden (B, d), new state (each subclass its own kind:
        a GRU's hidden tensor, an LSTM's (h, c), one tensor per SSM layer, a transformer's cache)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ rollout
    @torch.no_grad()
    def rollout(self, q_burn: torch.Tensor, u: torch.Tensor | None, H: int) -> torch.Tensor:
        """Open-loop rollout; one new position per step for stateful models, the base definition otherwise."""
        if not self.stateful:
            return super().rollout(q_burn, u, H)
        q_burn, _ = self._prep(q_burn, None)
        B, K, _ = q_burn.shape
        u_all = None if u is None else self.pad_u(u.to(q_burn.dtype), K + H)
        h, state = self.encode_state(self.features(q_burn, None if u_all is None else u_all[:, :K]))
        out = self.readout(h[:, -1], q_burn[:, -1])
        preds = [out]
        for k in range(1, H):
            u_k = None if u_all is None else u_all[:, K + k - 1: K + k]
            x = self.features(out[:, None], u_k)[:, 0]
            h_k, state = self.step(x, state)
            out = self.readout(h_k, out)
            preds.append(out)
        return torch.stack(preds, dim=1)
