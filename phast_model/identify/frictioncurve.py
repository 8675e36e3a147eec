"""The non-parametric friction curve: total friction force by speed band with block-bootstrap 95% intervals.

:func:`friction_curve`: the total friction force f~ of the weak form (sign convention: positive = opposes motion,
i.e. f~ sign(qdot)) averaged in speed bands, with block-bootstrap 95% intervals (resampling whole time blocks /
recordings, since samples in a band are time-correlated), and the model's own dissipative force in the same bands.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from phast_gym.systems.base import System

from .recordings import Recordings
from .weakform import WeakForm, weak_form


@dataclass
class FrictionBand:
    """One speed band of one coordinate: the mean total friction force there (positive = opposes motion)."""

    coordinate: int
    direction: str  # "both" (odd-symmetric average), "+" or "-" (qdot > 0 / < 0)
    speed_lo: float
    speed_hi: float
    speed_mean: float
    force: float
    ci95: tuple[float, float]
    model_force: float  # the calibrated model's own dissipative force in the band, same filter
    n_samples: int
    n_blocks: int

    @property
    def missing(self) -> float:
        """What the model leaves out in this band (force - model_force)."""
        return self.force - self.model_force


@dataclass
class FrictionCurve:
    """Non-parametric friction curve: total dissipative generalized force vs |qdot|, per coordinate, with 95% intervals.

    ``quantity`` says what is averaged.  The weak form it was computed from is kept (``weak``, not serialized) so that
    :func:`check_against_curve` can pass a law through the same filter and bands."""

    bands: list[FrictionBand]
    quantity: str
    filter: dict[str, Any]
    interval: str
    max_speed: list[float]  # per coordinate, largest |qdot| of the smoothed recordings
    n_recordings: int
    weak: WeakForm | None = field(default=None, repr=False)
    band_index: list[np.ndarray] = field(default_factory=list, repr=False)  # per band: boolean mask over weak samples

    def coordinate(self, i: int, direction: str = "both") -> list[FrictionBand]:
        return [b for b in self.bands if b.coordinate == i and b.direction == direction]

    def to_dict(self) -> dict[str, Any]:
        return {"quantity": self.quantity, "filter": self.filter, "interval": self.interval,
                "max_speed": self.max_speed,
                "n_recordings": self.n_recordings,
                "bands": [{**asdict(b), "ci95": list(b.ci95), "missing": b.missing} for b in self.bands]}

    def table(self) -> str:
        rows = ["| coord | dir | |qdot| band | force [95% CI] | model's own | missing |", "|---|---|---|---|---|---|"]
        for b in self.bands:
            rows.append(f"| {b.coordinate} | {b.direction} | {b.speed_lo:.3g}-{b.speed_hi:.3g} | {b.force:.4g} "
                        f"[{b.ci95[0]:.4g}, {b.ci95[1]:.4g}] | {b.model_force:.4g} | {b.missing:.4g} |")
        return "\n".join(rows)


def speed_edges(speed: np.ndarray, bands: int | str | Sequence[float], n_bands: int) -> np.ndarray:
    if not isinstance(bands, str) and not isinstance(bands, int):
        return np.asarray(bands, dtype=float)
    k = bands if isinstance(bands, int) else n_bands
    hi = float(np.max(speed))
    if bands == "log":
        lo = max(float(np.quantile(speed, 0.02)), 1e-3 * hi)
        e = np.geomspace(lo, hi, k + 1)
        e[0] = 0.0
        return e
    e = np.quantile(speed, np.linspace(0, 1, k + 1))
    e[-1] = hi * (1 + 1e-12)
    return e


def _boot_ratio(num: np.ndarray, den: np.ndarray, rng: np.random.Generator,
                n_boot: int) -> tuple[float, tuple[float, float]]:
    """Ratio estimate sum(num)/sum(den) over clusters with a cluster-bootstrap percentile 95% interval."""
    G = len(num)
    est = float(num.sum() / max(den.sum(), 1e-300))
    if G < 2:
        return est, (float("nan"), float("nan"))
    w = rng.multinomial(G, np.full(G, 1.0 / G), size=n_boot).astype(float)
    d = w @ den
    r = (w @ num)[d > 0] / d[d > 0]
    lo, hi = np.quantile(r, [0.025, 0.975])
    return est, (float(lo), float(hi))


@dataclass(frozen=True)
class CurveOptions:
    """How :func:`friction_curve` bands and bootstraps.

    ``bands``: "quantile" (equal sample counts, default), "log" (log-spaced), an int (quantile bands) or explicit
    edges in |qdot|.  ``directions=True`` adds the qdot > 0 and qdot < 0 halves separately (direction "+" / "-").
    Samples with |qdot| < ``min_speed`` are left out."""

    bands: int | str | Sequence[float] = "quantile"
    n_bands: int = 8
    directions: bool = False
    n_boot: int = 2000
    seed: int = 0
    min_speed: float = 0.0


def friction_curve(system: System, rec: Recordings, window: int | None = None, eps: float | None = None,
                   block: int | None = None,
                   options: CurveOptions | None = None, **overrides: Any) -> FrictionCurve:
    """Total friction force (the model's own dissipation plus what it leaves out) vs |qdot|, per coordinate.

    ``options`` (:class:`CurveOptions`; its fields may also be given as keywords, e.g. ``bands=6``) say how speeds are
    banded.  Intervals: percentile bootstrap over clusters (time blocks of each recording, see
    :func:`.weakform.weak_form`);
    the band value is a ratio estimate sum(f sign(qdot)) / count over the band."""
    opts = replace(options or CurveOptions(), **overrides)
    bands, n_bands, directions, min_speed = opts.bands, opts.n_bands, opts.directions, opts.min_speed
    wf = weak_form(system, rec, window, eps, block)
    rng = np.random.default_rng(opts.seed)
    out: list[FrictionBand] = []
    masks: list[np.ndarray] = []
    labels = wf.blocks
    G = int(labels.max()) + 1
    for i in range(wf.n):
        v = wf.vs[..., i]
        s = np.sign(v)
        sp = np.abs(v)
        keep = sp >= min_speed
        e = speed_edges(sp[keep], bands, n_bands)
        dirs = [("both", np.ones_like(keep))] + ([("+", v > 0), ("-", v < 0)] if directions else [])
        for dname, dm in dirs:
            for a, b in zip(e[:-1], e[1:]):
                m = keep & dm & (sp >= a) & (sp < b)
                if not np.any(m):
                    continue
                num = np.bincount(labels[m], weights=(wf.total[..., i] * s)[m], minlength=G)
                den = np.bincount(labels[m], minlength=G).astype(float)
                own = float(np.sum((wf.own[..., i] * s)[m]) / m.sum())
                est, ci = _boot_ratio(num, den, rng, opts.n_boot)
                out.append(FrictionBand(i, dname, float(a), float(b), float(sp[m].mean()), est, ci, own, int(m.sum()),
                                        int(np.sum(den > 0))))
                masks.append(m)
    blk = int(np.bincount(labels[0]).max()) if labels.size else 0
    return FrictionCurve(out, "total dissipative generalized force f = S*(F_cons + u) - d/dt S*p, times sign(qdot) "
                         "(positive opposes motion; includes the model's own dissipation, listed as model_force)",
                         {"kind": "savitzky-golay cubic, same on both sides", "window_samples": wf.window, "dt": wf.dt,
                          "coulomb_eps": wf.eps},
                         f"95% percentile bootstrap over {G} clusters (time blocks of {blk} samples within each "
                         "recording)",
                         [float(np.max(np.abs(wf.vs[..., i]))) for i in range(wf.n)], int(rec.n_traj), wf, masks)

