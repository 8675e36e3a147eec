"""Friction from q-only recordings: a non-parametric friction curve, weak-form law fits and law selection by prediction.

The pieces, one module per concern (this module re-exports their public names):

* :mod:`.weakform`: the filtered momentum balance f~ = S*(F_cons + u) - d/dt S*p (the total dissipative force);
* :mod:`.frictioncurve`: :func:`friction_curve`, f~ averaged in speed bands with block-bootstrap 95% intervals;
* :mod:`.laws`: :func:`fit_law`, least squares of f~ - S*(own) on S*(basis) of dissipative vocabulary terms;
* :mod:`.passivity`: :func:`is_passive` (the total force opposes motion) and :func:`check_against_curve`;
* :mod:`.lawselect`: :func:`select_law` / :func:`select_friction`, laws chosen by how well they predict left-out
  recordings;
* :mod:`.friction_plots`: :func:`plot_friction_curve`.

The friction laws are built from the dissipative kinds of the term registry (:mod:`.registry`): registering a new
one makes it a candidate of every law fit and selection.
"""

from __future__ import annotations

from .friction_plots import plot_friction_curve
from .frictioncurve import CurveOptions, FrictionBand, FrictionCurve, friction_curve
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
from .registry import law_terms
from .weakform import Balance, WeakForm, default_eps, default_window, momentum_balance, weak_form

__all__ = ["Balance", "CandidateScore", "CurveOptions", "FrictionBand", "FrictionCurve", "FrictionLaw", "LawSelection",
           "LawSelectionOptions", "LawTerm", "Passivity", "STRIBECK_FRACTIONS", "Spec", "WeakForm", "candidate_laws",
           "check_against_curve", "coordinate_laws", "default_eps", "default_window", "fit_law", "friction_curve",
           "is_passive", "law_band_forces", "law_terms", "momentum_balance", "plot_friction_curve", "rollout_score",
           "select_friction", "select_law", "weak_form"]
