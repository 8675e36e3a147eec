"""Signal preparation of recordings: noise level, time scale, and smoothing / differentiation of q.

Shared by the mismatch tool and the rig path of the world model; nothing here fits a model.

The smoothing and differentiation are one swappable object, as in PySINDy's ``pysindy.differentiation``: a
:class:`Differentiator` (:meth:`~Differentiator.smooth`, :meth:`~Differentiator.derivative` and its window rule
:meth:`~Differentiator.fit_window`).  The default, :data:`SAVGOL`, is a cubic :class:`SavitzkyGolay` filter; every
function here and the weak form (:mod:`phast_model.identify.weakform`), the weak-form identification and the
residual map take another one through their ``differentiator`` argument.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from scipy.signal import savgol_filter


def odd(k: int) -> int:
    """``k`` rounded up to an odd number (a Savitzky-Golay window)."""
    k = int(k)
    return k if k % 2 else k + 1


@runtime_checkable
class Differentiator(Protocol):
    """Smooths and differentiates uniformly sampled signals along one axis with a window of ``window`` samples."""

    def fit_window(self, window: int, T: int) -> int:
        """The window used for a requested ``window`` on ``T`` samples."""
        ...

    def smooth(self, x: np.ndarray, window: int, axis: int = 1) -> np.ndarray:
        """``x`` smoothed along ``axis`` (same shape)."""
        ...

    def derivative(self, x: np.ndarray, window: int, dt: float, order: int = 1, axis: int = 1) -> np.ndarray:
        """The ``order``-th time derivative of ``x`` along ``axis`` (sample time ``dt``), smoothed like
        :meth:`smooth`."""
        ...


@dataclass(frozen=True)
class SavitzkyGolay:
    """The Savitzky-Golay filter (local least-squares polynomials of degree ``polyorder``), edges fitted (``interp``).

    Window rule (:meth:`fit_window`): odd, at least ``polyorder + 2`` (5 for the cubic default) and at most the
    largest odd number <= T."""

    polyorder: int = 3
    mode: str = "interp"

    @property
    def min_window(self) -> int:
        return odd(self.polyorder + 2)

    def fit_window(self, window: int, T: int) -> int:
        return odd(min(max(window, self.min_window), T - (1 - T % 2)))

    def smooth(self, x: np.ndarray, window: int, axis: int = 1) -> np.ndarray:
        return savgol_filter(x, window, self.polyorder, axis=axis, mode=self.mode)

    def derivative(self, x: np.ndarray, window: int, dt: float, order: int = 1, axis: int = 1) -> np.ndarray:
        return savgol_filter(x, window, self.polyorder, deriv=order, delta=dt, axis=axis, mode=self.mode)


#: the default differentiator: the cubic Savitzky-Golay filter
SAVGOL = SavitzkyGolay()


def estimate_noise(q: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
    """Per-coordinate white-noise std of q (N, T, n) from 4th differences (robust MAD).

    For white noise e, var(Delta^4 e) = 70 sigma^2; a smooth signal contributes
    dt^4 q'''' which is negligible at the sampling rates of encoders and cameras.
    ``t`` (N, T): recorded times when they are not uniform; the 4th divided differences (which
    annihilate cubics on any grid), scaled to unit noise gain, then replace Delta^4 / sqrt(70):
    plain differences of a moving signal at jittered times would count the jitter as noise.
    """
    if t is not None:
        d = np.diff(t, axis=1)
        med = float(np.median(d))
        if np.max(np.abs(d - med)) > 1e-3 * med:
            t = np.asarray(t, dtype=float)
            T = t.shape[1]
            tt = np.stack([t[:, j: T - 4 + j] for j in range(5)], -1)  # (N, T-4, 5) five consecutive times
            c = np.ones(tt.shape)
            for j in range(5):
                for k in range(5):
                    if k != j:
                        c[..., j] /= (tt[..., j] - tt[..., k]) / med
            c /= np.linalg.norm(c, axis=-1, keepdims=True)
            qq = np.stack([q[:, j: T - 4 + j] for j in range(5)], -1)  # (N, T-4, n, 5)
            d4 = np.einsum("ntij,ntj->nti", qq, c).reshape(-1, q.shape[2])
            return 1.4826 * np.median(np.abs(d4 - np.median(d4, axis=0)), axis=0)
    d4 = np.diff(q, n=4, axis=1).reshape(-1, q.shape[2])
    mad = np.median(np.abs(d4 - np.median(d4, axis=0)), axis=0)
    return 1.4826 * mad / math.sqrt(70.0)


def time_scale(q: np.ndarray, dt: float, differentiator: Differentiator = SAVGOL) -> float:
    """Characteristic time tau (1/omega of an oscillation): the smaller of rms(q - trend)/rms(qdot)
    and rms(qdot)/rms(qddot), so rotating or drifting coordinates do not inflate it."""
    win = odd(max(7, min(q.shape[1] // 4, 31)))
    v = differentiator.derivative(q, win, dt, 1)
    a = differentiator.derivative(q, win, dt, 2)
    t = np.arange(q.shape[1]) - (q.shape[1] - 1) / 2
    slope = np.sum(q * t[None, :, None], axis=1, keepdims=True) / np.sum(t**2)
    qc = q - q.mean(axis=1, keepdims=True) - slope * t[None, :, None]
    rq = np.sqrt(np.mean(qc**2, axis=(0, 1)))
    rv = np.sqrt(np.mean(v**2, axis=(0, 1)))
    ra = np.sqrt(np.mean(a**2, axis=(0, 1)))
    cands = [rq[i] / rv[i] for i in range(q.shape[2]) if rv[i] > 1e-12]
    cands += [rv[i] / ra[i] for i in range(q.shape[2]) if ra[i] > 1e-12 and rv[i] > 1e-12]
    if not cands:
        return dt * q.shape[1] / 4
    return float(np.clip(min(cands), 2 * dt, dt * q.shape[1]))


def smooth(q: np.ndarray, dt: float, window: int, t: np.ndarray | None = None,
           differentiator: Differentiator = SAVGOL) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed q and qdot along time, (N, T, n) each (the cubic Savitzky-Golay filter by default; ``window`` fitted
    to the recordings by the differentiator's window rule).

    ``t`` (N, T): recorded sample times when they are not uniform; q is then interpolated (cubic spline)
    onto the uniform grid of step dt for the filter and the results are interpolated back to the recorded times.
    """
    if t is not None:
        d = np.diff(t, axis=1)
        if np.max(np.abs(d - dt)) > 1e-3 * dt:
            return _smooth_jittered(q, dt, window, np.asarray(t, dtype=float), differentiator)
    window = differentiator.fit_window(window, q.shape[1])
    return differentiator.smooth(q, window), differentiator.derivative(q, window, dt, 1)


def _smooth_jittered(q: np.ndarray, dt: float, window: int, t: np.ndarray,
                     differentiator: Differentiator) -> tuple[np.ndarray, np.ndarray]:
    from scipy.interpolate import CubicSpline

    qs, vs = np.empty_like(q), np.empty_like(q)
    for i in range(q.shape[0]):
        ti = t[i]
        grid = ti[0] + np.arange(int(np.floor((ti[-1] - ti[0]) / dt + 1e-9)) + 1) * dt
        qg = CubicSpline(ti, q[i], axis=0)(grid)[None]
        a, b = smooth(qg, dt, window, differentiator=differentiator)
        # back to the recorded times (the grid ends up to one step before the last recorded time: extrapolate)
        qs[i] = CubicSpline(grid, a[0], axis=0)(ti)
        vs[i] = CubicSpline(grid, b[0], axis=0)(ti)
    return qs, vs


