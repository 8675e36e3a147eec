"""Issue 55's benchmark: ``phast-rl --agent mpc`` (MPPI through the learned PHAST model + the learned hold) on the
issue's plants, seeds 0-4 by default, one run after another, each at the options the issue allows (the plant's own
settings, --max-action and the plant-time budget; the rest are defaults).

    taskset -c 1 python benchmarks/control_mpc.py --case pendulum --seeds 0 1 2 3 4
    taskset -c 1 python benchmarks/control_mpc.py --case pilco --seeds 0 1 2 3 4
    python benchmarks/control_mpc.py --case pilco --budget-s 2.5        # a case at another plant-time budget
    python benchmarks/control_mpc.py --case machine --more '--hold auto' --tag machine_ec   # a variant of a case
    python benchmarks/control_mpc.py --case pilco --seeds               # only summarize the runs already in OUT
    python benchmarks/control_mpc.py --table     # the rows of docs/control.md from the summaries

Each run writes its phast-rl outputs to ``OUT/<case>_s<seed>/`` (default OUT: docs/control_results/rl_mpc); the case's
summary over every seed in OUT (per seed: quiet success, angle only, RMS input and its ratio to the plant's LQG floor, plant seconds, wall
time, controller ms; the mean over seeds and the worst seed) is printed and written to ``OUT/<case>_summary.json``.
A benchmark, not a test: a run takes minutes.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import shlex
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from phast_gym.fileio import atomic_write_json

#: case -> (env id, env kwargs, --max-action, --budget-s, extra options); the issue's targets in docs/control.md
#: (``pendulum_sim11``: the pendulum with the SAC rows' 10%-heavy description, for the comparison)
CASES: dict[str, tuple[str, dict[str, Any], float, float, list[str]]] = {
    "pendulum": ("PHAST/Pendulum-v0", {}, 10.0, 5.0, []),
    "pilco": ("PHAST/WindyCartPole-v0", {"cart_mass": 0.5, "pole_mass": 0.5, "length": 0.6, "d_cart": 0.1, "d0": 0.0,
                                         "dd": 0.0, "actuated_dofs": [0]}, 10.0, 17.5, []),
    "windy": ("PHAST/WindyCartPole-v0", {"actuated_dofs": [0]}, 30.0, 30.0, []),
    "acrobot": ("PHAST/DoublePendulum-v0", {"actuated_dofs": [1]}, 10.0, 30.0, []),
    # the SAC rows' setting: a description 10% heavier than the plant (not the target's setting: a comparison)
    "pendulum_sim11": ("PHAST/Pendulum-v0", {}, 10.0, 5.0, ["--sim-kwargs", '{"mass": 1.1}']),
    # the stand-in machine (a hidden 1.15-kg pendulum with pivot friction behind reset/step), its seed the run's (SEED)
    "machine": ("PHAST/Pendulum-v0", {}, 10.0, 5.0, ["--machine", "examples/machines/pendulum_bench.py:make",
                                                     "--machine-kwargs", '{"seed": SEED}']),
}


def run_args(case: str, seed: int, out: Path, budget: float | None, more: Sequence[str] = ()) -> list[str]:
    """The phast-rl command line of one run (``budget`` None: the case's; ``more``: options added to the case's)."""
    env, kw, max_action, default_budget, extra = CASES[case]
    return ["--agent", "mpc", "--env", env, "--env-kwargs", json.dumps(kw), "--max-action", str(max_action),
            "--task", "swingup", "--budget-s", str(default_budget if budget is None else budget), "--seed", str(seed),
            "--out", str(out), "--no-progress", *(x.replace("SEED", str(seed)) for x in extra), *more]


def lqg_floor(case: str) -> float:
    """The plant's LQG floor (the least stationary RMS input of a q-only controller at sigma 0.01)."""
    from phast_model.control.lqg_bound import system_lqg_floor
    from phast_model.rl.plant import PlantSpec, plant_system

    env, kw, max_action, _, _ = CASES[case]
    spec = PlantSpec(env, kw, max_action=max_action)
    return float(system_lqg_floor(plant_system(spec), spec.sigma, math.pi, spec.dt,
                                  kw.get("actuated_dofs"))["rms_torque"])


