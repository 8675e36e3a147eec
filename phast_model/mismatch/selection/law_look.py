"""The selection's longer look at one joint's dissipation law: law combinations fitted on shooting windows longer than
the selection's.

Half-period windows resolve *that* a joint dissipates long before they resolve *how*: a viscous, a quadratic and a
position-dependent law (or a Coulomb and a viscous one) drain a swing's energy at nearly the same rate over half a
period and differ in how the decay goes on.  Where the forward selection (:mod:`.forward`) meets laws of equal
evidence on one joint (:func:`contenders`), the chosen set, each other law swapped in for the chosen one and each
added beside it are fitted on windows :data:`LAW_LOOK` times longer, and :func:`look_longer` keeps the best.  On the
bench this settled a pendulum's viscous 0.003 + quadratic 0.001 (a Coulomb term had taken the viscous part's place
at one seed in five) and the viscous / position-dependent confusions of two sweeps.  Longer windows are not the
default: they cost more, and their fits can fall into local minima (a pendulum's state put on the wrong side of its
separatrix, a chaotic arm).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from phast_gym.systems.base import System

from ...identify.shooting import ShootFit
from ..calibrate import followed_windows
from ..fitting.problem import Problem, longer_windows, smoothed_states
from ..vocabulary.candidates import Candidate
from .search import EQUAL_EVIDENCE, AnyCandidate, Search

#: the longer look's windows, in multiples of the selection's
LAW_LOOK = 2


@dataclass(frozen=True)
class LawSet:
    """One combination of items to fit: their g order (candidate indices), how to build its system, its start."""

    order: list[int]
    build: Callable[[np.ndarray], System]
    g0: np.ndarray


def fit_on_longer_windows(problem: Problem, current: System, sets: list[LawSet]) -> list[ShootFit]:
    """Each set fitted on windows :data:`LAW_LOOK` times the selection's (the same caps on windows x samples), from
    window states fitted to the current model (by the homotopy on the window length); windows the current model does
    not follow at all are set aside as in the nominal fit (:func:`.calibrate.followed_windows`).  One set of windows
    for all, so their chi^2 compare directly."""
    windows = longer_windows(problem, LAW_LOOK * problem.shoot_window)
    shooter = problem.shooter(windows)
    states = shooter.fit_states(current, smoothed_states(problem.qs, problem.vs, windows),
                                max_iter=problem.opts.max_iter)
    keep = followed_windows(states.r)
    X = states.X
    if not np.all(keep) and np.sum(keep) >= 2:
        shooter = problem.shooter(windows.select(keep))
        X = X[keep]
    return [shooter.fit(s.build, X, s.g0, max_iter=problem.opts.max_iter) for s in sets]


#: most laws of equal evidence examined beside one chosen law (the strongest by linear gain)
MAX_CONTENDERS = 2


def contenders(s: Search, k: int, ranked: list[tuple[float, int, float]]) -> list[tuple[int, int, float]]:
    """Other dissipation laws on the coordinate of the chosen term k of equal evidence (linear gain within threshold^2
    or :data:`EQUAL_EVIDENCE` of its own): the windows did not decide between them (:func:`look_longer` looks
    longer)."""
    c = s.cands[k]
    if not isinstance(c, Candidate) or c.component != "dissipation":
        return []
    top = next(g for g, kk, _ in ranked if kk == k)
    margin = max(s.thr2, EQUAL_EVIDENCE * top)
    out = [(k, kk, z) for g, kk, z in ranked if kk != k and g >= top - margin and _same_joint_other_law(c, s.cands[kk])]
    return out[:MAX_CONTENDERS]


def _same_joint_other_law(a: Candidate, b: AnyCandidate) -> bool:
    return (isinstance(b, Candidate) and b.component == "dissipation" and b.coordinate == a.coordinate
            and b.term != a.term)


def look_longer(s: Search) -> list[dict[str, Any]]:
    """Where the selection met dissipation laws of equal evidence on one joint, the chosen set against each law swapped
    in for the chosen one and each added beside it, all fitted on windows :data:`LAW_LOOK` times longer
    (:func:`fit_on_longer_windows`); the best there is refitted on the selection's windows and adopted.  An added law
    must gain threshold^2 there and every term must stay significant and passive; a swap must fit better by 2 chi^2
    units."""
    pairs = [(k, a, z) for k, a, z in s.marks.contenders if k in s.chosen and a not in s.chosen]
    if not pairs or min(LAW_LOOK * s.problem.shoot_window, s.problem.train.T) <= s.problem.shoot_window:  # none longer
        return []
    if s.fit.chi2_red > s.problem.opts.systematic_chi2:  # chi^2 measures misfit there: the weak form chooses the law
        s.problem.log("model error dominates: no longer look (the weak form chooses the dissipation law)")
        return []
    orders, starts = _law_sets(s, pairs)
    fits = fit_on_longer_windows(s.problem, s.system_now(),
                                 [LawSet(o, s.family_of(o).build, g) for o, g in zip(orders, starts)])
    best = _winner(s, orders, fits)
    label = {i: " + ".join(s.cands[kk].label for kk in o if not s.cands[kk].is_param) for i, o in enumerate(orders)}
    row: dict[str, Any] = {
        "item": f"dissipation law ({label[0]})", "kept": best == 0,
        "chi2_on_longer_windows": {label[i]: float(f.cost) for i, f in enumerate(fits)},
        "note": f"laws of equal evidence on one joint: compared on {fits[0].r.shape[0]} windows {LAW_LOOK}x longer"}
    if best == 0:
        s.problem.log(f"longer look: {label[0]} stands")
        return [row]
    before, gains = s.fit.cost, dict(s.gains)
    s.chosen, s.fam = orders[best], s.family_of(orders[best])
    s.fit = s.screen.shooter.fit(s.fam.build, s.fit.X, fits[best].g, max_iter=s.problem.opts.max_iter)
    s.cov = s.fit.covariance()
    for k, a, _ in pairs:  # a swapped-in law inherits the gain of the one it replaces; an added one has its own
        if a in s.chosen:
            s.marks.longer_look.add(a)
            s.gains[a] = max((gains[k] if k not in s.chosen else 0.0) + before - s.fit.cost, 0.0)
    s.problem.log(f"longer look: {label[best]} instead of {label[0]}; chi2/dof = {s.fit.chi2_red:.3g}")
    return [{**row, "note": f"{row['note']}; adopted: {label[best]}"}]


def _law_sets(s: Search, pairs: list[tuple[int, int, float]]) -> tuple[list[list[int]], list[np.ndarray]]:
    """The sets the longer look compares (g orders and starts): the chosen one first, then per (chosen law k, other
    law a, a's linear z) a swapped in for k (from z) and a added beside k (from no effect)."""
    sets: dict[tuple[int, ...], np.ndarray] = {tuple(s.chosen): s.fit.g.copy()}
    for k, a, z in pairs:
        j = s.pos(k)
        sets.setdefault(tuple(a if kk == k else kk for kk in s.chosen),
                        np.concatenate([s.fit.g[:j], [z], s.fit.g[j + 1:]]))
        sets.setdefault((*s.chosen, a), np.concatenate([s.fit.g, [0.0]]))
    return [list(o) for o in sets], list(sets.values())


def _winner(s: Search, orders: list[list[int]], fits: list[ShootFit]) -> int:
    """Index of the best set on the longer windows, the chosen one (0) unless beaten: a set of equal size by 2 chi^2
    units, a larger one by threshold^2 per added law, with every term significant and passive."""
    best = 0
    for i in range(1, len(orders)):
        bigger = len(orders[i]) - len(orders[best])
        cov = fits[i].covariance()
        ok = all(s.item_ok(fits[i], cov, orders[i], kk) for kk in orders[i] if not s.cands[kk].is_param)
        if ok and fits[i].cost < fits[best].cost - (2.0 if bigger <= 0 else s.thr2 * bigger):
            best = i
    return best
