"""The report's PNG plots: the residual map, the held-out fit, the energy decay and (when the report carries one) the
friction curve.  They draw ``Report.plot_data`` (matplotlib, Agg backend, imported only when plotting)."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from phast_gym.systems import break_at_wraps, wrap

from .files import CURVE_PLOT, PLOTS

_MODELS = (("nominal", ":"), ("calibrated", "--"), ("augmented", "-"))


def _residual_map(plt: ModuleType, pd: dict[str, Any], out: Path) -> None:
    """residual_map.png: the calibrated model's residual force over (q_i, qdot_i), per coordinate."""
    rm = pd["resid_map"]
    n = rm["r"].shape[-1]
    fig, axes = plt.subplots(1, n, figsize=(5 * n, 4), squeeze=False)
    for i in range(n):
        ax = axes[0, i]
        q, v, r = rm["q"][..., i].reshape(-1), rm["v"][..., i].reshape(-1), rm["r"][..., i].reshape(-1)
        if i in pd["train"].angle_dims:
            q = wrap(q)
        H, xe, ye = np.histogram2d(q, v, bins=40, weights=r)
        C, _, _ = np.histogram2d(q, v, bins=[xe, ye])
        M = np.where(C > 0, H / np.maximum(C, 1), np.nan)
        lim = np.nanpercentile(np.abs(M), 98) if np.any(np.isfinite(M)) else 1.0
        im = ax.imshow(M.T, origin="lower", aspect="auto", extent=[xe[0], xe[-1], ye[0], ye[-1]], cmap="RdBu_r",
                       vmin=-lim, vmax=lim)
        fig.colorbar(im, ax=ax, label="residual force (pdot units)")
        ax.set_xlabel(f"q{i}")
        ax.set_ylabel(f"qdot{i}")
        ax.set_title(f"calibrated-model residual, coordinate {i}")
    fig.tight_layout()
    fig.savefig(out / "residual_map.png", dpi=90)
    plt.close(fig)


def _heldout_fit(plt: ModuleType, pd: dict[str, Any], out: Path) -> None:
    """heldout_fit.png: the first held-out recording and the three models' rollouts, with their errors."""
    hold, roll = pd["hold"], pd["rollouts"]
    n = hold.n
    t = np.arange(hold.T) * hold.dt
    fig, axes = plt.subplots(2, n, figsize=(6 * n, 6), squeeze=False, sharex=True)
    for i in range(n):
        ax = axes[0, i]
        ax.plot(t, hold.q[0, :, i], "k.", ms=2, label="measured")
        for name, style in _MODELS:
            ax.plot(t, roll[name][0, :, i], style, lw=1, label=name)
        ax.set_ylabel(f"q{i}")
        ax.set_title(f"held-out recording 0, coordinate {i}")
        ax.legend(fontsize=7)
        ax = axes[1, i]
        for name, style in _MODELS:
            e = roll[name][0, :, i] - hold.q[0, :, i]
            if i in hold.angle_dims:
                e = break_at_wraps(wrap(e))
            ax.plot(t, e, style, lw=1, label=name)
        ax.set_ylabel("error")
        ax.set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(out / "heldout_fit.png", dpi=90)
    plt.close(fig)


def _decay(plt: ModuleType, pd: dict[str, Any], smoothing_window: int, out: Path) -> None:
    """decay.png: energy of the calibrated H along the smoothed held-out states vs along the models' rollouts."""
    from ...identify.shooting import momentum, smooth

    hold, roll, sysC = pd["hold"], pd["rollouts"], pd["calibrated_system"]
    n = hold.n
    t = np.arange(hold.T) * hold.dt
    w = min(smoothing_window, hold.T - 1 - (hold.T % 2 == 0))
    qs, vs = smooth(hold.q, hold.dt, max(w, 5))

    def energy(q: np.ndarray, v: np.ndarray) -> np.ndarray:
        p = momentum(sysC, q, v)
        return np.asarray(sysC.base.hamiltonian(tuple(q[..., i] for i in range(n)), tuple(p[..., i] for i in range(n))))

    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(t, energy(qs, vs).mean(0), "k", lw=2, label="measured (smoothed)")
    for name, style in _MODELS:
        qr = roll[name]
        vr = np.gradient(qr, hold.dt, axis=1)
        ax.plot(t, energy(qr, vr).mean(0), style, label=name)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("mean energy H (calibrated)")
    ax.set_title("energy decay, held-out recordings")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "decay.png", dpi=90)
    plt.close(fig)


def plot(pd: dict[str, Any], smoothing_window: int, out: Path) -> list[str]:
    """residual_map.png, heldout_fit.png and decay.png (and friction_curve.png when ``pd`` holds a friction curve) of
    the plot data ``pd`` (``Report.plot_data``) into ``out``; returns the names written.  ``smoothing_window``
    [samples] smooths the held-out states of the decay plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    _residual_map(plt, pd, out)
    _heldout_fit(plt, pd, out)
    _decay(plt, pd, smoothing_window, out)
    curve = pd.get("friction_curve")
    if curve is None:
        return list(PLOTS)
    from ..friction.plots import plot_friction_curve

    plot_friction_curve(curve, pd.get("friction_laws"), str(out / CURVE_PLOT))
    return [*PLOTS, CURVE_PLOT]
