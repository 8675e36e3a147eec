"""Damping models D(q) (PSD), applied as ``D(q) v`` without forming D.

:class:`HouseholderDamping` (paper Eq. 10-11, Fig. 23):
``D(q) = d0 I + sum_{i=1..r} beta_i(q) k_i(q) k_i(q)^T``, ``|k_i| = 1``,
``beta_i >= 0``; optional cap ``sum_i beta_i <= beta_bar`` via a softmax with a
slack logit, certifying ``lambda_max(D) <= d0 + beta_bar``.

With one coordinate every unit vector is +-1 and ``k k^T = 1``, so ``k_i = 1`` there.  Normalizing a learned
scalar instead (``k = x / sqrt(x^2 + 1e-8)``) leaves ``x`` with a gradient only from the 1e-8 regularizer, which
Adam with a tiny eps (the identification settings) turns into lr-sized steps: ``x`` random-walks to a zero
crossing, where ``k k^T`` falls to 0 and a 1e4 gradient drives the strengths ``beta_i`` into softplus's flat
tail.  That lost the identified D on 2 of 8 rounding-level perturbations of one windy-pendulum KNOWN run.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial
from typing import cast

import torch
from torch import nn

from phast_gym.systems import TORCH, System, split, stack

from .features import coordinate_features, n_features


class Damping(nn.Module):
    """Interface: ``force(q, v) = D(q) v`` and ``diag(q)`` (diagonal of D, for metrics)."""

    def force(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """The damping force ``D(q) v`` (it enters ``pdot`` with a minus sign, as :meth:`JointFriction.force`)."""
        raise NotImplementedError

    def at(self, q: torch.Tensor) -> Callable[[torch.Tensor], torch.Tensor]:
        """``v -> D(q) v`` with the q-dependent part evaluated once: a Strang step applies D twice at each q."""
        return partial(self.force, q)

    def diag(self, q: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def bound(self, q: torch.Tensor) -> torch.Tensor:
        """Upper bound of lambda_max(D(q)), shape (...)."""
        raise NotImplementedError


class HouseholderDamping(Damping):
    """Low-rank PSD damping with normalized directions, O(n r) application."""

    q_scale: torch.Tensor  # buffers
    fixed_d0: torch.Tensor  # only when d0 is not learned

    def __init__(self, n: int, angle_dims: tuple[int, ...] = (), rank: int = 2, hidden: int = 32,
                 cap: float | None = None, d0: float = 0.0, learn_d0: bool = True, beta_init: float = 0.1,
                 q_scale: torch.Tensor | float = 1.0) -> None:
        super().__init__()
        if cap is not None and not cap > 0:
            raise ValueError(f"damping cap must be > 0 or None, got {cap!r}")
        if d0 < 0:
            raise ValueError(f"d0 must be >= 0, got {d0!r}")
        self.n, self.angle_dims, self.rank, self.cap = n, tuple(angle_dims), int(rank), cap
        n_eu = n - len(self.angle_dims)
        self.register_buffer("q_scale", torch.as_tensor(q_scale, dtype=torch.float32).expand(n_eu).clone())
        n_logit = self.rank + (1 if cap is not None else 0)
        self.net = nn.Sequential(nn.Linear(n_features(n, self.angle_dims), hidden), nn.SiLU(),
                                 nn.Linear(hidden, hidden), nn.SiLU(), nn.Linear(hidden, self.rank * n + n_logit))
        with torch.no_grad():
            last = cast(nn.Linear, self.net[-1])
            last.weight[self.rank * n:].mul_(0.1)
            # directions start near the coordinate axes k_i = e_(i mod n): most mechanical damping acts per
            # coordinate, and a weakly excited coordinate (a heavy cart) gives too little gradient to rotate a
            # random direction onto its axis
            last.weight[: self.rank * n].mul_(0.1)
            last.bias[: self.rank * n] = torch.eye(n).repeat(self.rank // n + 1, 1)[: self.rank].reshape(-1)
            if cap is None:  # softplus(b) = beta_init per term
                last.bias[self.rank * n:] = math.log(math.expm1(beta_init))
        self.learn_d0 = bool(learn_d0)
        if self.learn_d0:
            # d0 = 0 starts at 0.1 (a responsive softplus); a positive d0 is the start (the identification settings
            # start it at MIN_D0 and let the x100 damping network raise D where the data need it)
            self.raw_d0 = nn.Parameter(torch.tensor(math.log(math.expm1(d0 if d0 > 0 else 0.1))))
        else:
            self.register_buffer("fixed_d0", torch.tensor(float(d0)))

    @property
    def d0(self) -> torch.Tensor:
        return nn.functional.softplus(self.raw_d0) if self.learn_d0 else self.fixed_d0

    @torch.no_grad()
    def set_d0(self, value: float) -> None:
        """Start a learned floor at ``value`` (> 0)."""
        if not self.learn_d0:
            raise ValueError("set_d0: this damping's floor d0 is fixed")
        self.raw_d0.copy_(torch.log(torch.expm1(torch.tensor(float(value), dtype=self.raw_d0.dtype))))

    def terms(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(beta (..., r) >= 0, k (..., r, n) unit vectors)."""
        out = self.net(coordinate_features(q, self.angle_dims, self.q_scale))
        if self.n == 1:  # k = +-1 (module docstring); the network's direction outputs are left unused
            k = out.new_ones(*q.shape[:-1], self.rank, 1)
        else:
            k = out[..., : self.rank * self.n].reshape(*q.shape[:-1], self.rank, self.n)
            k = k / torch.sqrt((k * k).sum(-1, keepdim=True) + 1e-8)
        logits = out[..., self.rank * self.n:]
        if self.cap is None:
            beta = nn.functional.softplus(logits)
        else:  # beta_i = beta_bar softmax([logits, slack])_i  =>  sum_i beta_i <= beta_bar (Eq. 11)
            beta = self.cap * torch.softmax(logits, -1)[..., : self.rank]
        return beta, k

    def at(self, q: torch.Tensor) -> Callable[[torch.Tensor], torch.Tensor]:
        beta, k = self.terms(q)
        d0 = self.d0

        def d_times(v: torch.Tensor) -> torch.Tensor:
            proj = (k * v.unsqueeze(-2)).sum(-1)  # (..., r): k_i^T v
            return d0 * v + ((beta * proj).unsqueeze(-1) * k).sum(-2)

        return d_times

    def force(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        return self.at(q)(v)

    def diag(self, q: torch.Tensor) -> torch.Tensor:
        beta, k = self.terms(q)
        return self.d0 + (beta.unsqueeze(-1) * k * k).sum(-2)

    def matrix(self, q: torch.Tensor) -> torch.Tensor:
        """Dense D(q) (tests and plots only)."""
        beta, k = self.terms(q)
        eye = torch.eye(self.n, dtype=q.dtype, device=q.device)
        return self.d0 * eye + (beta[..., None, None] * k.unsqueeze(-1) * k.unsqueeze(-2)).sum(-3)

    def bound(self, q: torch.Tensor) -> torch.Tensor:
        beta, _ = self.terms(q)
        return self.d0 + beta.sum(-1)


class KnownDamping(Damping):
    """The env's own D(q) (oracle / tests): calls ``system.damping``."""

    def __init__(self, system: System) -> None:
        super().__init__()
        self.system = system

    def diag(self, q: torch.Tensor) -> torch.Tensor:
        return stack(self.system.damping(split(q), TORCH)) + 0.0 * q

    def force(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        return self.diag(q) * v

    def bound(self, q: torch.Tensor) -> torch.Tensor:
        return self.diag(q).max(-1).values