def summarize(case: str, runs: dict[int, dict[str, Any]], floor: float) -> dict[str, Any]:
    """The case's table: per seed and over seeds."""
    rows = {s: {"success": r["success"], "success_angle_only": r["success_angle_only"], "rms": r["rms_torque"],
                "rms_over_floor": r["rms_torque"] / floor, "plant_seconds": r["plant_seconds"], "wall_s": r["wall_s"],
                "controller_ms": r["controller_ms"]} for s, r in runs.items()}
    succ = [r["success"] for r in rows.values()]
    return {"case": case, "floor": floor, "seeds": rows,
            "mean_success": sum(succ) / len(succ), "min_success": min(succ),
            "mean_plant_seconds": sum(r["plant_seconds"] for r in rows.values()) / len(rows),
            "max_wall_s": max(r["wall_s"] for r in rows.values()),
            "max_controller_ms_p99": max(r["controller_ms"]["p99"] for r in rows.values())}


def table_row(summary: dict[str, Any]) -> str:
    """One markdown row of docs/control.md's comparison from a case's summary: success mean (per seed), RMS / floor
    (mean, range), plant seconds, wall s (range), controller ms (mean, p99 and max ranges)."""
    rows = list(summary["seeds"].values())

    def rng(key: str, fmt: str = "{:.0f}") -> str:
        vals = [r[key] for r in rows]
        return f"{fmt.format(min(vals))}-{fmt.format(max(vals))}"

    ms = [r["controller_ms"] for r in rows]
    per_seed = ", ".join("{:.2f}".format(r["success"]) for r in rows)
    return (f"| {summary['case']} | `--agent mpc` | {summary['mean_success']:.2f} ({per_seed}) | "
            f"{sum(r['rms_over_floor'] for r in rows) / len(rows):.2f}x ({rng('rms_over_floor', '{:.2f}')}) | "
            f"{summary['mean_plant_seconds']:g} | {rng('wall_s')} | "
            f"{min(m['mean'] for m in ms):.1f}-{max(m['mean'] for m in ms):.1f} / "
            f"{min(m['p99'] for m in ms):.1f}-{max(m['p99'] for m in ms):.1f} / "
            f"{min(m['max'] for m in ms):.0f}-{max(m['max'] for m in ms):.0f} |")


def main(argv: list[str] | None = None) -> int:
    from phast_model.cli.rl import main as phast_rl

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--table", action="store_true", help="print the markdown rows of OUT/*_summary.json and exit")
    ap.add_argument("--case", choices=sorted(CASES))
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2, 3, 4],
                    help="seeds to run (none: only summarize the case's runs already in OUT)")
    ap.add_argument("--budget-s", type=float, default=None, help="plant seconds (default: the case's target)")
    ap.add_argument("--out", default="docs/control_results/rl_mpc")
    ap.add_argument("--more", default="", help="phast-rl options added to the case's, e.g. '--hold lqr' (a variant: "
                                               "give --tag too)")
    ap.add_argument("--tag", default=None, help="the runs' name in OUT (default: the case, with _b<budget>)")
    args = ap.parse_args(argv)
    root = Path(args.out)
    if args.table:
        for path in sorted(root.glob("*_summary.json")):
            print(table_row(json.loads(path.read_text())))
        return 0
    if args.case is None:
        ap.error("--case is required (or --table)")
    runs: dict[int, dict[str, Any]] = {}
    tag = args.tag or (args.case if args.budget_s is None else f"{args.case}_b{args.budget_s:g}")
    for seed in args.seeds:
        out = root / f"{tag}_s{seed}"
        t0 = time.perf_counter()
        rc = phast_rl(run_args(args.case, seed, out, args.budget_s, shlex.split(args.more)))
        if rc != 0:
            print(f"{tag} seed {seed}: phast-rl exited {rc}")
            return rc
        runs[seed] = json.loads((out / "summary.json").read_text())
        print(f"{tag} seed {seed}: done in {time.perf_counter() - t0:.0f} s", flush=True)
    for path in sorted(root.glob(f"{tag}_s*/summary.json")):  # with the seeds run before into the same OUT
        seed_dir = re.fullmatch(rf"{re.escape(tag)}_s(\d+)", path.parent.name)  # not pendulum_sim11_s0 for pendulum
        if seed_dir:
            runs.setdefault(int(seed_dir.group(1)), json.loads(path.read_text()))
    summary = summarize(tag, dict(sorted(runs.items())), lqg_floor(args.case))
    atomic_write_json(root / f"{tag}_summary.json", summary)
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
