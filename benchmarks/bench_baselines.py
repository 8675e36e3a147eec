"""Parameter counts and CPU cost of every baseline (and PHAST regime) per env: one training step and one rollout.

    .venv/bin/python benchmarks/bench_baselines.py --envs WindyPendulum-v0,DampedOscillator-v0 \\
        --out docs/results/baselines_cost.json

For each (env, model): trainable parameters, seconds per optimizer step on a
batch of 64 trajectories x T = 200 (forward + backward, 1 torch thread), and
seconds for an H = 100 open-loop rollout of 64 trajectories.  Training-step
time x (n_train / 64) x epochs estimates a run's cost (used to size the reduced
sweep in docs/results.md).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from phast_gym.datasets import make_dataset
from phast_gym.registry import resolve_env_id
from phast_model.bench import ALL_MODELS, TABLE4_ENVS, RunSpec
from phast_model.bench.runner import build_run_model
from phast_model.interfaces import coordinate_error


def time_model(env_id: str, model_name: str, batch: int = 64, T: int = 200, H: int = 100, reps: int = 3) -> dict:
    ds = make_dataset(env_id, batch, T=T, seed=42)
    spec = RunSpec(env_id, model_name)
    torch.manual_seed(0)
    model = build_run_model(spec, ds)
    q = torch.as_tensor(ds.q, dtype=torch.float32)
    u = torch.as_tensor(ds.u, dtype=torch.float32) if ds.u.size else None
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
    model.train()
    times = []
    for _ in range(reps + 1):
        t0 = time.perf_counter()
        opt.zero_grad()
        e = coordinate_error(model(q, u)[:, :-1], q[:, 1:], model.angle_dims)
        (e * e).mean().backward()
        opt.step()
        times.append(time.perf_counter() - t0)
    model.eval()
    t0 = time.perf_counter()
    with torch.no_grad():
        model.rollout(q[:, :10], u, H)
    return {"env": env_id, "model": model_name, "params": model.n_parameters(),
            "train_step_s": float(np.median(times[1:])), "rollout_h100_s": time.perf_counter() - t0}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--envs", default="WindyPendulum-v0", help="comma list of env ids or 'all' (Table 4)")
    p.add_argument("--models", default="all", help=f"comma list or 'all' ({','.join(ALL_MODELS)})")
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
    rows = [time_model(e, m) for e in tqdm(envs, desc="envs") for m in models]
    for r in rows:
        print(f"{r['env']:32s} {r['model']:14s} params {r['params']:7d}  step {r['train_step_s']:.3f}s  "
              f"rollout {r['rollout_h100_s']:.2f}s")
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=out.parent, suffix=".tmp")
        with os.fdopen(fd, "w") as fh:
            json.dump({"threads": args.threads, "torch": torch.__version__, "rows": rows}, fh, indent=1)
        os.replace(tmp, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
