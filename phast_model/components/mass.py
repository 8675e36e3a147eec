"""Mass models M: the env's known M(q), or a learned constant ``diag(d) + U U^T``.

Interface (:class:`Mass`): ``velocity(q, p) = M^-1 p`` (= dH/dp), ``momentum(q, v) = M v``,
``matrix(q)``, ``kinetic_dq(q, p) = d/dq (p^T M(q)^-1 p / 2)`` and ``constant``.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from phast_gym.systems import TORCH, System, split, stack


class Mass(nn.Module):
    """Abstract mass model."""

    constant: bool = True

    def velocity(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def momentum(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        return (self.matrix(q) @ v.unsqueeze(-1)).squeeze(-1)

    def matrix(self, q: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def kinetic_dq(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """dT/dq at fixed p (zero for a constant mass)."""
        return torch.zeros_like(q)


class LowRankMass(Mass):
    """Constant ``M = diag(softplus(d)) + U U^T`` (Eq. 79); ``M^-1 p`` by Woodbury (Algorithm 2)."""

    constant = True

    def __init__(self, n: int, rank: int = 1, diag_init: float = 1.0, u_init: float = 0.05, seed: int = 0) -> None:
        super().__init__()
        self.n, self.rank = n, int(rank)
        self.raw_d = nn.Parameter(torch.full((n,), math.log(math.expm1(diag_init))))
        g = torch.Generator().manual_seed(seed)
        self.U = nn.Parameter(u_init * torch.randn(n, self.rank, generator=g))

    def diag(self) -> torch.Tensor:
        return nn.functional.softplus(self.raw_d) + 1e-4

    def matrix(self, q: torch.Tensor | None = None) -> torch.Tensor:
        m = torch.diag(self.diag()) + self.U @ self.U.T
        return m if q is None else m.expand(*q.shape[:-1], self.n, self.n)

    def momentum(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        return v * self.diag() + (v @ self.U) @ self.U.T

    def velocity(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        # Woodbury: (L + U U^T)^-1 = L^-1 - L^-1 U (I_r + U^T L^-1 U)^-1 U^T L^-1, O(n r^2 + r^3)
        inv_d = 1.0 / self.diag()
        li_u = self.U * inv_d.unsqueeze(-1)  # (n, r)
        cap = torch.eye(self.rank, dtype=p.dtype, device=p.device) + self.U.T @ li_u  # (r, r)
        y = p * inv_d
        corr = torch.linalg.solve(cap, (p @ li_u).reshape(-1, self.rank).T).T.reshape(*p.shape[:-1], self.rank)
        return y - corr @ li_u.T

    def lambda_min(self) -> torch.Tensor:
        """Lower bound of the spectrum: min diag (U U^T is PSD)."""
        return self.diag().min()


class KnownMass(Mass):
    """The env's M(q) (KNOWN regime): calls ``system.mass_matrix`` / ``system.velocity`` / ``system.dH_dq``."""

    def __init__(self, system: System) -> None:
        super().__init__()
        self.system = system
        self.constant = bool(system.separable)

    def velocity(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        return stack(self.system.velocity(split(q), split(p), TORCH))

    def matrix(self, q: torch.Tensor) -> torch.Tensor:
        rows = self.system.mass_matrix(split(q), TORCH)
        return torch.stack([stack(r) for r in rows], -2)

    def kinetic_dq(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        if self.constant:
            return torch.zeros_like(q)
        qs, ps = split(q), split(p)
        return stack(self.system.dH_dq(qs, ps, TORCH)) - stack(self.system.grad_potential(qs, TORCH))
