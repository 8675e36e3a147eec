"""The PHAST world model: observer -> canonicalizer -> Strang-splitting core.

:class:`PHAST` is a :class:`~phast_model.world.interfaces.ForecastModel`; its parts are
composed from a :class:`PHASTConfig` by :func:`build_from_config` (the regimes
of :mod:`phast_model.world.regimes` are such configs).  :class:`LatentODEModel` is the
structured model of the non-Hamiltonian predator-prey env (see its docstring).  The configuration itself
(:class:`PHASTConfig`, :func:`config_system`, :func:`system_scales`) lives in :mod:`phast_model.world.config` and is
re-exported here.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, NamedTuple, TypeVar

import numpy as np
import torch
from torch import nn

from phast_gym.systems import NUMPY, TORCH, System, split, stack

from ..components import (
    CholeskyMass,
    FDTCNObserver,
    HouseholderDamping,
    HybridPotential,
    KnownDamping,
    KnownMass,
    KnownPotential,
    LowRankMass,
    NeuralPotential,
    TemplateMass,
    make_template,
)
from ..components.damping import Damping
from ..components.features import coordinate_features, n_features
from ..components.friction import JointFriction
from ..components.mass import Mass
from ..components.observer import training_velocity
from ..components.potentials import Potential, TemplatePotential
from ..components.rigid_body import LearnedBodies, RigidBodyMass, RigidBodyPotential
from . import data_init
from .config import PHASTConfig, config_system, system_scales
from .core import PHASTCore, SubstepCore
from .interfaces import ForecastModel, coordinate_error, wrap_angles


class PHAST(ForecastModel):
    """q-only port-Hamiltonian forecaster (paper Sec. 3, Algorithm 1)."""

    core: PHASTCore
    G: torch.Tensor  # buffer: the port's input matrix (identity columns of the actuated coordinates)

    def __init__(self, config: PHASTConfig, observer: FDTCNObserver, core: SubstepCore, system: System,
                 actuated_dofs: tuple[int, ...], loss_observer: nn.Module | None = None) -> None:
        super().__init__(system.n, len(actuated_dofs), system.angle_dims)
        self.config = config
        self.system = system  # the env's physics (metrics, known parts); not a parameter
        self.dt = float(system.dt)
        self.observer = observer
        #: the training loss's velocity estimate when it is not the observer (``train_velocity``; no parameters)
        self.loss_observer = loss_observer
        # a PHASTCore here; LatentODEModel passes its LatentODECore (and annotates core as one)
        self.core = core  # type: ignore[assignment]
        self.actuated_dofs = tuple(actuated_dofs)
        self.register_buffer("G", torch.eye(self.n)[:, list(self.actuated_dofs)])
        #: training leaves out predictions made before the backward difference has all its samples
        self.loss_skip = int(getattr(observer, "fd_order", 1))

    # ---- public pieces (control and mismatch reuse these) --------------------
    @property
    def potential(self) -> Potential:
        return self.core.potential

    @property
    def mass(self) -> Mass:
        return self.core.mass

    @property
    def damping(self) -> Damping | None:
        return self.core.damping

    @property
    def friction(self) -> JointFriction | None:
        """The core's joint friction (None without one); its ``coefficients()`` are the identified laws."""
        return getattr(self.core, "friction", None)

    def port_force(self, u: torch.Tensor | None) -> torch.Tensor | None:
        """G u: (..., m) -> (..., n)."""
        return None if u is None else u.to(self.G.dtype) @ self.G.T

    def canonicalize(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        """(q, qdot_hat) -> p_hat: identity, or M(q) qdot_hat (``canonicalizer="mass"``)."""
        return self.mass.momentum(q, v) if self.config.canonicalizer == "mass" else v

    def hamiltonian(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        return self.core.hamiltonian(q, p)

    def velocity(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """dH/dp = M^-1 p."""
        return self.mass.velocity(q, p)

    def damping_diag(self, q: torch.Tensor) -> torch.Tensor:
        """Diagonal of the learned D(q), (..., n)."""
        if self.damping is None:
            return torch.zeros_like(q)
        return self.damping.diag(q)

    def step(self, q: torch.Tensor, p: torch.Tensor, u: torch.Tensor | None = None
             ) -> tuple[torch.Tensor, torch.Tensor]:
        """One observation step of the core (Strang splitting; RK4 for the predator-prey latent ODE) with port input u
        (..., m)."""
        return self.core(q, p, self.port_force(u))

    def infer_state(self, q_hist: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, T, n) observed history -> the canonical state (q_T-1, p_T-1) at its last sample."""
        v = self.observer(q_hist[:, -self.observer.window:])[:, -1]
        q = q_hist[:, -1]
        return q, self.canonicalize(q, v)

    # ---- least-squares start (init_from="data") ----------------------------------
    @property
    def floor_margin(self) -> float:
        """The learned damping floor starts at this fraction of the smallest damping the data show."""
        return float(self.config.damping_floor_margin)

    @torch.no_grad()
    def initialize_from_data(self, q: torch.Tensor, u: torch.Tensor | None) -> dict[str, float]:
        """Start the learned physics from one least squares on the training set (:mod:`phast_model.world.data_init`):
        PARTIAL's template and mass coefficients, KNOWN's damping floor d0.  Called by
        :func:`phast_model.train.fit.fit` before the first epoch (not on resume); a no-op unless
        ``init_from == "data"``.  Returns what it set."""
        if self.config.init_from != "data" or not isinstance(self.core, PHASTCore):
            return {}
        f = self.port_force(self.pad_u(u, q.shape[1])) if u is not None else None
        kin = data_init.kinematics(q, f, self.dt, tuple(self.angle_dims))
        pot = self.potential
        if isinstance(pot, (TemplatePotential, HybridPotential)) and hasattr(self.mass, "linear_basis"):
            fit = data_init.initialize_partial(self, kin)
            out = {"init_residual": fit.residual}
            if isinstance(self.damping, HouseholderDamping) and self.damping.learn_d0:
                out["init_d0"] = float(self.damping.d0)
            return out
        damp = self.damping
        if isinstance(pot, KnownPotential) and isinstance(damp, HouseholderDamping) and damp.learn_d0:
            floor = data_init.damping_floor(self, kin)
            d0 = max(self.floor_margin * floor, data_init.MIN_D0)
            damp.set_d0(d0)
            return {"init_damping_floor": floor, "init_d0": d0}
        return {}

    # ---- ForecastModel --------------------------------------------------------
    def _prep(self, q: torch.Tensor, u: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        dtype = next(self.parameters()).dtype
        q = q.to(dtype)
        return q, (None if u is None else self.pad_u(u.to(dtype), q.shape[1]))

    def _prep_rollout(self, q_burn: torch.Tensor, u: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Like :meth:`_prep`, but ``u`` keeps its full length: a rollout reads it past the burn-in."""
        q, _ = self._prep(q_burn, None)
        return q, (None if u is None else u.to(q.dtype))

    def forward(self, q: torch.Tensor, u: torch.Tensor | None = None) -> torch.Tensor:
        """Teacher-forced next-step predictions for every t at once: (B, T, n) -> (B, T, n)."""
        return self._teacher_forced(q, u, self.observer)

    def loss_forward(self, q: torch.Tensor, u: torch.Tensor | None = None) -> torch.Tensor:
        """The teacher-forced predictions the training loss compares (Eq. 85): :meth:`forward`'s, each step started
        from the training velocity estimate (:meth:`loss_velocity`) instead of the causal observer's."""
        return self(q, u) if self.loss_observer is None else self._teacher_forced(q, u, self.loss_observer)

    def loss_velocity(self, q: torch.Tensor) -> torch.Tensor:
        """Velocities (B, T, n) the training loss starts from (``train_velocity``)."""
        return (self.observer if self.loss_observer is None else self.loss_observer)(q)

    def _teacher_forced(self, q: torch.Tensor, u: torch.Tensor | None, observer: nn.Module) -> torch.Tensor:
        """One core step from (q_t, M(q_t) observer(q)_t) at every t (Algorithm 1, teacher-forced)."""
        q, u = self._prep(q, u)
        p = self.canonicalize(q, observer(q))
        q1, _ = self.core(q, p, self.port_force(u), need_p=False)
        return wrap_angles(q1, self.angle_dims)

    def predict_next(self, hist: torch.Tensor, u_t: torch.Tensor | None = None) -> torch.Tensor:
        """One autoregressive step: history (B, >=1, n) (only the observer window is used) and u_t (B, m)
        held over [t, t+1] -> q_{t+1} (B, n), angles wrapped."""
        qt, pt = self.infer_state(hist)
        q1, _ = self.core(qt, pt, self.port_force(u_t), need_p=False)
        return wrap_angles(q1, self.angle_dims)

    @torch.no_grad()
    def rollout(self, q_burn: torch.Tensor, u: torch.Tensor | None, H: int) -> torch.Tensor:
        """Autoregressive rollout; the observer is re-run on its finite window only (exactly the
        autoregressive definition, O(H) instead of O(H^2)).  ``u`` covers the burn-in and the horizon
        (zeros beyond it)."""
        return self.differentiable_rollout(q_burn, u, H)

    def differentiable_rollout(self, q_burn: torch.Tensor, u: torch.Tensor | None, H: int) -> torch.Tensor:
        """:meth:`rollout` with the autograd graph kept (the ``roll_mode="observer"`` training loss)."""
        q, u = self._prep_rollout(q_burn, u)
        K, W = q.shape[1], self.observer.window
        hist = q[:, -W:]
        preds = []
        for h in range(H):
            ut = None if u is None else (u[:, K - 1 + h] if K - 1 + h < u.shape[1] else torch.zeros_like(u[:, 0]))
            q1 = self.predict_next(hist, ut)
            preds.append(q1)
            hist = torch.cat([hist, q1.unsqueeze(1)], 1)[:, -W:]
        return torch.stack(preds, 1)

    @torch.no_grad()
    def rollout_takeover(self, q_burn: torch.Tensor, u: torch.Tensor | None, H: int,
                         return_p: bool = False) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Takeover rollout (Eq. 8): infer one state at the end of the burn-in, then integrate the core only."""
        q_burn, u = self._prep_rollout(q_burn, u)
        q, p = self.infer_state(q_burn)
        qs, ps = self.integrate(q, p, u, q_burn.shape[1] - 1, H)
        return (qs, ps) if return_p else qs

    def integrate(self, q: torch.Tensor, p: torch.Tensor, u: torch.Tensor | None, start: int, H: int,
                  **step_kw: float | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """H steps of the core alone from the state (q, p) at sample ``start``, with u[:, start + k] held over step k
        (zeros past the end of u): (B, H, n) wrapped positions and (B, H, n) momenta.  ``step_kw`` go to the core
        (e.g. ``h`` and ``substeps`` of the Strang step)."""
        qs, ps = [], []
        for k in range(H):
            t = start + k
            ut = None if u is None else (u[:, t] if t < u.shape[1] else torch.zeros_like(u[:, 0]))
            q, p = self.core(q, p, self.port_force(ut), **step_kw)
            qs.append(wrap_angles(q, self.angle_dims))
            ps.append(p)
        return torch.stack(qs, 1), torch.stack(ps, 1)

    def param_groups(self, lr: float) -> list[dict[str, Any]]:
        """Optimizer parameter groups (the trainer uses this hook when present): the damping
        parameters get ``damping_lr_mult * lr``."""
        # the multiplier is for the damping *network*; its constant floor d0 keeps the base lr: at lr x 100 the
        # scalar d0 raced the network above min_q D (windy pendulum seed 0: 0.1 -> 0.45 in 10 epochs), the softplus
        # logits of the region where D < d0 were driven to -60..-120 (scale-free Adam, eps 1e-15), their gradient
        # underflowed to exactly 0 and D stayed at d0 there for good (R^2 0.626)
        floor = {id(getattr(self.damping, "raw_d0", None))} - {id(None)} if self.damping is not None else set()
        damp = {id(p) for p in self.damping.parameters()} - floor if self.damping is not None else set()
        rest = [p for p in self.parameters() if p.requires_grad and id(p) not in damp]
        groups = [{"params": rest, "lr": lr}] if rest else []
        dp = [p for p in self.parameters() if p.requires_grad and id(p) in damp]
        if dp:
            groups.append({"params": dp, "lr": lr * self.config.damping_lr_mult})
        return groups

    # ---- optional losses (paper Eq. 86-88) --------------------------------------
    def extra_losses(self, q: torch.Tensor, u: torch.Tensor | None, pred: torch.Tensor) -> dict[str, torch.Tensor]:
        """Weighted L_pass, L_energy, L_roll on the model's inferred states (weights from the config; 0 by default)."""
        cfg = self.config
        out: dict[str, torch.Tensor] = {}
        if cfg.lambda_pass <= 0 and cfg.lambda_energy <= 0 and cfg.lambda_roll <= 0:
            return out
        q, u = self._prep(q, u)
        needs_p = cfg.lambda_pass > 0 or cfg.lambda_energy > 0 or cfg.roll_mode == "core"
        p = self.canonicalize(q, self.loss_velocity(q)) if needs_p else None  # observer-mode L_roll: its own
        f = self.port_force(u)
        if cfg.lambda_pass > 0 or cfg.lambda_energy > 0:
            assert p is not None  # needs_p
            q1, p1 = self.core(q[:, :-1], p[:, :-1], None if f is None else f[:, :-1])
            H0, H1 = self.hamiltonian(q[:, :-1], p[:, :-1]), self.hamiltonian(q1, p1)
            if cfg.lambda_pass > 0:  # Eq. 86 (u = 0 benchmarks; with u the port power is not subtracted)
                out["pass"] = cfg.lambda_pass * torch.relu(H1 - H0).mean()
            if cfg.lambda_energy > 0:  # Eq. 87
                dt = self.core.h * self.core.substeps
                out["energy"] = cfg.lambda_energy * ((H1 - H0) / dt
                                                     - self.core.power(q[:, :-1], p[:, :-1])).abs().mean()
        if cfg.lambda_roll > 0:
            out["roll"] = cfg.lambda_roll * self._roll_loss(q, u, p, f)
        return out

    def _roll_loss(self, q: torch.Tensor, u: torch.Tensor | None, p: torch.Tensor | None,
                   f: torch.Tensor | None) -> torch.Tensor:
        """Mean squared open-loop error over ``roll_horizon`` steps from one random start (the same for the batch):
        the core alone (Eq. 88) or, with ``roll_mode="observer"``, the autoregressive rollout of :meth:`rollout`
        (with its autograd graph)."""
        cfg = self.config
        if cfg.roll_mode not in ("core", "observer"):
            raise ValueError(f"roll_mode must be 'core' or 'observer', got {cfg.roll_mode!r}")
        first = self.loss_skip if cfg.roll_mode == "core" else max(self.loss_skip, self.observer.window - 1)
        Hr = min(cfg.roll_horizon, q.shape[1] - 1 - first)
        t0 = int(torch.randint(first, q.shape[1] - Hr, ()).item())  # observer warm-up excluded
        target = q[:, t0 + 1:t0 + 1 + Hr]
        if cfg.roll_mode == "observer":
            start = t0 + 1 - self.observer.window
            pred = self.differentiable_rollout(q[:, start:t0 + 1], None if u is None else u[:, start:], Hr)
            return (coordinate_error(pred, target, self.angle_dims) ** 2).mean()
        assert p is not None  # roll_mode "core": extra_losses inferred p
        qq, pp = q[:, t0], p[:, t0]
        errs = []
        for h in range(Hr):
            qq, pp = self.core(qq, pp, None if f is None else f[:, t0 + h])
            errs.append((coordinate_error(qq, target[:, h], self.angle_dims) ** 2).mean())
        return torch.stack(errs).mean()


# ------------------------------------------------------------------------------ predator-prey
def _zero_last(net: nn.Sequential) -> nn.Sequential:
    """``net`` with its last layer zeroed: it starts as the constant 0 (a correction that starts as none)."""
    last = net[-1]
    assert isinstance(last, nn.Linear)
    nn.init.zeros_(last.weight)
    nn.init.zeros_(last.bias)
    return net


class SystemField(nn.Module):
    """Known vector field: the env's ``rhs``; latent p from the observed qdot by inverting the
    q-equation, which is affine in p (two ``rhs`` evaluations, no retyped formula)."""

    def __init__(self, system: System) -> None:
        super().__init__()
        self.system = system

    def rhs(self, q: torch.Tensor, p: torch.Tensor, f: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        dq, dp = self.system.rhs(split(q), split(p), None if f is None else split(f), TORCH)
        return stack(dq) + 0.0 * q, stack(dp) + 0.0 * p

    def latent(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        a = self.rhs(q, torch.zeros_like(q), None)[0]
        b = self.rhs(q, torch.ones_like(q), None)[0] - a
        p = (v - a) / torch.where(b.abs() > 1e-6, b, torch.full_like(b, -1e-6))
        # the env's own state projection (populations >= 0): as the prey density collapses the inversion divides by
        # it, and an unphysical negative latent made autoregressive rollouts grow without bound
        _, ps = self.system.post_step(list(split(q)), list(split(p)), TORCH)
        return stack(ps) + 0.0 * p


class LVTemplateField(nn.Module):
    """Lotka-Volterra template ``qdot = q (c1 + c2 q + c3 p)``, ``pdot = p (c4 q + c5) + G u`` with learnable c,
    plus ``softplus(rho) * MLP`` on pdot.

    ``init_from``: "data" (the default) starts from a neutral c that :meth:`LatentODEModel.initialize_from_data`
    replaces by a least squares on the observed prey (:func:`phast_model.world.data_init.lotka_volterra_start`);
    "physics" fits c to the env's ``rhs`` (the "template given" variant); "none" keeps the neutral c."""

    #: neutral start: no growth, no interaction, predation of unit strength (so the latent map is defined)
    NEUTRAL = (0.0, 0.0, -1.0, 0.0, 0.0)

    def __init__(self, system: System, q_scale: float, eps_init: float = 0.01, init_from: str = "data") -> None:
        super().__init__()
        if init_from == "physics":
            rng = np.random.default_rng(0)
            x = system.sample_initial(rng, 512)
            q, p = x[:, :1], x[:, 1:]
            dq, dp = (np.asarray(a[0]) for a in system.rhs(split(q), split(p), None, NUMPY))
            A1 = np.concatenate([q, q * q, q * p], 1)
            c1 = np.linalg.lstsq(A1, dq, rcond=None)[0]
            A2 = np.concatenate([p * q, p], 1)
            c2 = np.linalg.lstsq(A2, dp, rcond=None)[0]
            coef = np.concatenate([c1.ravel(), c2.ravel()])
        else:
            coef = np.array(self.NEUTRAL)
            coef[2] = coef[2] / float(q_scale)
        self.coef = nn.Parameter(torch.tensor(coef, dtype=torch.float32))
        self.scale = float(q_scale)
        self.rho = nn.Parameter(torch.tensor(math.log(math.expm1(eps_init))))
        self.net = nn.Sequential(nn.Linear(2, 32), nn.SiLU(), nn.Linear(32, 1))

    def rhs(self, q: torch.Tensor, p: torch.Tensor, f: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        c = self.coef
        dq = q * (c[0] + c[1] * q + c[2] * p)
        corr = nn.functional.softplus(self.rho) * self.scale * self.net(torch.cat([q, p], -1) / self.scale)
        dp = p * (c[3] * q + c[4]) + corr
        return dq, dp if f is None else dp + f

    def latent(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        c = self.coef
        return (v / q.clamp_min(1e-3) - c[0] - c[1] * q) / c[2]


class NeuralField(nn.Module):
    """Neural vector field on (q, p) with a learned latent map (q, qdot_hat) -> p."""

    def __init__(self, n: int, q_scale: float, v_scale: float, hidden: int = 64) -> None:
        super().__init__()
        self.qs, self.vs = float(q_scale), float(v_scale)
        self.f = nn.Sequential(nn.Linear(2 * n, hidden), nn.SiLU(), nn.Linear(hidden, hidden), nn.SiLU(),
                               nn.Linear(hidden, 2 * n))
        self.g = nn.Sequential(nn.Linear(2 * n, hidden), nn.SiLU(), nn.Linear(hidden, n))
        self.n = n

    def rhs(self, q: torch.Tensor, p: torch.Tensor, f: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        out = self.f(torch.cat([q, p], -1) / self.qs) * self.vs
        dq, dp = out[..., : self.n], out[..., self.n:]
        return dq, dp if f is None else dp + f

    def latent(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        return self.g(torch.cat([q / self.qs, v / self.vs], -1)) * self.qs


#: the vector fields a :class:`LatentODECore` integrates (each with ``rhs`` and the latent map ``latent``)
LatentField = SystemField | LVTemplateField | NeuralField


class LatentODECore(SubstepCore):
    """RK4 on a (q, p) vector field with L substeps and a learnable log dt (predator-prey is not Hamiltonian,
    so no symplectic/dissipative split applies)."""

    def __init__(self, field_: LatentField, dt: float, substeps: int = 1, learn_dt: bool = True) -> None:
        super().__init__()
        self.field = field_
        self.init_substeps(dt, substeps, learn_dt)

    def rk4_step(self, q: torch.Tensor, p: torch.Tensor, f: torch.Tensor | None = None,
                 need_p: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
        """One observation step: L classical RK4 substeps with the port force f held."""
        h = self.h
        F = self.field.rhs
        for _ in range(self.substeps):
            k1 = F(q, p, f)
            k2 = F(q + 0.5 * h * k1[0], p + 0.5 * h * k1[1], f)
            k3 = F(q + 0.5 * h * k2[0], p + 0.5 * h * k2[1], f)
            k4 = F(q + h * k3[0], p + h * k3[1], f)
            q = q + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            p = p + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        return q, p

    forward = rk4_step


class LatentODEModel(PHAST):
    """Predator-prey: observer -> latent predator density p (inverting the prey equation) -> RK4 core.

    KNOWN uses the env's rhs, PARTIAL a Lotka-Volterra template with learnable coefficients plus a small
    neural correction, UNKNOWN a neural field with a learned latent map. ``hamiltonian`` returns the env's
    Lotka-Volterra invariant (a Lyapunov-like energy), ``damping_diag`` is zero (no dissipation structure)."""

    core: LatentODECore  # type: ignore[assignment]  # the predator-prey core replaces PHAST's PHASTCore

    #: learning-rate multiplier of the latent prior (one scalar per latent, trained on the t = 0 step only)
    prior_lr_mult = 100.0

    def init_prior(self, q_typical: torch.Tensor, scale: float) -> None:
        """Start-up latents, used where the history is shorter than the observer's backward difference.

        t = 0 has no velocity information.  Unlike the mechanical envs, whose initial momenta have zero mean,
        populations have a nonzero mean latent state, so the first prediction is learnable: ``p_prior = scale *
        raw``, initialized at the latent of qdot = 0.  ``latent_prior = "learned"`` adds a network of q_0 to it
        (the best first prediction is E[q_1 | q_0], and a learned field need not reach it from one constant latent)
        and, for each start-up step t = 1 .. loss_skip - 1, a correction of the latent map's output from (q_t,
        qdot_hat_t), whose backward difference has order t only.  All of them train on the start-up steps with
        the dynamics detached (:meth:`extra_losses`), so they cannot bias the field."""
        with torch.no_grad():
            p0 = self.canonicalize(q_typical, torch.zeros_like(q_typical)).mean(0)
        self.prior_scale = float(scale)
        self.prior_raw = nn.Parameter((p0 / self.prior_scale).float())
        if self.config.latent_prior == "learned":
            n, n_lat = q_typical.shape[-1], p0.shape[-1]
            self.prior_net = _zero_last(nn.Sequential(nn.Linear(n, 32), nn.SiLU(), nn.Linear(32, n_lat)))
            self.startup_nets = nn.ModuleList(
                _zero_last(nn.Sequential(nn.Linear(2 * n, 32), nn.SiLU(), nn.Linear(32, n_lat)))
                for _ in range(1, self.loss_skip))
        elif self.config.latent_prior != "constant":
            raise ValueError(f"latent_prior must be constant or learned, got {self.config.latent_prior!r}")

    def prior_latent(self, q0: torch.Tensor) -> torch.Tensor:
        """The latent used where the history holds q_0 only: (B, n) -> (B, n_latent)."""
        raw = self.prior_raw.to(q0.dtype).expand(*q0.shape[:-1], -1)
        if hasattr(self, "prior_net"):
            raw = raw + self.prior_net(q0 / self.prior_scale)
        return self.prior_scale * raw

    def startup_latents(self, q: torch.Tensor, v: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        """Latents of the first k = q.shape[1] <= loss_skip steps (B, k, .): the prior at t = 0, then the latent
        map's ``p`` plus the learned start-up corrections (``latent_prior = "learned"``)."""
        rows = [self.prior_latent(q[:, 0])]
        nets = getattr(self, "startup_nets", None)
        for t in range(1, q.shape[1]):
            pt = p[:, t]
            if nets is not None:
                x = torch.cat([q[:, t] / self.prior_scale, v[:, t] / self.observer.v_scale.to(v.dtype)], -1)
                pt = pt + self.prior_scale * nets[t - 1](x)
            rows.append(pt)
        return torch.stack(rows, 1)

    @torch.no_grad()
    def initialize_from_data(self, q: torch.Tensor, u: torch.Tensor | None) -> dict[str, float]:
        """PARTIAL: the Lotka-Volterra coefficients from one least squares on the observed prey
        (:func:`phast_model.world.data_init.lotka_volterra_start`), then the latent prior from the training data's
        first samples.  A no-op for KNOWN / UNKNOWN or unless ``init_from == "data"``."""
        fld = self.core.field
        if self.config.init_from != "data" or not isinstance(fld, LVTemplateField):
            return {}
        f = self.port_force(self.pad_u(u, q.shape[1])) if u is not None else None
        coef, resid = data_init.lotka_volterra_start(data_init.kinematics(q, f, self.dt, ()))
        fld.coef.copy_(coef.to(fld.coef.dtype))
        if hasattr(self, "prior_raw"):
            q0 = q[:, 0].to(fld.coef.dtype)
            self.prior_raw.copy_(self.canonicalize(q0, torch.zeros_like(q0)).mean(0) / self.prior_scale)
        return {**{f"lv_c{i + 1}": float(c) for i, c in enumerate(coef)}, "lv_residual": resid}

    def canonicalize(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        return self.core.field.latent(q, v)

    def infer_state(self, q_hist: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(q, p) at the last sample; at a start-up step (t = len - 1 < ``loss_skip``) the start-up latent, as in
        :meth:`forward` (so ``predict_next`` on t + 1 samples is forward's prediction at t)."""
        if not hasattr(self, "prior_raw") or q_hist.shape[1] > self.loss_skip:
            return super().infer_state(q_hist)
        v = self.observer(q_hist)
        return q_hist[:, -1], self.startup_latents(q_hist, v, self.canonicalize(q_hist, v))[:, -1]

    def forward(self, q: torch.Tensor, u: torch.Tensor | None = None) -> torch.Tensor:
        """Teacher-forced next-step predictions; the first sample of the sequence uses the learned latent prior."""
        q, u = self._prep(q, u)
        v = self.observer(q)
        p = self.canonicalize(q, v)
        if hasattr(self, "prior_raw"):
            k = min(self.loss_skip, q.shape[1])
            p = torch.cat([self.startup_latents(q[:, :k], v[:, :k], p[:, :k]), p[:, k:]], 1)
        q1, _ = self.core(q, p, self.port_force(u), need_p=False)
        return q1

    def param_groups(self, lr: float) -> list[dict[str, Any]]:
        prior = [self.prior_raw] if hasattr(self, "prior_raw") else []  # the prior net trains at the base lr
        rest = [p for p in self.parameters() if p.requires_grad and all(p is not x for x in prior)]
        return [g for g in ({"params": rest, "lr": lr}, {"params": prior, "lr": lr * self.prior_lr_mult})
                if g["params"]]

    @property
    def potential(self):  # noqa: ANN201
        return None

    @property
    def mass(self):  # noqa: ANN201
        return None

    @property
    def damping(self):  # noqa: ANN201
        return None

    def hamiltonian(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        return self.system.energy(split(q), split(p), TORCH)

    def velocity(self, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
        return self.core.field.rhs(q, p, None)[0]

    def extra_losses(self, q: torch.Tensor, u: torch.Tensor | None, pred: torch.Tensor) -> dict[str, torch.Tensor]:
        """The t = 0 step (left out of L_data, see ``loss_skip``) trains the latent prior only: the core runs with
        detached parameters, so the irreducible first-step error (the unseen initial latent) cannot bias the field."""
        if not hasattr(self, "prior_raw") or q.shape[1] < 2:
            return {}
        q, u = self._prep(q, u)
        f = self.port_force(u)
        params = {k: v.detach() for k, v in self.core.named_parameters()}
        k = 1 if self.config.latent_prior == "constant" else min(self.loss_skip, q.shape[1] - 1)
        with torch.no_grad():  # the latent map belongs to the dynamics: detached like them
            v = self.observer(q[:, :k])
            p = self.canonicalize(q[:, :k], v)
        p = self.startup_latents(q[:, :k], v, p)
        q1, _ = torch.func.functional_call(self.core, params, (q[:, :k], p, None if f is None else f[:, :k]),
                                           {"need_p": False})
        return {"prior": ((q1 - q[:, 1:k + 1]) ** 2).mean()}


# ------------------------------------------------------------------------------ builder
@dataclass
class _EnvScales:
    """What the components are sized and scaled by: the env's system, its angle coordinates and the RMS scales of
    :func:`system_scales`."""

    env_id: str
    system: System
    n: int
    angle: tuple[int, ...]
    q_scale: np.ndarray
    v_scale: np.ndarray
    #: parts the components of one model share (a model file's learned body parameters, for V and M alike)
    shared: dict[str, LearnedBodies] = field(default_factory=dict)


def _env_scales(env_id: str, system: System, cfg: PHASTConfig | None = None) -> _EnvScales:
    """The :class:`_EnvScales` of ``system`` (numpy RNG only: leaves the torch RNG alone); the config's own scales
    (recordings) replace the ones of the system's initial-state distribution."""
    if cfg is not None and cfg.v_scale is not None:
        q_scale = np.asarray(cfg.q_scale or [], dtype=np.float32)
        v_scale = np.asarray(cfg.v_scale, dtype=np.float32)
    else:
        q_scale, v_scale = system_scales(system)
    return _EnvScales(env_id, system, system.n, tuple(system.angle_dims), q_scale, v_scale)


def _observer(cfg: PHASTConfig, env: _EnvScales) -> FDTCNObserver:
    """The finite-difference / TCN observer that estimates velocities from q."""
    return FDTCNObserver(env.n, env.system.dt, env.angle, hidden=cfg.observer_hidden, layers=cfg.observer_layers,
                         q_scale=torch.as_tensor(env.q_scale), v_scale=torch.as_tensor(env.v_scale),
                         use_tcn=cfg.use_tcn, fd_order=cfg.observer_fd_order)


def _loss_observer(cfg: PHASTConfig, env: _EnvScales) -> nn.Module | None:
    """The training velocity estimate of ``cfg.train_velocity`` (:data:`TRAIN_VELOCITIES`); a non-causal one needs
    a frozen observer (the loss would not train it) and a PHAST model (not the latent ODE)."""
    est = training_velocity(cfg.train_velocity, env.n, env.system.dt, env.angle, cfg.train_velocity_order)
    if est is not None and (cfg.observer_trainable or cfg.kind != "phast"):
        raise ValueError(f"train_velocity={cfg.train_velocity!r} needs observer_trainable=False and kind='phast' "
                         "(the training loss would not use the observer)")
    return est


def _latent_ode_model(cfg: PHASTConfig, env: _EnvScales, observer: FDTCNObserver,
                      actuated: tuple[int, ...]) -> LatentODEModel:
    """The latent-ODE model (non-Hamiltonian envs): ``cfg.ode_field`` as vector field, prior fitted to typical q."""
    qs, vs = float(np.mean(env.q_scale)) if len(env.q_scale) else 1.0, float(np.mean(env.v_scale))
    fld: LatentField
    if cfg.ode_field == "known":
        fld = SystemField(env.system)
    elif cfg.ode_field == "template":
        fld = LVTemplateField(env.system, qs, cfg.hybrid_eps, cfg.init_from)
    elif cfg.ode_field == "neural":
        fld = NeuralField(env.n, qs, vs)
    else:
        raise ValueError(f"field must be known, template or neural, got {cfg.ode_field!r}")
    core = LatentODECore(fld, env.system.dt, cfg.substeps, cfg.learn_dt)
    model = LatentODEModel(cfg, observer, core, env.system, actuated)
    q_typ = torch.as_tensor(env.system.sample_initial(np.random.default_rng(0), 256)[:, :env.n], dtype=torch.float32)
    model.init_prior(q_typ, qs)
    return model


def _check_phast_config(cfg: PHASTConfig, env: _EnvScales) -> None:
    """ValueError for a PHAST config that cannot be built: unknown ``init_from`` or ``kind``, or an env that is not
    port-Hamiltonian."""
    if cfg.init_from not in ("data", "physics", "none", "rig", "motion", "drives"):
        raise ValueError(f"init_from must be data, physics, rig, motion, drives or none, got {cfg.init_from!r}")
    if cfg.kind != "phast":
        raise ValueError(f"kind must be 'phast' or 'latent_ode', got {cfg.kind!r}")
    if not env.system.hamiltonian_system:
        raise ValueError(f"{env.env_id} is not port-Hamiltonian; use kind='latent_ode'")


def _template_potential(cfg: PHASTConfig, env: _EnvScales) -> TemplatePotential:
    """The named template potential, fitted to the env's true V when ``init_from='physics'``."""
    if cfg.template is None:
        raise ValueError(f"potential={cfg.potential!r} needs a template name")
    t = make_template(cfg.template, env.n, tuple(cfg.template_dims) if cfg.template_dims is not None else None)
    if cfg.init_from == "physics":
        t.fit_to(env.system)
    return t


def _neural_potential(cfg: PHASTConfig, env: _EnvScales) -> NeuralPotential:
    """An MLP potential, its output scaled to the typical kinetic energy scale mean(v_scale^2)."""
    e_scale = float(np.mean(env.v_scale**2))
    return NeuralPotential(env.n, env.angle, cfg.potential_hidden, cfg.potential_layers,
                           q_scale=torch.as_tensor(env.q_scale), out_scale=e_scale)


def _hybrid_potential(cfg: PHASTConfig, env: _EnvScales) -> HybridPotential:
    """Template + eps * neural (Eq. 84)."""
    neural = _neural_potential(cfg, env)  # before the template: the creation order fixes the initial weights
    return HybridPotential(_template_potential(cfg, env), neural, cfg.hybrid_eps)


_C = TypeVar("_C")
#: a component builder: (config, env scales) -> the component (or None: no such component)
Builder = Callable[[PHASTConfig, _EnvScales], _C]


class Components(NamedTuple):
    """The physics a :class:`PHASTCore` is composed of, built by the registries below from a :class:`PHASTConfig`
    (:func:`build_components`)."""

    potential: Potential
    mass: Mass
    damping: Damping | None
    friction: JointFriction | None


def _learned_bodies(env: _EnvScales) -> LearnedBodies:
    """The one set of learned body parameters V and M of a model-file rig share (built once per env)."""
    if "bodies" not in env.shared:
        env.shared["bodies"] = LearnedBodies(env.system)
    return env.shared["bodies"]


#: ``PHASTConfig.potential`` -> builder
POTENTIALS: dict[str, Builder[Potential]] = {
    "known": lambda cfg, env: KnownPotential(env.system), "template": _template_potential,
    "neural": _neural_potential, "hybrid": _hybrid_potential,
    "rigid_body": lambda cfg, env: RigidBodyPotential(_learned_bodies(env))}


def _component(kind: str, registry: dict[str, Builder[_C]], name: str, cfg: PHASTConfig, env: _EnvScales) -> _C:
    """Build the ``kind`` component registered as ``name``; an unknown name is a ValueError listing the choices."""
    if name not in registry:
        raise ValueError(f"{kind} must be {_choices(list(registry))}, got {name!r}")
    return registry[name](cfg, env)


def _choices(names: list[str]) -> str:
    return ", ".join(names[:-1]) + " or " + names[-1]


def _potential(cfg: PHASTConfig, env: _EnvScales) -> Potential:
    """V(q) of ``cfg.potential``: known, template, neural or hybrid (template + eps * neural)."""
    return _component("potential", POTENTIALS, cfg.potential, cfg, env)


def _lowrank_mass(cfg: PHASTConfig, env: _EnvScales) -> LowRankMass:
    """A low-rank + diagonal mass; with ``init_from='physics'`` and the mass canonicalizer its diagonal starts at
    the mean diagonal of the env's M(q)."""
    mass = LowRankMass(env.n, cfg.mass_rank, diag_init=1.0, seed=cfg.seed)
    if cfg.init_from == "physics" and cfg.canonicalizer == "mass":
        x = env.system.sample_initial(np.random.default_rng(0), 256)[:, :env.n]
        rows = env.system.mass_matrix(split(x), NUMPY)
        mass.set_linear(torch.tensor([float(np.mean(rows[i][i])) for i in range(env.n)]))
    return mass


def _template_mass(cfg: PHASTConfig, env: _EnvScales) -> TemplateMass:
    """The named mass template, checked against the env's coordinate count."""
    if cfg.mass_template is None:
        raise ValueError("mass='template' needs mass_template (cartpole, double_pendulum, double_pendulum_relative)")
    mass = TemplateMass(cfg.mass_template)
    if env.n != mass.n:
        raise ValueError(f"mass template {cfg.mass_template!r} has {mass.n} coordinates, {env.env_id} has {env.n}")
    return mass


#: ``PHASTConfig.mass`` -> builder
MASSES: dict[str, Builder[Mass]] = {
    "known": lambda cfg, env: KnownMass(env.system), "lowrank": _lowrank_mass, "template": _template_mass,
    "rigid_body": lambda cfg, env: RigidBodyMass(_learned_bodies(env)),
    "cholesky": lambda cfg, env: CholeskyMass(env.n, env.angle, cfg.mass_hidden, q_scale=torch.as_tensor(env.q_scale))}


def _mass(cfg: PHASTConfig, env: _EnvScales) -> Mass:
    """M(q) of ``cfg.mass``: known, lowrank, template or cholesky."""
    return _component("mass", MASSES, cfg.mass, cfg, env)


#: ``PHASTConfig.damping`` -> builder (``none``: no dissipation)
DAMPINGS: dict[str, Builder[Damping | None]] = {
    "householder": lambda cfg, env: HouseholderDamping(
        env.n, env.angle, cfg.damping_rank, hidden=cfg.damping_hidden, cap=cfg.damping_cap, d0=cfg.d0,
        learn_d0=cfg.learn_d0, q_scale=torch.as_tensor(env.q_scale)),
    "known": lambda cfg, env: KnownDamping(env.system), "none": lambda cfg, env: None}


def _damping(cfg: PHASTConfig, env: _EnvScales) -> Damping | None:
    """D(q) of ``cfg.damping``: householder (learned), known or none."""
    return _component("damping", DAMPINGS, cfg.damping, cfg, env)


#: ``PHASTConfig.friction`` -> builder (``none``: no velocity-dependent friction)
FRICTIONS: dict[str, Builder[JointFriction | None]] = {
    "joint": lambda cfg, env: JointFriction(
        env.n, cfg.friction_joints, tuple(cfg.friction_laws), cfg.friction_eps, cfg.friction_vs, cfg.friction_init,
        newton_iters=cfg.friction_newton_iters),
    "none": lambda cfg, env: None}


def _friction(cfg: PHASTConfig, env: _EnvScales) -> JointFriction | None:
    """The joint friction f(v) of ``cfg.friction``: joint or none."""
    return _component("friction", FRICTIONS, cfg.friction, cfg, env)


def build_components(cfg: PHASTConfig, env: _EnvScales) -> Components:
    """Potential, mass, damping and friction of ``cfg``, created in this order (it fixes their initial weights)."""
    pot = _potential(cfg, env)
    mass = _mass(cfg, env)
    damp = _damping(cfg, env)
    return Components(pot, mass, damp, _friction(cfg, env))


def _phast_core(cfg: PHASTConfig, env: _EnvScales) -> PHASTCore:
    """The Strang-splitting core on the :class:`Components` of ``cfg``."""
    c = build_components(cfg, env)
    return PHASTCore(c.potential, c.mass, c.damping, env.system.dt, cfg.substeps, cfg.learn_dt, cfg.integrator,
                     cfg.midpoint_iters, friction=c.friction)


def build_from_config(cfg: PHASTConfig, system: System | None = None) -> PHAST:
    """Compose a PHAST (or predator-prey latent ODE) model from its configuration; ``system``: the config's env
    system when the caller has already built it (:func:`config_system`; the model then owns it).

    Every module draws its initial weights from the torch RNG seeded here, so the creation order (observer, then
    potential, mass, damping; or the latent-ODE field) is part of the model's definition."""
    env_id, system = config_system(cfg, system)
    actuated = tuple(cfg.actuated_dofs) if cfg.actuated_dofs is not None else tuple(range(system.n))
    torch.manual_seed(cfg.seed)
    env = _env_scales(env_id, system, cfg)
    observer = _observer(cfg, env)
    loss_observer = _loss_observer(cfg, env)  # no parameters: draws nothing
    if cfg.kind == "latent_ode":
        return _latent_ode_model(cfg, env, observer, actuated)
    _check_phast_config(cfg, env)
    core = _phast_core(cfg, env)
    if not cfg.observer_trainable:
        observer.requires_grad_(False)
    return PHAST(cfg, observer, core, system, actuated, loss_observer)


__all__ = ["PHAST", "PHASTConfig", "LatentODEModel", "build_from_config", "config_system", "system_scales",
           "n_features", "coordinate_features"]
