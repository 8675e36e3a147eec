"""The friction stage: friction from q-only recordings (weak-form law fits, law selection by leave-one-out
prediction, passivity) and the weak-form answer built on them.

:mod:`.systematic` is the stage's answer (:class:`~.systematic.WeakFormExplainer`, an :class:`..explainers.Explainer`):
the systematic regime, run when model error, not noise, dominates the shooting fit.  The stage builds on the weak
form and the friction curve of the shared identification layer (``identify``), which fit nothing (this package
re-exports their public names with its own):

* :mod:`phast_model.identify.weakform`: the filtered momentum balance f~ = S*(F_cons + u) - d/dt S*p (the total
  dissipative force);
* :mod:`phast_model.identify.frictioncurve`: :func:`friction_curve`, f~ averaged in speed bands with block-bootstrap 95%
  intervals;
* :mod:`.laws`: :func:`fit_law`, least squares of f~ - S*(own) on S*(basis) of dissipative vocabulary terms;
* :mod:`.passivity`: :func:`is_passive` (the total force opposes motion) and :func:`check_against_curve`;
* :mod:`.lawselect`: :func:`select_law` / :func:`select_friction`, laws chosen by leave-one-out prediction (each
  training recording, or time block, left out of the fit in turn and predicted; not the held-out recordings of
  :mod:`..evaluate`, which no stage fits);
* :mod:`.weakid`: :func:`~.weakid.identify`, the simulator's parameters, the reflected rotor inertia and a friction law
  in one weak-form least squares, and :func:`~.weakid.check_parameters` (leave-one-out as well);
* :mod:`.plots`: :func:`plot_friction_curve`;
* :mod:`.systematic`: the weak-form answer: which parameters to calibrate, the law chosen per coordinate, the joint
  refit, the delays of the shooting answer it competes with (not re-exported here: it is the stage's answer, and
  the earlier stages' modules above need none of it).

The friction laws are built from the dissipative kinds of the term registry (:mod:`..vocabulary.registry`):
registering a new one makes it a candidate of every law fit and selection.
"""

from __future__ import annotations

from ...identify.frictioncurve import CurveOptions, FrictionBand, FrictionCurve, friction_curve
from ...identify.weakform import Balance, WeakForm, default_eps, default_window, momentum_balance, weak_form
from ..vocabulary.registry import law_terms
from .laws import STRIBECK_FRACTIONS, FrictionLaw, LawTerm, Spec, fit_law
from .lawselect import (
    CandidateScore,
    LawSelection,
    LawSelectionOptions,
    candidate_laws,
    coordinate_laws,
    rollout_score,
    select_friction,
    select_law,
)
from .passivity import Passivity, check_against_curve, is_passive, law_band_forces
from .plots import plot_friction_curve

__all__ = ["Balance", "CandidateScore", "CurveOptions", "FrictionBand", "FrictionCurve", "FrictionLaw", "LawSelection",
           "LawSelectionOptions", "LawTerm", "Passivity", "STRIBECK_FRACTIONS", "Spec", "WeakForm", "candidate_laws",
           "check_against_curve", "coordinate_laws", "default_eps", "default_window", "fit_law", "friction_curve",
           "is_passive", "law_band_forces", "law_terms", "momentum_balance", "plot_friction_curve", "rollout_score",
           "select_friction", "select_law", "weak_form"]
