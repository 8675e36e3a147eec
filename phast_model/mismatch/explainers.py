"""The explainers: strategies that answer "what does the simulator leave out?", behind one interface.

An :class:`Explainer` reads the shared :class:`Context` (the fitting problem, the calibration, the shooting selection
the calibration was fitted with, the held-out recordings and the answer standing so far) and returns an
:class:`Answer` (the augmented model, its shooting fit, calibrated parameter rows, missing-physics rows and what the
report says about it), a :class:`Declined` (it does not apply; what the report says about that) or ``None`` (it does
not apply and has nothing to say).  :func:`explain_in_turn` runs an ordered list of them: the first answer stands,
and each later answer challenges it and is adopted only when its augmented model predicts the held-out recordings
better than the calibrated model (rollout RMSE); otherwise it is kept, with the reason, in the report's details.

Two ship with the tool, in :data:`phast_model.mismatch.analysis.EXPLAINERS`' order: :class:`ShootingExplainer` (the
forward selection by multiple shooting, :mod:`.selection`) and
:class:`~phast_model.mismatch.friction.systematic.WeakFormExplainer` (the friction stage's answer: the friction law
from the weak form when model error dominates).  A new one is a class in a module of its own plus its place in that
list (or ``analyze(..., explainers=[...])`` for one run); docs/extending.md shows one.

This interface sits between the selection stage (whose result :class:`Context` carries) and the friction stage
(which implements it): it imports no later stage, so what an answer hands the friction-curve plot is a :class:`Law`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

import numpy as np

from phast_gym.systems.base import System

from ..identify.frictioncurve import FrictionCurve
from ..identify.shooting import ShootFit
from .calibrate import Calibration
from .evaluate import FitTable, HeldOut
from .fitting.problem import Problem
from .rows import Alternative, ParamRow, TermRow, param_value
from .selection import INTERVALS, Selection, quantile95
from .vocabulary.candidates import Candidate, ParamCandidate

__all__ = ["METHOD", "Answer", "Context", "Declined", "Explained", "Explainer", "Law", "ShootingExplainer",
           "calibrated_rows", "explain_in_turn", "missing_rows"]


class Law(Protocol):
    """A fitted friction law as an answer hands it to the friction-curve plot (what the plot reads of
    :class:`.friction.laws.FrictionLaw`; the interface names no stage that implements it)."""

    own_samples: list[tuple[np.ndarray, np.ndarray]]

    def force(self, i: int, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The law's added force on coordinate i (positive opposes +qdot)."""
        ...


@dataclass(frozen=True)
class Answer:
    """One explainer's answer.  ``method`` is appended to details.method and ``section`` (a details key) holds
    ``evidence`` (plus ``not_adopted`` when a challenge failed) whenever the answer was computed, adopted or not;
    ``intervals`` is details.intervals when the answer is adopted; ``curve`` / ``laws`` feed the friction-curve plot."""

    label: str  # names the answer in the not-adopted reason, e.g. "weak-form answer"
    system: System  # the augmented model
    fit: ShootFit  # its multiple-shooting fit on the training windows
    calibrated: dict[str, ParamRow]
    missing: tuple[TermRow, ...]
    method: str
    intervals: str
    section: str | None = None
    evidence: dict[str, Any] = field(default_factory=dict)
    curve: FrictionCurve | None = None
    laws: Mapping[str, Law] = field(default_factory=dict)
    not_adopted: str | None = None

    def details(self) -> dict[str, Any]:
        """The report.details entries of this answer."""
        if self.section is None:
            return {}
        return {self.section: {**self.evidence,
                               **({} if self.not_adopted is None else {"not_adopted": self.not_adopted})}}


@dataclass(frozen=True)
class Declined:
    """An explainer that does not apply, with what report.details says about it (e.g. why not)."""

    entries: dict[str, Any]

    def details(self) -> dict[str, Any]:
        return dict(self.entries)


@dataclass(frozen=True)
class Context:
    """What every explainer reads (none changes it).  The shooting selection runs before any explainer: the
    calibration is fitted with its terms, and every explainer starts from that calibration."""

    problem: Problem
    cal: Calibration
    selection: Selection
    held: HeldOut
    models: dict[str, System]  # "nominal" and "calibrated", scored with every challenger on the held-out recordings
    compare: dict[str, System]  # the user's comparison models (extra rows of report.fit)
    current: Answer | None = None  # the answer standing so far (None for the first explainer)

    def fit_table(self, augmented: System) -> tuple[FitTable, dict[str, np.ndarray]]:
        """report.fit (and the rollouts) with ``augmented`` as the augmented model."""
        table = self.held.fit_table({**self.models, "augmented": augmented, **self.compare})
        self.problem.log(f"held-out: {table[0].to_dict()}")
        return table


