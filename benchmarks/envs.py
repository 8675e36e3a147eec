"""Env-suite benchmark: single-env step throughput vs Gymnasium's Pendulum-v1, dataset cost, batching gain.

Everything is measured side by side in one run, so the ratios are meaningful on any machine::

    python benchmarks/envs.py --out docs/envs_benchmark.json

Targets (issue "phast_gym"): PHAST/Pendulum-v0 >= 0.5x Pendulum-v1 steps/s; every full 1400 x 200
dataset <= 2 s (LennardJones3 <= 10 s); batched throughput >= 100x single-env; peak memory < 1 GB.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import gymnasium as gym
import numpy as np
from tqdm import tqdm

import phast_gym
from phast_gym.datasets import make_dataset


def steps_per_second(env_id: str, n_steps: int, repeats: int = 3) -> float:
    """Best-of-``repeats`` single-env throughput through gym.make's default wrappers."""
    env = gym.make(env_id)
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    for _ in range(200):  # warm-up (also passes the env checker's first-step checks)
        _, _, term, trunc, _ = env.step(action)
        if term or trunc:
            env.reset()
    best = 0.0
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n_steps):
            _, _, term, trunc, _ = env.step(action)
            if term or trunc:
                env.reset()
        best = max(best, n_steps / (time.perf_counter() - t0))
    return best


def dataset_cost(env_id: str, n_traj: int = 1400, T: int = 200) -> tuple[float, float]:
    """(best wall seconds of two runs, peak traced MB) to generate the full dataset, cache off.

    Memory is traced in a separate run: tracemalloc slows Python-level code several-fold."""
    make_dataset(env_id, 4, T=5, cache=False)  # warm imports
    wall = float("inf")
    for _ in range(2):
        t0 = time.perf_counter()
        make_dataset(env_id, n_traj, T=T, seed=42, cache=False)
        wall = min(wall, time.perf_counter() - t0)
    tracemalloc.start()
    make_dataset(env_id, n_traj, T=T, seed=42, cache=False)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return wall, peak / 2**20


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=5000, help="single-env steps per timing repeat")
    ap.add_argument("--n-traj", type=int, default=1400)
    ap.add_argument("--T", type=int, default=200)
    ap.add_argument("--envs", default="all", help="comma-separated ids or 'all'")
    ap.add_argument("--out", default=None, help="write the JSON results here")
    args = ap.parse_args(argv)
    os.environ.setdefault("PHAST_CACHE_DIR", tempfile.mkdtemp())
    ids = phast_gym.env_ids() if args.envs == "all" else [phast_gym.resolve_env_id(e) for e in args.envs.split(",")]

    ref = steps_per_second("Pendulum-v1", args.steps)
    rows = []
    for env_id in tqdm(ids, desc="envs", file=sys.stderr):
        sps = steps_per_second(env_id, args.steps)
        wall, peak = dataset_cost(env_id, args.n_traj, args.T)
        batched_sps = args.n_traj * (args.T - 1) / wall
        limit = 10.0 if "LennardJones" in env_id else 2.0
        rows.append({
            "env_id": env_id, "steps_per_s": sps, "ratio_vs_pendulum_v1": sps / ref,
            "dataset_wall_s": wall, "dataset_limit_s": limit, "dataset_peak_mb": peak,
            "batched_steps_per_s": batched_sps, "batched_vs_single": batched_sps / sps,
        })
    ru = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KB -> MB on Linux
    pend = next((r for r in rows if r["env_id"] == "PHAST/Pendulum-v0"), None)
    targets = {
        "pendulum_ratio>=0.5": None if pend is None else pend["ratio_vs_pendulum_v1"] >= 0.5,
        "datasets_within_limit": all(r["dataset_wall_s"] <= r["dataset_limit_s"] for r in rows),
        "batched>=100x": all(r["batched_vs_single"] >= 100 for r in rows),
        "peak_memory<1GB": ru < 1024,
    }
    result = {
        "command": "python benchmarks/envs.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__,
                    "gymnasium": gym.__version__, "platform": platform.platform()},
        "pendulum_v1_steps_per_s": ref, "process_peak_rss_mb": ru, "rows": rows, "targets_met": targets,
    }
    print(f"Gymnasium Pendulum-v1: {ref:,.0f} steps/s (reference, same run)")
    print(f"{'env':32s} {'steps/s':>9s} {'x Pend-v1':>9s} {'dataset s':>9s} {'peak MB':>8s} {'batch/single':>12s}")
    for r in rows:
        print(f"{r['env_id']:32s} {r['steps_per_s']:9,.0f} {r['ratio_vs_pendulum_v1']:9.2f} {r['dataset_wall_s']:9.2f} "
              f"{r['dataset_peak_mb']:8.0f} {r['batched_vs_single']:12.0f}")
    print(f"process peak RSS {ru:.0f} MB; targets: {targets}")
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_suffix(".tmp")
        tmp.write_text(json.dumps(result, indent=2))
        os.replace(tmp, out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
