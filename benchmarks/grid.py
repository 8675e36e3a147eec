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
import subprocess
import sys
from pathlib import Path

from phast_model.bench.grid_driver import draw_figures, dry_run, grid_envs, grid_models, pending, run_blocks
from phast_model.bench.spec import parse_seeds


def diagnose(env: str, model: str, seeds: str, out: Path) -> int:
    """Refresh ``OUT/diagnostics.{json,md}`` (benchmarks/regime_diagnostics.py) for one finished PHAST block."""
    script = Path(__file__).with_name("regime_diagnostics.py")
    return subprocess.call([sys.executable, str(script), "--out", str(out), "--envs", env, "--models", model,
                            "--seeds", seeds, "--json", str(out / "diagnostics.json"), "--md",
                            str(out / "diagnostics.md"), "--merge"], stderr=subprocess.DEVNULL)


def redraw_figures(env: str, seeds: str, out: Path) -> int:
    """The figures of one env in their own process (a figure error cannot stop the grid)."""
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
    models, envs = grid_models(args.models), grid_envs(args.envs)
    seeds, out = parse_seeds(args.seeds), Path(args.out)
    if args.figures_only:
        print("\n".join(str(p) for p in draw_figures(envs, seeds, out)))
        return 0
    todo = pending(envs, models, seeds, out)
    print(f"grid: {len(todo)} (env, model) blocks left of {len(envs) * len(models)}", flush=True)
    if args.dry_run:
        print(dry_run(todo, seeds, out, Path(args.cost)))
        return 0
    run_blocks(todo, args.seeds, out, diagnose, redraw_figures, commit_each=args.commit)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
