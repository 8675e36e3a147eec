"""Potential energies V(q): known physics, templates, neural networks and hybrids.

Interface (:class:`Potential`): ``energy(q) -> (...)`` and ``grad(q) -> (..., n)``
for q of shape (..., n).  Templates are linear in their coefficients
(``V = sum_k c_k phi_k(q)``, paper Eq. 80-81 plus the pair potentials), so
their coefficients can be initialised by a least-squares fit of ``grad V``
to a reference system's gradient (:meth:`TemplatePotential.fit_to`).
"""

from __future__ import annotations

import math
from itertools import combinations
from typing import cast

import numpy as np
import torch
from torch import nn

from phast_gym.systems import TORCH, System, split, stack

from .features import coordinate_features


def autograd_grad(fn, q: torch.Tensor) -> torch.Tensor:
    """d fn(q).sum() / dq; keeps the graph when gradients are enabled (training), detached otherwise."""
    outer = torch.is_grad_enabled()
    with torch.enable_grad():
        qq = q if (outer and q.requires_grad) else q.detach().requires_grad_(True)
        (g,) = torch.autograd.grad(fn(qq).sum(), qq, create_graph=outer)
    return g


class Potential(nn.Module):
    """V(q) with its gradient."""

    def energy(self, q: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def grad(self, q: torch.Tensor) -> torch.Tensor:
        """dV/dq (autograd unless a subclass has an analytic form)."""
        return autograd_grad(self.energy, q)

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        return self.energy(q)


class KnownPotential(Potential):
    """The env's own potential (KNOWN regime): calls ``system.potential`` / ``system.grad_potential``."""

    def __init__(self, system: System) -> None:
        super().__init__()
        self.system = system

    def energy(self, q: torch.Tensor) -> torch.Tensor:
        return self.system.potential(split(q), TORCH) + 0.0 * q[..., 0]

    def grad(self, q: torch.Tensor) -> torch.Tensor:
        return stack(self.system.grad_potential(split(q), TORCH))


# --------------------------------------------------------------------------- templates
def _pairs(q: torch.Tensor, n_particles: int, dim: int = 2) -> torch.Tensor:
    """Squared pair distances (..., n_pairs) of planar particles stored as (x1, y1, x2, ...)."""
    r2 = []
    for i, j in combinations(range(n_particles), 2):
        d = q[..., dim * i:dim * i + dim] - q[..., dim * j:dim * j + dim]
        r2.append((d * d).sum(-1))
    return torch.stack(r2, -1)


class TemplatePotential(Potential):
    """Structured potential ``V = sum_k c_k phi_k(q)`` with learnable coefficients c.

    kinds: ``cosine`` (``sum_i a_i (1 - cos q_i)`` over ``dims``, Eq. 80), ``chain_cosine`` (the gravity regressor
    of a planar chain in joint coordinates: ``sum_i a_i (1 - cos(q_1 + ... + q_i))``, the absolute link angles),
    ``quadratic`` (``q^T K q / 2``, K symmetric, Eq. 81), ``lennard_jones``
    (``c1 sum r^-12 - c2 sum r^-6``), ``gravity`` (``-c sum (r^2 + eps^2)^-1/2``,
    eps learnable).
    """

    KINDS = ("cosine", "chain_cosine", "quadratic", "lennard_jones", "gravity")

    def __init__(self, kind: str, n: int, dims: tuple[int, ...] | None = None, softening: float = 0.1) -> None:
        super().__init__()
        if kind not in self.KINDS:
            raise ValueError(f"unknown potential template {kind!r}; known: {self.KINDS}")
        self.kind, self.n = kind, int(n)
        self.dims = tuple(range(n)) if dims is None else tuple(int(i) for i in dims)
        if kind in ("cosine", "chain_cosine"):
            k = len(self.dims)
        elif kind == "quadratic":
            self.tri = [(i, j) for i in range(n) for j in range(i, n)]
            k = len(self.tri)
        elif kind == "lennard_jones":
            k = 2
        else:
            k = 1
            self.log_eps = nn.Parameter(torch.tensor(math.log(softening)))
        self.n_particles = n // 2
        self.coef = nn.Parameter(torch.ones(k))

    def basis(self, q: torch.Tensor) -> torch.Tensor:
        """(..., n) -> (..., K) basis functions phi_k(q)."""
        if self.kind == "cosine":
            return 1.0 - torch.cos(q[..., list(self.dims)])
        if self.kind == "chain_cosine":
            return 1.0 - torch.cos(torch.cumsum(q, -1)[..., list(self.dims)])
        if self.kind == "quadratic":
            return torch.stack([(0.5 if i == j else 1.0) * q[..., i] * q[..., j] for i, j in self.tri], -1)
        r2 = _pairs(q, self.n_particles)
        if self.kind == "lennard_jones":
            return torch.stack([(r2 ** -6).sum(-1), -(r2 ** -3).sum(-1)], -1)
        eps2 = torch.exp(2 * self.log_eps)
        return -(1.0 / torch.sqrt(r2 + eps2)).sum(-1, keepdim=True)

    def energy(self, q: torch.Tensor) -> torch.Tensor:
        return (self.basis(q) * self.coef).sum(-1)

    def grad(self, q: torch.Tensor) -> torch.Tensor:
        if self.kind == "cosine":  # analytic (Eq. 80)
            g = torch.zeros_like(q)
            g = g.index_copy(-1, torch.tensor(self.dims, device=q.device),
                             self.coef * torch.sin(q[..., list(self.dims)]))
            return g
        if self.kind == "chain_cosine":  # dV/dq_j = sum_{i >= j} a_i sin(Q_i), Q = cumsum(q)
            g = torch.zeros_like(q)
            Q = torch.cumsum(q, -1)
            g = g.index_copy(-1, torch.tensor(self.dims, device=q.device),
                             self.coef * torch.sin(Q[..., list(self.dims)]))
            return torch.flip(torch.cumsum(torch.flip(g, (-1,)), -1), (-1,))
        return autograd_grad(self.energy, q)

    def gradient_basis(self, q: torch.Tensor) -> torch.Tensor:
        """(M, n) -> (M, n, K): dphi_k/dq of every basis function (columns of least squares on dV/dq; zero where a
        basis function does not depend on q), in the coefficients' dtype."""
        with torch.enable_grad():
            qq = q.detach().to(self.coef.dtype).requires_grad_(True)
            b = self.basis(qq)
            cols = []
            for k in range(b.shape[-1]):
                g = torch.autograd.grad(b[:, k].sum(), qq, retain_graph=True, allow_unused=True)[0] \
                    if b.requires_grad else None
                cols.append(torch.zeros_like(qq) if g is None else g)
        return torch.stack(cols, -1).detach()

    @torch.no_grad()
    def fit_to(self, system: System, n_samples: int = 512, seed: int = 0, q: torch.Tensor | None = None) -> float:
        """Least-squares init of the coefficients from ``system.grad_potential`` on its initial-state
        distribution, or at the configurations ``q`` (M, n) when given (a rig: the recorded ones) (PARTIAL: the
        template is given, coefficients stay learnable). Returns the relative residual."""
        if q is None:
            rng = np.random.default_rng(seed)
            q = torch.as_tensor(system.sample_initial(rng, n_samples)[:, : self.n], dtype=torch.float64)
        q = torch.as_tensor(q, dtype=torch.float64)
        target = stack(system.grad_potential(split(q), TORCH)).reshape(-1)
        eps_grid = [None] if self.kind != "gravity" else list(np.logspace(-2, 0, 21))
        best: tuple[float, torch.Tensor | None, float | None] = (math.inf, None, None)  # (residual, coef, eps)
        for eps in eps_grid:
            if eps is not None:
                self.log_eps.fill_(math.log(eps))
            A = self.gradient_basis(q).to(q.dtype).reshape(-1, self.coef.numel())
            sol = torch.linalg.lstsq(A, target.unsqueeze(-1)).solution.squeeze(-1)
            res = float(torch.linalg.norm(A @ sol - target) / (torch.linalg.norm(target) + 1e-12))
            if res < best[0]:
                best = (res, sol, eps)
        assert best[1] is not None, f"fit_to: no finite least-squares residual for {system.name}"
        self.coef.copy_(best[1].to(self.coef.dtype))
        if best[2] is not None:
            self.log_eps.fill_(math.log(best[2]))
        return best[0]


def make_template(kind: str, n: int, dims: tuple[int, ...] | None = None) -> TemplatePotential:
    """Template by name, including the paper's per-env aliases (pendulum, cart-pole, ...)."""
    aliases = {"pendulum": "cosine", "cartpole": "cosine", "double_pendulum": "cosine", "circuit": "quadratic",
               "heat": "quadratic", "spring": "quadratic", "softened_gravity": "gravity"}
    return TemplatePotential(aliases.get(kind, kind), n, dims)


# --------------------------------------------------------------------------- neural
class NeuralPotential(Potential):
    """MLP potential (3 layers, SiLU, hidden 64; Eq. 82) with Fourier features on angles (Eq. 83)."""

    q_scale: torch.Tensor  # buffer

    def __init__(self, n: int, angle_dims: tuple[int, ...] = (), hidden: int = 64, layers: int = 3,
                 n_freq: int = 2, q_scale: torch.Tensor | float = 1.0, out_scale: float = 1.0) -> None:
        super().__init__()
        self.n, self.angle_dims, self.n_freq = n, tuple(angle_dims), int(n_freq)
        n_eu = n - len(self.angle_dims)
        self.register_buffer("q_scale", torch.as_tensor(q_scale, dtype=torch.float32).expand(n_eu).clone())
        self.out_scale = float(out_scale)
        width = n_eu + 2 * self.n_freq * len(self.angle_dims)
        mods: list[nn.Module] = []
        for i in range(layers - 1):
            mods += [nn.Linear(width if i == 0 else hidden, hidden), nn.SiLU()]
        mods.append(nn.Linear(hidden, 1))
        self.net = nn.Sequential(*mods)

    def features(self, q: torch.Tensor) -> torch.Tensor:
        n_eu = self.n - len(self.angle_dims)
        parts = []
        if n_eu:
            parts.append(coordinate_features(q, self.angle_dims, self.q_scale)[..., :n_eu])
        if self.angle_dims:
            a = q[..., list(self.angle_dims)]
            for k in range(1, self.n_freq + 1):
                parts += [torch.sin(k * a), torch.cos(k * a)]
        return torch.cat(parts, -1)

    def energy(self, q: torch.Tensor) -> torch.Tensor:
        return self.out_scale * self.net(self.features(q)).squeeze(-1)

    def grad(self, q: torch.Tensor) -> torch.Tensor:
        """dV/dq by the chain rule written out: one forward pass keeping SiLU'(z), then the transposed weights.
        Equal to autograd's gradient; training differentiates through it with fewer, fused operations than
        through a double backward (``benchmarks/bench_baselines.py`` times both)."""
        linears = cast(list[nn.Linear], list(self.net)[::2])  # Linear, SiLU, Linear, SiLU, ..., Linear
        x, slopes = self.features(q), []
        for lin in linears[:-1]:
            z = lin(x)
            s = torch.sigmoid(z)
            x = z * s  # SiLU(z)
            slopes.append(torch.addcmul(s, x, 1.0 - s))  # SiLU'(z) = s + SiLU(z) (1 - s)
        g = linears[-1].weight[0] * self.out_scale  # dV / d(last hidden layer)
        for lin, slope in zip(reversed(linears[:-1]), reversed(slopes)):
            g = (g * slope) @ lin.weight
        return self.features_vjp(q, g)

    def features_vjp(self, q: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        """dV/dq from dV/d(features) ``g``: the transposed Jacobian of :meth:`features` applied to ``g``."""
        n_eu, na = self.n - len(self.angle_dims), len(self.angle_dims)
        cols: dict[int, torch.Tensor] = {}
        eu = [i for i in range(self.n) if i not in self.angle_dims]
        for j, i in enumerate(eu):
            cols[i] = g[..., j] / self.q_scale[j]
        if na:
            a = q[..., list(self.angle_dims)]
            acc = torch.zeros_like(a)
            for k in range(1, self.n_freq + 1):
                c = n_eu + 2 * na * (k - 1)  # sin(k a) block, then cos(k a)
                acc = acc + k * (g[..., c:c + na] * torch.cos(k * a) - g[..., c + na:c + 2 * na] * torch.sin(k * a))
            for j, i in enumerate(self.angle_dims):
                cols[i] = acc[..., j]
        return torch.stack([cols[i] for i in range(self.n)], -1)


class HybridPotential(Potential):
    """``V = V_template + softplus(rho) * V_neural`` with a small learnable scale (Eq. 84)."""

    def __init__(self, template: Potential, neural: Potential, eps_init: float = 0.01) -> None:
        super().__init__()
        self.template, self.neural = template, neural
        self.rho = nn.Parameter(torch.tensor(math.log(math.expm1(eps_init))))

    @property
    def eps(self) -> torch.Tensor:
        return nn.functional.softplus(self.rho)

    def energy(self, q: torch.Tensor) -> torch.Tensor:
        return self.template.energy(q) + self.eps * self.neural.energy(q)

    def grad(self, q: torch.Tensor) -> torch.Tensor:
        return self.template.grad(q) + self.eps * self.neural.grad(q)
