"""Simulation vs. reality: locate the mismatch, name the missing physics, model it, show the fit improve.

``analyze(sim, recordings, sim_kwargs=None, holdout_fraction=0.3) -> Report`` implements
docs/mismatch.md; ``Report.write(out_dir)`` writes report.json / report.md / report.html / plots.

The pipeline: stages with interfaces, composed in one place (:mod:`.analysis`, the only module that imports them
all).  Each stage is a folder or a module, in the order they may import one another: a stage imports only earlier
ones (``tests/codebase/test_codebase.py``, ``MISMATCH_STAGES``); :mod:`.options` (the knobs and progress log) and
:mod:`.rows` (the typed answer rows) are shared by all.

1. **load recordings** -- :mod:`phast_model.identify.recordings` (one container and loader, shared with the world model)
   and :mod:`phast_model.identify.split` (the split: the *held-out* recordings are set aside here and no stage fits
   them); the simulator from :mod:`phast_model.identify.simulators`;
2. **vocabulary** -- :mod:`.vocabulary`: the term kinds (:mod:`~.vocabulary.registry`), the terms and the augmented
   model (:mod:`~.vocabulary.terms`), the candidates and the model family they are fitted in
   (:mod:`~.vocabulary.candidates`);
3. **prepare** -- :mod:`.fitting`: :mod:`~.fitting.problem` (noise, scales, shooting windows; the shooting fit is
   :mod:`phast_model.identify.shooting`) with :mod:`~.fitting.linear`;
4. **held-out scoring** -- :mod:`.evaluate` (the *held-out* recordings, set up on the prepared problem: one-step and
   open-loop rollout errors of any models; every answer is confirmed on them) and :mod:`.energy` (the energy balance);
5. **calibrate** -- :mod:`.calibrate`: the nominal fit and the parameter combinations the recordings determine;
6. **select** -- :mod:`.selection`: the candidates screened (:mod:`~.selection.screening`), parameter changes and
   terms in one forward selection by shooting (:mod:`~.selection.forward` on the state of :mod:`~.selection.search`),
   each chosen item confirmed by *two-fold validation* on the training recordings, and the longer look at
   dissipation laws of equal evidence (:mod:`~.selection.law_look`);
7. **explain** -- :mod:`.explainers`: the interface every answer goes through (:class:`~.explainers.Explainer`,
   :class:`~.explainers.Context`, :class:`~.explainers.Answer`) and the selection's answer
   (:class:`~.explainers.ShootingExplainer`); :func:`~.explainers.explain_in_turn` runs them in
   :data:`.analysis.EXPLAINERS`' order, a later answer adopted only when it predicts the held-out recordings better;
8. **friction** -- :mod:`.friction`: weak-form identification, friction laws chosen by *leave-one-out* prediction,
   passivity, and the stage's answer when model error dominates (:mod:`~.friction.systematic`,
   :class:`~.friction.systematic.WeakFormExplainer`);
9. **locate** -- :mod:`.locate`: where the calibrated model's residual force lives;
10. **report** -- :mod:`.report` (report.json / .md / .html, plots, safe writes) and, for a MuJoCo model file,
    :mod:`~.report.mjcf_answer` (the answer in the model's own attributes, ``calibrated.xml``).

:mod:`.analysis` runs them: prepare, set up the held-out scoring, calibrate, select, explain in turn, score the
adopted answer on the held-out recordings (with the energy balance), locate, report, and the MJCF answer; when the
selection's windows name no term it looks again with longer windows (:func:`.analysis.analyze`'s second look).
:mod:`phast_model.bench.reality` makes concealed-effect "realities" from the env suite (bench, tests, examples).

Three different checks predict recordings not used for a fit, one name each: *held-out* (the recordings the split
sets aside, :class:`.evaluate.HeldOut`); *two-fold validation* (the training recordings in two folds, each fitted on
the other, :mod:`.selection.forward`, ``Selection.validation``); *leave-one-out* (each training recording or time
block left out in turn, :mod:`.friction.lawselect` and :func:`.friction.weakid.check_parameters`).
"""

from ..identify.recordings import Recordings, load_raw, validate
from .analysis import analyze
from .options import Options
from .report import Report
from .vocabulary.terms import VOCABULARY, AugmentedSystem, Term

__all__ = ["analyze", "Options", "Report", "Recordings", "load_raw", "validate", "VOCABULARY", "AugmentedSystem",
           "Term"]
