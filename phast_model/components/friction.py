"""Velocity-dependent joint friction: a passive force f(v) added to PHAST's dissipation half-step.

:class:`JointFriction` is the per-joint force

    f_i(v) = sum_k c_ik phi_k(v_i)   on the joints ``joints`` (0 on the other coordinates),
    c_ik = softplus(raw_ik) >= 0

with the shapes (``laws``)

* ``coulomb``:   phi(v) = tanh(v / eps_i)                          (smoothed sign; eps_i default 0.01)
* ``viscous``:   phi(v) = v
* ``quadratic``: phi(v) = v |v|                                      (drag)
* ``stribeck``:  phi(v) = exp(-(v / vs_i)^2) tanh(v / eps_i)         (breakaway excess; vs_i default 0.1)

Every shape is odd with phi(v) v >= 0, and c >= 0, so f_i(v_i) v_i >= 0: the friction power
``sum_i f_i v_i`` is non-negative for every coefficient value (passive by construction).  eps and vs are in the
coordinate's velocity unit (rad/s for a hinge, m/s for a slider); the defaults suit speeds of order 1.

:meth:`JointFriction.half_step` integrates ``pdot = -f(M(q)^-1 p)`` at fixed q over ``tau`` by backward Euler
(see its docstring for why it cannot add energy).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Literal, overload

import torch
from torch import nn

from .features import inv_softplus
from .mass import Mass

LAWS = ("coulomb", "viscous", "quadratic", "stribeck")

#: default Coulomb smoothing velocity (tanh(v / eps) is within 2 % of sign(v) for |v| > 2.3 eps)
DEFAULT_EPS = 0.01
#: default Stribeck velocity: the breakaway excess decays as exp(-(v / vs)^2)
DEFAULT_VS = 0.1
#: default initial coefficient of every law (weak friction: the data raise what they need)
DEFAULT_INIT = 1e-3


def _per_joint(value: float | Sequence[float], k: int, name: str) -> torch.Tensor:
    """A positive scalar or one value per joint -> (k,) float32 tensor."""
    t = torch.as_tensor(value, dtype=torch.float32).flatten()
    t = t.expand(k).clone() if t.numel() == 1 else t
    if t.numel() != k:
        raise ValueError(f"{name} has {t.numel()} entries for {k} joints")
    if not bool((t > 0).all()):
        raise ValueError(f"{name} must be > 0, got {t.tolist()}")
    return t


def _per_law(init: float | Sequence[float] | Mapping[str, float], laws: tuple[str, ...]) -> list[float]:
    """Initial coefficient of each law from a scalar, a sequence in ``laws`` order or a dict law -> value."""
    if isinstance(init, Mapping):
        missing = sorted(set(laws) - set(init))
        if missing:
            raise ValueError(f"init has no value for law(s) {missing}")
        vals = [float(init[law]) for law in laws]
    elif isinstance(init, (int, float)):
        vals = [float(init)] * len(laws)
    else:
        vals = [float(x) for x in init]
    if len(vals) != len(laws) or not all(v > 0 for v in vals):
        raise ValueError(f"init must give one value > 0 per law {laws}, got {vals}")
    return vals


def _matvec(m: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """M v for (..., n, n) and (..., n)."""
    return (m @ v.unsqueeze(-1)).squeeze(-1)


def _stribeck_slope(g: torch.Tensor, x: torch.Tensor, th: torch.Tensor, inv_eps: torch.Tensor,
                    inv_vs: torch.Tensor) -> torch.Tensor:
    """d/dv of g tanh(v / eps) with g = exp(-x^2), x = v / vs: g' = -2 x g / vs."""
    return g * ((1 - th * th) * inv_eps - 2 * x * inv_vs * th)