class Explainer(Protocol):
    """A strategy behind the mismatch tool's answer."""

    def explain(self, ctx: Context) -> Answer | Declined | None:
        """The answer, or why this explainer does not apply (:class:`Declined`), or ``None``."""
        ...


#: details.method of the shooting answer (an answer adopted after it appends its own text)
METHOD = ("multiple shooting of the simulator on windows (fit by simulation); Levenberg-Marquardt; "
          "forward selection on the linearized problem with a chi^2 gain > threshold^2, then nonlinear refit; "
          "significance (|t|) from the larger of Gauss-Newton and window-cluster sandwich covariance; the reported "
          "95% intervals as details.intervals says")


class ShootingExplainer:
    """The forward selection by multiple shooting (:func:`.selection.select`, run before the explainers): its augmented
    model, the calibration's parameter rows and the selected terms' rows."""

    def explain(self, ctx: Context) -> Answer:
        problem, cal, sel = ctx.problem, ctx.cal, ctx.selection
        excess0 = cal.fit_nominal.cost - cal.fit_nominal.dof
        return Answer("shooting answer", sel.system, sel.fit, calibrated_rows(problem, cal, sel),
                      tuple(missing_rows(sel, excess0)), METHOD, INTERVALS)


@dataclass(frozen=True)
class Explained:
    """What :func:`explain_in_turn` decided: the adopted answer, every explainer's outcome in order, and the held-out
    table of the adopted answer when a challenge already computed it."""

    answer: Answer
    outcomes: tuple[Answer | Declined, ...]
    table: tuple[FitTable, dict[str, np.ndarray]] | None

    @property
    def answers(self) -> list[Answer]:
        """Every computed answer, adopted or not, in order."""
        return [o for o in self.outcomes if isinstance(o, Answer)]

    @property
    def method(self) -> str:
        """details.method: the texts of the answers adopted in turn (a challenger that was not adopted says why in its
        own details section, not here)."""
        return "".join(a.method for a in self.answers if a.not_adopted is None)

    @property
    def intervals(self) -> str:
        """details.intervals: how the adopted answer's intervals were computed."""
        return self.answer.intervals

    @property
    def curve(self) -> FrictionCurve | None:
        return next((a.curve for a in reversed(self.answers) if a.curve is not None), None)

    @property
    def laws(self) -> dict[str, Law]:
        return {k: law for a in self.answers for k, law in a.laws.items()}

    def details(self) -> dict[str, Any]:
        """The report.details entries of every outcome."""
        return {k: v for o in self.outcomes for k, v in o.details().items()}


def explain_in_turn(explainers: Sequence[Explainer], ctx: Context) -> Explained:
    """Run ``explainers`` in order: the first answer stands; a later one (which sees the standing answer as
    ``ctx.current``) is adopted only when its held-out rollout RMSE is below the calibrated model's."""
    outcomes: list[Answer | Declined] = []
    current: Answer | None = None
    table = None
    for explainer in explainers:
        out = explainer.explain(replace(ctx, current=current))
        if isinstance(out, Answer) and current is not None:  # a challenger
            challenge = ctx.fit_table(out.system)
            a, c = challenge[0].rmse("augmented"), challenge[0].rmse("calibrated")
            if a >= c:  # its parameters included, it does not predict: the standing answer stays
                out = replace(out,
                              not_adopted=(f"the {out.label} does not improve the held-out prediction (rollout RMSE "
                                                f"{a:.4g} >= calibrated {c:.4g})"))
            else:
                table = challenge
        if out is not None:
            outcomes.append(out)
        if isinstance(out, Answer) and out.not_adopted is None:
            current = out
    if current is None:
        raise ValueError(f"no explainer answered: {[type(e).__name__ for e in explainers]}")
    return Explained(current, tuple(outcomes), table)


