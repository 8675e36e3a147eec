"""The weak-form answer of a model file, refitted by shooting through the engine that simulates it.

The weak form (:mod:`.weakid`) chooses the friction law and gives every coefficient from a filtered momentum balance:
local evidence, free of open-loop drift, but noisy where the balance is (a rotor inertia behind a heavy proximal joint
of a long arm is a small share of d/dt (M qdot)).  On a MuJoCo model file the answer is what MuJoCo simulates
(``damping``, ``frictionloss``, ``armature`` written into the file), so its coefficients are refitted here on the
short shooting windows, every window's state free, simulated by MuJoCo (:func:`~..written.in_mujoco`): the coefficients
then mean what the written ``calibrated.xml`` means, and the windows, whose prediction error grows with the inertia,
pin a rotor inertia far better than the balance does.  A rotor inertia is refitted on every driven joint (the weak form
may have left one out as not significant).  A term the data do not back is not missing physics, so terms are then
eliminated backward and the rest refitted once: each refitted term is a test, so the bar is family-wise (likelihood
ratio at 95% with Bonferroni's correction over the terms, :func:`_eliminated`), and MuJoCo's inertia, damping and
frictionloss are non-negative, so a term fitted at zero or below goes.  When the terms left no longer follow the
windows to the noise, the linearization misjudged one and every term stays.  All this only where the refit leaves
noise and no model error (chi^2/dof <= 3): a real arm's recordings, with model error, keep the weak form's answer.
The refit is kept only when it follows the windows, before elimination, at least as well as the values it starts from
(the weak form's, or a trial's).  Body values start at the weak form's or the file's, whichever follows the windows
better, and one refitted beyond :data:`MAX_CHANGE` times the file's (a moment no joint turns) goes back to the file's.
Body values are fitted under a prior centred on the file's (:func:`body_prior`, a maximum a posteriori fit): a CAD
value is a measurement of the machine too, so the windows move the values they pin and the prior holds those they
leave free (a link's moment about an axis that only trades with the rotor inertia behind it).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np
from scipy.stats import norm

from phast_gym.systems.base import System
from phast_gym.systems.mjcf import is_body_value

from ...identify.shooting import Prior, Shooter, ShootFit
from ..rows import ParamRow
from ..selection.forward import quantile95
from ..vocabulary.registry import ARMATURE
from ..vocabulary.terms import Term
from ..written import in_engine, mujoco_runs
from .laws import LawTerm
from .weakid import WeakFit, WeakModel

#: the least scale of a coefficient that starts at zero, relative to the largest start of its kind
FLOOR = 0.1
#: a refit stops when an iteration gains less than this share of chi^2 (about 0.5 chi^2 units on a 6-joint arm's 16
#: windows: the coefficients move by a small fraction of their standard error); each iteration simulates every window
#: once per coefficient and state direction, seconds on a 7-joint arm
TOL = 1e-4
#: a refit whose chi^2/dof is at most this leaves noise (1) and no model error: its intervals decide which terms stay
AT_NOISE = 3.0
#: a log-relative parameter's largest excursion in a trial step (exp(30): 1e13 times its start)
LOG_BOUND = 30.0
#: a body value refitted beyond this factor of the file's is not pinned by the windows: held at the file's
MAX_CHANGE = 3.0
#: a body value's prior standard deviation, on log(value / the file's value): a CAD file's masses, centres of mass and
#: moments are measurements of the machine too, good to some tens of per cent (:class:`~...identify.shooting.Prior`)
BODY_PRIOR_SD = 0.2
#: start values that leave a chi^2/dof above this (a real arm's model error: 7.9e3 on the C.0 arm, 1.8e8 on the
#: UR10e) are not refitted: no change of the same terms brings them to the noise, and the refit would cost minutes.  A
#: CAD file a few per cent off with its drives missing starts at up to a few hundred (335 on the 3-joint arm's), and its
#: refit with every body value under the file's prior reaches the noise
FAR = 1000.0


@dataclass(frozen=True)
class Item:
    """One refitted value: a law term (``law``), a rotor inertia (``inertia``) or a parameter (``param``, log-relative:
    value = start * exp(g)); a term's coefficient is scale * g, so that g = 0 is the term absent
    (:meth:`ShootFit.without`)."""

    kind: str
    name: str  # term or parameter name
    coordinate: int = -1
    velocity: float = 0.0  # a Stribeck term's v_s (held)
    start: float = 0.0
    scale: float = 1.0
    nominal: float = 0.0  # a parameter's value in the file

    def runaway(self, g: float) -> bool:
        """A parameter fitted more than a factor :data:`MAX_CHANGE` from the file's value: not a CAD value a few per
        cent off but one the windows do not pin (a principal moment the motion leaves unexcited runs to zero)."""
        return (self.kind == "param" and self.nominal != 0.0
                and not abs(math.log(max(self.value(g) / self.nominal, 1e-300))) <= math.log(MAX_CHANGE))

    @property
    def label(self) -> str:
        return self.name if self.kind == "param" else f"{self.name}[{self.coordinate}]"

    def value(self, g: float) -> float:
        # a Levenberg-Marquardt trial far out (exp(g) beyond 1e13) is a bad step, not an overflow
        return self.start * math.exp(min(max(g, -LOG_BOUND), LOG_BOUND)) if self.kind == "param" else self.scale * g

    @property
    def g0(self) -> float:
        """The fit's start: the start value."""
        return 0.0 if self.kind == "param" else self.start / self.scale


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
    held: tuple[str, ...] = ()  # parameters returned to the file's values (:meth:`Item.runaway`)
    data_share: np.ndarray | None = None  # (P,) per item, :attr:`_Tested.data_share`

    def applied(self, final: WeakFit) -> WeakFit:
        """``final`` with the refit's values and intervals, and the held parameters at the file's values."""
        return updated(_at_file(final, self.held), self.items, self.values, self.ci95, self.t_quantile,
                       self.data_share)

    @property
    def at_noise(self) -> bool:
        """The refit leaves noise, no model error (chi^2/dof at most :data:`AT_NOISE`): its values and intervals
        stand."""
        return self.fit.chi2_red <= AT_NOISE

    def to_dict(self) -> dict[str, Any]:
        return {"items": [{"item": it.label, "start": it.start, "refit": float(v), "ci95": list(map(float, c))}
                          for it, v, c in zip(self.items, self.values, self.ci95)],
                "chi2_per_dof": {"start": self.cost_before / max(self.fit.dof, 1), "refit": self.fit.chi2_red},
                "dropped_not_backed": self.dropped}

    def terms(self) -> tuple[Term, ...]:
        """The refitted terms (rotor inertias and the law) with a positive value: where a later refit starts."""
        return tuple(Term(it.name, it.coordinate, float(v), it.velocity)
                     for it, v in zip(self.items, self.values) if it.kind != "param" and v > 0)


