"""A PHAST world model of the user's rig, learned from real recordings (docs/rig_world_model.md).

The recordings are the ``phast-mismatch`` format, read by the same loader (:mod:`phast_model.identify.recordings`):
q (N, T, n), recorded times ``t`` (jitter allowed) or ``dt``, the measured port input u, ``angle_dims``,
``angle_offset``.  The rig (an env id or a user's ``path.py:Class``) gives the template: V and M forms and the port.

* :func:`load_rig_data`: validate, split off the held-out trajectories, put both parts on one uniform grid (the
  PHAST core steps at a fixed dt; q by cubic spline, u held per interval).
* :func:`rig_config`: KNOWN (the rig's V and M), PARTIAL (the rig's templates, coefficients fitted from the data),
  UNKNOWN (neural V and M); dissipation learned in every regime as a passive per-joint friction
  ``f_i(qdot_i)`` (:class:`phast_model.components.friction.JointFriction`).
* :func:`fit_recordings`: multiple shooting.  A real encoder is quantized (the DFKI arm: 3.8e-4 rad at 2 ms), so
  a finite-difference velocity is too noisy to start a one-step prediction from; each training window instead
  gets its own initial state, refitted by Gauss-Newton with the model fixed, and the model is trained by AdamW
  on the open-loop error over the windows: the objective :class:`Shooting` of the one epoch loop both trainers
  share (:func:`phast_model.train.loop.train_loop`: the NaN guard, a checkpoint after every epoch and ``resume``,
  the best validation weights, early stopping on the validation windows, ``RigTrainConfig.patience``).
* :func:`phast_model.train.rig_heldout.heldout_rollouts`: the held-out score, computed by the same code for every
  model (PHAST, the nominal rig as a KNOWN model without dissipation): each window's state is fitted to its
  burn-in, then the model runs open loop with the recorded u; RMSE of q, wrapped on angles.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from phast_gym.systems.base import System
from phast_gym.systems.mjcf import MJCFSystem

from ..components.mass import KnownMass, LinearMass, LowRankMass
from ..components.potentials import TemplatePotential
from ..identify.recordings import Recordings, load_raw, validate
from ..identify.shooting import odd, smooth, substeps_for
from ..identify.simulators import load_simulator
from ..identify.split import check_holdout_indices, split
from ..train.groups import param_groups
from ..train.loop import CHECKPOINT, LoopConfig, NanCounts, Optim, train_loop
from ..world.interfaces import coordinate_error
from ..world.model import PHAST, PHASTConfig, build_from_config

REGIMES = ("known", "partial", "unknown")
#: burn-in before each held-out window [s] (the state is fitted to it)
BURN_IN_S = 0.1
#: starting friction force, as a fraction of the rig's typical force (RMS of dV/dq and of u over the recordings)
FRICTION_INIT = 0.01
#: Coulomb smoothing velocity of the learned friction, as a fraction of the coordinate's RMS speed in the data
FRICTION_EPS = 0.05
#: Savitzky-Golay window for the starting states [s]
SMOOTH_S = 0.03
#: Gauss-Newton iterations of a compared system's state fit to each window's burn-in
STATE_FIT_ITERS = 15
#: the ``format`` entry of a recordings run's checkpoint.pt
CHECKPOINT_FORMAT = "phast-rig-checkpoint"
#: the learning rates' factor after UNKNOWN's start from the recorded motion (:func:`lr_mult`).  At the base rates
#: the first epoch undid the real pendulum's start (2-s window RMSE 0.007 -> 0.44 rad); with only the networks
#: slowed (x 0.05), the mass and friction still moved fast enough to break the free swing's V / M ratio (0.137 rad)
LR_AFTER_START = 0.01
#: learning-rate schedules of :class:`RigTrainConfig`
SCHEDULES = ("plateau", "cosine")


# --------------------------------------------------------------------------- data
@dataclass(frozen=True)
class RigData:
    """Training and held-out recordings on one uniform grid of step ``dt``."""

    train: Recordings
    heldout: Recordings | None
    holdout: tuple[int, ...]
    source: str
    u_bound: tuple[float, ...]  # largest |u| recorded per coordinate (the world env's action bound)

    @property
    def dt(self) -> float:
        return float(self.train.dt)

    @property
    def driven(self) -> bool:
        return self.train.u is not None


def load_rig_data(recordings: str | Path | Mapping[str, object], sim: str,
                  sim_kwargs: Mapping[str, object] | None = None, holdout: list[int] | None = None,
                  decimate: int = 1) -> RigData:
    """Read and check the recordings against the rig ``sim`` (shapes, u width, angles), hold out ``holdout``
    (trajectory indices; log indices for a log set) and resample both parts onto the uniform grid of their median step
    (the model's joint names and ranges checked too); ``decimate`` keeps every
    k-th sample of free-motion recordings (a 1 kHz encoder on a 1 Hz pendulum: the model then steps at k dt)."""
    system = load_simulator(sim, sim_kwargs or {}).build()
    holdout = check_holdout_indices(holdout)
    raw, src = load_raw(recordings)
    rec = validate(raw, system.n, tuple(system.angle_dims), src, actuated_dofs=getattr(system, "actuated_dofs", None),
                   model=system)
    if holdout:
        train, held, _ = split(rec, 0.0, holdout)
    else:
        train, held = rec, None
    train = train.resampled().decimate(decimate)
    held = None if held is None else held.resampled().decimate(decimate)
    u_all = rec.u if rec.u is not None else np.zeros((1, 1, system.n))
    bound = tuple(float(b) for b in np.max(np.abs(u_all), axis=(0, 1)))
    return RigData(train, held, tuple(holdout or ()), src, bound)


def check_window_room(rec: Recordings, samples: int, what: str) -> None:
    if rec.T < samples:
        raise ValueError(f"{rec.source}: recordings of T={rec.T} samples at dt={rec.dt:.4g} s are too short for {what} "
                         f"({samples} samples)")


# --------------------------------------------------------------------------- regimes
def _template(system: System) -> tuple[str, list[int] | None, str | None]:
    """(potential template, its dims, mass template) of a rig: the class's ``PHAST_TEMPLATES`` when it declares
    them, else the suite's defaults for its kind (a pendulum, a relative or absolute double pendulum)."""
    declared = getattr(system, "PHAST_TEMPLATES", None)
    if declared is not None:
        return declared["potential"], declared.get("dims"), declared.get("mass")
    name = getattr(system, "name", "")
    if "double_pendulum" in name and system.params.get("coordinates") == "relative":
        return "chain_cosine", [0, 1], "double_pendulum_relative"
    if "double_pendulum" in name:
        return "cosine", [0, 1], "double_pendulum"
    if "pendulum" in name and system.n == 1:
        return "cosine", [0], None
    raise ValueError(f"the rig {type(system).__name__} declares no PARTIAL templates: set a class attribute "
                     "PHAST_TEMPLATES = {'potential': 'cosine' | 'chain_cosine' | 'quadratic', 'dims': [...], "
                     "'mass': None | 'double_pendulum_relative' | ...}, or use --regime known / unknown")


def data_scales(rec: Recordings) -> tuple[list[float], list[float]]:
    """RMS of the Euclidean coordinates and of the (smoothed) velocities of the recordings."""
    _, v = smooth(rec.q, rec.dt, odd_samples(SMOOTH_S, rec.dt))
    eu = [i for i in range(rec.n) if i not in rec.angle_dims]
    q_scale = [float(np.sqrt(np.mean(rec.q[..., i] ** 2)) + 1e-3) for i in eu]
    return q_scale, [float(np.sqrt(np.mean(v[..., i] ** 2)) + 1e-3) for i in range(rec.n)]


def friction_start(system: System, rec: Recordings, v_scale: list[float]) -> dict[str, float]:
    """Starting coefficient of each friction law: a force of FRICTION_INIT x the rig's typical force F (the larger of
    the RMS of dV/dq under the rig and of u, averaged over the coordinates) at the typical speed V: Coulomb and
    Stribeck F, viscous F / V, quadratic F / V^2.  A real pendulum's friction is ~1e-4 N m, an arm joint's ~0.1 N m:
    one fixed start is far off on one of them."""
    from phast_gym.systems import NUMPY, split

    q = rec.q.reshape(-1, rec.n)[:: max(1, rec.n_traj * rec.T // 4000)]
    dv = np.stack([np.broadcast_to(np.asarray(g, dtype=float), (q.shape[0],))
                   for g in system.grad_potential(split(q), NUMPY)], -1)
    F = np.sqrt(np.mean(dv**2, 0))
    if rec.u is not None:
        F = np.maximum(F, np.sqrt(np.mean(rec.u.reshape(-1, rec.n) ** 2, 0)))
    F0, V = FRICTION_INIT * max(float(np.mean(F)), 1e-9), float(np.mean(v_scale))
    return {"coulomb": F0, "stribeck": F0, "viscous": F0 / V, "quadratic": F0 / V**2}


def rig_config(sim: str, sim_kwargs: dict[str, Any], regime: str, data: RigData, **overrides: Any) -> PHASTConfig:
    """The PHAST configuration of ``regime`` on the rig ``sim`` at the data's grid; ``overrides`` replace fields."""
    regime = regime.lower()
    if regime not in REGIMES:
        raise ValueError(f"regime must be one of {REGIMES}, got {regime!r}")
    system = load_simulator(sim, sim_kwargs).build()
    q_scale, v_scale = data_scales(data.train)
    init = friction_start(system, data.train, v_scale)
    base = PHASTConfig(env_id=sim, sim=sim, regime=regime, env_kwargs=dict(sim_kwargs), dt=data.train.dt,
                       q_scale=q_scale, v_scale=v_scale, damping="none", canonicalizer="mass", substeps=1,
                       learn_dt=False, observer_trainable=False, friction="joint", friction_init=init,
                       friction_newton_iters=0, midpoint_iters=1,
                       friction_eps=[FRICTION_EPS * v for v in v_scale], friction_vs=[0.2 * v for v in v_scale])
    if regime == "known":
        cfg = replace(base, potential="known", mass="known")
    # the file's rigid-body structure, its parameters learned
    elif regime == "partial" and isinstance(system, MJCFSystem):
        cfg = replace(base, potential="rigid_body", mass="rigid_body", init_from="drives" if data.driven else "none")
    elif regime == "partial":
        tmpl, dims, mass_t = _template(system)
        mass: dict[str, Any] = ({"mass": "template", "mass_template": mass_t} if mass_t
                                else {"mass": "lowrank", "mass_rank": min(4, system.n)})
        cfg = replace(base, potential="template", template=tmpl, template_dims=dims, init_from="rig", **mass)
    else:
        mass = {"mass": "lowrank", "mass_rank": min(4, system.n)} if system.separable else {"mass": "cholesky"}
        cfg = replace(base, potential="neural", init_from="motion", **mass)
    return replace(cfg, **overrides)


def nominal_config(cfg: PHASTConfig) -> PHASTConfig:
    """The rig itself as a model: its V and M, no dissipation beyond its own (scored by the same code as PHAST),
    integrated with substeps no longer than the rig's own (:func:`substeps_for`): a file's arm whose light wrists
    the recorded torques spin up overflows a step of the recordings' 10 ms, and its score is then inf, not the
    rig's."""
    system = load_simulator(cfg.sim or cfg.env_id, dict(cfg.env_kwargs)).build()
    sub = max(int(cfg.substeps), int(substeps_for(system, system.dt if cfg.dt is None else cfg.dt)))
    return replace(cfg, regime="nominal", potential="known", mass="known", damping="known", friction="none",
                   init_from="none", substeps=sub)


def odd_samples(seconds: float, dt: float) -> int:
    """An odd number of samples, at least 5, spanning about ``seconds``."""
    return odd(max(5, int(round(seconds / dt))))


# --------------------------------------------------------------------------- shooting
@dataclass
class ShootWindows:
    """Equal windows of the recordings with one initial state (q, qdot) each (the state at the first sample)."""

    q: torch.Tensor  # (W, L, n)
    u: torch.Tensor | None  # (W, L-1, n) generalized force held over each interval
    X: torch.Tensor  # (W, 2n) initial (q, qdot)

    @property
    def length(self) -> int:
        return self.q.shape[1]


def cut_windows(rec: Recordings, length: int, dtype: torch.dtype = torch.float64) -> ShootWindows:
    """Consecutive windows of ``length`` samples; states start from Savitzky-Golay smoothing."""
    check_window_room(rec, length, "one window")
    qs, vs = smooth(rec.q, rec.dt, odd_samples(SMOOTH_S, rec.dt))
    k = rec.T // length
    starts = np.arange(k) * length
    idx = starts[:, None] + np.arange(length)[None, :]
    q = rec.q[:, idx].reshape(-1, length, rec.n)
    u = None if rec.u is None else rec.u[:, idx[:, :-1]].reshape(-1, length - 1, rec.n)
    X = np.concatenate([qs[:, starts], vs[:, starts]], -1).reshape(-1, 2 * rec.n)
    return ShootWindows(torch.as_tensor(q, dtype=dtype), None if u is None else torch.as_tensor(u, dtype=dtype),
                        torch.as_tensor(X, dtype=dtype))


def simulate(model: PHAST, X: torch.Tensor, u: torch.Tensor | None, steps: int) -> torch.Tensor:
    """(W, steps+1, n) unwrapped q of the core from the states X = (q0, qdot0) with u (W, >=steps, n) held."""
    n = model.n
    q = X[:, :n]
    p = model.canonicalize(q, X[:, n:])
    out = [q]
    for k in range(steps):
        f = None if u is None else u[:, k]
        q, p = model.core(q, p, f)
        out.append(q)
    return torch.stack(out, 1)


def _residual(model: PHAST, X: torch.Tensor, q: torch.Tensor, u: torch.Tensor | None) -> torch.Tensor:
    sim = simulate(model, X, u, q.shape[1] - 1)
    return coordinate_error(sim, q, model.angle_dims)


@torch.no_grad()
def fit_states(model: PHAST, X: torch.Tensor, q: torch.Tensor, u: torch.Tensor | None, iters: int = 3) -> torch.Tensor:
    """Gauss-Newton (Levenberg-damped) refit of each window's initial state to its samples, the model fixed; all
    windows and all 2n finite-difference directions in one batch."""
    W, two_n = X.shape
    scale = torch.cat([torch.full((two_n // 2,), 1e-6), torch.full((two_n // 2,), 1e-4)]).to(X)
    for _ in range(iters):
        Xs = X.unsqueeze(0).repeat(two_n + 1, 1, 1)
        Xs[1:, :, :] += torch.diag_embed(scale).unsqueeze(1).expand(two_n, W, two_n)
        qs = q.repeat(two_n + 1, 1, 1)
        us = None if u is None else u.repeat(two_n + 1, 1, 1)
        r = _residual(model, Xs.reshape(-1, two_n), qs, us).reshape(two_n + 1, W, -1)
        J = ((r[1:] - r[:1]) / scale[:, None, None]).permute(1, 2, 0)  # (W, L n, 2n)
        r0 = r[0]
        A = J.transpose(1, 2) @ J
        A = A + 1e-6 * torch.diag_embed(torch.diagonal(A, dim1=1, dim2=2)) + 1e-12 * torch.eye(two_n).to(X)
        dx = torch.linalg.solve(A, -(J.transpose(1, 2) @ r0.unsqueeze(-1))).squeeze(-1)
        X_new = X + dx
        better = (_residual(model, X_new, q, u) ** 2).sum((1, 2)) < (r0 ** 2).sum(-1)
        X = torch.where(better.unsqueeze(-1), X_new, X)
    return X


# --------------------------------------------------------------------------- training
@dataclass(frozen=True)
class RigTrainConfig:
    """Multiple-shooting training: windows of ``window_s`` seconds, passes of AdamW over minibatches of
    ``batch_windows`` windows, window states refitted every ``refit_every`` epochs, validation on ``val_fraction`` of
    the (held-in) training windows, the best-validation weights kept.

    The model is chosen by validation, not by an epoch count: with ``schedule="plateau"`` (the default) the learning
    rates are multiplied by ``plateau_factor`` whenever the validation RMSE has not improved for ``plateau_epochs``
    epochs, and training stops once it has not improved for ``patience`` epochs (or after ``epochs``, a cap).
    ``schedule="cosine"`` decays the rates to zero over exactly ``epochs`` epochs (stepped per minibatch); with it,
    ``patience=None`` runs every epoch."""

    epochs: int = 150
    window_s: float = 0.15
    batch_windows: int = 64
    lr: float = 2e-2
    weight_decay: float = 0.0
    refit_every: int = 1
    state_iters: int = 1  # Gauss-Newton iterations of the window states per refit after the first epoch (3)
    val_fraction: float = 0.15
    #: each epoch trains on a fresh draw of at most this many training windows, their states refitted first (None:
    #: every window): a large arm's logs are many alike windows (the UR10e's 17 runs: 3,800 windows of 0.15 s, 3 min
    #: a pass), and validation, patience and the plateau rule need epochs, not passes
    epoch_windows: int | None = 1024
    friction_lr_mult: float = 5.0  # friction coefficients' lr factor (phast_model.train.groups.param_groups)
    #: every rate's factor; None: LR_AFTER_START after UNKNOWN's start from the recorded motion, else 1
    lr_mult: float | None = None
    seed: int = 0
    progress: bool = True
    #: a curriculum on the window length: the first ``warmup_epochs`` epochs on windows of ``warmup_window_s`` (an
    #: all-neural start has no restoring force, and a long window of a swing is outside its basin); None: none.  The
    #: warm-up stage always decays by cosine over its ``warmup_epochs``
    warmup_window_s: float | None = None
    warmup_epochs: int = 0
    #: early stopping: stop when the validation RMSE (on the final window length) has not improved for this many
    #: epochs; None: run every epoch up to ``epochs``
    patience: int | None = 12
    #: the final stage's learning-rate schedule: "plateau" (validation-driven) or "cosine" (over ``epochs``)
    schedule: str = "plateau"
    plateau_epochs: int = 3
    plateau_factor: float = 0.5
    #: the NaN guard (phast_model.train.loop): max gradient norm, rollbacks allowed before training stops, the
    #: learning rates' factor after a rollback
    grad_clip: float | None = 10.0
    max_nan_events: int = 5
    nan_lr_factor: float = 0.5

    def __post_init__(self) -> None:
        if int(self.epochs) != self.epochs or self.epochs < 1:
            raise ValueError(f"epochs must be a positive integer, got {self.epochs!r}")
        if self.patience is not None and (int(self.patience) != self.patience or self.patience < 1):
            raise ValueError(f"patience must be a positive integer or None, got {self.patience!r}")
        if self.schedule not in SCHEDULES:
            raise ValueError(f"schedule must be one of {SCHEDULES}, got {self.schedule!r}")
        if int(self.plateau_epochs) != self.plateau_epochs or self.plateau_epochs < 1:
            raise ValueError(f"plateau_epochs must be a positive integer, got {self.plateau_epochs!r}")
        if not 0.0 < self.plateau_factor < 1.0:
            raise ValueError(f"plateau_factor must be in (0, 1), got {self.plateau_factor!r}")
        if not (self.window_s > 0 and math.isfinite(self.window_s)):
            raise ValueError(f"window_s must be positive, got {self.window_s!r}")
        w = self.warmup_window_s
        if w is not None and not (w > 0 and math.isfinite(w)):
            raise ValueError(f"warmup_window_s must be positive, got {w!r}")
        if not 0 <= self.warmup_epochs < self.epochs:
            raise ValueError(f"warmup_epochs must be in [0, epochs), got {self.warmup_epochs!r}")
        if self.warmup_epochs and w is None:
            raise ValueError("warmup_epochs needs warmup_window_s (the warm-up's window length)")
        if self.epoch_windows is not None and (int(self.epoch_windows) != self.epoch_windows or self.epoch_windows < 1):
            raise ValueError(f"epoch_windows must be a positive integer or None, got {self.epoch_windows!r}")
        if not 0.0 <= self.val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in [0, 1), got {self.val_fraction!r}")


@dataclass
class RigFit:
    """What :func:`fit_recordings` returns: the best-validation model and the learning curve; ``nan_skipped``
    minibatch steps were skipped for a non-finite loss or gradient, ``nan_rollbacks`` epochs ended with non-finite
    parameters and were undone (the learning rates halved each time); ``stopped_early``: by ``patience``."""

    model: PHAST
    history: list[dict[str, float]] = field(default_factory=list)
    best_val: float = math.inf
    best_epoch: int = -1
    wall_time_s: float = 0.0
    init: dict[str, float] = field(default_factory=dict)
    nan_skipped: int = 0
    nan_rollbacks: int = 0
    stopped_early: bool = False


def _template_start(model: PHAST, rec: Recordings) -> dict[str, float]:
    """PARTIAL's template and mass coefficients from the rig's nominal V and M, by least squares at the recorded
    configurations (the data then refit every coefficient).  A start from the measured motion alone (the envs'
    :func:`phast_model.world.data_init.initialize_partial`) is not usable on a real arm: on the DFKI C.0 runs its force
    balance leaves 66% of the force unexplained (finite differences of a 3.8e-4 rad encoder, a torque held per
    interval, unmodelled Coulomb friction) and every coefficient comes out 5-10x too small."""
    system = model.system
    q = torch.as_tensor(rec.q.reshape(-1, rec.n)[:: max(1, rec.q.shape[0] * rec.T // 4000)], dtype=torch.float64)
    pot = model.potential
    if not isinstance(pot, TemplatePotential):
        raise ValueError(f"init_from='rig' starts a template potential (the PARTIAL regime), got {type(pot).__name__}")
    out = {"potential_fit_residual": pot.fit_to(system, q=q)}
    mass = model.mass
    if isinstance(mass, LinearMass):
        Mq = KnownMass(system).matrix(q)  # (S, n, n): the rig's M at the recorded configurations
        B = mass.linear_basis(q).to(q.dtype)  # (S, J, n, n)
        Bm = B.permute(0, 2, 3, 1).reshape(-1, B.shape[1])
        th = torch.linalg.lstsq(Bm, Mq.reshape(-1, 1)).solution.squeeze(-1)
        if isinstance(mass, LowRankMass):
            _set_lowrank(mass, th)
        else:
            mass.set_linear(th)
        out["mass_fit_residual"] = float(torch.linalg.norm(Bm @ th - Mq.reshape(-1)) / torch.linalg.norm(Mq))
    return out


def _start(model: PHAST, data: RigData, cfg: RigTrainConfig) -> dict[str, float]:
    """The model's start before the shooting fit: PARTIAL's template coefficients from the rig (``init_from='rig'``),
    UNKNOWN's components from the recorded force balance (``'motion'``: :mod:`.motion_start`), a model file's rotor
    inertias and friction from it (``'drives'``), else as built."""
    if model.config.init_from == "rig":
        return _template_start(model, data.train)
    if model.config.init_from in ("motion", "drives"):
        from .motion_start import fit_drives, fit_force_balance, motion_start

        fit = fit_drives if model.config.init_from == "drives" else fit_force_balance
        return motion_start(model, data.train, lambda m: window_rmse(m, data, cfg), fit=fit, progress=cfg.progress)
    return {}


@torch.no_grad()
def _set_lowrank(mass: LowRankMass, diag: torch.Tensor) -> None:
    """diag(softplus(d)) + U U^T = diag(diag) up to U's off-diagonal part, with U shrunk to 1% of the diagonal: its
    initial draw (0.05) is comparable to a real rig's inertia (a 0.15 kg arm: 0.003 kg m^2), and set_linear clips the
    diagonal at 1e-3 for the envs' O(1) masses."""
    d = diag.to(mass.raw_d.dtype)
    mass.U.mul_(torch.sqrt(0.01 * d.mean()) / mass.U.pow(2).sum(-1).sqrt().max().clamp_min(1e-12))
    rest = (d - mass.U.pow(2).sum(-1) - 1e-4).clamp_min(1e-12)  # diag() adds 1e-4
    mass.raw_d.copy_(torch.log(torch.expm1(rest)))


def _split_windows(w: ShootWindows, frac: float, seed: int) -> tuple[ShootWindows, ShootWindows | None]:
    W = w.q.shape[0]
    k = int(round(frac * W))
    if k == 0 or W - k < 1:
        return w, None
    perm = torch.randperm(W, generator=torch.Generator().manual_seed(seed))
    va, tr = perm[:k], perm[k:]
    pick = lambda idx: ShootWindows(w.q[idx], None if w.u is None else w.u[idx], w.X[idx])  # noqa: E731
    return pick(tr), pick(va)


def _loss(model: PHAST, w: ShootWindows, idx: torch.Tensor | None = None) -> torch.Tensor:
    q, X = (w.q, w.X) if idx is None else (w.q[idx], w.X[idx])
    u = None if w.u is None else (w.u if idx is None else w.u[idx])
    return (_residual(model, X, q, u) ** 2).mean()


@dataclass
class _Stage:
    """One window length of the curriculum: its training and validation windows and its optimizer and schedule (a
    cosine decay stepped after every minibatch, or a plateau rule stepped on the validation loss after every epoch)."""

    train: ShootWindows
    val: ShootWindows | None
    optim: Optim
    n_batches: int
    #: the training windows whose states have been fitted (a window's first fit takes 3 Gauss-Newton iterations)
    fitted: torch.Tensor
    #: this epoch's training windows (all, or a draw of ``epoch_windows``)
    drawn: torch.Tensor | None = None


def lr_mult(model: PHAST, cfg: RigTrainConfig) -> float:
    """The learning rates' factor: ``cfg.lr_mult``, else :data:`LR_AFTER_START` for a model started from the recorded
    motion (a fitted model is refined, not relearned), else 1."""
    if cfg.lr_mult is not None:
        return cfg.lr_mult
    return LR_AFTER_START if model.config.init_from == "motion" else 1.0


def _window_samples(window_s: float, dt: float) -> int:
    """Samples of a shooting window of ``window_s`` seconds (at least 5)."""
    return max(5, int(round(window_s / dt)) + 1)


def _stage(model: PHAST, data: RigData, cfg: RigTrainConfig, window_s: float, epochs: int,
           schedule: str = "cosine") -> _Stage:
    """Windows of ``window_s`` seconds, split into training and validation, with a fresh AdamW and its schedule:
    cosine over ``epochs`` epochs, or the validation plateau rule of ``cfg``."""
    train, val = _split_windows(cut_windows(data.train, _window_samples(window_s, data.dt)), cfg.val_fraction, cfg.seed)
    lr = cfg.lr * lr_mult(model, cfg)
    opt = torch.optim.AdamW(param_groups(model, lr, cfg.friction_lr_mult), lr=lr, weight_decay=cfg.weight_decay)
    W = train.q.shape[0]
    n_batches = max(1, math.ceil(min(W, cfg.epoch_windows or W) / cfg.batch_windows))
    fitted = torch.zeros(W, dtype=torch.bool)
    if schedule == "plateau":
        plateau = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=cfg.plateau_factor,
                                                             patience=cfg.plateau_epochs - 1, threshold=1e-3)
        return _Stage(train, val, Optim(opt, plateau), n_batches, fitted)
    cosine = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs * n_batches)
    return _Stage(train, val, Optim(opt, cosine), n_batches, fitted)


def _stage_at(model: PHAST, data: RigData, cfg: RigTrainConfig, epoch: int) -> _Stage:
    """A fresh stage of the curriculum that trains ``epoch`` (0-based): the warm-up's windows before
    ``warmup_epochs`` (cosine over the warm-up), the final windows and ``cfg.schedule`` from then on."""
    warm = cfg.warmup_epochs
    if epoch < warm:
        return _stage(model, data, cfg, cfg.warmup_window_s or cfg.window_s, warm)
    return _stage(model, data, cfg, cfg.window_s, cfg.epochs - warm, cfg.schedule)


def _window_states(saved: object, like: torch.Tensor, what: str) -> torch.Tensor:
    """The checkpoint's window states, checked against this run's windows."""
    if not isinstance(saved, torch.Tensor) or saved.shape != like.shape:
        shape = tuple(saved.shape) if isinstance(saved, torch.Tensor) else type(saved).__name__
        raise ValueError(f"its {what} window states are {shape}, this run has {tuple(like.shape)} windows "
                         "(were the recordings changed?)")
    return saved.to(like.dtype)


class Shooting:
    """The rig path's objective for :func:`phast_model.train.loop.train_loop`: the mean squared open-loop residual
    of minibatches of windows, each from its own initial state (multiple shooting).  A curriculum of window lengths
    (a warm-up stage, then the final one), each stage with its own windows, AdamW and schedule; the window states
    refitted by Gauss-Newton, the model fixed, at the start of every ``refit_every``-th epoch; validation on the
    held-in validation windows (the training windows when there are none); the window states in the checkpoint."""

    checkpoint_format, kind = CHECKPOINT_FORMAT, "a recordings run"

    def __init__(self, model: PHAST, data: RigData, cfg: RigTrainConfig) -> None:
        self.model, self.data, self.cfg = model, data, cfg
        self.stage: _Stage | None = None

    def optimizer(self, epoch: int, current: Optim | None) -> Optim:
        """A fresh stage (windows, AdamW, schedule) at the first epoch and where the curriculum switches."""
        if current is None or self.stage is None or epoch == self.cfg.warmup_epochs:
            self.stage = _stage_at(self.model, self.data, self.cfg, epoch)
        return self.stage.optim

    def _current(self) -> _Stage:
        if self.stage is None:
            raise RuntimeError("no stage yet: optimizer() starts one")
        return self.stage

    def begin_epoch(self, epoch: int) -> None:
        """This epoch's training windows drawn (``epoch_windows``, from a generator of the seed and the epoch, so a
        resumed run draws the same) and their states refitted: 3 Gauss-Newton iterations for a window fitted for the
        first time, ``state_iters`` after (the states move little between epochs); the validation states likewise."""
        st, cfg = self._current(), self.cfg
        W = st.train.q.shape[0]
        if cfg.epoch_windows is None or cfg.epoch_windows >= W:
            st.drawn = torch.arange(W)
        else:
            gen = torch.Generator().manual_seed(1_000_003 * cfg.seed + epoch)
            st.drawn = torch.randperm(W, generator=gen)[: cfg.epoch_windows].sort().values
        if epoch % cfg.refit_every == 0:
            first = epoch in (0, cfg.warmup_epochs)
            self._refit(st.train, st.drawn, st.fitted, cfg.state_iters)
            if st.val is not None:
                st.val.X = fit_states(self.model, st.val.X, st.val.q, st.val.u, 3 if first else cfg.state_iters)

    def _refit(self, w: ShootWindows, idx: torch.Tensor, fitted: torch.Tensor, iters: int) -> None:
        """The states of windows ``idx`` refitted, 3 iterations where never fitted before, else ``iters``."""
        for part, k in ((idx[~fitted[idx]], 3), (idx[fitted[idx]], iters)):
            if len(part):
                w.X[part] = fit_states(self.model, w.X[part], w.q[part], None if w.u is None else w.u[part], k)
        fitted[idx] = True

    def batches(self, gen: torch.Generator) -> Iterator[torch.Tensor]:
        st = self._current()
        drawn = torch.arange(st.train.q.shape[0]) if st.drawn is None else st.drawn
        perm = drawn[torch.randperm(len(drawn), generator=gen)]
        for b in range(st.n_batches):
            yield perm[b * self.cfg.batch_windows:(b + 1) * self.cfg.batch_windows]

    def loss(self, batch: torch.Tensor) -> tuple[torch.Tensor, int]:
        return _loss(self.model, self._current().train, batch), len(batch)

    @torch.no_grad()
    def validation_loss(self) -> float:
        st = self._current()
        return float(_loss(self.model, st.val if st.val is not None else st.train))

    def record(self, epoch: int, train_loss: float, val_loss: float | None, lr: float, time_s: float,
               guard: NanCounts) -> dict[str, Any]:
        return {"epoch": epoch, "train_rmse": math.sqrt(train_loss), "time_s": time_s,
                "val_rmse": math.nan if val_loss is None else math.sqrt(val_loss), "lr": float(lr),
                "nan_skipped": guard.skipped, "nan_rollbacks": guard.rollbacks}

    def state(self) -> dict[str, Any]:
        st = self._current()
        return {"X_train": st.train.X, "X_val": None if st.val is None else st.val.X, "fitted": st.fitted}

    def load_state(self, saved: dict[str, Any]) -> None:
        st = self._current()
        st.train.X = _window_states(saved["X_train"], st.train.X, "training")
        fitted = saved.get("fitted")  # a checkpoint of before the draws refitted every window every epoch
        st.fitted = torch.ones_like(st.fitted) if fitted is None else torch.as_tensor(fitted, dtype=torch.bool)
        if st.val is not None:
            st.val.X = _window_states(saved["X_val"], st.val.X, "validation")


def loop_config(cfg: RigTrainConfig) -> LoopConfig:
    """The shared loop's settings of a :class:`RigTrainConfig`: validation every epoch, the model chosen (and
    patience counted) on the final window length only, a checkpoint after every epoch."""
    return LoopConfig(epochs=cfg.epochs, seed=cfg.seed, grad_clip=cfg.grad_clip, max_nan_events=cfg.max_nan_events,
                      nan_lr_factor=cfg.nan_lr_factor, val_every=1, select_from=cfg.warmup_epochs,
                      patience=cfg.patience, checkpoint_every=1, progress=cfg.progress,
                      desc="fit rig (multiple shooting)")


def fit_recordings(model: PHAST, data: RigData, cfg: RigTrainConfig | None = None, run_dir: str | Path | None = None,
                   resume: bool = False, identity: dict[str, Any] | None = None) -> RigFit:
    """Train ``model`` on ``data.train`` by multiple shooting (the objective :class:`Shooting`) in the shared epoch
    loop :func:`phast_model.train.loop.train_loop`; with a warm-up, the best validation is tracked on the final
    window length only.

    The loop's NaN guard: a minibatch whose loss or gradient is not finite makes no update (``nan_skipped``); a step
    that leaves non-finite parameters is undone back to the epoch's start and the learning rates halved
    (``nan_rollbacks``).  With ``run_dir``, ``checkpoint.pt`` is written there atomically after every epoch (model,
    optimizer and schedule, window states, best state, history, RNG states) and ``resume=True`` continues from it to
    the model an uninterrupted run ends with; ``identity`` (what else defines the run: the model config, the
    recordings ...) is recorded in it and a checkpoint of another run, a missing or an unreadable one is a
    ValueError."""
    cfg = cfg or RigTrainConfig()
    model = model.double()
    t0 = time.perf_counter()
    init = _start(model, data, cfg)
    if init:
        init["start_s"] = time.perf_counter() - t0
    ckpt = None if run_dir is None else Path(run_dir) / CHECKPOINT
    if resume and ckpt is not None and not ckpt.exists():
        raise ValueError(f"cannot resume: {ckpt} is missing (no epoch of a run in {ckpt.parent} has finished); "
                         "start without --resume")
    start = copy.deepcopy(model.state_dict()) if "start_rmse" in init else None
    res = train_loop(Shooting(model, data, cfg), loop_config(cfg), cfg, ckpt, resume, identity)
    best_val, best_epoch = math.sqrt(res.best_val), res.best_epoch
    if start is not None and _start_wins(model, start, data, cfg, init):
        best_val, best_epoch = init["start_rmse"], 0
    return RigFit(model, res.history, best_val, best_epoch, res.wall_time_s, init, res.nan.skipped, res.nan.rollbacks,
                  res.stopped)


def _start_wins(model: PHAST, start: dict[str, Any], data: RigData, cfg: RigTrainConfig,
                init: dict[str, float]) -> bool:
    """The start from the recorded motion competes with the trained model on the held-in validation windows, each
    scored by :func:`window_rmse` (the start was scored so when it was chosen); the start's weights are restored
    when they fit better (on the real pendulum the shooting fit improved the 2-s training windows and worsened the
    held-out 9-s rollouts, so it must earn its place on held-in windows)."""
    init["trained_rmse"] = window_rmse(model, data, cfg)
    if not init["start_rmse"] < init["trained_rmse"]:
        return False
    model.load_state_dict(start)
    return True


@torch.no_grad()
def window_rmse(model: PHAST, data: RigData, cfg: RigTrainConfig, iters: int = 5) -> float:
    """RMSE of ``model`` on the validation windows a run of ``cfg`` selects its model on (the final window length,
    the same split), each window's state fitted to this model: the training-window score of another model (the
    nominal one) on the same footing as the run's best validation RMSE."""
    train, val = _split_windows(cut_windows(data.train, _window_samples(cfg.window_s, data.dt)), cfg.val_fraction,
                                cfg.seed)
    w = val if val is not None else train
    model = model.double()
    X = fit_states(model, w.X, w.q, w.u, iters)
    return math.sqrt(float(_loss(model, ShootWindows(w.q, w.u, X))))


def build(cfg: PHASTConfig) -> PHAST:
    """The model of a rig config, in float64 (the shooting fits difference rollouts)."""
    model = build_from_config(cfg)
    if not isinstance(model, PHAST):
        raise ValueError("recordings runs need a port-Hamiltonian rig")
    return model.double()
