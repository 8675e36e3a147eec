"""Dissipative Hamiltonian neural network (Sosanya & Greydanus, 2022), for the full-state ablation.

The observed state is ``x = (q, p)`` (n = 2k coordinates: k positions then k
momenta; ``angle_dims`` index positions).  Two scalar MLPs learn a Hamiltonian
``H(x)`` and a dissipation potential ``D(x)``; the vector field is their Helmholtz
decomposition (DHNN Eq. 5)::

    xdot = J grad H(x) + grad D(x) + [0; G u],   J = [[0, I], [-I, 0]],

(rotational part from H, irrotational part from D), with a learned port map G.
One classical RK4 step of length ``dt`` maps ``x_t`` to ``x_{t+1}`` (Markov, so the
rollout just iterates it).  Gradients of H and D come from autograd.
Paper Table 25: full-state Windy Pendulum, PHAST vs DHNN.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from ..world.interfaces import ForecastModel, wrap_angles


def _mlp(d_in: int, hidden: int, depth: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(depth):
        layers += [nn.Linear(d_in if i == 0 else hidden, hidden), nn.Tanh()]
    layers.append(nn.Linear(hidden, 1))
    return nn.Sequential(*layers)


class DHNNBaseline(ForecastModel):
    """Full-state DHNN next-step predictor: q input is the (B, T, 2k) state (q, p)."""

    x_mean: torch.Tensor  # buffers: input standardization (fit_normalizer)
    x_std: torch.Tensor

    def __init__(self, n: int, m: int, angle_dims: tuple[int, ...] = (), dt: float = 0.05, hidden: int = 200,
                 depth: int = 2) -> None:
        super().__init__(n, m, angle_dims)
        if n < 2 or n % 2:
            raise ValueError(f"DHNN needs the full state (q, p): n must be even and >= 2, got {n}")
        k = n // 2
        if any(not 0 <= i < k for i in self.angle_dims):
            raise ValueError(f"angle_dims {self.angle_dims} must index positions (< {k})")
        if dt <= 0:
            raise ValueError(f"dt must be positive, got {dt}")
        self.k, self.dt = k, float(dt)
        self.lin_dims = tuple(i for i in range(n) if i not in self.angle_dims)
        d_in = len(self.lin_dims) + 2 * len(self.angle_dims)
        self.H = _mlp(d_in, hidden, depth)
        self.D = _mlp(d_in, hidden, depth)
        self.G = nn.Parameter(torch.zeros(k, m)) if m > 0 else None
        self.register_buffer("x_mean", torch.zeros(n))
        self.register_buffer("x_std", torch.ones(n))

    @torch.no_grad()
    def fit_normalizer(self, q: np.ndarray | torch.Tensor, u: np.ndarray | torch.Tensor | None = None) -> None:
        """Input standardization of the non-angular coordinates from training states (N, T, n)."""
        x = torch.as_tensor(q).to(self.x_mean.dtype).reshape(-1, self.n)
        self.x_mean.copy_(x.mean(0))
        self.x_std.copy_(x.std(0).clamp_min(1e-6))

    def _feat(self, x: torch.Tensor) -> torch.Tensor:
        idx = list(self.lin_dims)
        parts = [(x[..., idx] - self.x_mean[idx]) / self.x_std[idx]]
        if self.angle_dims:
            a = x[..., list(self.angle_dims)]
            parts += [torch.sin(a), torch.cos(a)]
        return torch.cat(parts, -1)

    def field(self, x: torch.Tensor, u: torch.Tensor | None) -> torch.Tensor:
        """``J grad H + grad D + [0; G u]`` (DHNN Eq. 5)."""
        outer_grad = torch.is_grad_enabled()  # build a graph through the gradients only when training
        with torch.enable_grad():
            if not x.requires_grad:
                x = x.detach().requires_grad_(True)
            f = self._feat(x)
            gH = torch.autograd.grad(self.H(f).sum(), x, create_graph=outer_grad, retain_graph=True)[0]
            gD = torch.autograd.grad(self.D(f).sum(), x, create_graph=outer_grad)[0]
        k = self.k
        xdot = torch.cat([gH[..., k:], -gH[..., :k]], -1) + gD
        if self.G is not None and u is not None:
            xdot = xdot + torch.cat([torch.zeros_like(x[..., :k]), u @ self.G.T], -1)
        return xdot

    def _step(self, x: torch.Tensor, u: torch.Tensor | None) -> torch.Tensor:
        h = self.dt
        k1 = self.field(x, u)
        k2 = self.field(x + 0.5 * h * k1, u)
        k3 = self.field(x + 0.5 * h * k2, u)
        k4 = self.field(x + h * k3, u)
        return wrap_angles(x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4), self.angle_dims)

    def forward(self, q: torch.Tensor, u: torch.Tensor | None = None) -> torch.Tensor:
        if q.ndim != 3 or q.shape[-1] != self.n:
            raise ValueError(f"q must have shape (B, T, {self.n}), got {tuple(q.shape)}")
        x = q.to(self.x_mean.dtype)
        u = None if u is None else self.pad_u(u.to(x.dtype), x.shape[1])
        return self._step(x, u)

    @torch.no_grad()
    def rollout(self, q_burn: torch.Tensor, u: torch.Tensor | None, H: int) -> torch.Tensor:
        """Markov rollout from the last burn-in state (equal to the autoregressive definition)."""
        x = q_burn[:, -1].to(self.x_mean.dtype)
        K = q_burn.shape[1]
        u_all = None if u is None else self.pad_u(u.to(x.dtype), K + H)
        preds = []
        for h in range(H):
            u_h = None if u_all is None else u_all[:, K - 1 + h]
            x = self._step(x, u_h)
            preds.append(x)
        return torch.stack(preds, 1)