def _items(final: WeakFit, armature_on: Sequence[int], starts: Sequence[Term],
           law_on: Sequence[tuple[str, int]] = ()) -> list[Item]:
    """The law terms and the friction terms of ``starts`` (e.g. a trial's), each (kind, joint) of ``law_on`` (from
    zero where neither has it), a rotor inertia on every joint of ``armature_on`` and the weak form's fitted
    parameters; a term starts at its value in ``starts`` where there is one."""
    given = {(t.name, t.coordinate): t for t in starts}

    def term(kind: str, name: str, i: int, velocity: float, value: float, floor: float) -> Item:
        start = given[(name, i)].coefficient if (name, i) in given else value
        return Item(kind, name, i, velocity, start, max(abs(start), floor, 1e-12))

    law = [term("law", t.term, t.coordinate, t.velocity, t.coefficient, 0.0) for t in final.law.terms]
    have = {(it.name, it.coordinate) for it in law}
    law += [term("law", t.name, t.coordinate, t.velocity, t.coefficient, 0.0) for t in starts
            if t.name != ARMATURE.name and (t.name, t.coordinate) not in have]
    have = {(it.name, it.coordinate) for it in law}
    sizes = [abs(it.start) for it in law]
    law += [term("law", name, i, 0.0, 0.0, FLOOR * max(sizes, default=1.0)) for name, i in law_on
            if (name, i) not in have]
    arm = {a.coordinate: a.coefficient for a in final.armature if a.coefficient > 0}
    big = max([*arm.values(), 0.0])
    inertia = [term("inertia", ARMATURE.name, i, 0.0, arm.get(i, 0.0), FLOOR * big) for i in armature_on]
    params = [Item("param", k, start=row.fitted, nominal=row.nominal) for k, row in final.params.items()]
    return [*law, *inertia, *params]


