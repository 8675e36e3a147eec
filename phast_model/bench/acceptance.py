"""The acceptance benchmark of the PHAST world model (paper protocol, CPU; ``benchmarks/phast_windy.py`` runs it).

Windy pendulum (1000 / 200 / 200 trajectories, T = 200, dataset seed 42, 50 epochs) in the
KNOWN / PARTIAL / UNKNOWN regimes, plus the damped pendulum and the windy cart-pole, each
seed a full ``phast-train`` run (:func:`train_one`).  Acceptance (windy pendulum, :data:`ACCEPT`): KNOWN damping
R^2 >= 0.99, PARTIAL rollout wrap-MSE(H=100) <= 0.092, UNKNOWN <= 0.298, wall time per 50-epoch run <= 180 s.

:func:`check` (``make check-results``) re-runs committed runs with the current code and compares them with the
committed numbers within :data:`TOLERANCE`, or with this machine's reproduction of them where one was imported
(:func:`import_references`; a run's last digits depend on the CPU, :func:`numerics`).
"""

from __future__ import annotations

import json
import math
import platform
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from ..train.checkpoint import atomic_write_json
from ..train.fit import TrainConfig
from ..train.metrics import benchmark_metric
from ..train.provenance import code_commit
from ..train.runs import DataSpec, train_run

DEFAULT_RUNS = [
    ("PHAST/WindyPendulum-v0", "known"),
    ("PHAST/WindyPendulum-v0", "partial"),
    ("PHAST/WindyPendulum-v0", "unknown"),
    ("PHAST/DampedPendulum-v0", "known"),
    ("PHAST/WindyCartPole-v0", "known"),
]
ACCEPT = {  # (env, regime) -> (metric, comparison, threshold)
    ("PHAST/WindyPendulum-v0", "known"): ("damping_r2", ">=", 0.99),
    ("PHAST/WindyPendulum-v0", "partial"): ("rollout_theta_wrap_mse_h100", "<=", 0.092),
    ("PHAST/WindyPendulum-v0", "unknown"): ("rollout_theta_wrap_mse_h100", "<=", 0.298),
}
MAX_WALL_S = 180.0
#: --check tolerances: metric -> (absolute, relative); a number passes when it is within either of the two.  The runs
#: are deterministic on one machine (1 thread); the slack covers other CPUs' floating-point summation order.
TOLERANCE: dict[str, tuple[float, float]] = {
    "damping_r2": (0.005, 0.0),
    "rollout_theta_wrap_mse_h100": (1e-4, 0.10),
    "theta_wrap_mse": (1e-9, 0.10),
}


def git_commit() -> str:
    """The code's commit, with ``+dirty`` when phast_gym / phast_model differ from it ("unknown" outside git)."""
    return code_commit(short=True, dirty=True) or "unknown"


def numerics() -> dict[str, str]:
    """What a run's last digits depend on besides the code: CPU, torch's SIMD kernels, package versions.

    A drift is read together with this fingerprint: summation order differs between CPUs, and the same code has given
    different damping R^2 on two machines (docs/phast_model.md, "Acceptance benchmark").
    """
    import numpy
    import scipy

    cpuinfo = Path("/proc/cpuinfo")
    names = [ln.split(":", 1)[1].strip() for ln in cpuinfo.read_text().splitlines() if ln.startswith("model name")] \
        if cpuinfo.exists() else []
    cpu = names[0] if names else platform.processor()
    return {"cpu": cpu, "torch_cpu_capability": str(torch.backends.cpu.get_cpu_capability()),
            "torch": str(torch.__version__), "numpy": numpy.__version__, "scipy": scipy.__version__}


def compare(committed: dict, fresh: dict) -> list[tuple[str, float, float, bool]]:
    """(metric, committed, fresh, within tolerance) for every metric of ``TOLERANCE`` both runs hold."""
    rows = []
    for k, (atol, rtol) in TOLERANCE.items():
        if k in committed and k in fresh:
            a, b = float(committed[k]), float(fresh[k])
            rows.append((k, a, b, bool(abs(a - b) <= max(atol, rtol * abs(a)))))
    return rows


#: key of the reproductions of committed runs on other machines: the committed code (or code checked to give the
#: committed numbers bit for bit) run there, so that ``--check`` on that machine compares like with like
MACHINE_REFS = "machine_references"


