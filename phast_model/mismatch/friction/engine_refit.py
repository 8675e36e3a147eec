"""The weak-form answer of a model file, refitted by shooting through the engine that simulates it.

The weak form (:mod:`.weakid`) chooses the friction law and gives every coefficient from a filtered momentum balance:
local evidence, free of open-loop drift, but noisy where the balance is (a rotor inertia behind a heavy proximal joint
of a long arm is a small share of d/dt (M qdot)).  On a MuJoCo model file the answer is what MuJoCo simulates
(``damping``, ``frictionloss``, ``armature`` written into the file), so its coefficients are refitted here on the
short shooting windows, every window's state free, simulated by MuJoCo (:func:`~..written.in_mujoco`): the coefficients
then mean what the written ``calibrated.xml`` means, and the windows, whose prediction error grows with the inertia,
pin a rotor inertia far better than the balance does.  A rotor inertia is refitted on every driven joint (the weak form
may have left one out as not significant); a term whose 95% interval then includes zero is dropped (and the rest
refitted once), since a term the data do not back is not missing physics (MuJoCo's inertia, damping and
frictionloss are non-negative, so an interval reaching zero or below does not back one).  The refit is kept only when
it follows the windows at least as well as the values it starts from (the weak form's, or a trial's).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from phast_gym.systems.base import System

from ...identify.shooting import Shooter, ShootFit
from ..selection.forward import quantile95
from ..vocabulary.registry import ARMATURE
from ..vocabulary.terms import Term
from ..written import in_mujoco
from .laws import LawTerm
from .weakid import WeakFit, WeakModel

#: the least scale of a coefficient that starts at zero, relative to the largest start of its kind
FLOOR = 0.1


@dataclass(frozen=True)
class Item:
    """One refitted value: a law term (``law``), a rotor inertia (``inertia``) or a parameter (``param``, log-relative:
    value = start * exp(g)); a coefficient is start + scale * g."""

    kind: str
    name: str  # term or parameter name
    coordinate: int = -1
    velocity: float = 0.0  # a Stribeck term's v_s (held)
    start: float = 0.0
    scale: float = 1.0

    @property
    def label(self) -> str:
        return self.name if self.kind == "param" else f"{self.name}[{self.coordinate}]"

    def value(self, g: float) -> float:
        return self.start * math.exp(g) if self.kind == "param" else self.start + self.scale * g


@dataclass
class EngineRefit:
    """The refit: its items, their values and 95% intervals, the fit, and the start values' cost on the same windows."""

    items: list[Item]
    fit: ShootFit
    values: np.ndarray
    ci95: np.ndarray  # (P, 2)
    t_quantile: float
    cost_before: float
    dropped: list[str]

    def to_dict(self) -> dict[str, Any]:
        return {"items": [{"item": it.label, "start": it.start, "refit": float(v), "ci95": list(map(float, c))}
                          for it, v, c in zip(self.items, self.values, self.ci95)],
                "chi2_per_dof": {"start": self.cost_before / max(self.fit.dof, 1), "refit": self.fit.chi2_red},
                "dropped_interval_includes_zero": self.dropped}

    def terms(self) -> tuple[Term, ...]:
        """The refitted terms (rotor inertias and the law): where a later refit starts."""
        return tuple(Term(it.name, it.coordinate, float(v), it.velocity)
                     for it, v in zip(self.items, self.values) if it.kind != "param")


def _items(final: WeakFit, armature_on: Sequence[int], starts: Sequence[Term]) -> list[Item]:
    """The law terms and the friction terms of ``starts`` (e.g. a trial's), a rotor inertia on every joint of
    ``armature_on`` and the weak form's fitted parameters; a term starts at its value in ``starts`` where there is
    one."""
    given = {(t.name, t.coordinate): t for t in starts}

    def term(kind: str, name: str, i: int, velocity: float, value: float, floor: float) -> Item:
        start = given[(name, i)].coefficient if (name, i) in given else value
        return Item(kind, name, i, velocity, start, max(abs(start), floor, 1e-12))

    law = [term("law", t.term, t.coordinate, t.velocity, t.coefficient, 0.0) for t in final.law.terms]
    have = {(it.name, it.coordinate) for it in law}
    law += [term("law", t.name, t.coordinate, t.velocity, t.coefficient, 0.0) for t in starts
            if t.name != ARMATURE.name and (t.name, t.coordinate) not in have]
    arm = {a.coordinate: a.coefficient for a in final.armature if a.coefficient > 0}
    big = max([*arm.values(), 0.0])
    inertia = [term("inertia", ARMATURE.name, i, 0.0, arm.get(i, 0.0), FLOOR * big) for i in armature_on]
    params = [Item("param", k, start=row.fitted) for k, row in final.params.items()]
    return [*law, *inertia, *params]


