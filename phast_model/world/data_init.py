"""Least-squares initialization of a PHAST model from its q-only training data.

The equation of motion in Lagrangian form,

    d/dt (M(q) v) - 1/2 d/dq (v^T M(q) v) + dV/dq + D(q) v = G u,          (Eq. 1-3 with p = M v)

is linear in every coefficient that enters M, V or D linearly.  With v and d/dt taken by central differences
of the recorded q, one least squares over a subsample of the training set gives

* PARTIAL: the potential template's coefficients and the mass coefficients (the template's own form), instead
  of reading them off the env's true physics;
* KNOWN: a floor for the damping d0 (the smallest damping the data show, from a per-coordinate D_ii(q) on a
  small Fourier basis), so the learned floor does not have to climb to it (a slow floor left a weakly excited
  coordinate, the cart of the cart-pole, under-damped).

Scale gauge: without a port input (u = 0), (M, V, D) and a(M, V, D) give the same trajectories.  A constant mass
then starts neutral (M = I, which also fixes the scale of decoupled coordinates); a mass template is fitted by the
smallest right singular vector of the homogeneous problem, normalized to a mean mass diagonal of 1.  A fixed
physical damping floor d0 (the windy systems) rescales the result so that the smallest fitted damping equals it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..components.potentials import HybridPotential, TemplatePotential

#: the smallest starting value of a learned damping floor d0 (the softplus of a smaller one hardly moves)
MIN_D0 = 1e-3


@dataclass(frozen=True)
class Kinematics:
    """Samples (M, n) of the recorded motion at interior times, from second-order central differences."""

    q: torch.Tensor  # positions at t
    v: torch.Tensor  # (q_{t+1} - q_{t-1}) / (2 dt)
    q_prev: torch.Tensor  # positions at t -+ 1 and their velocities (for d/dt of M(q) v)
    q_next: torch.Tensor
    v_prev: torch.Tensor
    v_next: torch.Tensor
    f: torch.Tensor | None  # port force G u held over [t, t+1] (mean of the two intervals around t)
    dt: float


def kinematics(q: torch.Tensor, f: torch.Tensor | None, dt: float, angle_dims: tuple[int, ...],
               max_traj: int = 256, stride: int = 3) -> Kinematics:
    """Central-difference velocities of (N, T, n) positions (angles unwrapped first), sampled every
    ``stride`` steps of the first ``max_traj`` trajectories; ``f`` (N, T, n) is the port force."""
    if q.shape[1] < 5:
        raise ValueError(f"least-squares initialization needs trajectories of >= 5 samples, got T={q.shape[1]}")
    q = q[:max_traj].double()
    if angle_dims:
        qn = q.numpy().copy()
        qn[..., list(angle_dims)] = np.unwrap(qn[..., list(angle_dims)], axis=1)
        q = torch.from_numpy(qn)
    v = (q[:, 2:] - q[:, :-2]) / (2 * dt)  # at t = 1 .. T-2
    t = torch.arange(1, v.shape[1] - 1, stride)  # centre index into v (t + 1 into q)
    ff = None
    if f is not None and bool((f != 0).any()):  # an all-zero port input carries no scale information
        f = f[:max_traj].double()
        ff = 0.5 * (f[:, t] + f[:, t + 1]).reshape(-1, q.shape[-1])

    def flat(x: torch.Tensor) -> torch.Tensor:
        return x.reshape(-1, q.shape[-1])

    return Kinematics(q=flat(q[:, t + 1]), v=flat(v[:, t]), q_prev=flat(q[:, t]), q_next=flat(q[:, t + 2]),
                      v_prev=flat(v[:, t - 1]), v_next=flat(v[:, t + 1]), f=ff, dt=float(dt))


def _grad_or_zero(y: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """dy/dx, zeros where y does not depend on x (a constant basis element)."""
    if not y.requires_grad:
        return torch.zeros_like(x)
    (g,) = torch.autograd.grad(y, x, retain_graph=True, allow_unused=True)
    return torch.zeros_like(x) if g is None else g


def mass_columns(kin: Kinematics, basis) -> torch.Tensor:  # noqa: ANN001 - basis: (..., n) -> (..., J, n, n)
    """(M, n, J): for each B_j, d/dt (B_j(q) v) - 1/2 d/dq (v^T B_j(q) v) at every sample."""
    def bv(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        return (basis(q) @ v[:, None, :, None]).squeeze(-1)  # (M, J, n)

    ddt = (bv(kin.q_next, kin.v_next) - bv(kin.q_prev, kin.v_prev)) / (2 * kin.dt)
    with torch.enable_grad():
        q = kin.q.clone().requires_grad_(True)
        quad = (kin.v[:, None, None, :] @ basis(q) @ kin.v[:, None, :, None]).squeeze(-1).squeeze(-1)  # (M, J)
        grads = [_grad_or_zero(quad[:, j].sum(), q) for j in range(quad.shape[1])]
    return (ddt - 0.5 * torch.stack(grads, 1)).transpose(1, 2).detach()


def damping_columns(kin: Kinematics, features: torch.Tensor | None = None) -> torch.Tensor:
    """(M, n, n K): D_ii(q) = sum_k w_ik phi_k(q) on each coordinate (``features`` (M, K); constant if None)."""
    phi = torch.ones(kin.q.shape[0], 1, dtype=kin.q.dtype) if features is None else features
    n, K = kin.q.shape[-1], phi.shape[-1]
    eye = torch.eye(n, dtype=kin.q.dtype)
    return (kin.v[:, :, None, None] * eye[None, :, :, None] * phi[:, None, None, :]).reshape(-1, n, n * K)


@dataclass(frozen=True)
class LinearFit:
    """Coefficients of the stacked columns and the relative residual of the fit."""

    theta: torch.Tensor
    residual: float


def solve(A: torch.Tensor, b: torch.Tensor | None, gauge: torch.Tensor | None = None) -> LinearFit:
    """Least squares ``A theta = b`` over all samples and coordinates; without a right-hand side (b None or
    zero), the smallest right singular vector scaled so that ``gauge . theta = 1``."""
    A2 = A.reshape(-1, A.shape[-1])
    col = A2.norm(dim=0).clamp_min(1e-12)  # column scaling: the problem mixes units
    if b is not None and float(b.abs().max()) > 0:
        b2 = b.reshape(-1)
        th = torch.linalg.lstsq(A2 / col, b2.unsqueeze(-1)).solution.squeeze(-1) / col
        res = float((A2 @ th - b2).norm() / b2.norm().clamp_min(1e-300))
        return LinearFit(th, res)
    _, s, vh = torch.linalg.svd(A2 / col, full_matrices=False)
    th = vh[-1] / col
    if gauge is None:
        raise ValueError("least-squares initialization: a homogeneous problem needs a gauge")
    scale = gauge @ th
    if abs(float(scale)) < 1e-12:
        raise ValueError("least-squares initialization: the mass is not identified by the data (zero scale)")
    return LinearFit(th / scale, float(s[-1] / s[0]))


def _fourier(q: torch.Tensor, angle_dims: tuple[int, ...]) -> torch.Tensor:
    """A small basis in q: 1, and per coordinate (cos, sin, cos 2x, sin 2x, |sin x|) of angles or (x, x^2) of the
    others (scaled by their RMS).  |sin x| lets the fit follow a kink at x = 0 (the windy damping laws); without it
    a truncated series overshoots the minimum there (windy pendulum floor 0.37 with harmonics up to 4x against
    0.33 with this basis, true 0.30), which the 0.8 margin of ``PHAST.floor_margin`` still absorbs."""
    parts = [torch.ones_like(q[:, 0])]
    for i in range(q.shape[-1]):
        x = q[:, i]
        if i in angle_dims:
            parts += [torch.cos(x), torch.sin(x), torch.cos(2 * x), torch.sin(2 * x), torch.abs(torch.sin(x))]
        else:
            z = x / x.pow(2).mean().sqrt().clamp_min(1e-9)
            parts += [z, z * z]
    return torch.stack(parts, -1)


def _fitted_floor(phi: torch.Tensor, w: torch.Tensor, quantile: float) -> float:
    """The ``quantile`` over samples of min_i D_ii(q) of a per-coordinate fit D_ii = phi @ w_i (w: (n K,))."""
    d = phi @ w.reshape(-1, phi.shape[-1]).T  # (M, n)
    return float(torch.quantile(d.min(-1).values, quantile))


def damping_floor(model, kin: Kinematics, quantile: float = 0.01) -> float:  # noqa: ANN001 - a PHAST model
    """Smallest damping the data show under the model's known V and M: D_ii(q) fitted on a small basis per
    coordinate to the residual force; returns the ``quantile`` of min_i D_ii over the samples (>= 0)."""
    with torch.no_grad():
        dtype = next(model.parameters()).dtype
        mass, pot = model.mass, model.potential

        def p_of(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
            return mass.momentum(q.to(dtype), v.to(dtype)).double()

        pdot = (p_of(kin.q_next, kin.v_next) - p_of(kin.q_prev, kin.v_prev)) / (2 * kin.dt)
        q, v = kin.q.to(dtype), kin.v.to(dtype)
        dH = (pot.grad(q) + mass.kinetic_dq(q, mass.momentum(q, v))).double()
        resid = (kin.f if kin.f is not None else 0.0) - pdot - dH  # = D(q) v
    phi = _fourier(kin.q, tuple(model.angle_dims))
    fit = solve(damping_columns(kin, phi), resid)
    return max(0.0, _fitted_floor(phi, fit.theta, quantile))


def initialize_partial(model, kin: Kinematics, quantile: float = 0.01) -> LinearFit:  # noqa: ANN001 - a PHAST model
    """Template and mass coefficients of a PARTIAL model from one least squares, with a per-coordinate D_ii(q) on a
    small basis as nuisance and the port force on the right-hand side.  Without a port the scale is set by a fixed
    damping floor d0 when the model has one (Table 13: the smallest fitted D_ii(q) equals d0), else by the
    neutral mass (mean diagonal 1)."""
    pot = model.potential
    template = pot.template if isinstance(pot, HybridPotential) else pot
    if not isinstance(template, TemplatePotential):
        raise ValueError("initialize_partial needs a template (or hybrid) potential")
    mass = model.mass
    dtype = next(mass.parameters()).dtype
    Am = mass_columns(kin, lambda q: mass.linear_basis(q.to(dtype)).double())
    phi = _fourier(kin.q, tuple(model.angle_dims))
    Ad = damping_columns(kin, phi)
    J = Am.shape[-1]
    with torch.no_grad():  # mean diagonal of M(q) over the samples per coefficient (the homogeneous gauge)
        B = mass.linear_basis(kin.q.to(dtype)).double()
        g_mass = torch.diagonal(B, dim1=-2, dim2=-1).mean(-1).mean(0)  # (J,)
    # a constant mass starts neutral (M = I: its coefficients move to the right-hand side, which also fixes the
    # scale of each decoupled coordinate); a mass template is fitted, in the gauge of a mean diagonal of 1
    neutral = bool(mass.constant) and kin.f is None  # with a port, the input fixes the scale: M is fitted too
    theta_m = torch.ones(J, dtype=Am.dtype) if neutral else None  # None: M is fitted
    rhs = -(Am @ theta_m) if theta_m is not None else kin.f
    best: tuple[LinearFit, float | None] | None = None
    for eps in ([None] if template.kind != "gravity" else list(np.logspace(-2, 0, 11))):
        if eps is not None:
            with torch.no_grad():
                template.log_eps.fill_(float(np.log(eps)))
        Ap = template.gradient_basis(kin.q).double()
        if theta_m is not None:
            fit = solve(torch.cat([Ap, Ad], -1), rhs)
            fit = LinearFit(torch.cat([theta_m, fit.theta]), fit.residual)
        else:
            A = torch.cat([Am, Ap, Ad], -1)
            fit = solve(A, rhs, torch.cat([g_mass, torch.zeros(A.shape[-1] - J, dtype=g_mass.dtype)]))
        if best is None or fit.residual < best[0].residual:
            best = (fit, eps)
    if best is None:  # the loop runs at least once
        raise RuntimeError("initialize_partial: no least-squares fit was made")
    fit, eps = best
    K = template.coef.numel()
    theta = fit.theta
    damp = model.damping
    fixed_floor = float(damp.d0) if damp is not None and not damp.learn_d0 else 0.0
    floor = _fitted_floor(phi, theta[J + K:], quantile)
    if kin.f is None and fixed_floor > 0 and floor > 0:
        theta, floor = theta * (fixed_floor / floor), fixed_floor
    if damp is not None and damp.learn_d0:  # a learned floor starts below the data's smallest D, as KNOWN's
        damp.set_d0(max(model.floor_margin * max(floor, 0.0), MIN_D0))
    mass.set_linear(theta[:J])
    with torch.no_grad():
        template.coef.copy_(theta[J:J + K].to(template.coef.dtype))
        if eps is not None:
            template.log_eps.fill_(float(np.log(eps)))
    return LinearFit(theta, fit.residual)


def lotka_volterra_start(kin: Kinematics) -> tuple[torch.Tensor, float]:
    """Coefficients c of the Lotka-Volterra template (``qdot = q (c1 + c2 q + c3 p)``, ``pdot = p (c4 q + c5) + f``)
    from the observed prey q alone, and the relative residual of the fit.

    The predator p is latent: with z = qdot / q = c1 + c2 q + c3 p, eliminating p gives
    ``zdot = (c2 + c4) qdot + c5 z - (c1 c4 + c2 c5) q - c1 c5 - c2 c4 q^2 + c3 f``, linear in six combined
    coefficients.  c5 and c1 = (c1 c5) / c5 follow at once, c2 and c4 are the roots of
    ``x^2 - (c2 + c4) x - c2 c4`` (assigned so the q coefficient is matched best).  c3 is identified by the port
    force; without one it is a gauge (the latent's unit), fixed so the mean latent equals the mean prey density."""
    q, v = kin.q[:, 0], kin.v[:, 0]
    lp, lq, ln_ = (torch.log(x[:, 0].clamp_min(1e-9)) for x in (kin.q_prev, kin.q, kin.q_next))
    z = (ln_ - lp) / (2 * kin.dt)  # d/dt ln q: compact stencils in log space (O(dt^2), no nested differences)
    zdot = (ln_ - 2 * lq + lp) / kin.dt**2
    cols = [v, z, q, torch.ones_like(q), q * q]
    if kin.f is not None:
        cols.append(kin.f[:, 0])
    fit = solve(torch.stack(cols, -1), zdot)
    th = fit.theta
    s, c5, k_q, k_1, k_qq = (float(t) for t in th[:5])
    if abs(c5) < 1e-12:
        raise ValueError("Lotka-Volterra start: the predator's own rate c5 is not identified by the data")
    c1 = -k_1 / c5
    disc = max(s * s + 4.0 * k_qq, 0.0)  # x^2 - s x - c2 c4 = 0 with c2 c4 = -k_qq
    roots = ((s + math.sqrt(disc)) / 2, (s - math.sqrt(disc)) / 2)
    c2, c4 = min((roots, roots[::-1]), key=lambda r: abs(k_q + c1 * r[1] + r[0] * c5))
    if kin.f is not None:
        c3 = float(th[5])
    else:
        resid = z - c1 - c2 * q  # = c3 p
        c3 = float(resid.mean() / q.mean())  # mean latent p = mean q
    if abs(c3) < 1e-12:
        raise ValueError("Lotka-Volterra start: the predation coefficient c3 is not identified by the data")
    return torch.tensor([c1, c2, c3, c4, c5], dtype=torch.float64), fit.residual