def _with_params(final: WeakFit, model: WeakModel, names: Sequence[str]) -> WeakFit:
    """``final`` with the body values ``names`` fitted too, from the file's values (the weak form left them out as not
    predicting its left-out balance better; the windows judge them here, and hold those they do not pin)."""
    if not names:
        return final
    nominal = model.sim.numeric_params(model.sim.build())
    rows = {k: ParamRow(float(nominal[k]), float(nominal[k])) for k in names if k not in final.params}
    kwargs = {**final.kwargs, **{k: r.fitted for k, r in rows.items()}}
    return replace(final, params={**final.params, **rows}, kwargs=kwargs)


def _at_file(final: WeakFit, names: Sequence[str]) -> WeakFit:
    """``final`` with the parameters ``names`` at the file's values (no longer fitted; one ``final`` never fitted is
    at the file's value already)."""
    names = [k for k in names if k in final.params]
    if not names:
        return final
    kwargs = {**final.kwargs, **{k: final.params[k].nominal for k in names}}
    params = {k: row for k, row in final.params.items() if k not in names}
    return replace(final, kwargs=kwargs, params=params)


def updated(final: WeakFit, items: Sequence[Item], values: np.ndarray, ci95: np.ndarray | None = None,
            t_quantile: float = 1.96, data_share: np.ndarray | None = None) -> WeakFit:
    """``final`` with the items' values (and intervals and the recordings' share of a prior-fitted value's
    information, when given); rotor inertias replace the weak form's."""
    def ci(j: int) -> tuple[float, float]:
        return (float(ci95[j, 0]), float(ci95[j, 1])) if ci95 is not None else (math.nan, math.nan)

    terms = [LawTerm(it.name, it.coordinate, float(values[j]), ci(j), it.velocity, t_quantile)
             for j, it in enumerate(items) if it.kind == "law"]
    armature = [LawTerm(ARMATURE.name, it.coordinate, float(values[j]), ci(j), 0.0, t_quantile)
                for j, it in enumerate(items) if it.kind == "inertia"]
    kwargs, params = dict(final.kwargs), dict(final.params)
    for j, it in enumerate(items):
        if it.kind == "param":
            kwargs[it.name] = float(values[j])
            row = params.get(it.name, ParamRow(it.nominal, it.nominal))  # a body value the refit added
            share = None if data_share is None or not np.isfinite(data_share[j]) else float(data_share[j])
            params[it.name] = replace(row, fitted=float(values[j]), ci95=ci(j) if ci95 is not None else row.ci95,
                                      relative_change=float(values[j]) / row.nominal - 1.0 if row.nominal else None,
                                      data_share=share)
    return replace(final, kwargs=kwargs, params=params, armature=armature, law=replace(final.law, terms=terms))


def _builder(model: WeakModel, final: WeakFit, items: list[Item]):  # noqa: ANN202 - a closure for Shooter.fit
    def build(g: np.ndarray) -> System:
        values = np.array([it.value(float(x)) for it, x in zip(items, g)])
        # MuJoCo refuses a negative inertia or friction: at zero the term is absent, which the interval then says
        values = np.where([it.kind != "param" for it in items], np.maximum(values, 0.0), values)
        fit = updated(final, items, values)
        return in_engine(fit.law.augmented(model.build(fit.kwargs, fit.armature_terms(significant_only=False))))
    return build


