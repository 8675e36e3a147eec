"""CPU cost of every model of the grid per env: one training step and the evaluation rollouts.

    PYTHONPATH=. OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_baselines.py
    .venv/bin/python benchmarks/bench_baselines.py --envs WindyPendulum-v0,DampedOscillator-v0 --out cost.json

What is timed, and the slower references timed beside it: :mod:`phast_model.bench.cost`.
Training-step time x (n_train / 64) x epochs estimates a run's training cost.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile

import torch

from phast_gym.registry import resolve_env_id
from phast_model.bench import ALL_MODELS, TABLE4_ENVS, RunSpec
from phast_model.bench.cost import format_row, format_total, time_model


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--envs", default="WindyPendulum-v0", help="comma list of env ids or 'all' (Table 4)")
    p.add_argument("--models", default="all", help=f"comma list or 'all' ({','.join(ALL_MODELS)})")
    p.add_argument("--reps", type=int, default=3, help="timed training steps (the minimum is reported)")
    p.add_argument("--n-eval", type=int, default=200, help="trajectories in the evaluation rollout")
    p.add_argument("--no-reference", action="store_true", help="skip the reference timings")
    p.add_argument("--out", default=None, help="JSON output path (default: print only)")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    torch.set_num_threads(args.threads)
    try:
        envs = list(TABLE4_ENVS) if args.envs == "all" else [resolve_env_id(e) for e in args.envs.split(",")]
        models = list(ALL_MODELS) if args.models == "all" else args.models.split(",")
        for m in models:
            RunSpec(envs[0], m)  # validates the name
    except Exception as exc:  # noqa: BLE001 - bad input: one clear line
        print(f"bench_baselines: error: {exc}", file=sys.stderr)
        return 2
    rows = []
    for e in envs:
        env_rows = []
        for m in models:
            env_rows.append(time_model(e, m, n_eval=args.n_eval, reps=args.reps, reference=not args.no_reference))
            print(format_row(env_rows[-1]), flush=True)
        print(format_total(env_rows), flush=True)
        rows += env_rows
    if args.out:
        out = os.path.abspath(args.out)
        os.makedirs(os.path.dirname(out), exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=os.path.dirname(out), suffix=".tmp")
        with os.fdopen(fd, "w") as fh:
            json.dump({"threads": args.threads, "torch": str(torch.__version__), "rows": rows}, fh, indent=1)
        os.replace(tmp, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
