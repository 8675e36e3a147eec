"""Delays between the recorded signals and the physics: an input (actuator) delay and a sensor delay, in seconds.

Both shift a sampled signal in time by a fraction of a sample, by linear interpolation between samples, batched over
samples and coordinates (no per-sample Python loop):

* **input delay** ``d``: the port delivers ``u(t - d)``.  The recorded u is held over each interval (zero-order hold);
  the delayed hold switches ``d`` after each sample, and its average over an interval is the linear interpolation of
  the recorded sequence at ``k - d / dt`` (weights ``1 - f`` and ``f`` on the samples ``k - m`` and ``k - m - 1``,
  ``d / dt = m + f``).  That average is what :func:`shift` gives and what the simulation holds over the interval (one
  value per interval, as the recorded u): exact for a whole number of samples, and a second-order error in q over an
  interval otherwise.  The samples before a window's start come from the recording (``u_before``,
  :data:`HISTORY` of them; the first sample held before a recording's start).
* **sensor delay** ``d`` on coordinate i: the sensor reports ``q_i(t - d)``: the simulated q at ``t_k - d``, linearly
  interpolated between simulated samples; before the window's first sample, extrapolated back along its initial
  velocity (``q0 - v0 s``).

A delay is clipped to ``[0, MAX_DELAY_SAMPLES]`` samples of the recording (5; docs/mismatch.md states the bound).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeAlias

import numpy as np

#: samples of recorded input kept before each shooting window (the longest input delay is one fewer)
HISTORY = 6
#: the longest delay a term may take, in samples of the recording (docs/mismatch.md: 5 samples, 50 ms at 100 Hz)
MAX_DELAY_SAMPLES = HISTORY - 1

#: per-coordinate delays [s]: floats, or per-sample arrays of a merged system
Delays: TypeAlias = Sequence["float | np.ndarray"]

__all__ = ["HISTORY", "MAX_DELAY_SAMPLES", "any_delay", "history", "shift", "delay_samples"]


def any_delay(delays: Delays) -> bool:
    """Whether any per-coordinate delay (floats, or per-sample arrays of a merged system) is non-zero."""
    return any(np.any(np.asarray(d) != 0) for d in delays)


def history(u: np.ndarray, traj: np.ndarray, start: np.ndarray, count: int = HISTORY) -> np.ndarray:
    """(W, count, m) the ``count`` inputs of recordings ``u`` (N, T-1, m) before each window (trajectory ``traj``,
    first sample ``start``), oldest first; before a recording's first sample its first input is held."""
    idx = np.clip(np.asarray(start)[:, None] - count + np.arange(count)[None, :], 0, None)
    return u[np.asarray(traj)[:, None], idx]


def delay_samples(delays: Delays, steps: float | np.ndarray, B: int, K: int) -> np.ndarray:
    """(B, K, n) each coordinate's delay in samples of the local step ``steps`` (a scalar, (K,) or (B, K))."""
    d = np.stack([np.broadcast_to(np.asarray(di, dtype=float), (B,)) for di in delays], -1)[:, None, :]  # (B, 1, n)
    h = np.asarray(steps, dtype=float)
    if h.ndim == 1:
        h = h[None, :]
    h = h[..., None] if h.ndim == 2 else h
    return np.broadcast_to(d / h, (B, K, len(delays)))


def shift(x: np.ndarray, before: np.ndarray, s: np.ndarray) -> np.ndarray:
    """x (B, K, n) read at the fractional index ``k - s`` (s (B, K, n) samples, clipped to [0, P]) by linear
    interpolation; indices before 0 read ``before`` (B, P, n), its last sample at index -1.  s = 0 returns x exactly."""
    B, K, n = x.shape
    P = before.shape[1]
    s = np.clip(s, 0.0, float(P))
    m = np.floor(s)
    f = s - m
    ext = np.concatenate([before, x], axis=1)  # index k of x is P + k of ext
    i0 = (np.arange(K)[None, :, None] + P - m).astype(int)
    i1 = np.maximum(i0 - 1, 0)
    a = np.take_along_axis(ext, i0, axis=1)
    b = np.take_along_axis(ext, i1, axis=1)
    return a + f * (b - a)


def delayed_input(u: np.ndarray, delays: Delays, steps: float | np.ndarray,
                  u_before: np.ndarray | None) -> np.ndarray:
    """The port input actually delivered over each interval: u (B, K, n) delayed per coordinate by ``delays`` [s]
    (module docstring); ``u_before`` (B, P, n) the recorded inputs before the first interval (None: u[:, 0] held)."""
    B, K, n = u.shape
    if not any_delay(delays):
        return u
    before = np.repeat(u[:, :1], HISTORY, axis=1) if u_before is None else np.asarray(u_before, dtype=float)
    return shift(u, before, np.minimum(delay_samples(delays, steps, B, K), MAX_DELAY_SAMPLES))


def delayed_output(q: np.ndarray, v0: np.ndarray, delays: Delays, steps: float | np.ndarray) -> np.ndarray:
    """What a sensor with ``delays`` [s] per coordinate reports at the samples of a simulated q (B, K+1, n) that
    started at (q[:, 0], v0): q_i(t_k - d_i), interpolated; before the start extrapolated along v0."""
    B, K1, n = q.shape
    if not any_delay(delays):
        return q
    h = np.asarray(steps, dtype=float)
    if h.ndim == 0:
        h_out: float | np.ndarray = float(h)
        h0 = np.full((B, 1), float(h))
    else:
        hb = np.broadcast_to(h if h.ndim == 2 else h[None, :], (B, K1 - 1))
        h_out = np.concatenate([hb[:, :1], hb], axis=1)  # sample k's local step: the interval before it (k=0: after)
        h0 = hb[:, :1]
    back = (HISTORY - np.arange(HISTORY))[None, :, None] * h0[:, :, None]  # (B, P, 1) seconds before the start
    before = q[:, :1] - v0[:, None, :] * back
    return shift(q, before, np.minimum(delay_samples(delays, h_out, B, K1), MAX_DELAY_SAMPLES))
