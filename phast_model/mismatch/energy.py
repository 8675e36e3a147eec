"""The held-out energy check: does the dissipation found on the training recordings carry over?

Between two turning points a and b of a free (u = 0) oscillation the port-Hamiltonian power balance (paper Eq. 4,
dH/dt = -v^T D v) integrates to H(a) - H(b) = the energy the model dissipates over the stretch.  At turning points
v ~ 0, so H is the potential of the measured q (no differentiation), and the dissipated energy is a smooth average:
phase and frequency errors barely enter.  :func:`energy_check` compares the two per half-cycle, fitting nothing.
"""

from __future__ import annotations

import math
from typing import TypedDict

import numpy as np

from phast_gym.systems.base import NUMPY, System

from ..identify.recordings import Recordings
from ..identify.shooting import momentum, smooth
from .options import Z95


def _intervals(v: np.ndarray, margin: int, min_len: int) -> list[tuple[int, int]]:
    s = np.sign(v)
    z = np.where((s[:-1] != s[1:]) & (s[:-1] != 0))[0] + 1
    z = z[(z >= margin) & (z < len(v) - margin)]
    return [(int(a), int(b)) for a, b in zip(z[:-1], z[1:]) if b - a >= min_len]


def _energy_state(system: System, rec: Recordings, smoothing_window: int) -> tuple:
    """Smoothed (q, v) mapped through the inverse sensor map, q components, H, the model's dissipated power, and the
    coordinate whose turning points cut the record into half-cycles."""
    n = rec.n
    qs, vs = smooth(rec.q, rec.dt, smoothing_window)
    qs = getattr(system, "unmeasure", lambda y: y)(qs)
    p = momentum(system, qs, vs)
    qc = tuple(qs[..., i] for i in range(n))
    pc = tuple(p[..., i] for i in range(n))
    H = np.broadcast_to(system.hamiltonian(qc, pc, NUMPY), qs.shape[:-1])
    P = np.broadcast_to(system.power_balance(qc, pc, None, NUMPY)[0], qs.shape[:-1])
    j = int(np.argmax(np.sqrt(np.mean(vs**2, axis=(0, 1)))))
    return qs, vs, qc, H, P, j


class EnergyCheck(TypedDict):
    """:func:`energy_check`'s answer: measured over predicted energy loss, its 95% interval, per recording."""

    measured_over_predicted: float
    ci95: list[float]
    per_recording: list[float | None]
    n_half_cycles: int


def energy_check(system: System, rec: Recordings, smoothing_window: int,
                 min_intervals: int = 4) -> EnergyCheck | None:
    """Does ``system``'s dissipation account for the energy the recordings lose?  (A check, nothing is fitted.)

    Per half-cycle between turning points, measured loss H(a) - H(b) against the model's
    dissipated energy integral of v^T D v (+ the found friction) dt (paper Eq. 4).  Returns the ratio
    sum(measured) / sum(predicted) with a 95% interval (recording-cluster when there are >= 3
    recordings), and the ratio per recording.  A ratio away from 1 on held-out recordings while it is
    ~1 on the training ones says the dissipation law does not carry over (it changes with amplitude,
    time or conditions in a way the chosen terms do not describe).
    None when the balance cannot be formed (input u, no dissipation, too few half-cycles).
    """
    if rec.u is not None and np.any(rec.u != 0):
        return None
    dt = rec.dt
    _, vs, _, H, P, j = _energy_state(system, rec, smoothing_window)
    ys, ps, grp = [], [], []
    for tr in range(rec.n_traj):
        for a, b in _intervals(vs[tr, :, j], max(3, smoothing_window // 2), 4):
            ys.append(H[tr, a] - H[tr, b])
            ps.append(np.trapezoid(P[tr, a:b + 1], dx=dt))
            grp.append(tr)
    y, pr, g = np.asarray(ys), np.asarray(ps), np.asarray(grp)
    if len(y) < min_intervals or not float(np.sum(pr)) > 0:
        return None
    ratio = float(np.sum(y) / np.sum(pr))
    r = y - ratio * pr
    G = np.unique(g)
    if len(G) >= 3:  # ratio estimator, recording-cluster variance
        var = len(G) / (len(G) - 1) * sum(float(np.sum(r[g == k])) ** 2 for k in G) / float(np.sum(pr)) ** 2
    else:
        var = len(y) / max(len(y) - 1, 1) * float(np.sum(r**2)) / float(np.sum(pr)) ** 2
    sd = math.sqrt(max(var, 0.0))
    per = [float(np.sum(y[g == k]) / np.sum(pr[g == k])) if np.sum(pr[g == k]) > 0 else None for k in range(rec.n_traj)]
    return {"measured_over_predicted": ratio, "ci95": [ratio - Z95 * sd, ratio + Z95 * sd], "per_recording": per,
            "n_half_cycles": int(len(y))}
