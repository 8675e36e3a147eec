"""Writing a mismatch report: report.json (MISMATCH.md schema), report.md and PNG plots, atomically."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from phast_gym.fileio import jsonable as _jsonable
from phast_gym.systems import wrap

if TYPE_CHECKING:
    from .analysis import Report


def markdown(report: Report) -> str:
    """A human-readable version of the report."""
    d = report.to_dict()
    lines = [f"# Mismatch report: {d['sim']['env_id']}", "", d["summary"], "",
             f"Data: {d['data']['n_traj']} recordings x {d['data']['T']} samples, dt = {d['data']['dt']}, "
             f"estimated noise std {d['data']['noise_std']:.3g} ({d['data']['source']}).", "", "## Calibrated parameters", "",
             "| parameter | nominal | fitted | 95% CI | note |", "|---|---|---|---|---|"]
    for k, v in d["sim"]["calibrated"].items():
        ci = v.get("ci95")
        ci_s = f"[{ci[0]:.4g}, {ci[1]:.4g}]" if ci else "-"
        lines.append(f"| {k} | {v['nominal']:.4g} | {v['fitted']:.4g} | {ci_s} | {v.get('note', 'fitted')} |")
    lines += ["", "## Where the mismatch is (calibrated model, training recordings)", ""]
    if d["located"]:
        lines += ["| coordinate | component | where | when | share |", "|---|---|---|---|---|"]
        for loc in d["located"]:
            lines.append(f"| {loc['coordinate']} | {loc['component']} | {loc['where']} | {loc['when']} | {loc['share']:.2f} |")
    else:
        lines.append("Nothing beyond the noise.")
    lines += ["", "## Missing physics", ""]
    if d["missing_physics"]:
        lines += ["| term | coordinate | component | coefficient | 95% CI | expression | explains | alternatives |",
                  "|---|---|---|---|---|---|---|---|"]
        for m in d["missing_physics"]:
            alts = ", ".join(a.get("term", a.get("parameter", "")) for a in m.get("alternatives", [])) or "-"
            expl = "-" if m["explains"] is None else format(m["explains"], ".2f")
            lines.append(f"| {m['term']} | {m['coordinate']} | {m['component']} | {m['coefficient']:.4g} | "
                         f"[{m['ci95'][0]:.4g}, {m['ci95'][1]:.4g}] | `{m['expression']}` | {expl} | {alts} |")
    else:
        lines.append("None found.")
    f = d["fit"]
    lines += ["", f"## Fit on {f['evaluated_on']}", "", "| model | one-step MSE | rollout RMSE |", "|---|---|---|"]
    for name in ("nominal", "calibrated", "augmented"):
        lines.append(f"| {name} | {f[name]['one_step_mse']:.4g} | {f[name]['rollout_rmse']:.4g} |")
    lines += ["", f"Rollout: {f.get('rollout', '')}", ""]
    ec = f.get("energy_check") or {}
    if any(ec.get(k) for k in ("training", "held_out")):
        lines += ["Energy check (measured energy loss / energy the augmented model dissipates, per half-cycle between turning "
                  "points; 1 = the found dissipation accounts for all of it):", "",
                  "| recordings | measured / predicted | 95% CI | per recording |", "|---|---|---|---|"]
        for k in ("training", "held_out"):
            e = ec.get(k)
            if e:
                per = ", ".join("-" if x is None else f"{x:.3g}" for x in e["per_recording"])
                lo, hi = e["ci95"]
                lines.append(f"| {k.replace('_', '-')} | {e['measured_over_predicted']:.3g} | [{lo:.3g}, {hi:.3g}] | {per} |")
        lines.append("")
    lines += ["Plots: residual_map.png, heldout_fit.png, decay.png", "",
              "## Method", "", str(d["details"].get("method", "")), ""]
    return "\n".join(lines)


def plot(report: Report, out: Path) -> list[str]:
    """residual_map.png, heldout_fit.png and decay.png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pd = report.plot_data
    written = []
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
        im = ax.imshow(M.T, origin="lower", aspect="auto", extent=[xe[0], xe[-1], ye[0], ye[-1]], cmap="RdBu_r", vmin=-lim, vmax=lim)
        fig.colorbar(im, ax=ax, label="residual force (pdot units)")
        ax.set_xlabel(f"q{i}")
        ax.set_ylabel(f"qdot{i}")
        ax.set_title(f"calibrated-model residual, coordinate {i}")
    fig.tight_layout()
    fig.savefig(out / "residual_map.png", dpi=90)
    plt.close(fig)
    written.append("residual_map.png")

    hold, roll = pd["hold"], pd["rollouts"]
    t = np.arange(hold.T) * hold.dt
    fig, axes = plt.subplots(2, n, figsize=(6 * n, 6), squeeze=False, sharex=True)
    for i in range(n):
        ax = axes[0, i]
        ax.plot(t, hold.q[0, :, i], "k.", ms=2, label="measured")
        for name, style in (("nominal", ":"), ("calibrated", "--"), ("augmented", "-")):
            ax.plot(t, roll[name][0, :, i], style, lw=1, label=name)
        ax.set_ylabel(f"q{i}")
        ax.set_title(f"held-out recording 0, coordinate {i}")
        ax.legend(fontsize=7)
        ax = axes[1, i]
        for name, style in (("nominal", ":"), ("calibrated", "--"), ("augmented", "-")):
            e = roll[name][0, :, i] - hold.q[0, :, i]
            if i in hold.angle_dims:
                e = wrap(e)
            ax.plot(t, e, style, lw=1, label=name)
        ax.set_ylabel("error")
        ax.set_xlabel("t [s]")
    fig.tight_layout()
    fig.savefig(out / "heldout_fit.png", dpi=90)
    plt.close(fig)
    written.append("heldout_fit.png")

    # energy decay of the held-out recordings (energy of the calibrated H along smoothed states vs the models' rollouts)
    from .shooting import momentum, smooth

    sysC = pd["calibrated_system"]
    w = min(int(report.details.get("smoothing_window_samples", 7)), hold.T - 1 - (hold.T % 2 == 0))
    qs, vs = smooth(hold.q, hold.dt, max(w, 5))

    def energy(q: np.ndarray, v: np.ndarray) -> np.ndarray:
        p = momentum(sysC, q, v)
        return np.asarray(sysC.base.hamiltonian(tuple(q[..., i] for i in range(n)), tuple(p[..., i] for i in range(n))))

    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(t, energy(qs, vs).mean(0), "k", lw=2, label="measured (smoothed)")
    for name, style in (("nominal", ":"), ("calibrated", "--"), ("augmented", "-")):
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
    written.append("decay.png")
    return written


def write_report(report: Report, out_dir: str | Path, plots: bool = True) -> Path:
    """Write into a temporary sibling directory, then rename: no half-written report is ever left."""
    out = Path(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp creates 0700; a report directory is an ordinary one
    try:
        (tmp / "report.json").write_text(json.dumps(_jsonable(report.to_dict()), indent=2) + "\n")
        (tmp / "report.md").write_text(markdown(report))
        if plots:
            plot(report, tmp)
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
            os.rmdir(old)
            os.replace(out, old)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