def _ref_key(env: str, regime: str, seed: int, numerics: dict[str, str]) -> tuple:
    return env, regime, seed, json.dumps(numerics, sort_keys=True)


def reference_for(doc: dict, env: str, regime: str, seed: int, here: dict[str, str]) -> dict | None:
    """The reproduction of (env, regime, seed) measured on a machine with this numerics fingerprint, if any."""
    key = _ref_key(env, regime, seed, here)
    refs = [r for r in doc.get(MACHINE_REFS, []) if _ref_key(r["env_id"], r["regime"], r["seed"], r["numerics"]) == key]
    return refs[-1] if refs else None


def import_references(out: Path, src: Path) -> list[dict]:
    """Add the runs of ``src`` (a JSON this script wrote, typically from a checkout of an older commit on another
    machine) to ``out``'s machine references; a reference of the same run and fingerprint is replaced."""
    doc, new = json.loads(out.read_text()), json.loads(src.read_text()).get("runs", [])
    stored = {(r["env_id"], r["regime"], r["seed"]) for r in doc.get("runs", [])}
    refs = []
    for r in new:
        key = (r.get("env_id"), r.get("regime"), r.get("seed"))
        if key not in stored or "numerics" not in r or "commit" not in r:
            raise SystemExit(f"--import-references: {src} run {key} has no committed run in {out} or lacks "
                             "numerics/commit")
        refs.append({"env_id": key[0], "regime": key[1], "seed": key[2], "commit": r["commit"],
                     "numerics": r["numerics"], **{k: r[k] for k in TOLERANCE if k in r}})
    replaced = {_ref_key(n["env_id"], n["regime"], n["seed"], n["numerics"]) for n in refs}
    keep = [r for r in doc.get(MACHINE_REFS, [])
            if _ref_key(r["env_id"], r["regime"], r["seed"], r["numerics"]) not in replaced]
    atomic_write_json(out, {**doc, MACHINE_REFS: keep + refs})
    return refs


def check(out: Path, todo: list[tuple[str, str]], seeds: list[int], epochs: int, n_train: int) -> int:
    """Re-run the selected committed runs and compare; 0 when every number reproduces, else 1."""
    if not out.exists():
        raise SystemExit(f"--check: {out} does not exist (nothing committed to compare with)")
    doc = json.loads(out.read_text())
    stored = {(r["env_id"], r["regime"], r["seed"]): r for r in doc.get("runs", [])}
    missing = [(e, r, s) for e, r in todo for s in seeds if (e, r, s) not in stored]
    if missing:
        raise SystemExit(f"--check: {out} holds no committed run for {missing}")
    ok, here = True, numerics()
    print("check-results: this machine", json.dumps(here))
    with tempfile.TemporaryDirectory(prefix="phast_check_") as tmp:
        jobs = [(e, r, s) for e, r in todo for s in seeds]
        for env, regime, seed in tqdm(jobs, desc="check-results"):
            fresh = train_one(env, regime, seed, tmp, epochs, n_train)
            ref = reference_for(doc, env, regime, seed, here)
            old = ref or stored[(env, regime, seed)]
            what = "this machine's reference" if ref else "committed"
            rows = compare(old, fresh)
            for k, a, b, good in rows:
                ok &= good
                print(f"{env.split('/')[-1]:<22} {regime:<8} seed {seed}  {k:<28} {what} {a:.6g} "
                      f"(at {old.get('commit', '?')})  now {b:.6g}  {'ok' if good else 'DRIFT'}")
            if not all(g for *_, g in rows) and old.get("numerics") != here:
                where = json.dumps(old.get("numerics", "an unrecorded machine"))
                print(f"  measured on {where}: rerun there before calling it a regression")
    print("check-results:", "every number reproduces" if ok else "DRIFT: update the docs with the new numbers "
          "(benchmarks/phast_windy.py --append --replace ...) or fix the regression")
    return 0 if ok else 1


