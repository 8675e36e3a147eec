"""Tables and plots of closed-loop results (the rows of :func:`~phast_gym.control.evaluation.evaluate_estimators`).

* :func:`results_markdown`: tables shaped like the paper's Tables 7-11 (all start regimes pooled per sigma,
  the near-stable regime, success rate by start regime);
* :func:`plot_traces`: angle error and torque of kept episodes, one figure per sigma;
* :func:`plot_success_by_regime`: success rate per start regime (paper Fig. 8).

matplotlib is imported by the plotting functions only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..systems import break_at_wraps, wrap
from .evaluation import START_REGIMES, ControlProtocol, ControlRow, Episode

#: estimator name -> (method, velocity estimate) as the tables print them
LABELS = {
    "oracle": ("Oracle", "oracle"), "fd": ("Finite differences", "FD"), "map": ("MAP smoother", "MAP smoother"),
    "tcn": ("FD+TCN observer", "FD+TCN (noise-matched)"), "tcn-uniform": ("FD+TCN observer", "FD+TCN (U[0, s_max])"),
    "tcn-cond": ("FD+TCN observer", "FD+TCN (noise-conditioned)"), "ekf": ("UKF (plant physics)", "model-based UKF"),
    "ukf": ("UKF (plant physics)", "model-based UKF"), "phast-observer": ("PHAST-trained observer", "PHAST observer"),
    "phast-model": ("PHAST model-based (q, p)", "dH_hat/dp"),
}


def _fmt(v: float, kind: str) -> str:
    if not math.isfinite(v):
        return "nan"
    if kind == "err":
        return f"{v:.2e}"
    if kind == "eff":
        return f"{v:.1f}"
    return f"{v:.3f}" if kind == "vel" else f"{v:.2f}"


def results_markdown(rows: Sequence[ControlRow], protocol: ControlProtocol) -> str:
    """Tables shaped like paper Tables 7-11: one 'all' table per sigma, the near-stable table, and success by regime."""
    star = "pi (upright)" if abs(protocol.q_star - math.pi) < 1e-9 else f"{protocol.q_star:g}"
    lines = [f"# Energy-Casimir control ({protocol.env_id}, q_star = {star}, k_c = {protocol.k_c:g}, "
             f"d_inj = {protocol.d_inj:g}, k_xi = {protocol.k_xi:g}, xi feedback {protocol.xi_feedback}, "
             f"dt = {protocol.dt:g} s, horizon {protocol.horizon} steps)", "",
             f"Success: |wrap(q - q_star)| < {protocol.tol:g} rad and RMS torque < {protocol.u_tol:g} N m over the "
             f"last {protocol.settle_steps} steps (success_angle: angle criterion only). "
             "Final error: |wrap(q_T - q_star)| (true q). "
             "Effort: sum_t u_t^2. Velocity error: mean_t |qdot_hat - qdot|.", ""]
    sigmas = sorted({r["sigma"] for r in rows})
    per = rows[0]["n_trials"] if rows else 0
    lines += [f"## All regimes ({per} trials per regime, pooled; paper Tables 7, 8, 11)", "",
              "| sigma | Method | Velocity estimate | Success | Success (angle only) | Final error | Effort "
              "| abs(qdot_hat - qdot) | RMS torque, last window (mean / p90) |",
              "|---|---|---|---|---|---|---|---|---|"]
    for s in sigmas:
        for r in rows:
            if r["sigma"] == s and r["regime"] == "all":
                m, v = LABELS.get(r["estimator"], (r["estimator"], r["estimator"]))
                lines.append(f"| {s:.2f} | {m} | {v} | {_fmt(r['success_rate'], 's')} | "
                             f"{_fmt(r['success_angle_rate'], 's')} | {_fmt(r['final_error'], 'err')} | "
                             f"{_fmt(r['effort'], 'eff')} | {_fmt(r['velocity_error'], 'vel')} | "
                             f"{_fmt(r.get('u_rms_final', math.nan), 'vel')} / "
                             f"{_fmt(r.get('u_rms_final_p90', math.nan), 'vel')} |")
    for s in sigmas:
        lines += ["", f"## Near-stable regime, sigma = {s:g} (paper Tables 9-10)", "",
                  "| Method | Success | Final error | Effort | abs(qdot_hat - qdot) |", "|---|---|---|---|---|"]
        for r in rows:
            if r["sigma"] == s and r["regime"] == "near_stable":
                lines.append(f"| {LABELS.get(r['estimator'], (r['estimator'],))[0]} ({r['estimator']}) | "
                             f"{_fmt(r['success_rate'], 's')} | {_fmt(r['final_error'], 'err')} | "
                             f"{_fmt(r['effort'], 'eff')} | {_fmt(r['velocity_error'], 'vel')} |")
    regs = list(START_REGIMES)
    lines += ["", "## Success rate by regime (paper Fig. 8)", "", "| sigma | estimator | " + " | ".join(regs) + " |",
              "|---|---|" + "---|" * len(regs)]
    for s in sigmas:
        for name in dict.fromkeys(r["estimator"] for r in rows):
            vals = {r["regime"]: r["success_rate"] for r in rows if r["sigma"] == s and r["estimator"] == name}
            if vals:
                lines.append(f"| {s:.2f} | {name} | " + " | ".join(_fmt(vals.get(g, float('nan')), 's') for g in regs)
                             + " |")
    return "\n".join(lines) + "\n"


def plot_traces(kept: dict[tuple[float, str, str, int], Episode], protocol: ControlProtocol, out: Path) -> None:
    """Angle error and torque of the first far-unstable trial, one figure per sigma."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for s in sorted({k[0] for k in kept}):
        fig, axes = plt.subplots(2, 1, figsize=(8, 5.5), sharex=True)
        for (sig, name, _, _), ep in kept.items():
            if sig != s:
                continue
            t = np.arange(len(ep.u)) * protocol.dt
            err = break_at_wraps(wrap(ep.q[:-1, 0] - protocol.q_star))
            axes[0].plot(t, err, lw=1, label=name)
            axes[1].plot(t, ep.u[:, 0], lw=0.6, label=name)
        axes[0].set_ylabel("wrap(q - q*) [rad]")
        axes[1].set_ylabel("torque u [N m]")
        axes[1].set_xlabel("t [s]")
        axes[0].legend(fontsize=8)
        axes[0].set_title(f"Energy-Casimir closed loop, far-unstable trial 0, sigma = {s:g}")
        fig.tight_layout()
        fig.savefig(out / f"traces_sigma{s:g}.png", dpi=110)
        plt.close(fig)


def plot_success_by_regime(rows: Sequence[ControlRow], out: Path) -> None:
    """Grouped bars: success rate per regime, one panel per sigma (paper Fig. 8)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sigmas = sorted({r["sigma"] for r in rows})
    names = list(dict.fromkeys(r["estimator"] for r in rows))
    regs = list(START_REGIMES)
    fig, axes = plt.subplots(1, len(sigmas), figsize=(4.5 * len(sigmas), 3.6), squeeze=False)
    w = 0.8 / max(1, len(names))
    for ax, s in zip(axes[0], sigmas):
        for j, name in enumerate(names):
            vals = [next((r["success_rate"] for r in rows
                          if r["sigma"] == s and r["estimator"] == name and r["regime"] == g), np.nan)
                    for g in regs]
            ax.bar(np.arange(len(regs)) + j * w, vals, w, label=name)
        ax.set_xticks(np.arange(len(regs)) + 0.4 - w / 2, [g.replace("_", "\n") for g in regs], fontsize=7)
        ax.set_ylim(0, 1.05)
        ax.set_title(f"sigma = {s:g}")
    axes[0][0].set_ylabel("success rate")
    axes[0][-1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "success_by_regime.png", dpi=110)
    plt.close(fig)
