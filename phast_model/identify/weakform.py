"""The weak form of the momentum balance: the total dissipative force f~ the recordings ask of a model.

The momentum balance of a port-Hamiltonian model, d/dt p = F_cons(q, p) + u - f(q, qdot), with F_cons = -dH/dq and
f the *total* dissipative generalized force (the model's own D(q) qdot plus whatever it leaves out), is used in
weak form: one smooth filter (a :class:`~phast_model.identify.signals.Differentiator`, by default the cubic
Savitzky-Golay
filter, window ``window`` samples) is applied to both sides,

    f~(t) = [S * (F_cons + u)](t) - d/dt [S * p](t),

so the noisy second derivative of q never appears alone and a law's force is compared after the *same* filter
(``S * f_law``).  p = M(q) qdot through the system's own mass matrix (:func:`.shooting.momentum`), q and qdot from the
same filter, u the recorded port force held over each interval.  Everything here is per coordinate (friction is
diagonal, as in the mismatch tool's vocabulary).

It lives in the shared identification layer (``identify``) because it fits nothing: the mismatch tool's friction laws,
weak-form
identification and residual map build on it, and so does the rig path's friction check (through
:mod:`.frictioncurve`).  A system with friction terms of its own beyond D(q) (the mismatch tool's augmented model)
declares them through :class:`ExtraDissipation`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Protocol, runtime_checkable

import numpy as np

from phast_gym.systems.base import NUMPY, ArrayNamespace, Components, System

from .recordings import Recordings
from .shooting import momentum, odd, smooth, time_scale
from .signals import SAVGOL, Differentiator

#: tanh smoothing of sign(qdot), relative to the rms velocity (the mismatch tool's ``Options.coulomb_eps_rel``)
SIGN_SMOOTHING_REL = 0.005


@runtime_checkable
class ExtraDissipation(Protocol):
    """A system with dissipative forces beyond its D(q) qdot (the mismatch tool's ``AugmentedSystem``: its friction
    terms), and the tanh smoothing of sign(qdot) they use."""

    coulomb_eps: float

    def extra_dissipation(self, q: Components, v: Components, xp: ArrayNamespace) -> list: ...


@dataclass(frozen=True)
class WeakFilter:
    """The weak form's filter: window [samples], sample time, tanh smoothing of sign(qdot), trimmed edge, and the
    smoothing / differentiation (the cubic Savitzky-Golay filter by default)."""

    window: int
    dt: float
    eps: float
    trim: int
    differentiator: Differentiator = SAVGOL


@dataclass
class WeakForm:
    """Filtered momentum balance of recordings under a system (edges of the filter trimmed).

    Arrays are (N, T', n): ``qs``, ``vs`` the smoothed state, ``total`` the filtered total dissipative force f~
    (positive along +qdot means it decelerates +qdot motion), ``own`` the filtered dissipative force of the model
    itself (D(q) qdot plus the friction terms of an :class:`ExtraDissipation` system).  ``blocks`` (N, T') cluster
    labels."""

    qs: np.ndarray
    vs: np.ndarray
    total: np.ndarray
    own: np.ndarray
    blocks: np.ndarray
    filter: WeakFilter
    q_raw: np.ndarray = field(repr=False)  # (N, T, n) smoothed untrimmed (for filtering law forces)
    v_raw: np.ndarray = field(repr=False)
    carried: np.ndarray = field(repr=False)  # (N, T', n) filtered conservative + port force, trimmed

    @property
    def n(self) -> int:
        return self.qs.shape[2]

    @property
    def window(self) -> int:
        return self.filter.window

    @property
    def dt(self) -> float:
        return self.filter.dt

    @property
    def eps(self) -> float:
        return self.filter.eps

    @property
    def trim(self) -> int:
        return self.filter.trim

    def subset(self, idx: np.ndarray) -> WeakForm:
        """The weak form of the recordings ``idx`` alone: the filters run along each recording, so these are the
        numbers :func:`weak_form` gives on them (only the cluster labels keep the whole set's block length)."""
        return replace(self, qs=self.qs[idx], vs=self.vs[idx], total=self.total[idx], own=self.own[idx],
                       blocks=self.blocks[idx], q_raw=self.q_raw[idx], v_raw=self.v_raw[idx], carried=self.carried[idx])

    def filt(self, x: np.ndarray) -> np.ndarray:
        """The weak-form filter S along time of an untrimmed (N, T, ...) array, then trimmed."""
        y = self.filter.differentiator.smooth(x, self.window)
        return y[:, self.trim: x.shape[1] - self.trim]


def own_dissipation(system: System, qc: tuple, v: np.ndarray) -> np.ndarray:
    """The model's dissipative force (positive opposes motion): D(q) qdot (+ the friction terms of an
    :class:`ExtraDissipation` system)."""
    shape = v.shape[:-1]
    d = system.damping(qc, NUMPY)
    own = np.stack([np.broadcast_to(np.asarray(d[i], dtype=float), shape) * v[..., i] for i in range(v.shape[-1])], -1)
    if isinstance(system, ExtraDissipation):
        extra = system.extra_dissipation(qc, tuple(v[..., i] for i in range(v.shape[-1])), NUMPY)
        own = own - np.stack([np.broadcast_to(np.asarray(e, dtype=float), shape) for e in extra], -1)
    return own


def smoothing_window(period: float, dt: float) -> int:
    """The Savitzky-Golay window [samples] of the tool (seeds, residual map, weak form): 0.15 of an oscillation period,
    odd, >= 7."""
    return odd(max(7, int(round(0.15 * period / dt))))


def sign_smoothing(v_rms: np.ndarray, rel: float = SIGN_SMOOTHING_REL) -> float:
    """The tanh smoothing of sign(qdot) for all coordinates: ``rel`` x the median of the coordinates' rms speeds."""
    return float(rel * np.median(v_rms))


def rms_speed(vs: np.ndarray) -> np.ndarray:
    """(n,) rms of smoothed qdot (N, T, n) per coordinate (never 0)."""
    return np.sqrt(np.mean(vs**2, axis=(0, 1))) + 1e-12


def default_window(rec: Recordings, differentiator: Differentiator = SAVGOL) -> int:
    """Filter window [samples]: 0.15 of an oscillation period, as the mismatch tool smooths (>= 7)."""
    return smoothing_window(2 * math.pi * time_scale(rec.q, rec.dt, differentiator), rec.dt)


def default_eps(rec: Recordings, window: int, differentiator: Differentiator = SAVGOL) -> float:
    """tanh smoothing of sign(qdot), as the mismatch tool smooths (``Options.coulomb_eps_rel``)."""
    _, vs = smooth(rec.q, rec.dt, window, differentiator=differentiator)
    return sign_smoothing(rms_speed(vs))


def _block_labels(N: int, T: int, block: int) -> np.ndarray:
    """(N, T) cluster label: recording x consecutive time block of ``block`` samples (a short tail joins the last)."""
    nb = max(1, T // max(block, 1))
    b = np.minimum(np.arange(T) // max(block, 1), nb - 1)
    return np.arange(N)[:, None] * nb + b[None, :]


@dataclass
class Balance:
    """The momentum balance along the smoothed recordings, untrimmed (N, T, n): q, qdot, d/dt S*p and the model's
    pdot."""

    qs: np.ndarray
    vs: np.ndarray
    dp: np.ndarray
    pdot: np.ndarray

    @property
    def qc(self) -> tuple:
        return tuple(self.qs[..., i] for i in range(self.qs.shape[-1]))


def momentum_balance(system: System, rec: Recordings, window: int, differentiator: Differentiator = SAVGOL) -> Balance:
    """Smoothed q, qdot (measurement map undone), d/dt of the filtered momentum p = M(q) qdot, and the model's pdot
    (conservative, port and dissipative force) at those states with the recorded u held per interval (the mean of
    the two intervals that meet at each sample)."""
    n, dt = rec.n, rec.dt
    qs, vs = smooth(rec.q, dt, window, differentiator=differentiator)
    qs = getattr(system, "unmeasure", lambda y: y)(qs)
    p = momentum(system, qs, vs)
    dp = differentiator.derivative(p, window, dt, 1)
    qc, pc = tuple(qs[..., i] for i in range(n)), tuple(p[..., i] for i in range(n))

    def force(u: np.ndarray | None) -> np.ndarray:
        comps = None if u is None else tuple(u[..., i] for i in range(n))
        return np.stack([np.broadcast_to(f, qs.shape[:-1]) for f in system.rhs(qc, pc, comps, NUMPY)[1]], -1)

    if rec.u is None:
        return Balance(qs, vs, dp, force(None))
    # u_k is held over [t_k, t_k+1): around sample k the force is u_k-1 half the time and u_k the other half, so the
    # filtered balance takes their mean (u_k alone would shift the input by half a sample: under a stiff PD
    # controller, a damping of Kp dt / 2)
    after = np.concatenate([rec.u, rec.u[:, -1:]], axis=1)
    before = np.concatenate([rec.u[:, :1], rec.u], axis=1)
    return Balance(qs, vs, dp, 0.5 * (force(after) + force(before)))


def weak_form(system: System, rec: Recordings, window: int | None = None, eps: float | None = None,
              block: int | None = None, differentiator: Differentiator = SAVGOL) -> WeakForm:
    """The filtered momentum balance of ``rec`` under ``system`` (see the module docstring).

    ``block``: cluster length [samples] for intervals (default: the larger of 2 oscillation periods and 5 windows;
    each recording is cut into such blocks; with many recordings one may pass ``block=rec.T`` for recording clusters).
    ``differentiator``: the filter S and its derivative (default the cubic Savitzky-Golay filter)."""
    d = differentiator
    window = odd(window or default_window(rec, d))
    window = min(window, odd(rec.T // 3))
    eps = float(eps if eps is not None else (system.coulomb_eps if isinstance(system, ExtraDissipation)
                                             else default_eps(rec, window, d)))
    dt = rec.dt
    bal = momentum_balance(system, rec, window, d)
    qs, vs, dp = bal.qs, bal.vs, bal.dp
    own = own_dissipation(system, bal.qc, vs)
    cons = bal.pdot + own  # conservative + port force (the model's dissipation added back)
    tr = window // 2
    sl = slice(tr, rec.T - tr)
    carried_f = d.smooth(cons, window)[:, sl]
    total = carried_f - dp[:, sl]
    own_f = d.smooth(own, window)[:, sl]
    if block is None:
        period = 2 * math.pi * time_scale(rec.q, dt, d)
        block = max(int(round(2 * period / dt)), 5 * window)
    Tt = rec.T - 2 * tr
    return WeakForm(qs[:, sl], vs[:, sl], total, own_f, _block_labels(rec.n_traj, Tt, int(block)),
                    WeakFilter(window, dt, eps, tr, d), qs, vs, carried_f)

