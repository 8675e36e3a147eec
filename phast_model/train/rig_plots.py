"""Plots of a recordings run: held-out q (measured, PHAST, nominal) and the learned joint friction over the
non-parametric friction curve of ``phast-mismatch`` (:func:`phast_model.identify.frictioncurve.friction_curve`)."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from phast_gym.systems import System

from ..identify.frictioncurve import FrictionCurve, friction_curve
from ..identify.recordings import Recordings
from ..world.model import PHAST
from .rig_heldout import HeldoutWindows

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def _pyplot() -> ModuleType:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig: Figure, path: Path) -> Path:
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    tmp.replace(path)
    return path


def plot_heldout(w: HeldoutWindows, rolls: dict[str, np.ndarray], dt: float, path: Path, n_show: int = 3) -> Path:
    """The first ``n_show`` held-out windows, every coordinate: measured q, each model's open-loop q; the burn-in
    (state fitted there) shaded."""
    plt = _pyplot()
    n = w.q.shape[-1]
    k = min(n_show, w.q.shape[0])
    fig, axes = plt.subplots(n, k, figsize=(4.5 * k, 2.6 * n), squeeze=False)
    t = np.arange(w.q.shape[1]) * dt
    for j in range(k):
        for i in range(n):
            ax = axes[i][j]
            ax.axvspan(0, t[w.burn - 1], color="0.9", label="burn-in (state fitted)" if i == j == 0 else None)
            ax.plot(t, np.unwrap(w.q[j, :, i].numpy()), "k", lw=1.2, label="measured")
            for c, (name, r) in enumerate(rolls.items()):
                ax.plot(t, np.unwrap(r[j, :, i]), color=f"C{c}", lw=1, label=name)
            ax.set_title(f"window {j} (trajectory {w.trajectory[j]}), q{i}", fontsize=9)
            ax.set_xlabel("t [s]")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    out = _save(fig, Path(path))
    plt.close(fig)
    return out


def band_forces(model: Any, curve: FrictionCurve) -> list[float]:
    """Mean sign(v) f_i(v) of the learned joint friction over each band's samples of the curve's smoothed velocities
    (the bands and velocities of the curve, so the two are compared sample for sample)."""
    if curve.weak is None:
        raise ValueError("this FrictionCurve carries no weak form (built from a dict?); "
                         "recompute it with friction_curve")
    vs = curve.weak.vs
    out = []
    for band, mask in zip(curve.bands, curve.band_index):
        v = np.zeros(vs.shape[:-1] + (model.n,))
        v[..., band.coordinate] = vs[..., band.coordinate]
        vb = torch.as_tensor(v[mask], dtype=torch.float64)
        with torch.no_grad():
            f = model.friction.force(vb)[:, band.coordinate].numpy()
        out.append(float(np.mean(f * np.sign(vb[:, band.coordinate].numpy()))))
    return out


def friction_check(model: Any, curve: FrictionCurve) -> dict[str, Any]:
    """Per joint: how many of the curve's speed bands hold the learned friction inside their 95% interval."""
    forces = band_forces(model, curve)
    out: dict[str, Any] = {}
    for i in sorted({b.coordinate for b in curve.bands}):
        idx = [k for k, b in enumerate(curve.bands) if b.coordinate == i and b.direction == "both"]
        inside = [curve.bands[k].ci95[0] <= forces[k] <= curve.bands[k].ci95[1] for k in idx]
        out[f"joint {i}"] = {"bands_inside_ci95": int(sum(inside)), "bands": len(idx),
                             "fraction_inside": float(np.mean(inside)) if idx else float("nan"),
                             "learned": [forces[k] for k in idx], "curve": [curve.bands[k].force for k in idx],
                             "ci95": [list(curve.bands[k].ci95) for k in idx],
                             "speed": [curve.bands[k].speed_mean for k in idx]}
    return out


def plot_friction(model: PHAST, system: System, rec: Recordings, path: Path) -> dict[str, Any]:
    """The friction curve of the recordings under the nominal rig (bands, 95% intervals) with the learned law
    (in the same bands, and as f_i(v) on a speed grid); returns :func:`friction_check`."""
    if model.friction is None:
        return {}
    curve = friction_curve(system, rec)
    check = friction_check(model, curve)
    plt = _pyplot()
    joints = list(check)
    fig, axes = plt.subplots(1, len(joints), figsize=(6 * len(joints), 4.2), squeeze=False)
    for ax, name in zip(axes[0], joints):
        c = check[name]
        i = int(name.split()[-1])
        x, y, ci = np.array(c["speed"]), np.array(c["curve"]), np.array(c["ci95"])
        ax.errorbar(x, y, yerr=[y - ci[:, 0], ci[:, 1] - y], fmt="ko", capsize=3, label="phast-mismatch curve (95% CI)")
        ax.plot(x, c["learned"], "s", color="C0", mfc="none", label="PHAST, same bands")
        vg = np.linspace(0, curve.max_speed[i], 300)
        v = np.zeros((vg.size, model.n))
        v[:, i] = vg
        with torch.no_grad():
            f = model.friction.force(torch.as_tensor(v, dtype=torch.float64))[:, i].numpy()
        ax.plot(vg, f, "C0-", lw=1.2, label="PHAST f(v)")
        ax.set_xlabel(f"|qdot{i}|")
        ax.set_ylabel("friction force (opposing motion)")
        ax.set_title(f"{name}: {c['bands_inside_ci95']}/{c['bands']} bands inside the 95% CI", fontsize=9)
        ax.legend(fontsize=7)
    fig.tight_layout()
    _save(fig, Path(path))
    plt.close(fig)
    return check
