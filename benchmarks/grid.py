"""Background driver of the paper-protocol grid (all 13 rows x models x seeds), resumable across sessions.

    (echo 19 > /proc/self/autogroup; exec nice -n 19 .venv/bin/python benchmarks/grid.py --models baselines --commit) &

On Linux with autogroup scheduling (``/proc/sys/kernel/sched_autogroup_enabled`` = 1), ``nice`` only ranks processes
of one session: a sweep started from another shell or with ``setsid`` still takes an equal share of the CPU from
interactive work unless its autogroup is lowered too (the ``echo`` above; harmless where autogroups are off).
Runs ``phast-bench`` one (env, model) block at a time (5 seeds, one worker, one torch thread) into
``docs/results/full`` (per-run JSON under ``runs/``, keyed by the hash of the full configuration, so a finished run
is never redone), refreshes ``summary.csv`` / ``tables.md``, the block's figures under ``figures/`` (and, after a
PHAST block, the error decomposition ``diagnostics.json`` / ``diagnostics.md`` of benchmarks/regime_diagnostics.py)
after every block and, with ``--commit``, commits that directory (that path only; retried when another git command
holds the index), so a session that ends loses at most the block in progress.  ``--dry-run`` lists what is left and
estimates its CPU time from the measured cost of a training step (``docs/results/baselines_cost.json``, written by
benchmarks/bench_baselines.py).
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import time
from pathlib import Path

from phast_model.bench.paper import PAPER
from phast_model.bench.runner import load_result
from phast_model.bench.spec import ALL_MODELS, BASELINE_MODELS, PHAST_MODELS, RunSpec, parse_seeds
from phast_model.train.fit import TrainConfig

GROUPS = {"baselines": BASELINE_MODELS, "phast": PHAST_MODELS, "all": ALL_MODELS}


def pending(envs: list[str], models: tuple[str, ...], seeds: list[int], out: Path) -> list[tuple[str, str]]:
    """(env, model) blocks with at least one seed not finished in ``out``."""
    return [(e, m) for e in envs for m in models
            if any(load_result(out, RunSpec(env_id=e, model=m, seed=s)) is None for s in seeds)]


def seeds_left(env: str, model: str, seeds: list[int], out: Path) -> int:
    """How many of ``seeds`` of one block are not finished in ``out``."""
    return sum(load_result(out, RunSpec(env_id=env, model=model, seed=s)) is None for s in seeds)


def estimate_hours(todo: list[tuple[str, str, int]], cost_json: Path) -> float | None:
    """CPU-hours of the (env, model, seeds left) blocks at the paper's protocol: steps per run (epochs x
    ceil(n_train / batch)) x the measured training step, plus the evaluation rollouts; None without the cost file
    or with a block it does not cover."""
    if not cost_json.exists():
        return None
    rows = {(r["env"], r["model"]): r for r in json.loads(cost_json.read_text())["rows"]}
    spec = RunSpec(env_id="PHAST/Pendulum-v0", model="gru")
    steps = spec.epochs * math.ceil(spec.n_train / TrainConfig().batch_size)
    total = 0.0
    for env, model, n in todo:
        r = rows.get((env, model))
        if r is None:
            return None
        total += n * (steps * r["train_step_ms"] / 1e3 + r["eval_rollout_s"])
    return total / 3600


def bench(args: list[str]) -> int:
    return subprocess.call([sys.executable, "-m", "phast_model.cli.bench", *args])


def diagnose(env: str, model: str, seeds: str, out: Path) -> int:
    """Refresh ``OUT/diagnostics.{json,md}`` (benchmarks/regime_diagnostics.py) for one finished PHAST block."""
    script = Path(__file__).with_name("regime_diagnostics.py")
    return subprocess.call([sys.executable, str(script), "--out", str(out), "--envs", env, "--models", model,
                            "--seeds", seeds, "--json", str(out / "diagnostics.json"), "--md",
                            str(out / "diagnostics.md"), "--merge"], stderr=subprocess.DEVNULL)


def commit(out: Path, message: str, tries: int = 20) -> bool:
    """``git add`` + ``git commit`` of ``out`` only; retried while another git process holds the index."""
    for _ in range(tries):
        add = subprocess.run(["git", "add", "--", str(out)], capture_output=True, text=True)
        if add.returncode == 0:
            res = subprocess.run(["git", "commit", "-q", "-m", message, "--", str(out)], capture_output=True, text=True)
            if res.returncode == 0 or "nothing to commit" in res.stdout + res.stderr:
                return True
        time.sleep(15)
    print(f"grid: could not commit {out} (git busy?); the files are on disk", file=sys.stderr)
    return False


def draw_figures(envs: list[str], seeds: list[int], out: Path) -> list[Path]:
    """``OUT/figures/<env>_rollout.png`` and ``<env>_damping_energy.png`` (paper Figs. 5-6 shape) of each env's best
    PHAST regime and best baseline among the finished runs."""
    from phast_model.bench.figures import make_figures

    return make_figures(out, [RunSpec(env_id=e, model=m, seed=s) for e in envs for m in ALL_MODELS for s in seeds])


def redraw_figures(env: str, seeds: str, out: Path) -> int:
    """:func:`draw_figures` of one env in its own process (a figure error cannot stop the grid)."""
    return subprocess.call([sys.executable, __file__, "--figures-only", "--envs", env, "--seeds", seeds, "--out",
                            str(out)], stdout=subprocess.DEVNULL)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", default="baselines", help="baselines | phast | all | a comma list")
    ap.add_argument("--envs", default="all", help="'all' (the 13 rows of Table 4) or a comma list")
    ap.add_argument("--seeds", default="0-4")
    ap.add_argument("--out", default="docs/results/full")
    ap.add_argument("--commit", action="store_true", help="git-commit OUT after every finished block")
    ap.add_argument("--dry-run", action="store_true", help="list the blocks left and estimate their CPU time")
    ap.add_argument("--figures-only", action="store_true",
                    help="train nothing: redraw the figures of ENVS from the finished runs (done after every block)")
    ap.add_argument("--cost", default="docs/results/baselines_cost.json",
                    help="per-step costs for the --dry-run estimate (benchmarks/bench_baselines.py --envs all --out)")
    args = ap.parse_args(argv)
    models = GROUPS.get(args.models) or tuple(m.strip() for m in args.models.split(","))
    envs = list(PAPER) if args.envs == "all" else [e if e.startswith("PHAST/") else f"PHAST/{e}" for e in args.envs.split(",")]
    seeds, out = parse_seeds(args.seeds), Path(args.out)
    if args.figures_only:
        print("\n".join(str(p) for p in draw_figures(envs, seeds, out)))
        return 0
    todo = pending(envs, models, seeds, out)
    print(f"grid: {len(todo)} (env, model) blocks left of {len(envs) * len(models)}", flush=True)
    if args.dry_run:
        left = [(e, m, seeds_left(e, m, seeds, out)) for e, m in todo]
        print("\n".join(f"  {e} {m} ({n} of {len(seeds)} seeds left)" for e, m, n in left))
        cost = Path(args.cost)
        hours = estimate_hours(left, cost)
        print(f"grid: about {hours:.1f} CPU-hours left (training steps timed in {cost})" if hours is not None
              else f"grid: no estimate ({cost} is missing or does not cover every block)")
        return 0
    # the summary always covers all 13 rows: drivers that split the rows between them share OUT's tables
    every = ["--envs", ",".join(PAPER), "--models", ",".join(ALL_MODELS), "--seeds", args.seeds, "--out", str(out)]
    for env, model in todo:
        t0 = time.time()
        rc = bench(["--envs", env, "--models", model, "--seeds", args.seeds, "--out", str(out), "--workers", "1",
                    "--threads", "1", "--no-progress"])
        bench([*every, "--summarize-only", "--title", "Paper protocol (1000/200/200, 50 epochs, seeds " + args.seeds + ")",
               "--note", "Written by benchmarks/grid.py as blocks finish; rows fill in across sessions."])
        redraw_figures(env, args.seeds, out)
        if model in PHAST_MODELS:  # the error decomposition of docs/results.md, section 0, kept in step with the tables
            diagnose(env, model, args.seeds, out)
        print(f"grid: {env} {model} rc={rc} in {time.time() - t0:.0f} s", flush=True)
        if args.commit:
            commit(out, f"grid: {env.split('/')[-1]} {model} seeds {args.seeds}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
