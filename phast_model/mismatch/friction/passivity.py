"""Passivity of the total friction force and the band-by-band check of a law against the friction curve.

* :func:`is_passive`: the *total* force (own + law) opposes motion at every speed up to the largest observed one
  (a negative coefficient is allowed when the total stays passive; it is named).
* :func:`check_against_curve`: band by band, is the law inside the curve's interval?
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from phast_gym.systems.base import NUMPY

from ...identify.frictioncurve import FrictionCurve
from ..vocabulary.registry import VOCABULARY
from .laws import FrictionLaw


@dataclass
class Passivity:
    passive: bool
    # {"coordinate", "passive", "max_speed", "worst_speed", "min_force", "negative_terms"}
    per_coordinate: list[dict[str, Any]]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def is_passive(law: FrictionLaw, speeds: float | Sequence[float] | FrictionCurve, n_grid: int = 400,
               tol: float = 0.0) -> Passivity:
    """Does the *total* dissipative force (model's own D(q) qdot + the law) oppose motion at every speed up to the
    largest observed one?  Checked on a grid of speeds (log-spaced from eps/100 and linear, both directions) at the
    observed positions (the law's ``own_samples``; |sin q| and D(q) enter through them).  ``speeds``: max |qdot| per
    coordinate, one float for all, or a :class:`FrictionCurve`.  Names the negative terms of a passive combination."""
    if isinstance(speeds, FrictionCurve):
        vmax = list(speeds.max_speed)
    else:
        given = np.asarray(speeds, dtype=float)
        vmax = [float(given)] * law.n if given.ndim == 0 else [float(s) for s in given]
    per = []
    for i in range(law.n):
        vm = vmax[i]
        grid = np.unique(np.concatenate([np.geomspace(max(law.eps * 1e-2, vm * 1e-6), vm, n_grid),
                                         np.linspace(0, vm, n_grid)[1:]]))
        v = np.concatenate([grid, -grid])
        if law.own_samples:
            qi, di = law.own_samples[i]
        else:
            qi, di = np.array([0.0, math.pi / 2]), np.zeros(2)
        Q, Vv = np.meshgrid(qi, v, indexing="ij")
        total = di[:, None] * Vv + law.force(i, Q, Vv)
        for t in law.own_terms:
            if t.coordinate == i:
                total = total + t.coefficient * np.asarray(t.kind.basis(Q, Vv, law.eps, t.velocity, NUMPY))
        power = total * np.sign(Vv)  # force along the motion's opposite direction
        k = np.unravel_index(int(np.argmin(power)), power.shape)
        ok = bool(power[k] >= -tol)
        neg = [f"{VOCABULARY[t.term].short}[{i}]" for t in law.terms if t.coordinate == i and t.coefficient < 0]
        per.append({"coordinate": i, "passive": ok, "max_speed": vm, "worst_speed": float(abs(Vv[k])),
                    "min_force": float(power[k]),
                    "negative_terms": neg})
    return Passivity(all(p["passive"] for p in per), per)


def law_band_forces(law: FrictionLaw, curve: FrictionCurve) -> list[float]:
    """The total force of ``law`` (model's own + law) in each band of ``curve``, through the curve's filter."""
    wf = curve.weak
    if wf is None:
        raise ValueError("this FrictionCurve carries no weak form (built from a dict?); recompute it with "
                         "friction_curve")
    out = []
    cache: dict[int, np.ndarray] = {}
    for b, m in zip(curve.bands, curve.band_index):
        i = b.coordinate
        if i not in cache:
            cache[i] = wf.filt(law.force(i, wf.q_raw[..., i], wf.v_raw[..., i])) + wf.own[..., i]
        s = np.sign(wf.vs[..., i])
        out.append(float(np.sum((cache[i] * s)[m]) / max(m.sum(), 1)))
    return out


def check_against_curve(law: FrictionLaw, curve: FrictionCurve) -> list[dict[str, Any]]:
    """Band by band: is the law's total force (same filter, same samples) inside the curve's 95% interval?"""
    vals = law_band_forces(law, curve)
    return [{"coordinate": b.coordinate, "direction": b.direction, "band": [b.speed_lo, b.speed_hi], "curve": b.force,
             "ci95": list(b.ci95), "law": v, "inside": bool(b.ci95[0] <= v <= b.ci95[1])}
            for b, v in zip(curve.bands, vals)]

