"""A longer look at one joint's dissipation law: law combinations fitted on shooting windows longer than the selection's.

Half-period windows resolve *that* a joint dissipates long before they resolve *how*: a viscous, a quadratic and a
position-dependent law (or a Coulomb and a viscous one) drain a swing's energy at nearly the same rate over half a
period and differ in how the decay goes on.  Where the selection meets laws of equal evidence on one joint
(:func:`.select._contenders`), the chosen set, each other law swapped in for the chosen one and each added beside it
are fitted on windows :data:`LAW_LOOK` times longer, and :func:`.select._law_look` keeps the best.  On the bench this
settled a pendulum's viscous 0.003 + quadratic 0.001 (a Coulomb term had taken the viscous part's place at one seed
in five) and the viscous / position-dependent confusions of two sweeps.  Longer windows are not the default: they
cost more, and their fits can fall into local minima (a pendulum's state put on the wrong side of its separatrix, a
chaotic arm).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from phast_gym.systems.base import System

from ..identify.shooting import ShootFit
from .calibrate import followed_windows
from .fitting.problem import Problem, longer_windows, smoothed_states

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
    states = shooter.fit_states(current, smoothed_states(problem.qs, problem.vs, windows), max_iter=problem.opts.max_iter)
    keep = followed_windows(states.r)
    X = states.X
    if not np.all(keep) and np.sum(keep) >= 2:
        shooter = problem.shooter(windows.select(keep))
        X = X[keep]
    return [shooter.fit(s.build, X, s.g0, max_iter=problem.opts.max_iter) for s in sets]