class JointFriction(nn.Module):
    """Learnable passive per-joint friction ``f_i(v_i) = sum_k softplus(raw_ik) phi_k(v_i)`` (module docstring).

    ``n`` coordinates; ``joints`` the coordinates with friction; ``laws`` a subset of :data:`LAWS`; ``eps`` / ``vs``
    the Coulomb smoothing and Stribeck velocities (a scalar or one per joint, buffers); ``init`` the initial
    coefficients (a scalar, one per law, or a dict law -> value; > 0); ``newton_iters`` / ``line_search`` the
    fixed work of the backward-Euler solve in :meth:`half_step`."""

    index: torch.Tensor  # buffers: the joints' coordinates, their Coulomb smoothing and Stribeck velocities
    eps: torch.Tensor
    vs: torch.Tensor

    def __init__(self, n: int, joints: Sequence[int] | None = None, laws: Sequence[str] = ("coulomb", "viscous"),
                 eps: float | Sequence[float] = DEFAULT_EPS, vs: float | Sequence[float] = DEFAULT_VS,
                 init: float | Sequence[float] | Mapping[str, float] = DEFAULT_INIT, newton_iters: int = 8,
                 line_search: int = 6) -> None:
        super().__init__()
        joints = tuple(range(n)) if joints is None else tuple(int(j) for j in joints)
        laws = tuple(laws)
        if not joints or len(set(joints)) != len(joints) or not all(0 <= j < n for j in joints):
            raise ValueError(f"joints must be distinct coordinates in [0, {n}), got {joints}")
        if not laws or len(set(laws)) != len(laws) or not set(laws) <= set(LAWS):
            raise ValueError(f"laws must be distinct names from {LAWS}, got {laws}")
        if newton_iters < 0 or line_search < 1:
            raise ValueError("newton_iters must be >= 0 and line_search >= 1")
        self.n, self.joints, self.laws = int(n), joints, laws
        self.newton_iters, self.line_search = int(newton_iters), int(line_search)
        self.register_buffer("index", torch.tensor(joints, dtype=torch.long), persistent=False)
        self.register_buffer("eps", _per_joint(eps, len(joints), "eps"))
        self.register_buffer("vs", _per_joint(vs, len(joints), "vs"))
        raw = [[float(inv_softplus(c))] * len(joints) for c in _per_law(init, laws)]
        self.raw = nn.Parameter(torch.tensor(raw, dtype=torch.float32))  # (laws, joints)

    # ---- the force law ------------------------------------------------------------
    def coefficients(self) -> dict[str, torch.Tensor]:
        """law -> c (len(joints),) >= 0, the learned coefficients (for reports)."""
        c = nn.functional.softplus(self.raw)
        return {law: c[k] for k, law in enumerate(self.laws)}

    def _per_coordinate(self, t: torch.Tensor, fill: float, dtype: torch.dtype) -> torch.Tensor:
        """A per-joint (J,) or (K, J) tensor spread onto the n coordinates (``fill`` elsewhere)."""
        full = torch.full((*t.shape[:-1], self.n), fill, dtype=dtype, device=t.device)
        return full.index_copy(-1, self.index, t.to(dtype))

    def _shapes(self, v: torch.Tensor) -> list[tuple[torch.Tensor, Callable[[], torch.Tensor]]]:
        """(phi_k(v), a thunk for phi_k'(v)) of each law, on all n coordinates (module docstring)."""
        inv_eps = 1 / self._per_coordinate(self.eps, 1.0, v.dtype)
        th = torch.tanh(v * inv_eps)
        out: list[tuple[torch.Tensor, Callable[[], torch.Tensor]]] = []
        for law in self.laws:
            if law == "coulomb":
                out.append((th, lambda: (1 - th * th) * inv_eps))
            elif law == "viscous":
                out.append((v, lambda: torch.ones_like(v)))
            elif law == "quadratic":
                out.append((v * v.abs(), lambda: 2 * v.abs()))
            else:  # stribeck: g tanh with g = exp(-x^2), x = v / vs, g' = -2 x g / vs
                inv_vs = 1 / self._per_coordinate(self.vs, 1.0, v.dtype)
                x = v * inv_vs
                g = torch.exp(-x * x)
                out.append((g * th, partial(_stribeck_slope, g, x, th, inv_eps, inv_vs)))
        return out

    def _off_joints(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` (..., n) with zeros off the joints (0 * inf would be nan where v overflows a law)."""
        if len(self.joints) == self.n:
            return x
        on = self._per_coordinate(torch.ones_like(self.eps), 0.0, x.dtype) > 0
        return torch.where(on, x, torch.zeros_like(x))

    @overload
    def _law(self, v: torch.Tensor, slope: Literal[False] = False) -> tuple[torch.Tensor, None]: ...
    @overload
    def _law(self, v: torch.Tensor, slope: Literal[True]) -> tuple[torch.Tensor, torch.Tensor]: ...

    def _law(self, v: torch.Tensor, slope: bool = False) -> tuple[torch.Tensor, torch.Tensor | None]:
        """f(v) and, with ``slope``, the diagonal f'(v): (..., n) -> (..., n), zero off the joints.  Evaluated on all n
        coordinates with zero coefficients off the joints (cheaper than gathering and scattering v)."""
        c = self._per_coordinate(nn.functional.softplus(self.raw), 0.0, v.dtype)  # (K, n)
        f = torch.zeros_like(v)
        df = torch.zeros_like(v) if slope else None
        for k, (phi, dphi) in enumerate(self._shapes(v)):
            f = f + c[k] * phi
            if df is not None:
                df = df + c[k] * dphi()
        return self._off_joints(f), None if df is None else self._off_joints(df)

    def basis(self, v: torch.Tensor) -> torch.Tensor:
        """(K, ..., n) the laws' shapes phi_k(v), zero off the joints: f = sum_k c_k * basis[k] (a regressor)."""
        return torch.stack([self._off_joints(phi) for phi, _ in self._shapes(v)])

    @torch.no_grad()
    def set_coefficients(self, c: Mapping[str, torch.Tensor | Sequence[float]], floor: float = 1e-9) -> None:
        """Set each law's coefficients (len(joints),) to ``c[law]`` (clipped at ``floor``: a softplus never reaches 0);
        laws not in ``c`` keep theirs."""
        for k, law in enumerate(self.laws):
            if law in c:
                self.raw[k].copy_(inv_softplus(torch.as_tensor(c[law], dtype=torch.float64).clamp_min(floor)))

    def force(self, v: torch.Tensor) -> torch.Tensor:
        """f(v): (..., n) -> (..., n), with f_i(v_i) v_i >= 0."""
        return self._law(v)[0]

    def dforce(self, v: torch.Tensor) -> torch.Tensor:
        """The diagonal Jacobian d f_i / d v_i, (..., n) (analytic; may be negative for ``stribeck``)."""
        return self._law(v, slope=True)[1]

    def power(self, v: torch.Tensor) -> torch.Tensor:
        """Dissipated power sum_i f_i(v_i) v_i >= 0, shape (...)."""
        return (self.force(v) * v).sum(-1)

    # ---- the dissipation sub-step ----------------------------------------------------
    def half_step(self, mass: Mass, q: torch.Tensor, p: torch.Tensor, tau: torch.Tensor | float) -> torch.Tensor:
        """Backward Euler over ``tau`` at fixed q: ``p_new = p - tau f(v_new)``, ``v_new = M(q)^-1 p_new``.

        Why it is passive.  With Delta = p_new - p and T(p) = p^T M^-1 p / 2,
        T(p_new) - T(p) = Delta^T M^-1 p_new - |Delta|^2_{M^-1} / 2
                        = -tau f(v_new)^T v_new - |Delta|^2_{M^-1} / 2 <= 0
        for any f with f(v) v >= 0 and any tau >= 0, however stiff f is (an explicit step
        ``p - tau f(M^-1 p)`` overshoots once tau c / eps exceeds ~2 lambda_min(M)).

        The solve: ``newton_iters`` damped Newton iterations on ``R(v) = M v + tau f(v) - p`` from ``v0 = M^-1 p``
        (:meth:`_solve`); each keeps, per batch element, the candidate of least |R| among the Newton steps of
        length 0, 1, 1/2, ..., 2^-(line_search - 1).  Measured: with the defaults (8 iterations, 6 step lengths) it
        reaches |R| ~ rounding up to a stiffness tau c / (eps lambda_min(M)) of about 10 (Coulomb, viscous,
        quadratic and Coulomb + Stribeck; an explicit step already gains energy past ~2), 12 iterations reach
        ~100 for the monotone laws.  Finitely many iterations are not an exact solution, so a passivity
        guard follows: with b = Delta^T M^-1 p and c = Delta^T M^-1 Delta, T(p + a Delta) - T(p) = a (b + a c / 2),
        so ``p + alpha Delta`` with ``alpha = clamp(-2 b / c, 0, 1)`` never raises T (exact arithmetic).  At an
        exact solution b = -tau f^T v_new - c <= -c, so alpha = 1: the guard only acts on a poor iterate.

        Gradients: the iterations run without autograd; the solution's gradient is the implicit-function one,
        ``dv = -J^-1 dR`` at the final iterate (exact for a converged monotone f; with ``stribeck``, J uses
        max(f', 0), so it is approximate where the total friction slope is negative)."""
        tau = torch.as_tensor(tau, dtype=p.dtype, device=p.device)
        v0 = mass.velocity(q, p)
        # newton_iters = 0: the explicit step p - tau f(M^-1 p) (accurate while tau c / (eps lambda_min(M)) << 1, as on
        # rigs sampled at a few ms), kept passive by the same guard
        v = v0 if self.newton_iters == 0 else self._solve(mass.matrix(q).to(p.dtype), p, v0, tau)
        p_new = p - tau * self.force(v)
        return self._guard(mass, q, p, v0, p_new - p)

    def _residual(self, m: torch.Tensor, v: torch.Tensor, p: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
        """R(v) = M v + tau f(v) - p (the backward-Euler equation in velocity form)."""
        return _matvec(m, v) + tau * self.force(v) - p

    def _jacobian(self, m: torch.Tensor, v: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
        """M + tau diag(max(f'(v), 0)): symmetric positive definite (the implicit-function gradient's J)."""
        return m + torch.diag_embed(tau * self.dforce(v).clamp_min(0))

    def _solve(self, m: torch.Tensor, p: torch.Tensor, v0: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
        """Damped Newton on R(v) = 0 from v0, then the implicit-function gradient attached to the final iterate."""
        with torch.no_grad():
            md, pd, taud, v = m.detach(), p.detach(), tau.detach(), v0.detach()
            steps = 0.5 ** torch.arange(-1, self.line_search, dtype=p.dtype, device=p.device)
            steps[0] = 0.0  # candidate step lengths 0, 1, 1/2, ..., 2^-(line_search - 1)
            for _ in range(self.newton_iters):
                v = self._newton_iteration(md, v, pd, taud, steps)
        if not torch.is_grad_enabled():
            return v
        # value v, gradient -J^-1 dR (R differentiated in M(q), p, tau and the coefficients; zero value added)
        corr = -torch.linalg.solve(self._jacobian(m.detach(), v, tau.detach()), self._residual(m, v, p, tau))
        return v + (corr - corr.detach())

    def _newton_iteration(self, m: torch.Tensor, v: torch.Tensor, p: torch.Tensor, tau: torch.Tensor,
                          steps: torch.Tensor) -> torch.Tensor:
        """One damped Newton iteration: direction dv = -J^-1 R with the exact J = M + tau diag(f'(v)) (a descent
        direction of |R|^2 even where a Stribeck slope makes J indefinite; 0 where J is singular, masked without a
        host synchronization), then, per batch element, the step length among ``steps`` of least |R|^2 (s = 0
        keeps v, so |R| never grows; a tanh law with a small eps makes full steps overshoot its kink)."""
        f, df = self._law(v, slope=True)
        mv_p = _matvec(m, v) - p
        r = mv_p + tau * f
        dv, info = torch.linalg.solve_ex(m + torch.diag_embed(tau * df), -r)
        ok = (info == 0).unsqueeze(-1) & torch.isfinite(dv).all(-1, keepdim=True)
        dv = torch.where(ok, dv, torch.zeros_like(dv))
        s = steps.unsqueeze(-1)  # (S, 1)
        cand = v.unsqueeze(-2) + s * dv.unsqueeze(-2)  # (..., S, n)
        r_cand = mv_p.unsqueeze(-2) + s * _matvec(m, dv).unsqueeze(-2) + tau * self.force(cand)  # R is affine in M v
        score = torch.nan_to_num((r_cand * r_cand).sum(-1), nan=math.inf)  # (..., S)
        best = score.argmin(-1, keepdim=True).unsqueeze(-1).expand(*v.shape[:-1], 1, v.shape[-1])
        return cand.gather(-2, best).squeeze(-2)

    @staticmethod
    def _guard(mass: Mass, q: torch.Tensor, p: torch.Tensor, v0: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
        """p + alpha Delta with alpha = clamp(-2 Delta^T M^-1 p / Delta^T M^-1 Delta, 0, 1) (passivity guard)."""
        b = (delta * v0).sum(-1)
        c = (delta * mass.velocity(q, delta)).sum(-1)
        ok = c > 0
        alpha = torch.where(ok, -2 * b / torch.where(ok, c, torch.ones_like(c)), torch.zeros_like(c)).clamp(0, 1)
        return p + alpha.unsqueeze(-1) * delta
