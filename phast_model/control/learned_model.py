"""The learned-model-in-the-loop study's tables: the plant-physics UKF next to ``phast-ukf`` (the same filter with
a trained PHAST run as its process model), one row per (target, sigma, process model), and what each run's
prediction rests on near the targets (:func:`linearised`).  ``benchmarks/control_learned_model.py`` writes them.

The rows come from the ``results.json`` / ``protocol.json`` that ``phast-control-eval`` wrote into the
sub-directories of one directory (one per target and PHAST run, named ``<plant>_<target>_<run>``, e.g.
``windy_q0_known`` or ``windy_up_partial_excited``).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: estimators reported: the plant-physics UKF ("ukf"; stored results before the rename call it "ekf") and phast-ukf
PLANT_UKFS, LEARNED_UKF = ("ukf", "ekf"), "phast-ukf"


@dataclass(frozen=True)
class Row:
    """One pooled (all regimes) result."""

    target: str
    sigma: float
    process_model: str
    n: int
    success: float
    success_angle: float
    u_rms_final: float
    effort: float
    velocity_error: float


def _target(protocol: dict) -> str:
    return "upright (q* = pi)" if abs(math.cos(protocol["q_star"]) + 1) < 1e-9 else "hanging (q* = 0)"


#: run-name suffixes: how the run differs from the regime's defaults
VARIANTS = {"excited": "excited port", "ident": "identification settings"}


def label(run: str) -> str:
    """``partial`` -> "PHAST PARTIAL", ``partial_excited`` -> "PHAST PARTIAL, excited port" (trained on driven data)."""
    base, _, tag = run.partition("_")
    return f"PHAST {base.upper()}" + (f", {VARIANTS.get(tag, tag)}" if tag else "")


def _rows(sub: Path, regime: str) -> list[Row]:
    """Pooled rows of the plant UKF and phast-ukf in one evaluation directory (``regime``: the run's label)."""
    protocol = json.loads((sub / "protocol.json").read_text())
    out = []
    for r in json.loads((sub / "results.json").read_text()):
        if r["regime"] != "all" or r["estimator"] not in (*PLANT_UKFS, LEARNED_UKF):
            continue
        model = "plant physics" if r["estimator"] in PLANT_UKFS else label(regime)
        out.append(Row(_target(protocol), float(r["sigma"]), model, int(r["n_trials"]), r["success_rate"],
                       r["success_angle_rate"], r["u_rms_final"], r["effort"], r["velocity_error"]))
    return out


def summarize_runs(root: Path, runs: dict[str, Path]) -> tuple[list[Row], dict[str, dict]]:
    """All rows under ``root`` (sub-directories named ``*_<regime>``) and the runs' model metrics."""
    rows: list[Row] = []
    for sub in sorted(p for p in root.iterdir() if (p / "results.json").exists()):
        rows += _rows(sub, sub.name.split("_", 2)[-1])  # windy_up_partial_excited -> partial_excited
    uniq = {(r.target, r.sigma, r.process_model): r for r in rows}  # the plant UKF appears once per target
    rows = sorted(uniq.values(), key=lambda r: (r.target, r.sigma, r.process_model != "plant physics", r.process_model))
    keys = ("damping_r2", "rollout_theta_wrap_mse_h100", "rollout_takeover_theta_wrap_mse_h100", "mse")
    metrics = {}
    for name, run in runs.items():
        m = json.loads((run / "metrics.json").read_text())
        metrics[name] = {**{k: m[k] for k in keys if k in m}, **linearised(run)}
    return rows, metrics


def linearised(run: Path) -> dict[str, float]:
    """What the filter's prediction rests on near the targets, learned vs true (n = 1 runs).

    ``stiffness_0`` / ``stiffness_pi``: M^-1 d2V/dq2 at q = 0 and pi (the squared natural frequency, or the
    instability rate squared); ``port_gain``: M^-1 G, the acceleration per N m of torque.  Free-swing data
    (u = 0) fix only ratios of H's parts, so a learned scale of H shows up as a wrong port gain.
    """
    import torch

    from phast_gym import make_env_system
    from phast_gym.control.controller import potential_curvature

    from ..api import load_run

    model = load_run(run)
    cfg = json.loads((run / "config.json").read_text())["model"]
    system = make_env_system(cfg["env_id"], **cfg.get("env_kwargs", {}))
    out = {}
    for name, q0 in (("0", 0.0), ("pi", math.pi)):
        q = torch.full((1, 1), q0, dtype=torch.float64, requires_grad=True)
        (g,) = torch.autograd.grad(model.hamiltonian(q.float(), torch.zeros(1, 1)).sum(), q, create_graph=True)
        (h,) = torch.autograd.grad(g.sum(), q)
        minv = float(model.velocity(q.detach().float(), torch.ones(1, 1))[0, 0])
        out[f"stiffness_{name}"] = minv * float(h)
        true_minv = float(system.velocity((q0,), (1.0,))[0])
        out[f"true_stiffness_{name}"] = true_minv * float(potential_curvature(system, np.array([q0]))[0, 0])
    out["port_gain"] = float(model.velocity(torch.zeros(1, 1), torch.ones(1, 1))[0, 0]) * float(model.G[0, 0])
    out["true_port_gain"] = float(system.velocity((0.0,), (1.0,))[0])  # the torque acts on the angle itself (G = 1)
    return out


def runs_markdown(rows: list[Row], metrics: dict[str, dict]) -> str:
    lines = ["| process model | damping R^2 | rollout wrap-MSE(H=100) | takeover wrap-MSE(H=100) | M^-1 V''(0) | "
             "M^-1 V''(pi) | port gain M^-1 G |", "|---|---|---|---|---|---|---|"]
    nan = float("nan")
    for name, m in metrics.items():
        lines.append(f"| {label(name)} | {m.get('damping_r2', nan):.3f} | "
                     f"{m.get('rollout_theta_wrap_mse_h100', nan):.4f} | "
                     f"{m.get('rollout_takeover_theta_wrap_mse_h100', nan):.4f} | {m.get('stiffness_0', nan):.2f} "
                     f"(true {m.get('true_stiffness_0', nan):.2f}) | {m.get('stiffness_pi', nan):.2f} "
                     f"(true {m.get('true_stiffness_pi', nan):.2f}) | {m.get('port_gain', nan):.3f} "
                     f"(true {m.get('true_port_gain', nan):.3f}) |")
    lines += ["", "| target | sigma | filter's process model | n | success | success (angle only) | "
              "RMS torque last 1 s | effort | abs(qdot_hat - qdot) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r.target} | {r.sigma:g} | {r.process_model} | {r.n} | {r.success:.2f} | "
                     f"{r.success_angle:.2f} | {r.u_rms_final:.3f} | {r.effort:.1f} | {r.velocity_error:.4f} |")
    return "\n".join(lines) + "\n"
