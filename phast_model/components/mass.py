"""Mass models M: the env's known M(q), a learned constant ``diag(d) + U U^T``, a learned
configuration-dependent template ``M0 + cos(phi(q)) M1`` (PARTIAL) or a neural Cholesky factor (UNKNOWN).

Interface (:class:`Mass`): ``velocity(q, p) = M^-1 p`` (= dH/dp), ``momentum(q, v) = M v``,
``matrix(q)``, ``kinetic_dq(q, p) = d/dq (p^T M(q)^-1 p / 2)`` and ``constant``.  Learned masses with
coefficients that enter M linearly also expose ``linear_basis(q)`` (the matrices B_j(q) with
M = sum_j theta_j B_j) and ``set_linear(theta)`` (:class:`LinearMass`), used by the least-squares initialization
(:mod:`phast_model.world.data_init`).
"""

from __future__ import annotations

import math
from typing import Protocol, cast, runtime_checkable

import torch
from torch import nn

from phast_gym.systems import TORCH, System, split, stack

from .features import coordinate_features, n_features
from .potentials import autograd_grad


@runtime_checkable
class LinearMass(Protocol):
    """A mass whose coefficients enter M linearly (``isinstance`` is the ``hasattr`` test, typed)."""

    def linear_basis(self, q: torch.Tensor) -> torch.Tensor: ...

    def set_linear(self, theta: torch.Tensor) -> None: ...


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

    def linear_basis(self, q: torch.Tensor) -> torch.Tensor:
        """(..., n) -> (..., n, n, n): B_i = e_i e_i^T (the diagonal; U starts near zero)."""
        return torch.diag_embed(torch.eye(self.n, dtype=q.dtype)).expand(*q.shape[:-1], self.n, self.n, self.n)

    @torch.no_grad()
    def set_linear(self, theta: torch.Tensor) -> None:
        """Diagonal from least-squares coefficients (clipped to >= 1e-3 so M stays positive definite)."""
        d = torch.as_tensor(theta, dtype=self.raw_d.dtype).clamp_min(1e-3) - 1e-4  # diag() adds 1e-4
        self.raw_d.copy_(torch.log(torch.expm1(d)))


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


def _inv_softplus(x: float) -> float:
    return math.log(math.expm1(x))