# --------------------------------------------------------------------------- the shooting answer's report rows
def calibrated_rows(problem: Problem, cal: Calibration, sel: Selection) -> dict[str, ParamRow]:
    """report.sim.calibrated: changed parameters with 95% intervals (from the augmented fit when terms were added) and
    the combination the data fixed, then every other parameter held at nominal with the reason."""
    ident = cal.screen.identifiability
    if sel.chosen and sel.interval_cov is not None:
        g_src, cov_src, q95 = sel.fit.g, sel.interval_cov, sel.q95
    else:
        cov_src, dof = cal.fit.interval_covariance()
        g_src, q95 = cal.fit.g, quantile95(dof)
    out: dict[str, ParamRow] = {}
    changed = [k for k, _ in cal.selected]
    for j, (k, nom) in enumerate(cal.selected):
        z, sd = g_src[j], math.sqrt(max(cov_src[j, j], 0.0))
        same = [p for p, eq in ident.equivalents.items() if abs(eq.get(k, 0.0)) >= 0.5 and p not in changed]
        equivalent = None
        if same:
            equivalent = ("the recordings fix a combination: the same fit follows from changes of "
                          + ", ".join(f"{p} ({ident.sentence(p)})" for p in same))
        out[k] = ParamRow(nom, nom * math.exp(z), (nom * math.exp(z - q95 * sd), nom * math.exp(z + q95 * sd)),
                          math.exp(z) - 1.0, equivalent)
    for k, note in cal.notes.items():
        out.setdefault(k, ParamRow.held(param_value(problem.sys0.params[k]), note))
    for k in ident.examined:
        if k not in out:
            note = "identifiable, but no change of it was needed (held at nominal)"
            if (s := ident.sentence(k)) is not None:
                note = f"held at nominal: {s}"
            out[k] = ParamRow.held(param_value(problem.sys0.params[k]), note)
    return out


def _alternatives(sel: Selection, k: int, z: float) -> list[Alternative]:
    """Candidates with (>= 97% cosine) the same signature as candidate k (parameters included)."""
    cands, cols = sel.candidates, sel.columns
    alts: list[Alternative] = []
    ck = cols[:, k]
    for kk in sel.usable:
        if kk == k or cands[kk].key == cands[k].key:  # (the same term at another Stribeck velocity)
            continue
        ca = cols[:, kk]
        cos = float(ck @ ca) / (np.linalg.norm(ck) * np.linalg.norm(ca) + 1e-300)
        if abs(cos) > 0.97:
            za = z * float(ca @ ck) / float(ca @ ca)
            cand = cands[kk]
            if isinstance(cand, ParamCandidate):
                alts.append(Alternative(parameter=cand.name, value=cand.coefficient(za),
                                        similarity=float(round(abs(cos), 4)),
                                        note="a parameter change with the same effect on these recordings"))
            else:
                alts.append(Alternative(term=cand.term, coordinate=cand.coordinate, coefficient=cand.coefficient(za),
                                        similarity=float(round(abs(cos), 4))))
    return alts


def missing_rows(sel: Selection, excess0: float) -> list[TermRow]:
    """report.missing_physics: each selected term with its coefficient, 95% interval, share of the excess chi^2 it
    explains (``excess0``: excess chi^2 of the nominal fit) and its non-identifiable alternatives."""
    out = []
    for k in sel.term_indices:
        j = sel.chosen.index(k)
        cand = sel.candidates[k]
        assert isinstance(cand, Candidate)
        z = sel.fit.g[j]
        sd = math.sqrt(max(sel.interval_cov[j, j], 0.0)) if sel.interval_cov is not None else 0.0
        lo, hi = sorted([cand.coefficient(z - sel.q95 * sd), cand.coefficient(z + sel.q95 * sd)])
        term = cand.family_term.at(z)
        out.append(TermRow(cand.term, cand.coordinate, cand.component, term.coefficient, (lo, hi), term.expression(),
                           float(min(1.0, sel.gains.get(k, 0.0) / max(excess0, 1e-300))),
                           tuple(_alternatives(sel, k, z) + _swap_alternatives(sel, k)),
                           term.velocity if cand.kind.has_velocity else None))
    return out


def _swap_alternatives(sel: Selection, k: int) -> list[Alternative]:
    """The parameter changes a reported port gain stands for (an equivalent answer that the tool did not choose)."""
    swap = sel.equivalent_swap
    if not swap or swap["by"] != sel.candidates[k].label:
        return []
    return [Alternative(parameter=label.removeprefix("param "), note="changes of these parameters fit as well (cosine "
                        f"{swap['cosine']}); the port gain keeps the simulator's values") for label in swap["replaced"]]
