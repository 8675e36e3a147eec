"""Simulation vs. reality: locate the mismatch, name the missing physics, model it, show the fit improve.

``analyze(sim, recordings, sim_kwargs=None, holdout_fraction=0.3) -> Report`` implements
docs/mismatch.md; ``Report.write(out_dir)`` writes report.json / report.md / report.html / plots.

The pipeline, in the order :mod:`.analysis` runs it (the folder shows it):

1. **load recordings** -- :mod:`phast_model.identify.recordings` (one container and loader, shared with the world model)
   and :mod:`phast_model.identify.split` (the split: the *held-out* recordings are set aside here and no stage fits
   them); the simulator from :mod:`phast_model.identify.simulators`;
2. **prepare** -- :mod:`.fitting.problem` (noise, scales, shooting windows; the shooting fit is
   :mod:`phast_model.identify.shooting`) with :mod:`.fitting.linear` and the knobs of :mod:`.options`;
3. **calibrate** -- :mod:`.calibrate`: the nominal fit and the parameter combinations the recordings determine;
4. **screen candidates** -- :mod:`.vocabulary` (:mod:`~.vocabulary.registry` of term kinds, :mod:`~.vocabulary.terms`
   and the augmented model, :mod:`~.vocabulary.candidates`, :mod:`~.vocabulary.screening`);
5. **select and explain** -- :mod:`.select`: parameter changes and terms in one forward selection by shooting, each
   chosen item confirmed by *two-fold validation* on the training recordings; then the explainers of
   :mod:`.explainers` in turn: the shooting answer, and when model error dominates :mod:`.systematic`'s weak-form
   answer, built on :mod:`.friction` (weak-form identification, friction laws chosen by *leave-one-out* prediction,
   passivity), adopted only when it predicts the held-out recordings better; the typed answer rows are :mod:`.rows`;
6. **confirm on held-out** -- :mod:`.evaluate` (the *held-out* recordings: one-step and open-loop rollout errors of
   the nominal, calibrated and augmented models) and :mod:`.energy` (the energy balance on them);
7. **locate** -- :mod:`.locate`: where the calibrated model's residual force lives;
8. **report** -- :mod:`.report` (report.json / .md / .html, plots, safe writes) and, for a MuJoCo model file,
   :mod:`.mjcf_answer` (the answer in the model's own attributes, ``calibrated.xml``).

:mod:`.synth` makes concealed-effect "realities" from the env suite (bench, tests, examples).

Three different checks predict recordings not used for a fit, one name each: *held-out* (the recordings the split
sets aside, :class:`.evaluate.HeldOut`); *two-fold validation* (the training recordings in two folds, each fitted on
the other, :mod:`.select`, ``Selection.validation``); *leave-one-out* (each training recording or time block left out in
turn, :mod:`.friction.lawselect` and :func:`.friction.weakid.check_parameters`).
"""

from ..identify.recordings import Recordings, load_raw, validate
from .analysis import analyze
from .options import Options
from .report import Report
from .vocabulary.terms import VOCABULARY, AugmentedSystem, Term

__all__ = ["analyze", "Options", "Report", "Recordings", "load_raw", "validate", "VOCABULARY", "AugmentedSystem", "Term"]