class TemplateMass(Mass):
    """Configuration-dependent ``M(q) = M0 + cos(phi(q)) M1`` of a two-link system with three learnable
    coefficients (a, b, c), positive definite at every q by construction (paper Appendix H.2, nonseparable H).

    kinds: ``cartpole`` ``[[a, b cos q2], [b cos q2, c]]``; ``double_pendulum`` the same with phi = q1 - q2
    (absolute angles); ``double_pendulum_relative`` ``[[a + 2 b cos q2, c + b cos q2], [c + b cos q2, c]]``
    (q2 = link 2 relative to link 1).  M0 + s M1 is positive definite for all |s| <= 1 when it is at s = +-1,
    which the parameterization guarantees: ``a, c > 0, |b| < sqrt(a c)`` (absolute), ``a - c > 0, c > 0,
    |b| < sqrt((a - c) c)`` (relative)."""

    constant = False
    KINDS = ("cartpole", "double_pendulum", "double_pendulum_relative")
    dphi: torch.Tensor  # buffer: d phi / dq

    def __init__(self, kind: str, diag_init: float = 1.0) -> None:
        super().__init__()
        if kind not in self.KINDS:
            raise ValueError(f"unknown mass template {kind!r}; known: {self.KINDS}")
        self.kind, self.n = kind, 2
        self.relative = kind == "double_pendulum_relative"
        self.register_buffer("dphi", torch.tensor([1.0, -1.0] if kind == "double_pendulum" else [0.0, 1.0]))
        self.raw = nn.Parameter(torch.full((3,), _inv_softplus(diag_init)))
        with torch.no_grad():
            self.raw[2] = 0.0  # b = 0: start from a diagonal, uncoupled M

    def coefficients(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(a, b, c) of the template, inside the positive-definite set."""
        sp = nn.functional.softplus
        r = self.raw
        if self.relative:
            c, e = sp(r[1]) + 1e-4, sp(r[0]) + 1e-4
            return c + e, 0.999 * torch.tanh(r[2]) * torch.sqrt(e * c), c
        a, c = sp(r[0]) + 1e-4, sp(r[1]) + 1e-4
        return a, 0.999 * torch.tanh(r[2]) * torch.sqrt(a * c), c

    def _phi(self, q: torch.Tensor) -> torch.Tensor:
        return (q * self.dphi.to(q.dtype)).sum(-1)

    def _entries(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        a, b, c = self.coefficients()
        bc = b * torch.cos(self._phi(q))
        if self.relative:
            return a + 2 * bc, c + bc, c.expand_as(bc)
        return a.expand_as(bc), bc, c.expand_as(bc)

    def matrix(self, q: torch.Tensor) -> torch.Tensor:
        m11, m12, m22 = self._entries(q)
        return torch.stack([torch.stack([m11, m12], -1), torch.stack([m12, m22], -1)], -2)

    def momentum(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        m11, m12, m22 = self._entries(q)
        return torch.stack([m11 * v[..., 0] + m12 * v[..., 1], m12 * v[..., 0] + m22 * v[..., 1]], -1)

    def velocity(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        m11, m12, m22 = self._entries(q)
        det = m11 * m22 - m12 * m12
        return torch.stack([(m22 * p[..., 0] - m12 * p[..., 1]) / det, (m11 * p[..., 1] - m12 * p[..., 0]) / det], -1)

    def kinetic_dq(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """-v^T (dM/dq_k) v / 2 with v = M^-1 p and dM/dq_k = -sin(phi) dphi_k M1."""
        _, b, _ = self.coefficients()
        v = self.velocity(q, p)
        vm1v = 2 * b * v[..., 0] * (v[..., 0] + v[..., 1]) if self.relative else 2 * b * v[..., 0] * v[..., 1]
        return (0.5 * torch.sin(self._phi(q)) * vm1v).unsqueeze(-1) * self.dphi.to(q.dtype)

    def linear_basis(self, q: torch.Tensor) -> torch.Tensor:
        """(..., 2) -> (..., 3, 2, 2): B_a, B_b, B_c with M = a B_a + b B_b + c B_c."""
        cs = torch.cos(self._phi(q))
        z, o = torch.zeros_like(cs), torch.ones_like(cs)

        def mat(m11: torch.Tensor, m12: torch.Tensor, m22: torch.Tensor) -> torch.Tensor:
            return torch.stack([torch.stack([m11, m12], -1), torch.stack([m12, m22], -1)], -2)

        if self.relative:
            return torch.stack([mat(o, z, z), mat(2 * cs, cs, z), mat(z, o, o)], -3)
        return torch.stack([mat(o, z, z), mat(z, cs, z), mat(z, z, o)], -3)

    @torch.no_grad()
    def set_linear(self, theta: torch.Tensor) -> None:
        """(a, b, c) from least squares, projected into the positive-definite set (|b| at most 0.95 of its bound)."""
        a, b, c = (float(x) for x in theta)
        c = max(c, 1e-3)
        first = max(a - c, 1e-3) if self.relative else max(a, 1e-3)  # a - c (relative) or a
        ratio = max(-0.95, min(0.95, b / (0.999 * math.sqrt(first * c))))
        self.raw.copy_(torch.tensor([_inv_softplus(first - 1e-4), _inv_softplus(c - 1e-4), math.atanh(ratio)]))


class CholeskyMass(Mass):
    """Neural ``M(q) = L(q) L(q)^T``: L lower triangular from an MLP, diagonal ``softplus + 1e-3``, so M is
    symmetric positive definite at every q (UNKNOWN regime with a configuration-dependent mass)."""

    constant = False
    q_scale: torch.Tensor  # buffer

    def __init__(self, n: int, angle_dims: tuple[int, ...] = (), hidden: int = 32, diag_init: float = 1.0,
                 q_scale: torch.Tensor | float = 1.0) -> None:
        super().__init__()
        self.n, self.angle_dims = n, tuple(angle_dims)
        n_eu = n - len(self.angle_dims)
        self.register_buffer("q_scale", torch.as_tensor(q_scale, dtype=torch.float32).expand(n_eu).clone())
        self.rows, self.cols = torch.tril_indices(n, n)
        self.net = nn.Sequential(nn.Linear(n_features(n, self.angle_dims), hidden), nn.SiLU(),
                                 nn.Linear(hidden, len(self.rows)))
        with torch.no_grad():  # start at M = diag_init I, a small q-dependence
            last = cast(nn.Linear, self.net[-1])
            last.weight.mul_(0.01)
            last.bias.zero_()
            last.bias[self.rows == self.cols] = _inv_softplus(math.sqrt(diag_init) - 1e-3)

    def factor(self, q: torch.Tensor) -> torch.Tensor:
        """(..., n) -> L(q) (..., n, n)."""
        out = self.net(coordinate_features(q, self.angle_dims, self.q_scale))
        diag = self.rows == self.cols
        out = torch.where(diag, nn.functional.softplus(out) + 1e-3, out)
        L = out.new_zeros(*q.shape[:-1], self.n, self.n)
        L[..., self.rows, self.cols] = out
        return L

    def matrix(self, q: torch.Tensor) -> torch.Tensor:
        L = self.factor(q)
        return L @ L.transpose(-1, -2)

    def momentum(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        L = self.factor(q)
        return (L @ (L.transpose(-1, -2) @ v.unsqueeze(-1))).squeeze(-1)

    def velocity(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        return torch.cholesky_solve(p.unsqueeze(-1), self.factor(q)).squeeze(-1)

    def kinetic_dq(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """d/dq (p^T M(q)^-1 p / 2) at fixed p, by autograd (the graph is kept while training)."""
        return autograd_grad(lambda x: 0.5 * (p * self.velocity(x, p)).sum(-1), q)
