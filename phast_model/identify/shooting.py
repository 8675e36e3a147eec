"""Fitting by simulation: multiple shooting of the (augmented) simulator on windows.

Velocities and accelerations are never regressed on: every window of every
recording gets its own initial state (q0, qdot0), the model is simulated with
the system's own physics (:func:`phast_gym.integrate.step`, batched over all
windows) and compared with the measured q.  The residual is measurement noise
when the model is right, so least squares is the maximum-likelihood fit and the
Gauss-Newton covariance gives honest intervals; no smoothing choice enters the
answer (smoothing only seeds the initial states).

Levenberg-Marquardt with the arrow-shaped normal equations of shooting: the
per-window states are eliminated window by window (Schur complement), so the
cost of a step grows linearly with the number of windows.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import NamedTuple, Protocol

import numpy as np

from phast_gym.integrate import step
from phast_gym.systems import angle_diff, split
from phast_gym.systems.base import NUMPY, System

from .delays import history
from .merging import merge_systems, merged_field_ok
from .recordings import Recordings
from .signals import estimate_noise, odd, smooth, time_scale

__all__ = ["Heartbeat", "Shooter", "ShootFit", "Windows", "estimate_noise", "odd", "simulate_qv", "smooth",
           "substeps_for", "time_scale"]


def momentum(system: System, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """p = M(q) qdot (:meth:`System.momentum`) for (..., n) arrays."""
    return np.stack(np.broadcast_arrays(*system.momentum(split(q), split(v), NUMPY)), -1)


# --------------------------------------------------------------------------- simulation
def substeps_for(system: System, dt: float | np.ndarray) -> int | np.ndarray:
    """Enough RK4 substeps that each is no longer than the env's own substep: one count (int) for a scalar ``dt``;
    for per-sample steps (B, n_steps) one count per interval (from its longest step), an (n_steps,) int array."""
    h_env = system.dt / max(system.substeps, 1)
    if np.ndim(dt) == 0:
        return max(1, int(math.ceil(float(dt) / h_env - 1e-9)))
    d = np.asarray(dt, dtype=float)
    longest = d.reshape(-1, d.shape[-1]).max(axis=0) if d.ndim >= 2 else d
    return np.maximum(1, np.ceil(longest / h_env - 1e-9)).astype(int)


def _interval_counts(substeps: int | np.ndarray, n_steps: int) -> np.ndarray:
    k = np.broadcast_to(np.asarray(substeps), (n_steps,)).astype(int)
    if np.any(k < 1):
        raise ValueError(f"substeps must be positive, got {substeps}")
    return k


def simulate_qv(system: System, q0: np.ndarray, v0: np.ndarray, n_steps: int, u: np.ndarray | None,
                dt: float | np.ndarray, substeps: int | np.ndarray, u_before: np.ndarray | None = None,
                engine_substeps: int | None = None) -> np.ndarray:
    """Simulate a batch from (q0, qdot0) (B, n) and return measured q (B, n_steps+1, n).

    ``dt``: the sampling step (scalar), or the per-sample length of every interval, (B, n_steps) or (n_steps,)
    (recorded, jittered times: ``Recordings.steps`` / ``sim_dt``); u (B, n_steps, n) is held over each interval.
    ``substeps``: RK4 substeps per interval, an int (substep h = dt / substeps) or one count per interval, (n_steps,)
    (``substeps_for(system, dt)`` keeps every substep within the env's).  A model with delays (``delayed_input`` /
    ``delayed_output``, :mod:`.delays`) gets u delayed (``u_before`` (B, P, n): the inputs before the first interval;
    None: the first one held) and reports q delayed; its measurement map (``measure``: sensor terms) maps the output.
    A model another engine simulates (``external_rollout``: MuJoCo) takes its own step, or with ``engine_substeps`` no
    more steps an interval than that (a fit's coarser step; :mod:`.mujoco_sim`); the delays and map apply alike.
    """
    delay_in = getattr(system, "delayed_input", None)
    if u is not None and delay_in is not None:
        u = delay_in(u, dt, u_before)
    external = getattr(system, "external_rollout", None)  # a model another simulator runs (MuJoCo: mujoco_sim)
    if external is not None:
        out = external(q0, v0, n_steps, u, dt, *([engine_substeps] if engine_substeps else []))
    else:
        out = _integrated(system, q0, v0, n_steps, u, dt, substeps)
    delay_out = getattr(system, "delayed_output", None)
    if delay_out is not None:
        out = delay_out(out, v0, dt)
    measure = getattr(system, "measure", None)
    return measure(out) if measure is not None else out


def _integrated(system: System, q0: np.ndarray, v0: np.ndarray, n_steps: int, u: np.ndarray | None,
                dt: float | np.ndarray, substeps: int | np.ndarray) -> np.ndarray:
    """The true q (B, n_steps+1, n) of :func:`simulate_qv` by the tool's own integrator."""
    B, n = q0.shape
    p0 = momentum(system, q0, v0)
    q = [q0[:, i].copy() for i in range(n)]
    p = [p0[:, i].copy() for i in range(n)]
    out = np.empty((B, n_steps + 1, n))
    out[:, 0] = q0
    if np.ndim(dt) == 0 and np.ndim(substeps) == 0:
        with np.errstate(all="ignore"):
            for t in range(n_steps):
                ut = None if u is None else [u[:, t, i] for i in range(n)]
                q, p = step(system, q, p, ut, NUMPY, dt=dt, substeps=int(substeps))
                q = [np.broadcast_to(c, (B,)) for c in q]
                p = [np.broadcast_to(c, (B,)) for c in p]
                out[:, t + 1] = np.stack(q, -1)
    else:
        d = np.asarray(dt, dtype=float)
        if d.ndim == 0 or d.shape == (n_steps,):
            d = np.broadcast_to(d, (B, n_steps))
        if d.shape != (B, n_steps):
            raise ValueError(f"dt must be a scalar or per-sample steps (B, n_steps) = ({B}, {n_steps}), got {d.shape}")
        dT = np.ascontiguousarray(d.T)  # (n_steps, B): contiguous rows
        k = _interval_counts(substeps, n_steps)
        with np.errstate(all="ignore"):
            for t in range(n_steps):
                ut = None if u is None else [u[:, t, i] for i in range(n)]
                q, p = step(system, q, p, ut, NUMPY, dt=dT[t], substeps=int(k[t]))
                q = [np.broadcast_to(c, (B,)) for c in q]
                p = [np.broadcast_to(c, (B,)) for c in p]
                out[:, t + 1] = np.stack(q, -1)
    return out


# --------------------------------------------------------------------------- windows
def compared_samples(length: int, stride: int) -> np.ndarray:
    """Indices of a window's samples that enter the residual: 0, stride, 2 stride, ... and the last."""
    idx = np.arange(0, length, max(int(stride), 1))
    return idx if idx[-1] == length - 1 else np.append(idx, length - 1)


@dataclass
class Windows:
    """Equal-length windows cut from recordings; each gets its own initial state.

    The model is simulated over every recorded interval of a window (u held per interval, ``steps``
    the recorded interval lengths when the sampling is not uniform) and compared with the measured q
    at :attr:`obs` (every ``stride``-th sample, the first and the last).
    """

    traj: np.ndarray  # (W,) trajectory index of each window
    start: np.ndarray  # (W,) first sample
    length: int
    q: np.ndarray  # (W, L, n) measured
    u: np.ndarray | None  # (W, L-1, n)
    angle_dims: tuple[int, ...]
    dt: float  # (median) sampling step
    steps: np.ndarray | None = None  # (W, L-1) recorded interval lengths, None when uniform at dt
    stride: int = 1  # compare every stride-th sample
    # (W, P, n) the recorded inputs before each window (input delays, :mod:`.delays`)
    u_before: np.ndarray | None = None

    @classmethod
    def cut(cls, rec: Recordings, length: int, stride: int = 1) -> Windows:
        """Windows of ``length`` samples (the last one flush with the end); the residual compares every
        ``stride``-th sample of a window (and its last), the simulation still runs over every recorded interval."""
        stride = int(stride)
        if stride < 1:
            raise ValueError(f"stride must be a positive integer, got {stride}")
        T = rec.T
        length = int(min(max(length, 5), T))
        starts = list(range(0, T - length + 1, length))
        if starts[-1] + length < T:
            starts.append(T - length)
        traj = np.repeat(np.arange(rec.n_traj), len(starts))
        start = np.tile(np.asarray(starts), rec.n_traj)
        idx = start[:, None] + np.arange(length)[None, :]
        q = rec.q[traj[:, None], idx]
        u = None
        u_before = None
        if rec.u is not None:
            u = rec.u[traj[:, None], idx[:, :-1]]
            u_before = history(rec.u, traj, start)
        steps = None
        if not getattr(rec, "uniform", True):
            steps = rec.steps[traj[:, None], idx[:, :-1]]
        return cls(traj, start, length, q, u, rec.angle_dims, rec.dt, steps, stride, u_before)

    @property
    def count(self) -> int:
        return len(self.traj)

    @property
    def obs(self) -> np.ndarray:
        """Indices of the compared samples of every window."""
        return compared_samples(self.length, self.stride)

    @property
    def sim_dt(self) -> float | np.ndarray:
        """``dt`` for :func:`simulate_qv`: the scalar step, or the (W, L-1) recorded steps."""
        return self.dt if self.steps is None else self.steps

    def select(self, keep: np.ndarray) -> Windows:
        """The windows ``keep`` (index array or mask)."""
        return Windows(self.traj[keep], self.start[keep], self.length, self.q[keep],
                       None if self.u is None else self.u[keep],
                       self.angle_dims, self.dt, None if self.steps is None else self.steps[keep], self.stride,
                       None if self.u_before is None else self.u_before[keep])

    def prefix(self, length: int) -> Windows:
        """Every window cut to its first ``length`` samples."""
        return Windows(self.traj, self.start, length, self.q[:, :length],
                       None if self.u is None else self.u[:, : length - 1],
                       self.angle_dims, self.dt, None if self.steps is None else self.steps[:, : length - 1],
                       self.stride,
                       self.u_before)


# --------------------------------------------------------------------------- least squares
@dataclass(frozen=True)
class Prior:
    """A Gaussian prior on the globals: the penalty sum_j precision_j (g_j - center_j)^2 in chi^2 units, added to the
    fit's cost (a maximum a posteriori fit).  Precision zero: no prior on that global.  A body value of a CAD file is
    a measurement of the machine too, trusted to some tens of per cent: where the recordings do not pin it (a link's
    moment that trades with a rotor inertia on the same axis) it stays near the file's value instead of wandering."""

    precision: np.ndarray  # (P,)
    center: np.ndarray  # (P,)

    def cost(self, g: np.ndarray) -> float:
        return float(np.sum(self.precision * (g - self.center) ** 2))

    def without(self, j: int) -> Prior:
        keep = np.arange(self.precision.size) != j
        return Prior(self.precision[keep], self.center[keep])


@dataclass
class ShootFit:
    """Result of a shooting fit: window states, global vector, residuals and Jacobians."""

    X: np.ndarray  # (W, 2n) window initial (q, qdot)
    g: np.ndarray  # (P,) global parameters (scaled)
    r: np.ndarray  # (W, L*n) standardized residuals (L: compared samples per window, Windows.obs)
    JX: np.ndarray  # (W, L*n, 2n)
    Jg: np.ndarray  # (W, L*n, P)
    cost: float  # sum of squared standardized residuals
    n_obs: int
    iterations: int
    groups: np.ndarray | None = None  # (W,) the recording of each window: the clusters of interval_covariance
    prior: Prior | None = None  # on g (a maximum a posteriori fit): in the objective, steps and covariance

    @property
    def objective(self) -> float:
        """What the fit minimizes: the cost plus the prior's penalty (the cost alone without a prior)."""
        return self.cost + (0.0 if self.prior is None else self.prior.cost(self.g))

    @property
    def dof(self) -> int:
        return max(self.n_obs - self.X.size - self.g.size, 1)

    @property
    def chi2_red(self) -> float:
        return self.cost / self.dof

    def projected(self, cols: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Residual and columns (W, L*n, k) with the window-state directions projected out."""
        JX = self.JX
        Q = np.linalg.qr(JX)[0]  # (W, L*n, 2n) orthonormal basis per window
        def proj(a: np.ndarray) -> np.ndarray:
            return a - np.einsum("wla,wak->wlk", Q, np.einsum("wla,wlk->wak", Q, a))
        r = proj(self.r[..., None])[..., 0]
        if cols is None:
            cols = self.Jg
        return r, proj(cols)

    def without(self, j: int) -> ShootFit:
        """The fit with global ``j`` held at zero (no effect) and every other unknown (window states included) moved by
        one Gauss-Newton step on this linearization: the refit's statistics without a new simulation."""
        keep = [i for i in range(self.g.size) if i != j]
        r0 = self.r - self.Jg[..., j] * self.g[j]
        Jg = self.Jg[..., keep]
        JX = self.JX
        prior = None if self.prior is None else self.prior.without(j)
        dx, dg = _damped_step(Normal.of(JX, Jg, r0).with_prior(prior, self.g[keep]), 0.0)
        r = r0 + np.einsum("wla,wa->wl", JX, dx) + np.einsum("wlp,p->wl", Jg, dg)
        return ShootFit(self.X + dx, self.g[keep] + dg, r, JX, np.ascontiguousarray(Jg), float(np.sum(r**2)),
                        self.n_obs, 0, self.groups, prior)

    def without_effect(self, j: int) -> ShootFit:
        """The fit with global ``j`` taken out where it has no effect on the simulation (a coefficient the model clips
        at zero): the same residuals, nothing else moved."""
        keep = [i for i in range(self.g.size) if i != j]
        return replace(self, g=self.g[keep], Jg=np.ascontiguousarray(self.Jg[..., keep]),
                                   prior=None if self.prior is None else self.prior.without(j))

    def covariance(self) -> np.ndarray:
        """Covariance of g: max of Gauss-Newton (scaled by chi2_red) and window-cluster sandwich."""
        if not self.g.size:
            return np.zeros((0, 0))
        return self._covariance(*self._scores())

    def interval_covariance(self) -> tuple[np.ndarray, int | None]:
        """(covariance of g, degrees of freedom) for reported intervals: :meth:`covariance`, each variance raised to
        that of a sandwich clustered on recordings where it is larger (a misfit that a recording's windows share, e.g.
        over its range of speeds, is one piece of evidence, not one per window), with recordings - 1 degrees of freedom
        for Student's t quantile; None (the normal quantile) when the windows' recordings are unknown or fewer than
        3."""
        if not self.g.size:
            return np.zeros((0, 0)), None
        Hinv, scores = self._scores()
        cov = self._covariance(Hinv, scores)
        if self.groups is None:
            return cov, None
        _, inv = np.unique(self.groups, return_inverse=True)
        G = int(inv.max()) + 1
        if G < 3:
            return cov, None
        per_recording = np.zeros((G, scores.shape[1]))
        np.add.at(per_recording, inv, scores)
        return _widened(cov, np.diag(_sandwich(Hinv, per_recording))), G - 1

    def _scores(self) -> tuple[np.ndarray, np.ndarray]:
        """(H^-1 (P, P), per-window scores (W, P)) of the problem with the window states projected out."""
        r, Jp = self.projected()
        H = np.einsum("wlp,wlq->pq", Jp, Jp)
        Hinv = np.linalg.pinv(H if self.prior is None else H + np.diag(self.prior.precision))
        return Hinv, np.einsum("wlp,wl->wp", Jp, r)

    def _covariance(self, Hinv: np.ndarray, scores: np.ndarray) -> np.ndarray:
        """Gauss-Newton scaled by chi2_red, per parameter widened to the window-cluster sandwich where that is larger
        (robust to autocorrelated misfit)."""
        return _widened(Hinv * max(self.chi2_red, 1.0), np.diag(_sandwich(Hinv, scores)))


def _sandwich(Hinv: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """The cluster-robust covariance H^-1 (S^T S) H^-1 of per-cluster scores S (G, P), with the G / (G - 1)
    correction."""
    G = scores.shape[0]
    return Hinv @ (scores.T @ scores * (G / max(G - 1, 1))) @ Hinv


def _widened(cov: np.ndarray, var: np.ndarray) -> np.ndarray:
    """``cov`` with each parameter's variance raised to ``var`` where that is larger (correlations kept). Variances
    that round-off in a near-singular inverse left at or below zero count as zero: such a parameter takes ``var``
    (clipped at zero) with no correlations."""
    d = np.clip(np.diag(cov), 0.0, None)
    target = np.maximum(np.clip(var, 0.0, None), d)
    ok = d > 0
    scale = np.where(ok, np.sqrt(target / np.where(ok, d, 1.0)), 0.0)
    out = cov * np.outer(scale, scale)
    flat = np.flatnonzero(~ok)
    out[flat, flat] = target[flat]
    return out


def _perturbed(build: Callable[[np.ndarray], System], g: np.ndarray, g_step: float) -> list[System]:
    """The systems at g with each component in turn stepped by ``g_step`` (forward differences)."""
    out = []
    for j in range(g.size):
        gp = g.copy()
        gp[j] += g_step
        out.append(build(gp))
    return out


class Normal(NamedTuple):
    """The arrow-shaped Gauss-Newton normal equations of shooting: per-window blocks A = JX^T JX (W, 2n, 2n) and
    B = JX^T Jg (W, 2n, P), the global block C = Jg^T Jg (P, P), the gradients gx = JX^T r (W, 2n) and gg = Jg^T r."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    gx: np.ndarray
    gg: np.ndarray

    @classmethod
    def of(cls, JX: np.ndarray, Jg: np.ndarray, r: np.ndarray) -> Normal:
        return cls(np.einsum("wla,wlb->wab", JX, JX), np.einsum("wla,wlp->wap", JX, Jg),
                   np.einsum("wlp,wlq->pq", Jg, Jg),
                   np.einsum("wla,wl->wa", JX, r), np.einsum("wlp,wl->p", Jg, r))

    def with_prior(self, prior: Prior | None, g: np.ndarray) -> Normal:
        """The normal equations with ``prior``'s penalty at ``g`` added (its curvature and gradient)."""
        if prior is None:
            return self
        return self._replace(C=self.C + np.diag(prior.precision), gg=self.gg + prior.precision * (g - prior.center))


def _damped_step(normal: Normal, lam: float) -> tuple[np.ndarray, np.ndarray]:
    """The Levenberg-Marquardt step (dx (W, 2n), dg (P,)) at damping ``lam``, the window states eliminated window by
    window (Schur complement of the arrow-shaped normal equations)."""
    A, B, C, gx, gg = normal
    P = C.shape[0]
    Ad = A + lam * (np.diagonal(A, axis1=1, axis2=2)[..., None] * np.eye(A.shape[1]) + 1e-12 * np.eye(A.shape[1]))
    Ainv = np.linalg.inv(Ad)
    if not P:
        return -np.einsum("wab,wb->wa", Ainv, gx), np.zeros(0)
    Cd = C + lam * np.diag(np.diag(C)) + 1e-12 * np.eye(P)
    AiB = np.einsum("wab,wbp->wap", Ainv, B)
    S = Cd - np.einsum("wap,waq->pq", B, AiB)
    rhs = -gg + np.einsum("wap,wa->p", AiB, gx)
    dg = np.linalg.lstsq(S, rhs, rcond=None)[0]
    return -np.einsum("wab,wb->wa", Ainv, gx + np.einsum("wbp,p->wb", B, dg)), dg


class FitCheck(Protocol):
    """Told every fit's final model (:class:`.mujoco_sim.StepCheck`)."""

    def measure(self, shooter: Shooter, system: System, X: np.ndarray, r: np.ndarray) -> None: ...


@dataclass
class Heartbeat:
    """A progress line during a long computation (a shooting fit, the weak form's parameter check): :meth:`due` says
    when the next one is owed (``every`` seconds after the last, checked between the computation's steps, so a line
    comes at most a step later: 20 s keeps the gaps under the 30 s a user is promised), :attr:`say` writes it."""

    say: Callable[[str], None]
    every: float = 20.0
    last: float = field(default_factory=time.monotonic)

    def mark(self, text: str) -> None:
        """A line now, at a stage's start, and the next one owed ``every`` seconds later."""
        self.say(text)
        self.last = time.monotonic()

    def due(self) -> bool:
        now = time.monotonic()
        if now - self.last < self.every:
            return False
        self.last = now
        return True


class Shooter:
    """Standardized shooting residuals of a model family ``build(g) -> System`` on windows."""

    def __init__(self, windows: Windows, sigma: np.ndarray, substeps: int, x_scale: np.ndarray) -> None:
        self.w = windows
        self.sigma = np.asarray(sigma, dtype=float)
        self.substeps = substeps
        self.x_scale = np.asarray(x_scale, dtype=float)  # (2n,) typical |q|, |qdot|
        self.n = windows.q.shape[2]
        self.n_sims = 0
        self._tb_w: Windows | None = None  # windows the cached time base belongs to
        self._tb: tuple = ()
        self.heartbeat: Heartbeat | None = None  # progress lines during long fits
        #: MuJoCo-simulated systems at most this many steps an interval (:func:`simulate_qv`; None: the file's step)
        self.engine_substeps: int | None = None
        self.step_check: FitCheck | None = None  # where fits at a coarser step report their departure
        self.scaled_stop = True  # convergence in chi^2 units scaled by chi2/dof (False: a score's state fit, in noise)

    def _time_base(self) -> tuple[float | np.ndarray, int | np.ndarray]:
        """(dt, substeps) for simulate_qv: the scalar ones when the windows are uniform, else the recorded
        steps with per-interval counts that keep every substep within dt / substeps (a gap gets more)."""
        w = self.w
        if w.steps is None:
            return w.dt, self.substeps
        if self._tb_w is not w:
            longest = w.steps.max(axis=0) if w.count else np.full(w.length - 1, w.dt)
            k = np.maximum(1, np.ceil(self.substeps * longest / w.dt - 1e-9)).astype(int)
            self._tb_w, self._tb = w, (w.steps, k)
        return self._tb

    def residual(self, system: System, X: np.ndarray) -> np.ndarray:
        """(W, n_obs*n) standardized residuals at the compared samples (huge where the simulation blew up)."""
        return self._residuals(system, X[None])[0]

    def _residuals(self, system: System, Xs: np.ndarray) -> np.ndarray:
        """(K, W, n_obs*n) residuals of K sets of window states, simulated as one batch of K*W samples.

        Every sample is integrated on its own (elementwise arithmetic, crossings split per sample), so
        each set's residual equals the one :meth:`residual` gives; one batch saves K-1 passes of the
        per-step Python loop, which dominates at the window counts used here.
        """
        n, w = self.n, self.w
        K = Xs.shape[0]
        self.n_sims += K
        X = Xs.reshape(-1, 2 * n)
        dt, sub = self._time_base()
        if np.ndim(dt) == 2 and K > 1:
            dt = np.tile(dt, (K, 1))
        u = w.u if w.u is None or K == 1 else np.tile(w.u, (K, 1, 1))
        ub = w.u_before if w.u_before is None or K == 1 else np.tile(w.u_before, (K, 1, 1))
        sim = simulate_qv(system, X[:, :n], X[:, n:], w.length - 1, u, dt, sub, ub,
                          engine_substeps=self.engine_substeps)
        sim = sim.reshape((K, -1) + sim.shape[1:])
        if w.stride == 1:
            d = angle_diff(sim, w.q[None], w.angle_dims) / self.sigma
        else:
            obs = w.obs
            d = angle_diff(sim[:, :, obs], w.q[None][:, :, obs], w.angle_dims) / self.sigma
        d = np.where(np.isfinite(d), d, 1e6)
        return np.clip(d, -1e6, 1e6).reshape(K, d.shape[1], -1)

    def _state_steps(self, X: np.ndarray, with_base: bool) -> tuple[np.ndarray, np.ndarray]:
        """The window states X perturbed by a forward-difference step h in each of the 2n directions, (2n, W, 2n)
        (preceded by X itself when ``with_base``), and h (2n,)."""
        h = 1e-6 * np.maximum(self.x_scale, 1e-8) + 1e-9
        k = int(with_base)
        Xs = np.repeat(X[None], 2 * self.n + k, axis=0)
        Xs[k + np.arange(2 * self.n), :, np.arange(2 * self.n)] += h[:, None]
        return Xs, h

    def jac_X(self, system: System, X: np.ndarray, r0: np.ndarray) -> np.ndarray:
        """(W, L*n, 2n) forward-difference Jacobian w.r.t. each window's own state (all windows and all
        2n directions in one batch)."""
        Xs, h = self._state_steps(X, with_base=False)
        R = self._residuals(system, Xs)  # (2n, W, L*n)
        return np.moveaxis((R - r0[None]) / h[:, None, None], 0, -1)

    def residual_and_jac_X(self, system: System, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The residual at X and :meth:`jac_X` there, simulated as one batch of (2n + 1) W samples."""
        Xs, h = self._state_steps(X, with_base=True)
        R = self._residuals(system, Xs)
        return R[0], np.moveaxis((R[1:] - R[:1]) / h[:, None, None], 0, -1)

    def _jac_params(self, build: Callable[[np.ndarray], System], g: np.ndarray, X: np.ndarray, r: np.ndarray,
                    g_step: float) -> np.ndarray:
        """Forward-difference Jacobian of the residual w.r.t. the global parameters g: (..., P).

        The P perturbed systems are simulated as one batch of P*W samples when they merge
        (:func:`merge_systems`: per-sample parameter arrays, the same arithmetic per sample as P simulations).
        """
        if not g.size:
            return np.empty(r.shape + (0,))
        # contiguous (..., P) as the column-by-column fill gave: the normal equations' sums then round the same way
        R = self.residuals_of(_perturbed(build, g, g_step), X)
        return np.ascontiguousarray(np.moveaxis((R - r[None]) / g_step, 0, -1))

    def residuals_of(self, systems: Sequence[System], X: np.ndarray,
                     stand_ins: Sequence[System] | None = None) -> np.ndarray:
        """(K, W, L*n) residuals of K systems at the same window states X: one batch of K*W samples when the
        systems merge (and the merged vector field checks out at the windows' first samples), else one by one.

        ``stand_ins``: one system per system, all of one structure (every candidate term present, each but its own at
        no effect), merged in their place when they merge and give each system's vector field at those samples."""
        K, W = len(systems), X.shape[0]
        if K > 1 and W:
            Xs = np.repeat(X[None], K, axis=0)
            for group in ([stand_ins] if stand_ins is not None else []) + [systems]:
                R = self.residuals_each(group, Xs, reference=systems)
                if R is not None:
                    return R
        return np.stack([self.residual(s, X) for s in systems]) if K else np.empty((0, W, 0))

    def residuals_each(self, systems: Sequence[System], Xs: np.ndarray,
                       reference: Sequence[System] | None = None) -> np.ndarray | None:
        """(K, W, L*n) residuals of K systems, the k-th at its own window states ``Xs[k]``, as one batch of K*W
        samples; None when the systems do not merge, or the merged vector field differs from the ``reference``
        systems' (default: the systems themselves) at the windows' first samples."""
        K, W, n = len(systems), Xs.shape[1], self.n
        if K == 1 and reference is None:
            return self._residuals(systems[0], Xs)
        merged = merge_systems(systems, W) if W else None
        if merged is None:
            return None
        Xf = Xs.reshape(-1, 2 * n)
        q, v = [Xf[:, i] for i in range(n)], [Xf[:, n + i] for i in range(n)]
        u = None if self.w.u is None else [np.tile(self.w.u[:, 0, i], K) for i in range(n)]
        return self._residuals(merged, Xs) if merged_field_ok(merged, reference or systems, q, v, u) else None

    def linearize(self, build: Callable[[np.ndarray], System], system: System, g: np.ndarray, X: np.ndarray,
                  g_step: float, r: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(r, JX, Jg) at (X, g): the residual (simulated unless given), :meth:`jac_X` and the forward-difference
        parameter Jacobian, from one batch of (1 +) 2n + P simulations when the perturbed systems merge (the same
        numbers as separate calls: every sample is integrated on its own)."""
        P = g.size
        perturbed = _perturbed(build, g, g_step)
        Xs, h = self._state_steps(X, with_base=r is None)
        k = Xs.shape[0]
        R = self.residuals_each([system] * k + perturbed, np.concatenate([Xs, np.repeat(X[None], P, axis=0)])) \
            if P else self._residuals(system, Xs)
        if R is None:  # the systems do not merge: states in one batch, parameters one by one
            R = np.concatenate([self._residuals(system, Xs), self.residuals_of(perturbed, X)])
        if r is None:
            r = R[0]
        JX = np.moveaxis((R[k - 2 * self.n: k] - r[None]) / h[:, None, None], 0, -1)
        # contiguous (..., P) as the column-by-column fill gave: the normal equations' sums then round the same way
        Jg = np.ascontiguousarray(np.moveaxis((R[k:] - r[None]) / g_step, 0, -1)) if P else np.empty(r.shape + (0,))
        return r, JX, Jg

    #: Levenberg-Marquardt damping tries per iteration (lambda, 8 lambda, ..., 8^7 lambda), simulated in batches of
    #: these sizes: the first try alone (usually accepted), the next ones together (a converged fit rejects them all)
    LADDER = (1, 3, 4)

    def _lm_step(self, build: Callable[[np.ndarray], System], X: np.ndarray, g: np.ndarray, lam: float, cost: float,
                 normal: Normal, prior: Prior | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, System, float] | None:
        """The first of the damped steps ``lam 8^i`` (i = 0..7) that lowers the objective ``cost`` (with ``prior``'s
        penalty), as (X, g, r, objective, system, its lambda); the tries of one :data:`LADDER` rung are simulated as
        one batch.  None: none lowers it."""
        i = 0
        for rung in self.LADDER:
            lams = [lam * 8.0 ** (i + t) for t in range(rung)]
            i += rung
            trials = [_damped_step(normal, la) for la in lams]
            Xs = np.stack([X + dx for dx, _ in trials])
            gs = [g + dg for _, dg in trials]
            systems = [build(gn) for gn in gs]
            R = self.residuals_each(systems, Xs)
            if R is None:
                R = np.stack([self.residual(sn, Xn) for sn, Xn in zip(systems, Xs)])
            for t, la in enumerate(lams):
                cn = float(np.sum(R[t] ** 2)) + (0.0 if prior is None else prior.cost(gs[t]))
                if np.isfinite(cn) and cn < cost:
                    return Xs[t], gs[t], R[t], cn, systems[t], la
        return None

    def fit(self, build: Callable[[np.ndarray], System], X0: np.ndarray, g0: np.ndarray,
            max_iter: int = 25, tol: float = 1e-7, g_step: float = 1e-4, stats: bool = True,
            prior: Prior | None = None) -> ShootFit:
        """Levenberg-Marquardt on (window states, g) with Schur elimination of the states.  ``stats=False``: no
        Jacobians at the final point (JX and Jg come back with no columns), for a fit whose statistics are unused.
        ``prior``: a penalty on g added to the cost (:class:`Prior`)."""
        X, g = X0.copy(), np.asarray(g0, dtype=float).copy()
        system = build(g)
        r, JX, Jg = self.linearize(build, system, g, X, g_step)
        cost = float(np.sum(r**2)) + (0.0 if prior is None else prior.cost(g))  # the objective
        lam = 1e-3
        it = 0
        lin: tuple[np.ndarray, np.ndarray] | None = (JX, Jg)  # the Jacobians at the current point, when known
        started = time.monotonic()
        for it in range(1, max_iter + 1):  # noqa: B007
            if lin is None:
                lin = self.linearize(build, system, g, X, g_step, r)[1:]
            step = self._lm_step(build, X, g, lam, cost, Normal.of(*lin, r).with_prior(prior, g), prior)
            if step is None:
                break
            # converged when the gain is negligible in chi^2 units, scaled by chi^2/dof where model error leaves more
            # than noise (the intervals' scale: a value then moves by no visible share of its standard error)
            scale = max(1.0, cost / max(r.size, 1)) if self.scaled_stop else 1.0
            rel = 0.0 if cost - step[3] < 0.02 * scale else (cost - step[3]) / max(cost, 1e-300)
            X, g, r, cost, system, lam_used = step
            lam, lin = max(lam_used / 5, 1e-9), None
            if self.heartbeat is not None and self.heartbeat.due():
                per = (time.monotonic() - started) / it
                self.heartbeat.say(f"  shooting fit: iteration {it} of at most {max_iter}, chi2/dof "
                                   f"{float(np.sum(r**2)) / max(r.size, 1):.3g}, {per:.0f} s per iteration (at most "
                                   f"{per * (max_iter - it):.0f} s left)")
            if rel < tol:
                break
        if self.engine_substeps is not None and self.step_check is not None and self.w.count:
            self.step_check.measure(self, system, X, r)
        cost = float(np.sum(r**2))
        if not stats:
            return ShootFit(X, g, r, np.zeros(r.shape + (0,)), np.zeros(r.shape + (0,)), cost, r.size, it, self.w.traj,
                            prior)
        # Jacobians at the final point for statistics
        JX, Jg = lin if lin is not None else self.linearize(build, system, g, X, g_step, r)[1:]
        return ShootFit(X, g, r, JX, Jg, cost, r.size, it, self.w.traj, prior)

    def fit_states(self, system: System, X0: np.ndarray, max_iter: int = 25, in_basin: bool = False) -> ShootFit:
        """Window states only, by homotopy on the window length (short prefixes first): long windows have local
        minima (a pendulum seeded on the wrong side of the separatrix); fitting the first few samples first puts every
        window in the right basin before the whole window is used.  ``in_basin``: ``X0`` are states fitted to a model
        within per cent of this one (the whole window at once)."""
        X = X0.copy()
        L = self.w.length
        s = self.w.stride
        n_obs = len(self.w.obs)  # prefixes in compared samples (= samples at stride 1)
        lengths = [] if in_basin else sorted({min(L, 1 + s * (k - 1)) for k in (6, max(6, n_obs // 4),
                                                                                max(6, n_obs // 2))} - {L})
        full, check, self.step_check = self.w, self.step_check, None  # a prefix only starts the full fit, checked
        for k in lengths:
            self.w = full.prefix(k)
            X = self.fit(lambda g: system, X, np.zeros(0), max_iter=max_iter, stats=False).X
        self.w, self.step_check = full, check
        return self.fit(lambda g: system, X, np.zeros(0), max_iter=max_iter)

    def columns(self, builds: list[Callable[[], System]], fit: ShootFit, base_r: np.ndarray, h: list[float],
                stand_ins: list[Callable[[], System]] | None = None) -> np.ndarray:
        """(W, L*n, K) finite-difference columns of extra candidate directions at a fit (one batch when the
        K systems, or their ``stand_ins``, merge; see :meth:`residuals_of`)."""
        out = np.empty(base_r.shape + (len(builds),))
        R = self.residuals_of([b() for b in builds], fit.X, None if stand_ins is None else [b() for b in stand_ins])
        for k, hk in enumerate(h):
            out[..., k] = (R[k] - base_r) / hk
        return out
