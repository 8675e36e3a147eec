"""Acceptance benchmark of the PHAST world model (paper protocol, CPU).

    .venv/bin/python benchmarks/phast_windy.py --seeds 0 1 2 3 4 --out docs/results/phast_windy.json

Windy pendulum (1000 / 200 / 200 trajectories, T = 200, dataset seed 42, 50 epochs) in the
KNOWN / PARTIAL / UNKNOWN regimes, plus the damped pendulum and the windy cart-pole, each
seed a full ``phast-train`` run.  Acceptance (windy pendulum): KNOWN damping R^2 >= 0.99,
PARTIAL rollout wrap-MSE(H=100) <= 0.092, UNKNOWN <= 0.298, wall time per 50-epoch run <= 180 s.
The JSON is rewritten after every run (a partial sweep is never lost); every run records the commit it was
measured at.

``--check`` (``make check-results``) re-runs the selected runs of ``--out`` with the current code, in a temporary
directory, and compares them with the committed numbers within ``TOLERANCE``: exit status 1 and a table naming
each drifted number when they disagree.  Run it whenever phast_gym's integrators or phast_model change.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import platform
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

import torch
from tqdm.auto import tqdm

from phast_model.bench.acceptance import (
    DEFAULT_RUNS,
    MACHINE_REFS,
    check,
    import_references,
    markdown_table,
    numerics,
    summarize_acceptance,
    train_one,
)
from phast_model.train.checkpoint import atomic_write_json


class _call:
    """Run now, expose the result like a future (``--jobs 1``: runs stay sequential and lazy)."""

    def __init__(self, fn, *args) -> None:  # noqa: ANN001
        self.fn, self.args = fn, args

    def result(self) -> dict:
        return self.fn(*self.args)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--runs", nargs="*", default=None, metavar="ENV:REGIME",
                    help="subset, e.g. WindyPendulum-v0:partial (default: the five of the protocol)")
    ap.add_argument("--epochs", type=int, default=50)
    ap.add_argument("--n-train", type=int, default=1000)
    ap.add_argument("--runs-dir", default=None, help="keep run directories here (default: a temp dir)")
    ap.add_argument("--table", action="store_true", help="print the markdown table of --out and exit")
    ap.add_argument("--check", action="store_true",
                    help="re-run the selected runs of --out and compare with the committed numbers (exit 1 on drift)")
    ap.add_argument("--replace", action="store_true", help="with --append: drop and rerun the selected runs")
    ap.add_argument("--jobs", type=int, default=1,
                    help="runs in parallel processes (1 torch thread each; wall times then include contention)")
    ap.add_argument("--import-references", metavar="FILE", default=None,
                    help="add the runs of FILE (this script's JSON, e.g. from a checkout of the committed commit on "
                         "another machine) to --out as that machine's references for --check, and exit")
    ap.add_argument("--out", default="docs/results/phast_windy.json")
    ap.add_argument("--append", action="store_true",
                    help="keep the runs already in --out (same protocol) and skip those (env, regime, seed)")
    args = ap.parse_args(argv)
    if args.table:
        print(markdown_table(json.loads(Path(args.out).read_text())))
        return 0
    if args.import_references:
        for r in import_references(Path(args.out), Path(args.import_references)):
            print(f"reference {r['env_id']} {r['regime']} seed {r['seed']} (at {r['commit']}) on {json.dumps(r['numerics'])}")
        return 0
    torch.set_num_threads(1)
    todo = DEFAULT_RUNS if not args.runs else [
        (e if e.startswith("PHAST/") else f"PHAST/{e}", r) for e, r in (x.split(":") for x in args.runs)]
    if args.check:
        return check(Path(args.out), todo, args.seeds, args.epochs, args.n_train)
    runs_dir = Path(args.runs_dir) if args.runs_dir else Path(tempfile.mkdtemp(prefix="phast_windy_"))
    out = Path(args.out)
    results: list[dict] = []
    prev: dict = {}
    if args.append and out.exists():
        prev = json.loads(out.read_text())
        if prev.get("protocol", {}).get("epochs") != args.epochs or prev.get("protocol", {}).get("n_train") != args.n_train:
            raise SystemExit(f"{out} holds another protocol; drop --append or use another --out")
        results = list(prev.get("runs", []))
        if args.replace:  # rerun the selected (env, regime, seed) with the current code
            sel = {(e, r, sd) for e, r in todo for sd in args.seeds}
            results = [r for r in results if (r["env_id"], r["regime"], r["seed"]) not in sel]
            # their other-machine reproductions reproduce the replaced numbers: drop them too
            prev[MACHINE_REFS] = [r for r in prev.get(MACHINE_REFS, []) if (r["env_id"], r["regime"], r["seed"]) not in sel]
    done = {(r["env_id"], r["regime"], r["seed"]) for r in results}
    t0 = time.time()
    jobs = [(e, r, s) for e, r in todo for s in args.seeds if (e, r, s) not in done]
    if args.jobs < 1:
        raise SystemExit(f"--jobs must be >= 1, got {args.jobs}")
    pool = ProcessPoolExecutor(args.jobs, mp_context=mp.get_context("spawn")) if args.jobs > 1 else None
    futs = [(pool.submit if pool else _call)(train_one, env, regime, seed, str(runs_dir), args.epochs, args.n_train)
            for env, regime, seed in jobs]
    for fut in tqdm(as_completed(futs) if pool else futs, total=len(futs), desc="phast_windy"):
        results.append(fut.result())
        results.sort(key=lambda r: (r["env_id"], r["regime"], r["seed"]))
        atomic_write_json(out, {
            "command": "benchmarks/phast_windy.py " + " ".join(argv if argv is not None else __import__("sys").argv[1:]),
            "protocol": {"n_train": args.n_train, "n_val": 200, "n_test": 200, "T": 200, "data_seed": 42,
                         "epochs": args.epochs, "torch_threads": 1},
            "machine": {"platform": platform.platform(), "processor": platform.processor(), **numerics()},
            "elapsed_s": time.time() - t0, "summary": summarize_acceptance(results), "runs": results,
            **({MACHINE_REFS: prev[MACHINE_REFS]} if MACHINE_REFS in prev else {})})
    if pool:
        pool.shutdown()
    print(json.dumps({k: {kk: v.get(kk) for kk in ("accept", "accept_wall_time")} for k, v in summarize_acceptance(results).items()},
                     indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