def updated(final: WeakFit, items: Sequence[Item], values: np.ndarray, ci95: np.ndarray | None = None,
            t_quantile: float = 1.96) -> WeakFit:
    """``final`` with the items' values (and intervals, when given); rotor inertias replace the weak form's."""
    def ci(j: int) -> tuple[float, float]:
        return (float(ci95[j, 0]), float(ci95[j, 1])) if ci95 is not None else (math.nan, math.nan)

    law = [it for it in items if it.kind == "law"]
    terms = [LawTerm(it.name, it.coordinate, float(values[j]), ci(j), it.velocity, t_quantile)
             for j, it in enumerate(items) if it.kind == "law"]
    armature = [LawTerm(ARMATURE.name, it.coordinate, float(values[j]), ci(j), 0.0, t_quantile)
                for j, it in enumerate(items) if it.kind == "inertia"]
    kwargs, params = dict(final.kwargs), dict(final.params)
    for j, it in enumerate(items):
        if it.kind == "param":
            kwargs[it.name] = float(values[j])
            row = params[it.name]
            params[it.name] = replace(row, fitted=float(values[j]), ci95=ci(j) if ci95 is not None else row.ci95,
                                      relative_change=float(values[j]) / row.nominal - 1.0 if row.nominal else None)
    assert len(terms) == len(law)
    return replace(final, kwargs=kwargs, params=params, armature=armature, law=replace(final.law, terms=terms))


def _builder(model: WeakModel, final: WeakFit, items: list[Item]):  # noqa: ANN202 - a closure for Shooter.fit
    def build(g: np.ndarray) -> System:
        values = np.array([it.value(float(x)) for it, x in zip(items, g)])
        # MuJoCo refuses a negative inertia or friction: at zero the term is absent, which the interval then says
        values = np.where([it.kind != "param" for it in items], np.maximum(values, 0.0), values)
        fit = updated(final, items, values)
        return in_mujoco(fit.law.augmented(model.build(fit.kwargs, fit.armature_terms(significant_only=False))))
    return build


def _fit(shooter: Shooter, model: WeakModel, final: WeakFit, items: list[Item], X: np.ndarray,
         max_iter: int) -> tuple[ShootFit, np.ndarray, np.ndarray, float]:
    """The shooting fit of ``items``: (fit, values, 95% intervals (P, 2), t quantile)."""
    build = _builder(model, final, items)
    fit = shooter.fit(build, X, np.zeros(len(items)), max_iter=max_iter)
    with np.errstate(over="ignore", invalid="ignore"):  # a term with no effect: an infinite interval, then dropped
        cov, dof = fit.interval_covariance()
    tq = quantile95(dof)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    values = np.array([it.value(float(x)) for it, x in zip(items, fit.g)])
    lo_hi = np.array([[it.value(float(x - tq * s)), it.value(float(x + tq * s))]
                      for it, x, s in zip(items, fit.g, sd)])
    return fit, values, lo_hi, tq


def engine_refit(shooter: Shooter, X: np.ndarray, model: WeakModel, final: WeakFit, armature_on: Sequence[int],
                 max_iter: int, starts: Sequence[Term] = ()) -> EngineRefit | None:
    """The weak-form answer ``final`` refitted by shooting through MuJoCo on ``shooter``'s windows (states started at
    ``X``; the terms of ``starts``, e.g. a trial's refit, considered too and started at their values), as the module
    docstring says; None when it follows the windows worse than its start does."""
    items = _items(final, armature_on, starts)
    if not items:
        return None
    before = shooter.fit_states(_builder(model, final, items)(np.zeros(len(items))), X, max_iter=max_iter)
    fit, values, ci, tq = _fit(shooter, model, final, items, before.X, max_iter)
    backed = [j for j, it in enumerate(items) if it.kind == "param" or ci[j, 0] > 0]  # MuJoCo's values are >= 0
    dropped = [items[j].label for j in range(len(items)) if j not in backed]
    if dropped:
        kept = [replace(items[j], start=float(values[j]), scale=items[j].scale) for j in backed]
        fit, values, ci, tq = _fit(shooter, model, updated(final, kept, values[backed]), kept, fit.X, max_iter)
        items = kept
    if not fit.cost <= before.cost:
        return None
    return EngineRefit(items, fit, values, ci, tq, before.cost, dropped)
