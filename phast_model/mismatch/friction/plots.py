"""The friction-curve plot: bands with 95% intervals, the model's own force and candidate laws overlaid."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ...identify.frictioncurve import FrictionCurve
from .laws import FrictionLaw
from .passivity import law_band_forces


def plot_friction_curve(curve: FrictionCurve, laws: dict[str, FrictionLaw] | Sequence[FrictionLaw] | None,
                        path: str) -> str:
    """Curve (bands with 95% intervals, and the model's own force) per coordinate, with candidate laws overlaid
    (through the same filter and bands, and as their unfiltered force vs speed).  Writes a PNG (matplotlib Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if laws is None:
        laws = {}
    if not isinstance(laws, dict):
        laws = {lw.name: lw for lw in laws}
    coords = sorted({b.coordinate for b in curve.bands})
    fig, axes = plt.subplots(1, len(coords), figsize=(6.5 * len(coords), 4.5), squeeze=False)
    law_vals = {k: law_band_forces(lw, curve) for k, lw in laws.items()} if curve.weak is not None else {}
    for ax, i in zip(axes[0], coords):
        idx = [k for k, b in enumerate(curve.bands) if b.coordinate == i and b.direction == "both"]
        bs = [curve.bands[k] for k in idx]
        x = np.array([b.speed_mean for b in bs])
        y = np.array([b.force for b in bs])
        lo = np.array([b.ci95[0] for b in bs])
        hi = np.array([b.ci95[1] for b in bs])
        ax.errorbar(x, y, yerr=[y - lo, hi - y], fmt="ko", capsize=3, label="data (total friction, 95% CI)")
        ax.plot(x, [b.model_force for b in bs], "k--", lw=1, label="calibrated model's own")
        vg = np.linspace(0, curve.max_speed[i], 300)[1:]
        for k, (name, lw) in enumerate(laws.items()):
            col = f"C{k % 10}"
            if name in law_vals:
                ax.plot(x, [law_vals[name][j] for j in idx], "s", color=col, ms=5, mfc="none")
            own = lw.own_samples[i][1].mean() if lw.own_samples else 0.0
            qline = np.full_like(vg, math.pi / 2)  # |sin q| = 1: position-dependent damping at its largest
            ax.plot(vg, own * vg + lw.force(i, qline, vg), "-", color=col, lw=1.2, label=name)
        ax.set_xlabel(f"|qdot{i}|")
        ax.set_ylabel("friction force (opposing motion)")
        ax.set_title(f"coordinate {i}: total dissipative force vs speed")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)

