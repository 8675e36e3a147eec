"""A start for UNKNOWN from the recorded motion: the force balance matched by gradient descent.

An all-neural model starts with no restoring force and a unit mass.  On a real rig that start lies outside the basin
of the multiple-shooting fit: a pendulum swings at ~1.3 Hz, so a few hundred milliseconds of the wrong potential
already put the rollout half a swing away, and the DFKI arm's inertia (~0.01 kg m^2) is 100x below the unit mass,
so its measured torques hardly move the model (training RMSE stuck at 1.2 rad, held-out error 23x and 1.9x the
nominal model's; docs/rig_world_model.md).

Before the shooting fit, the model's potential, mass and joint friction are therefore fitted to the equation of
motion at the recorded samples,

    d/dt (M(q) qdot) - 1/2 d/dq (qdot^T M(q) qdot) + dV/dq + f(qdot) = G u          (Eq. 1-3 with p = M qdot)

with q, qdot and qddot from a Savitzky-Golay fit to the recordings (:data:`phast_model.identify.signals.SAVGOL`): a
regression on the model's own components (gradient matching, as in the derivative-based starts of SINDy), each
coordinate's residual scaled by its typical force.  Without a port input the scale of (V, M, f) is free: the mass
then keeps its initial gauge (a constant mass is not trained; a configuration-dependent one is held at a mean
diagonal of 1).  The shooting fit then refines the start on open-loop windows, where the differentiated signal's
noise no longer enters.

PARTIAL on a model file (an MJCF or URDF arm) starts from its drives instead (:func:`fit_drives`): the file's bodies
are kept and the same balance, linear in each joint's rotor inertia and friction coefficients, is solved by
non-negative least squares.  A file without rotor inertia is far off on a geared arm: the UR10e's wrist links have
1e-4 kg m^2 about their axes, its motors reflect 0.2-0.3, so the recorded torques spin the file's wrists up within a
step and the first shooting fit overflows.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from tqdm.auto import tqdm

from ..components.rigid_body import RigidBodyMass
from ..identify.recordings import Recordings
from ..identify.signals import SavitzkyGolay, odd, time_scale
from ..world.model import PHAST

#: Savitzky-Golay windows tried, in units of the recordings' time scale (1 / omega of their oscillation,
#: :func:`phast_model.identify.signals.time_scale`); the start whose open-loop windows fit best is kept
WINDOW_TAUS = (0.75, 1.1, 1.5, 2.2)
#: samples kept for the regression (every k-th interior sample of every trajectory)
MAX_SAMPLES = 8_000


@dataclass(frozen=True)
class MotionSamples:
    """(S, n) positions, velocities, accelerations and port force at interior recorded samples."""

    q: torch.Tensor
    v: torch.Tensor
    a: torch.Tensor
    f: torch.Tensor | None

    def __len__(self) -> int:
        return int(self.q.shape[0])


@dataclass(frozen=True)
class MotionStartConfig:
    """Adam on minibatches of the force-balance residual: ``steps`` steps of ``batch`` samples, learning rate ``lr``
    decayed by cosine to zero (the friction coefficients at ``friction_lr_mult`` x ``lr``: their softplus makes the
    steps relative, and they start orders of magnitude from a free swing's gauge); ``seed`` for the minibatches.
    The signal: a Savitzky-Golay filter of degree ``polyorder`` over each of ``window_taus`` x the time scale."""

    steps: int = 1500
    batch: int = 2048
    lr: float = 3e-3
    friction_lr_mult: float = 10.0
    seed: int = 0
    window_taus: tuple[float, ...] = WINDOW_TAUS
    polyorder: int = 5
    max_samples: int = MAX_SAMPLES
    #: L-BFGS iterations on all samples after Adam (0: none): minibatch Adam leaves the potential's slope wiggling by
    #: ~0.5%, a free swing's frequency by half that
    polish_iters: int = 300


def motion_samples(rec: Recordings, window_s: float, max_samples: int = MAX_SAMPLES,
                   polyorder: int = 5) -> MotionSamples:
    """q, qdot, qddot (Savitzky-Golay of degree ``polyorder``) and the port force held around each sample (the mean
    of the two intervals), at interior samples of every trajectory, subsampled to at most ``max_samples``.  A cubic
    filter's second derivative is biased by O((omega h)^2), which a free swing turns into a frequency error (0.3% on
    the real pendulum, 0.2 rad of phase over a 9-s rollout); degree 5 leaves O((omega h)^4)."""
    N, T, n = rec.q.shape
    sg = SavitzkyGolay(polyorder)
    w = sg.fit_window(odd(max(polyorder + 4, int(round(window_s / rec.dt)))), T)
    q = sg.smooth(rec.q, w)
    v = sg.derivative(rec.q, w, rec.dt, 1)
    a = sg.derivative(rec.q, w, rec.dt, 2)
    h = w // 2  # the filter's edges are extrapolations
    idx = np.arange(max(h, 1), T - max(h, 1))
    idx = idx[:: max(1, math.ceil(N * len(idx) / max_samples))]
    take = lambda x: torch.as_tensor(x[:, idx].reshape(-1, n), dtype=torch.float64)  # noqa: E731
    f = None
    if rec.u is not None:
        u = np.asarray(rec.u, dtype=np.float64)  # (N, T-1, n): held over each interval
        around = np.zeros_like(rec.q)
        around[:, 1:-1] = 0.5 * (u[:, :-1] + u[:, 1:])
        f = take(around)
    return MotionSamples(take(q), take(v), take(a), f)


def force_residual(model: PHAST, s: MotionSamples) -> torch.Tensor:
    """The equation of motion's residual (module docstring) at the samples, (S, n): the mass's d/dt and
    configuration terms by forward-mode derivatives of ``M(q) qdot`` along qdot and the gradient of the kinetic
    energy, zero for a constant mass."""
    mass, q, v = model.mass, s.q, s.v
    r = mass.momentum(q, s.a) + model.potential.grad(q)
    if not getattr(mass, "constant", True):
        qg = q.detach().requires_grad_(True)
        mdot_v = torch.func.jvp(lambda x: mass.momentum(x, v), (qg,), (v,))[1]
        kinetic = 0.5 * (v * mass.momentum(qg, v)).sum()
        dT = torch.autograd.grad(kinetic, qg, create_graph=True)[0]
        r = r + mdot_v - dT
    if model.friction is not None:
        r = r + model.friction.force(v)
    port = model.port_force(s.f) if s.f is not None else None
    return r if port is None else r - port


def _scales(model: PHAST, s: MotionSamples) -> torch.Tensor:
    """Each coordinate's typical force: the RMS port force where there is one, else the RMS of M qddot."""
    with torch.no_grad():
        typical = model.mass.momentum(s.q, s.a) if s.f is None else s.f
        rms = typical.pow(2).mean(0).sqrt()
    return rms.clamp_min(1e-6 * float(rms.max().clamp_min(1e-12)))