def _better_start(shooter: Shooter, X: np.ndarray, model: WeakModel, final: WeakFit, items: list[Item],
                  g0: np.ndarray, max_iter: int) -> tuple[list[Item], ShootFit]:
    """The items with their parameters at the weak form's values, or at the file's where those follow the windows
    better (with the window states fitted to each): a balance over a few samples can bend a body value that the
    drives, fitted first, leave within a few per cent of the file's.  Values MuJoCo refuses (the weak form's
    least squares can leave a body that is no rigid body) are no start: the file's are taken."""
    weak = _builder(model, final, items)(g0)
    if not any(it.kind == "param" for it in items):
        return items, shooter.fit_states(weak, X, max_iter=max_iter)
    at_file = [replace(it, start=final.params[it.name].nominal) if it.kind == "param" else it for it in items]
    filed = _builder(model, final, at_file)(g0)
    if mujoco_runs(filed) and not mujoco_runs(weak):
        return at_file, shooter.fit_states(filed, X, max_iter=max_iter)
    before = shooter.fit_states(weak, X, max_iter=max_iter)
    alt = shooter.fit_states(filed, before.X, max_iter=max_iter, in_basin=True)  # (the values differ by per cent)
    return (at_file, alt) if alt.cost < before.cost else (items, before)


def body_prior(items: Sequence[Item]) -> Prior:
    """The prior of the refit's body values: each log-relative value centred on the file's (:data:`BODY_PRIOR_SD`);
    rotor inertias and friction laws, which the file lacks, and other parameters (a gear) have none."""
    body = [it.kind == "param" and is_body_value(it.name) and it.nominal != 0.0 and it.start != 0.0 for it in items]
    center = [math.log(it.nominal / it.start) if b and it.nominal / it.start > 0 else 0.0
              for it, b in zip(items, body)]
    return Prior(np.where(body, 1.0 / BODY_PRIOR_SD**2, 0.0), np.array(center, dtype=float))


class _Tested(NamedTuple):
    ci95: np.ndarray  # (P, 2) 95% intervals of the values
    t_quantile: float
    data_share: np.ndarray  # (P,) 1 - variance / prior variance where a prior acts (NaN elsewhere)


def _tested(fit: ShootFit, items: Sequence[Item]) -> _Tested:
    """The 95% intervals of ``fit``'s values (:meth:`ShootFit.interval_covariance`)."""
    with np.errstate(over="ignore", invalid="ignore"):  # a term with no effect: an infinite interval
        cov, dof = fit.interval_covariance()
    tq = quantile95(dof)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    ci = np.array([[it.value(float(x - tq * s)), it.value(float(x + tq * s))] for it, x, s in zip(items, fit.g, sd)])
    prec = np.zeros(len(items)) if fit.prior is None else fit.prior.precision
    share = np.where(prec > 0, np.clip(1.0 - sd**2 * prec, 0.0, 1.0), np.nan)
    return _Tested(ci, tq, share)


def _eliminated(fit: ShootFit, items: list[Item]) -> tuple[ShootFit, list[Item], list[str]]:
    """Backward elimination on ``fit``'s linearization (:meth:`ShootFit.without`: no new simulation): the term whose
    removal costs least goes first while that cost, in chi^2 units of the fit (a likelihood-ratio test), stays below
    the family-wise 95% level (Bonferroni over the terms: z^2 = 7.5 for 8 terms, 9.0 for 18); a term fitted at zero
    or below goes in any case.  So of two terms that only together explain a force (viscous and Coulomb friction on
    one joint) the stronger stays."""
    n_terms = max(sum(it.kind != "param" for it in items), 1)
    bar = float(norm.ppf(1 - 0.025 / n_terms)) ** 2
    dropped: list[str] = []
    while True:
        scale = max(fit.chi2_red, 1.0)
        costs = [(fit.without(j).objective - fit.objective) / scale if it.kind != "param" and fit.g[j] > 0 else
                 (-math.inf if it.kind != "param" or it.runaway(float(fit.g[j])) else math.inf)
                 for j, it in enumerate(items)]
        if not costs or min(costs) >= bar:
            return fit, items, dropped
        j = int(np.argmin(costs))
        dropped.append(items[j].label)
        fit, items = fit.without(j), [it for k, it in enumerate(items) if k != j]


def _absent_at_zero(fit: ShootFit, items: list[Item], dropped: list[str]) -> tuple[ShootFit, list[Item], list[str]]:
    """Terms fitted at zero or below leave the answer: MuJoCo simulates them at zero (:func:`_builder`), so they are
    absent from the model the fit describes (the same fit, nothing else moved: :meth:`ShootFit.without_effect`), and a
    negative friction or inertia is not missing physics."""
    for j in reversed(range(len(items))):
        if items[j].kind != "param" and not items[j].value(float(fit.g[j])) > 0:
            dropped = [*dropped, items[j].label]
            fit, items = fit.without_effect(j), items[:j] + items[j + 1:]
    return fit, items, dropped


