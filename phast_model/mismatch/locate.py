"""Stage 3, locate: where the calibrated model's force residual lives (coordinate, component, state region, time).

The local residual force is d/dt p - F(q, qdot, u) with both sides passed
through the same filter (the momentum derivative and the smoothing of the model
force along the smoothed path; a :class:`~phast_model.identify.signals.Differentiator`,
the cubic Savitzky-Golay filter by default).  It only describes the
mismatch (and draws the residual map); nothing is fitted to it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from phast_gym.systems import wrap
from phast_gym.systems.base import System

from ..identify.recordings import Recordings
from ..identify.signals import SAVGOL, Differentiator
from ..identify.weakform import momentum_balance


def residual_force(system: System, rec: Recordings, smoothing_window: int, differentiator: Differentiator = SAVGOL
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, slice]:
    """(r, q, qdot, qddot, kept samples): the filtered residual force and the smoothed states, filter edges dropped."""
    d = differentiator
    w = d.fit_window(smoothing_window, rec.T)
    bal = momentum_balance(system, rec, w, d)
    qs, vs = bal.qs, bal.vs
    r = bal.dp - d.smooth(bal.pdot, w)
    e = w // 2
    sl = slice(e, rec.T - e) if rec.T > 2 * e + 10 else slice(None)
    a = d.derivative(rec.q, w, rec.dt, 2)[:, sl]
    return r[:, sl], qs[:, sl], vs[:, sl], a, sl


def _component_r2(groups: dict[str, list[np.ndarray]], ri: np.ndarray) -> dict[str, float]:
    """R^2 of the residual on each component's basis (least squares)."""
    r2 = {}
    for gname, cols in groups.items():
        Am = np.stack(cols, 1)
        coef = np.linalg.lstsq(Am, ri, rcond=None)[0]
        r2[gname] = max(0.0, 1.0 - float(np.sum((ri - Am @ coef) ** 2)) / (float(np.sum(ri**2)) + 1e-300))
    return r2


def _region(i: int, qi: np.ndarray, vi: np.ndarray, e_i: np.ndarray) -> tuple[str, float]:
    """The half of state space (by |qdot| or |q|, split at the median) where the squared residual concentrates, and its
    share."""
    vmed = float(np.median(np.abs(vi)))
    qmed = float(np.median(np.abs(qi)))
    regions = {
        f"abs(qdot{i}) < {vmed:.3g}": np.abs(vi) < vmed,
        f"abs(qdot{i}) >= {vmed:.3g}": np.abs(vi) >= vmed,
        f"abs(q{i}) < {qmed:.3g}": np.abs(qi) < qmed,
        f"abs(q{i}) >= {qmed:.3g}": np.abs(qi) >= qmed,
    }
    best, best_ratio, best_share = "everywhere", 1.0, 1.0
    for desc, mask in regions.items():
        frac = float(np.mean(mask))
        if frac <= 0:
            continue
        sh = float(np.sum(e_i[mask]) / (np.sum(e_i) + 1e-300))
        if sh / frac > best_ratio * 1.15:
            best, best_ratio, best_share = desc, sh / frac, sh
    return best, best_share


def _when(r_i: np.ndarray) -> str:
    """Which third of the recordings (and which trajectories) hold most of the squared residual (N, T)."""
    per_traj = np.sum(r_i**2, axis=1)
    per_traj = per_traj / (per_traj.sum() + 1e-300)
    th = np.array([float(np.sum(x)) for x in np.array_split(r_i**2, 3, axis=1)])
    th = th / (th.sum() + 1e-300)
    when = "throughout"
    if th.max() > 0.5:
        when = ["early (first third of each recording)", "middle third",
                "late (last third of each recording)"][int(np.argmax(th))]
    top = [int(k) for k in np.argsort(per_traj)[::-1][:3] if per_traj[k] > 2.0 / len(per_traj)]
    if top and len(per_traj) > 2:
        when += f"; largest in trajectories {top}"
    return when


def locate(system: System, rec: Recordings, smoothing_window: int, eps: float, share_floor: float = 0.1,
           differentiator: Differentiator = SAVGOL) -> tuple[list[dict], dict]:
    """Coordinates holding at least ``share_floor`` of the residual: component, region, time (largest share first),
    and the residual map data {"q", "v", "r"} (``differentiator``: the filter, default cubic Savitzky-Golay)."""
    r, qv, vv, a, sl = residual_force(system, rec, smoothing_window, differentiator)
    total = float(np.sum(r**2)) + 1e-300
    located: list[dict[str, Any]] = []
    for i in range(rec.n):
        ri = r[..., i].reshape(-1)
        qi = qv[..., i].reshape(-1)
        if i in rec.angle_dims:
            qi = wrap(qi)
        vi = vv[..., i].reshape(-1)
        share_i = float(np.sum(ri**2)) / total
        if share_i < share_floor:
            continue
        groups = {
            "dissipation": [vi, np.tanh(vi / eps), np.abs(vi) * vi],
            "potential": [np.ones_like(qi), qi, qi**3] + ([np.sin(qi), np.cos(qi)] if i in rec.angle_dims else []),
            "inertia": [a[..., i].reshape(-1)],
        }
        if rec.u is not None and np.any(rec.u[..., i] != 0):
            groups["port"] = [np.concatenate([rec.u, rec.u[:, -1:]], axis=1)[:, sl][..., i].reshape(-1)]
        r2 = _component_r2(groups, ri)
        where, where_share = _region(i, qi, vi, ri**2)
        diss = float(np.mean(ri * vi))
        located.append({"coordinate": i, "component": max(r2, key=lambda k: r2[k]), "where": where,
                        "when": _when(r[..., i]),
                        "share": round(share_i * where_share, 4), "residual_power": diss,
                        "removes_energy": bool(diss < 0),
                        "component_r2": {k: round(v, 4) for k, v in r2.items()}})
    located.sort(key=lambda d: -d["share"])
    return located, {"q": qv, "v": vv, "r": r}