def _gauge_penalty(model: PHAST, s: MotionSamples) -> torch.Tensor:
    """Without a port input: a configuration-dependent mass held at a mean diagonal of 1 (the scale is free)."""
    diag = torch.diagonal(model.mass.matrix(s.q[:256]), dim1=-2, dim2=-1)
    return (diag.mean() - 1.0) ** 2


def _trained(model: PHAST, driven: bool) -> list[torch.nn.Parameter]:
    """The potential, the friction, and the mass unless it is constant and the scale is free (no port input)."""
    mods: list[torch.nn.Module] = [model.potential]
    if model.friction is not None:
        mods.append(model.friction)
    if driven or not getattr(model.mass, "constant", True):
        mods.append(model.mass)
    seen: dict[int, torch.nn.Parameter] = {}  # a rigid-body V and M share one set of body parameters
    for p in (p for m in mods for p in m.parameters() if p.requires_grad):
        seen.setdefault(id(p), p)
    return list(seen.values())


def _polish(params: list[torch.nn.Parameter], loss_fn: Callable[[], torch.Tensor], iters: int) -> None:
    """L-BFGS (strong Wolfe line search) on the whole-sample loss; a non-finite loss stops it where it is."""
    opt = torch.optim.LBFGS(params, lr=1.0, max_iter=iters, history_size=20, line_search_fn="strong_wolfe",
                            tolerance_grad=1e-12, tolerance_change=1e-15)

    def closure() -> torch.Tensor:
        opt.zero_grad(set_to_none=True)
        loss = loss_fn()
        if torch.isfinite(loss):
            loss.backward()
        return loss

    saved = [p.detach().clone() for p in params]
    opt.step(closure)
    if not all(torch.isfinite(p).all() for p in params):
        with torch.no_grad():
            for p, old in zip(params, saved):
                p.copy_(old)


def fit_force_balance(model: PHAST, s: MotionSamples, cfg: MotionStartConfig) -> float:
    """Fit the model's potential, mass and friction to the force balance at the samples ``s`` (module docstring), in
    place: Adam on minibatches, then L-BFGS on all samples.  Returns the relative residual after (RMS residual / RMS
    typical force)."""
    driven = s.f is not None
    scale = _scales(model, s)
    params = _trained(model, driven)
    fric = {id(p) for p in model.friction.parameters()} if model.friction is not None else set()
    opt = torch.optim.Adam([{"params": [p], "lr": cfg.lr * (cfg.friction_lr_mult if id(p) in fric else 1.0)}
                            for p in params])
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.steps)
    gen = torch.Generator().manual_seed(cfg.seed)

    def loss_on(idx: torch.Tensor | None) -> torch.Tensor:
        part = s if idx is None else MotionSamples(s.q[idx], s.v[idx], s.a[idx], None if s.f is None else s.f[idx])
        loss = (force_residual(model, part) / scale).pow(2).mean()
        if not driven and not getattr(model.mass, "constant", True):
            loss = loss + _gauge_penalty(model, part)
        return loss

    for _ in range(cfg.steps):
        idx = torch.randint(len(s), (min(cfg.batch, len(s)),), generator=gen)
        opt.zero_grad(set_to_none=True)
        loss = loss_on(idx)
        if not torch.isfinite(loss):
            raise ValueError("the force-balance start diverged (a non-finite residual); train without it "
                             "(init_from='none')")
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, 10.0)
        opt.step()
        sched.step()
    if cfg.polish_iters:
        _polish(params, lambda: loss_on(None), cfg.polish_iters)
    return math.sqrt(float(loss_on(None).detach()))


