"""Tuning knobs of the mismatch pipeline and the progress log every stage writes to."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

#: two-sided 95% normal quantile (the reported intervals)
Z95 = 1.959964


@dataclass(frozen=True)
class Options:
    """Tuning knobs of :func:`analyze` (defaults are derived from the data when None)."""

    smoothing_window: int | None = None  # Savitzky-Golay window [samples] for seeds and the residual map
    shoot_window: int | None = None  # shooting window [samples] (default: one oscillation period)
    threshold: float = 5.0  # a term must reach |coefficient| / std > threshold (and the chi^2 gain threshold^2)
    max_terms: int = 5
    coulomb_eps_rel: float = 0.005  # tanh smoothing of sign(qdot), relative to the rms velocity
    max_windows: int = 200  # cap on shooting windows (subsampled evenly beyond it)
    max_residuals: int = 9000  # cap on windows x samples x coordinates (time per case)
    max_iter: int = 15
    progress: bool = False
    terms: tuple[str, ...] | None = None  # restrict the candidate vocabulary
    rollout_window: float | None = None  # held-out rollout window [s] (default: each held-out trajectory whole)
    decimate: int | None = None  # keep every k-th sample (default: auto, ~20 samples per time scale, never with u)
    # shooting chi^2/dof above this: the misfit is model error, not noise (a right model leaves ~1), and shooting gains
    # are no evidence; parameters, armature and the friction law then come from the weak form (systematic.py)
    systematic_chi2: float = 3.0
    # parameters the user frees although the simulator declares them known (Param(known=True), e.g. gravity)
    free: tuple[str, ...] = ()


@dataclass
class Progress:
    """Progress lines ``[mismatch   t s] msg`` (printed only when ``enabled``)."""

    enabled: bool = False
    t0: float = field(default_factory=time.time)

    def __call__(self, msg: str) -> None:
        if self.enabled:
            print(f"[mismatch {self.elapsed():6.1f}s] {msg}", flush=True)

    def elapsed(self) -> float:
        return time.time() - self.t0
