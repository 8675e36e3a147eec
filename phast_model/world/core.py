"""The PHAST core transition (paper Algorithm 1, Appendix A.2).

One observation step is ``L`` substeps of the Strang splitting

    Phi_h = Phi_D(h/2) o Phi_H(h) o Phi_D(h/2),     h = dt_model / L   (Eq. 78)

* dissipation half-step, q fixed: ``p <- p - (h/2) D(q) M^-1 p`` (Eq. 42), then, with a velocity-dependent
  joint friction f(v), its backward-Euler step ``p <- p - (h/2) f(M^-1 p_new)`` (passive for any stiffness);
* conservative step ``Phi_H``: leapfrog / Stormer-Verlet when H is separable
  (constant M), implicit midpoint with fixed-point iterations for M(q);
* the port force ``G u`` is held over the step and enters the momentum
  updates of the conservative step.

The internal step ``dt_model`` is log-parameterized and learnable by default.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import nn

from ..components.damping import Damping
from ..components.friction import JointFriction
from ..components.mass import Mass
from ..components.potentials import Potential


class SubstepCore(nn.Module):
    """A core that takes ``substeps`` = L steps of length h = dt_model / L per observation step, with
    ``log_dt`` = log h a parameter (learnable internal step) or a buffer (fixed)."""

    def init_substeps(self, dt: float, substeps: int, learn_dt: bool) -> None:
        """Set L and register ``log_dt``; called last in ``__init__`` so that ``log_dt`` follows the components
        in ``parameters()`` (the order optimizer states and checkpoints rely on)."""
        if int(substeps) != substeps or substeps < 1:
            raise ValueError(f"substeps must be a positive integer, got {substeps!r}")
        self.substeps = int(substeps)
        log_dt = torch.tensor(math.log(dt / self.substeps))
        if learn_dt:
            self.log_dt = nn.Parameter(log_dt)
        else:
            self.register_buffer("log_dt", log_dt)

    @property
    def h(self) -> torch.Tensor:
        """Substep length dt_model / L."""
        return torch.exp(self.log_dt)


class PHASTCore(SubstepCore):
    """``(q, p, G u) -> (q', p')`` with potential V, mass M, damping D and optional joint friction f(v).

    ``friction`` is registered after the other components (before ``log_dt``), so models without it keep their
    parameter order and state-dict keys."""

    def __init__(self, potential: Potential, mass: Mass, damping: Damping | None, dt: float, substeps: int = 1,
                 learn_dt: bool = True, integrator: str = "auto", midpoint_iters: int = 4, *,
                 friction: JointFriction | None = None) -> None:
        if integrator not in ("auto", "leapfrog", "implicit_midpoint"):
            raise ValueError(f"integrator must be 'auto', 'leapfrog' or 'implicit_midpoint', got {integrator!r}")
        super().__init__()
        self.potential, self.mass, self.damping = potential, mass, damping
        self.integrator = ("leapfrog" if mass.constant else "implicit_midpoint") if integrator == "auto" else integrator
        self.midpoint_iters = int(midpoint_iters)
        self.friction = friction
        self.init_substeps(dt, substeps, learn_dt)

    # ---- energy --------------------------------------------------------------
    def hamiltonian(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """H(q, p) = p^T M(q)^-1 p / 2 + V(q) (Eq. 2-3)."""
        return 0.5 * (p * self.mass.velocity(q, p)).sum(-1) + self.potential.energy(q)

    def dH_dq(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        return self.potential.grad(q) + self.mass.kinetic_dq(q, p)

    # ---- splitting pieces ------------------------------------------------------
    def damping_half_step(self, q: torch.Tensor, p: torch.Tensor, h: torch.Tensor,
                          d_at_q: Callable[[torch.Tensor], torch.Tensor] | None = None) -> torch.Tensor:
        """Phi_D(h/2): p <- p - (h/2) D(q) M^-1 p (Eq. 42); energy non-increasing when
        h lambda_max(D) / (2 lambda_min(M)) <= 2 (Eq. 44).  ``d_at_q`` = ``damping.at(q)`` when already built.
        Then the joint friction's backward-Euler half-step (:meth:`JointFriction.half_step`), which never raises
        the kinetic energy at any step size."""
        if self.damping is not None:
            d_at_q = self.damping.at(q) if d_at_q is None else d_at_q
            p = p - 0.5 * h * d_at_q(self.mass.velocity(q, p))
        if self.friction is not None:
            p = self.friction.half_step(self.mass, q, p, 0.5 * h)
        return p

    def conservative_step(self, q: torch.Tensor, p: torch.Tensor, f: torch.Tensor | None, h: torch.Tensor,
                          need_p: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
        """Phi_H(h) with the port force f = G u held over the step."""
        q1, p1, _ = self._conservative(q, p, f, h, need_p, None)
        return q1, p1

    def _conservative(self, q: torch.Tensor, p: torch.Tensor, f: torch.Tensor | None, h: torch.Tensor, need_p: bool,
                      grad_v: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Phi_H(h) given dV/dq at q (or None), returning dV/dq at q1 where the leapfrog computed it: the next
        substep starts at q1 (the damping half-steps leave q unchanged), so it need not evaluate it again."""
        if self.integrator == "leapfrog":
            grad_v = self.potential.grad(q) if grad_v is None else grad_v
            p_half = p + 0.5 * h * (-grad_v if f is None else f - grad_v)
            q1 = q + h * self.mass.velocity(q, p_half)
            if not need_p:
                return q1, p_half, None
            grad_v1 = self.potential.grad(q1)
            return q1, p_half + 0.5 * h * (-grad_v1 if f is None else f - grad_v1), grad_v1
        # implicit midpoint: z1 = z0 + h J grad H((z0 + z1) / 2), solved by fixed-point iteration
        q1, p1 = q, p
        for _ in range(self.midpoint_iters + 1):
            qm, pm = 0.5 * (q + q1), 0.5 * (p + p1)
            force = -self.dH_dq(qm, pm) if f is None else f - self.dH_dq(qm, pm)
            q1, p1 = q + h * self.mass.velocity(qm, pm), p + h * force
        return q1, p1, None

    def strang_step(self, q: torch.Tensor, p: torch.Tensor, f: torch.Tensor | None = None,
                    need_p: bool = True, h: torch.Tensor | None = None,
                    substeps: int | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """One observation step: L substeps of Phi_D(h/2) o Phi_H(h) o Phi_D(h/2) (Eq. 78).

        ``need_p=False`` skips work that only affects the final momentum (teacher-forced training).
        ``h`` / ``substeps`` override the learned substep and L, e.g. to step at a control rate.
        D(q) and dV/dq at a substep's end point are evaluated once and reused by the next substep, which starts
        there (the same values as composing :meth:`damping_half_step` and :meth:`conservative_step`)."""
        h = self.h if h is None else h
        substeps = self.substeps if substeps is None else int(substeps)
        d_at_q = None if self.damping is None else self.damping.at(q)
        grad_v = None
        for s in range(substeps):
            last = s == substeps - 1
            p = self.damping_half_step(q, p, h, d_at_q)
            q, p, grad_v = self._conservative(q, p, f, h, need_p or not last, grad_v)
            if need_p or not last:
                d_at_q = None if self.damping is None else self.damping.at(q)
                p = self.damping_half_step(q, p, h, d_at_q)
        return q, p

    forward = strang_step

    def power(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """Continuous-time dH/dt at u = 0: -v^T D(q) v - f(v)^T v <= 0 (Theorem A.1 plus the joint friction)."""
        v = self.mass.velocity(q, p)
        if self.damping is None:
            out = torch.zeros_like(q[..., 0])
        else:
            out = -(v * self.damping.force(q, v)).sum(-1)
        return out if self.friction is None else out - self.friction.power(v)


def composed_strang_step(core: PHASTCore, q: torch.Tensor, p: torch.Tensor, f: torch.Tensor | None = None,
                         need_p: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
    """Eq. 78 as the plain composition of the public splitting pieces, evaluating D and dV/dq afresh in every
    piece: the reference that :meth:`PHASTCore.strang_step` (which reuses them) is tested and timed against."""
    for s in range(core.substeps):
        last = s == core.substeps - 1
        p = core.damping_half_step(q, p, core.h)
        q, p = core.conservative_step(q, p, f, core.h, need_p=need_p or not last)
        if need_p or not last:
            p = core.damping_half_step(q, p, core.h)
    return q, p