#: the drives' start's smallest coefficient, as a share of the one that alone would carry the joint's whole force (a
#: softplus cannot start at 0, and one far below its scale takes many relative steps to come back)
DRIVES_FLOOR = 0.01


def drives_regressors(model: PHAST, s: MotionSamples) -> tuple[torch.Tensor, torch.Tensor]:
    """(y, A): y (S, n) the force the bodies leave, G u - (M_bodies(q) qddot + C(q, qdot) qdot + dV/dq), and A (S, n,
    1 + K) each joint's regressors: qddot_j (its armature) and the friction laws' shapes phi_k(qdot_j)."""
    if not isinstance(model.mass, RigidBodyMass) or model.friction is None or s.f is None:
        raise ValueError("the drives' start needs a model file's rigid-body mass (PARTIAL on an MJCF/URDF rig), joint "
                         "friction and a port input (u)")
    r = force_residual(model, s).detach()  # includes the current armature and friction
    with torch.no_grad():
        arm = model.mass.bodies.armature().to(s.a.dtype)
        y = -(r - arm * s.a - model.friction.force(s.v))
        A = torch.cat([s.a.unsqueeze(-1), model.friction.basis(s.v).movedim(0, -1)], -1)
    return y, A


def fit_drives(model: PHAST, s: MotionSamples, cfg: MotionStartConfig) -> float:
    """Each joint's rotor inertia (armature) and friction coefficients by non-negative least squares on the force the
    file's bodies leave at the samples (:func:`drives_regressors`), the bodies kept as the file gives them; each
    coefficient at least :data:`DRIVES_FLOOR` of its scale.  A rigid-body arm's equation of motion is linear in these,
    so no descent is needed.  Returns the relative residual (RMS residual / RMS force left by the bodies)."""
    from scipy.optimize import nnls

    y, A = (x.numpy() for x in drives_regressors(model, s))
    coef = np.zeros(A.shape[1:])  # (n, 1 + K)
    fitted = np.zeros_like(y)
    for j in range(y.shape[1]):
        scale = np.sqrt(np.mean(A[:, j] ** 2, 0)) + 1e-300
        x = nnls(A[:, j] / scale, y[:, j])[0]
        floor = DRIVES_FLOOR * np.sqrt(np.mean(y[:, j] ** 2))
        coef[j] = np.maximum(x, floor) / scale
        fitted[:, j] = A[:, j] @ coef[j]
    assert isinstance(model.mass, RigidBodyMass)  # drives_regressors checked it
    model.mass.bodies.set_armature(coef[:, 0])
    friction = model.friction
    assert friction is not None
    joints = friction.index.numpy()
    friction.set_coefficients({law: torch.as_tensor(coef[joints, 1 + k]) for k, law in enumerate(friction.laws)})
    return float(np.sqrt(np.mean((y - fitted) ** 2) / max(np.mean(y**2), 1e-300)))


def motion_start(model: PHAST, rec: Recordings, score: Callable[[PHAST], float],
                 cfg: MotionStartConfig | None = None,
                 fit: Callable[[PHAST, MotionSamples, MotionStartConfig], float] = fit_force_balance,
                 progress: bool = False) -> dict[str, float]:
    """The start of ``model`` from the recorded motion ``rec`` (module docstring), in place: one force-balance fit
    (``fit``: :func:`fit_force_balance`, or :func:`fit_drives` for a model file's drives) per Savitzky-Golay window of
    ``cfg.window_taus`` (a narrow window leaves noise in qddot, a wide one bias), each
    from the same initial weights; the one of least ``score`` (the run's open-loop RMSE on its held-in validation
    windows, :func:`phast_model.train.rig_fit.window_rmse`) is kept.  Returns what was chosen and every candidate's
    score."""
    cfg = cfg or MotionStartConfig()
    tau = time_scale(rec.q, rec.dt)
    initial = copy.deepcopy(model.state_dict())
    best: tuple[float, dict[str, torch.Tensor] | None] = (math.inf, None)
    info: dict[str, float] = {"time_scale_s": tau}
    for k in tqdm(cfg.window_taus, desc="start from the recorded motion", disable=not progress):
        model.load_state_dict(initial)
        s = motion_samples(rec, k * tau, cfg.max_samples, cfg.polyorder)
        residual = fit(model, s, cfg)
        rmse = float(score(model))
        info[f"window_{k:g}tau_force_residual"], info[f"window_{k:g}tau_rmse"] = residual, rmse
        if rmse < best[0]:
            best = (rmse, copy.deepcopy(model.state_dict()))
            info["window_s"], info["start_rmse"] = k * tau, rmse
    if best[1] is None:
        raise ValueError("no force-balance start could be scored (non-finite open-loop RMSE at every window)")
    model.load_state_dict(best[1])
    return info
