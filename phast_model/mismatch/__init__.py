"""Simulation vs. reality: locate the mismatch, name the missing physics, model it, show the fit improve.

``analyze(sim, recordings, sim_kwargs=None, holdout_fraction=0.3) -> Report`` implements
docs/mismatch.md; ``Report.write(out_dir)`` writes report.json / report.md / report.html / plots.
"""

from ..rigs.recordings import Recordings, load_raw, validate
from .analysis import analyze
from .options import Options
from .report import Report
from .synth import make_reality
from .terms import VOCABULARY, AugmentedSystem, Term

__all__ = ["analyze", "Options", "Report", "Recordings", "load_raw", "validate", "VOCABULARY", "AugmentedSystem", "Term",
           "make_reality"]