def summarize_acceptance(runs: list[dict]) -> dict:
    """mean / std over seeds of the headline keys, per (env, regime), with acceptance checks."""
    out = {}
    keys = ("rollout_theta_wrap_mse_h100", "rollout_mixed_mse_h100", "rollout_mse_h100", "theta_wrap_mse", "mse",
            "damping_r2", "damping_mae", "rollout_energy_budget_resid_h100", "rollout_passivity_violations_h100",
            "train_wall_time_s", "n_parameters")
    for env, regime in sorted({(r["env_id"], r["regime"]) for r in runs}):
        rs = [r for r in runs if r["env_id"] == env and r["regime"] == regime]
        s: dict[str, Any] = {"seeds": [r["seed"] for r in rs], "benchmark_metric": benchmark_metric(env)}
        for k in keys:
            # None / NaN: undefined for this run (damping R^2 where the true D is constant)
            vals = [float(r[k]) for r in rs if r.get(k) is not None and math.isfinite(float(r[k]))]
            if vals:
                s[k] = {"mean": float(np.mean(vals)), "std": float(np.std(vals)), "values": vals}
        crit = ACCEPT.get((env, regime))
        if crit:
            metric, op, thr = crit
            m = s[metric]["mean"]
            vals = s[metric]["values"]
            s["accept"] = {"metric": metric, "threshold": thr, "op": op, "mean": m,
                           "pass": bool(m >= thr if op == ">=" else m <= thr),
                           "every_seed_pass": bool(min(vals) >= thr if op == ">=" else max(vals) <= thr)}
        if env == "PHAST/WindyPendulum-v0":
            w = max(s["train_wall_time_s"]["values"])
            s["accept_wall_time"] = {"max_s": w, "threshold_s": MAX_WALL_S, "pass": bool(w <= MAX_WALL_S)}
        out[f"{env}|{regime}"] = s
    return out


def markdown_table(doc: dict) -> str:
    """The docs table (docs/phast_model.md) of a results JSON: one row per (env, regime), mean +- std over seeds."""
    lines = ["| env | regime | seeds | headline metric (mean +- std) | damping R^2 (per seed) | damping MAE |"
             " wall time per run [s] (max) | params | acceptance |", "|---|---|---|---|---|---|---|---|---|"]
    for key, s in summarize_acceptance(doc["runs"]).items():  # recomputed: tables always match the runs
        env, regime = key.split("|")
        bm = s["benchmark_metric"]

        def ms(k: str, f: str = ".3f", s: dict = s) -> str:
            return f"{s[k]['mean']:{f}} +- {s[k]['std']:{f}}" if k in s else "-"

        r2 = ms("damping_r2") + (" (" + ", ".join(f"{v:.4f}" for v in s["damping_r2"]["values"]) + ")"
                                  if "damping_r2" in s and ACCEPT.get((env, regime), ("",))[0] == "damping_r2" else "")
        acc = []
        if "accept" in s:
            a = s["accept"]
            acc.append(f"{a['metric']} {a['op']} {a['threshold']}: {'PASS' if a['pass'] else 'FAIL'} ({a['mean']:.4f})"
                       + ("" if "every_seed_pass" not in a
                          else f", every seed: {'PASS' if a['every_seed_pass'] else 'FAIL'}"))
        if "accept_wall_time" in s:
            acc.append(f"wall <= {MAX_WALL_S:.0f} s: {'PASS' if s['accept_wall_time']['pass'] else 'FAIL'}")
        wall = s["train_wall_time_s"]
        lines.append(f"| {env.split('/')[-1]} | {regime} | {len(s['seeds'])} | {bm} = {ms(bm, '.4f')} | {r2} | "
                     f"{ms('damping_mae')} | {wall['mean']:.0f} ({max(wall['values']):.0f}) | "
                     f"{s['n_parameters']['values'][0]:.0f} | {'; '.join(acc)} |")
    return "\n".join(lines)


def train_one(env: str, regime: str, seed: int, runs_dir: str, epochs: int, n_train: int) -> dict:
    """One ``phast-train`` run (1 torch thread; also the worker of ``--jobs``)."""
    torch.set_num_threads(1)
    rd = Path(runs_dir) / f"{env.split('/')[-1]}_{regime}_s{seed}"
    m = train_run(env, regime, rd, data=DataSpec(n_train=n_train),
                  train=TrainConfig(epochs=epochs, seed=seed, progress=False), plots=False)
    return {"env_id": env, "regime": regime, "seed": seed, "commit": git_commit(), "numerics": numerics(), **m}