def _kept_start(final: WeakFit, kept: list[Item], g: np.ndarray) -> tuple[WeakFit, list[Item], np.ndarray]:
    """``final`` with the kept items at ``g``, the items restarted there (a parameter's start: its value), and their
    g from that start."""
    start = updated(final, kept, np.array([it.value(float(x)) for it, x in zip(kept, g)]))
    items = [replace(it, start=it.value(float(x)) if it.kind == "param" else it.start) for it, x in zip(kept, g)]
    return start, items, np.where([it.kind == "param" for it in items], 0.0, g)


def _refit_kept(shooter: Shooter, model: WeakModel, final: WeakFit, kept: list[Item],
                starts: tuple[np.ndarray, np.ndarray], X: np.ndarray, max_iter: int) -> tuple[ShootFit, list[Item]]:
    """The items left after elimination refitted, from the linearized fit without the dropped ones (``starts[0]``,
    :meth:`ShootFit.without`), or from their values in the fit of every item (``starts[1]``), which MuJoCo simulated,
    where it refuses the first (a linear step is no simulated one)."""
    start, items, g = _kept_start(final, kept, starts[0])
    if not mujoco_runs(_builder(model, start, items)(g)):
        start, items, g = _kept_start(final, kept, starts[1])
    return shooter.fit(_builder(model, start, items), X, g, max_iter=max_iter, tol=TOL, prior=body_prior(items)), items


def engine_refit(shooter: Shooter, X: np.ndarray, model: WeakModel, final: WeakFit, armature_on: Sequence[int],
                 max_iter: int, starts: Sequence[Term] = (), more_params: Sequence[str] = (),
                 law_on: Sequence[tuple[str, int]] = ()) -> EngineRefit | None:
    """The weak-form answer ``final`` refitted by shooting through MuJoCo on ``shooter``'s windows (states started at
    ``X``; the terms of ``starts``, e.g. a trial's refit, considered too and started at their values; the friction
    kinds ``law_on`` on their joints too, from zero where neither has them), as the module docstring says; None when
    it follows the windows worse than its start does, the start itself (not at the noise) when that is :data:`FAR`
    from following them."""
    final = _with_params(final, model, more_params)
    items = _items(final, armature_on, starts, law_on)
    if not items:
        return None
    g0 = np.array([it.g0 for it in items])
    items, before = _better_start(shooter, X, model, final, items, g0, max_iter)
    if before.chi2_red > FAR:
        return EngineRefit(items, before, np.array([it.value(g) for it, g in zip(items, g0)]),
                           np.full((len(items), 2), np.nan), math.nan, before.cost, [])
    fit = shooter.fit(_builder(model, final, items), before.X, g0, max_iter=max_iter, tol=TOL, prior=body_prior(items))
    # a fit that leaves model error has intervals widened by it, which say nothing about a term: nothing is dropped
    fit_all = fit
    fit, kept, dropped = _eliminated(fit, items) if fit.chi2_red <= AT_NOISE else (fit, items, [])
    held = tuple(it.name for it in items if it.kind == "param" and it.label in dropped)
    if dropped:
        full = (fit_all, items)
        index = {it.label: j for j, it in enumerate(items)}
        in_full = [fit_all.g[index[it.label]] for it in kept]
        fit, kept = _refit_kept(shooter, model, _at_file(final, held), kept, (fit.g, np.array(in_full)), fit.X,
                                max_iter)
        if not fit.chi2_red <= AT_NOISE:  # the linearization misjudged a term the data need: every term stays
            (fit, kept), dropped, held = full, [], ()
    if not fit_all.objective <= before.cost + body_prior(items).cost(g0):  # (elimination is judged by its own test)
        return None
    fit, kept, dropped = _absent_at_zero(fit, kept, dropped)
    tested = _tested(fit, kept)
    values = np.array([it.value(float(x)) for it, x in zip(kept, fit.g)])
    return EngineRefit(kept, fit, values, tested.ci95, tested.t_quantile, before.cost, dropped, held,
                       tested.data_share)
