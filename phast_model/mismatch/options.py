"""Tuning knobs of the mismatch pipeline and the progress log every stage writes to."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields, replace
from typing import Any

from ..identify.weakform import SIGN_SMOOTHING_REL

#: two-sided 95% normal quantile (the reported intervals)
Z95 = 1.959964


@dataclass(frozen=True)
class WindowOptions:
    """Time scales (defaults are derived from the data when None)."""

    smoothing_window: int | None = None  # Savitzky-Golay window [samples] for seeds and the residual map
    shoot_window: int | None = None  # shooting window [samples] (default: half an oscillation period, >= 20 samples)
    rollout_window: float | None = None  # held-out rollout window [s] (default: each held-out trajectory whole)
    decimate: int | None = None  # keep every k-th sample (default: auto, ~20 samples per time scale, never with u)


@dataclass(frozen=True)
class Caps:
    """What bounds the time per case."""

    max_windows: int = 200  # cap on shooting windows (subsampled evenly beyond it)
    max_residuals: int = 9000  # cap on windows x samples x coordinates
    max_iter: int = 15


@dataclass(frozen=True)
class Options:
    """Tuning knobs of :func:`.analysis.analyze`.  Grouped; :meth:`with_` (and ``analyze(**overrides)``) take the flat
    names of every group (``shoot_window=40``, ``max_iter=10``, ...)."""

    windows: WindowOptions = WindowOptions()
    caps: Caps = Caps()
    threshold: float = 5.0  # a term must reach |coefficient| / std > threshold (and the chi^2 gain threshold^2)
    max_terms: int = 5
    coulomb_eps_rel: float = SIGN_SMOOTHING_REL  # tanh smoothing of sign(qdot), relative to the rms velocity
    progress: bool = False
    terms: tuple[str, ...] | None = None  # restrict the candidate vocabulary
    # shooting chi^2/dof above this: the misfit is model error, not noise (a right model leaves ~1), and shooting gains
    # are no evidence; parameters, armature and the friction law then come from the weak form (friction/systematic.py)
    systematic_chi2: float = 3.0
    # parameters the user frees although the simulator declares them known (Param(known=True), e.g. gravity)
    free: tuple[str, ...] = ()
    # MuJoCo threads for a model file's rollouts (mujoco.rollout's pool; the answer does not depend on it)
    threads: int = 1

    @classmethod
    def flat_names(cls) -> list[str]:
        """Every option's flat name (the groups' fields and the others)."""
        groups = {"windows": WindowOptions, "caps": Caps}
        return ([g.name for grp in groups.values() for g in fields(grp)]
                + [f.name for f in fields(cls) if f.name not in groups])

    def with_(self, **flat: Any) -> Options:
        """These options with the given flat-named fields changed (a new object: options are immutable)."""
        groups: dict[str, Any] = {"windows": self.windows, "caps": self.caps}
        sub: dict[str, dict[str, Any]] = {g: {} for g in groups}
        top: dict[str, Any] = {}
        for key, value in flat.items():
            group = next((g for g, obj in groups.items() if key in obj.__dataclass_fields__), None)
            if group is not None:
                sub[group][key] = value
            elif key in self.__dataclass_fields__ and key not in groups:
                top[key] = value
            else:
                raise ValueError(f"unknown option(s) {[key]}; valid: {sorted(self.flat_names())}")
        return replace(self, **top, **{g: replace(groups[g], **kw) for g, kw in sub.items() if kw})

    # the grouped knobs by their flat names (read-only)
    @property
    def smoothing_window(self) -> int | None:
        return self.windows.smoothing_window

    @property
    def shoot_window(self) -> int | None:
        return self.windows.shoot_window

    @property
    def rollout_window(self) -> float | None:
        return self.windows.rollout_window

    @property
    def decimate(self) -> int | None:
        return self.windows.decimate

    @property
    def max_windows(self) -> int:
        return self.caps.max_windows

    @property
    def max_residuals(self) -> int:
        return self.caps.max_residuals

    @property
    def max_iter(self) -> int:
        return self.caps.max_iter


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
