"""Env-suite benchmark: single-env step throughput vs Gymnasium's Pendulum-v1, dataset cost, batching gain.

Everything is measured side by side in one run, so the ratios are meaningful on any machine::

    python benchmarks/envs.py --out docs/envs_benchmark.json

Targets: PHAST/Pendulum-v0 >= 0.5x Pendulum-v1 steps/s; every full 1400 x 200
dataset <= 2 s (LennardJones3 <= 10 s); batched throughput >= 100x single-env; peak memory < 1 GB.

Everything runs on one core (``torch.set_num_threads(1)`` for the compiled backend; the NumPy batched
simulator and the single env are single-threaded).  ``--profile`` adds, per env, where the batched
generation spends its time (cProfile: share in sin/cos kernels and in the kink-crossing refinement)
and the cost of single numpy/torch operations at the dataset's batch size, which bound the batched
throughput from below.  ``--compiled`` times the same datasets with ``backend="compiled"``
(:mod:`phast_gym.compiled`), including the first call's compilation (cold unless ``--warm-cache``).
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import platform
import pstats
import resource
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from tqdm import tqdm

import phast_gym
from phast_gym.datasets import make_dataset
from phast_gym.fileio import atomic_write_text


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


def dataset_cost(env_id: str, n_traj: int = 1400, T: int = 200, repeats: int = 3) -> tuple[float, float]:
    """(best wall seconds of ``repeats`` runs, peak traced MB) to generate the full dataset, cache off.

    Memory is traced in a separate run: tracemalloc slows Python-level code several-fold."""
    make_dataset(env_id, 4, T=5, cache=False)  # warm imports
    wall = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        make_dataset(env_id, n_traj, T=T, seed=42, cache=False)
        wall = min(wall, time.perf_counter() - t0)
    tracemalloc.start()
    make_dataset(env_id, n_traj, T=T, seed=42, cache=False)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return wall, peak / 2**20


def per_op_costs(batch: int = 1400, repeats: int = 20000) -> dict[str, float]:
    """Microseconds per call of single operations on float64 arrays of the dataset's batch size."""
    x = np.random.default_rng(0).uniform(-3.0, 3.0, batch)
    y = x + 1.0
    xt, yt = torch.from_numpy(x), torch.from_numpy(y)
    ops = {"numpy add": lambda: x + y, "numpy multiply by float": lambda: 0.5 * x, "numpy sin": lambda: np.sin(x),
           "torch sin (incl. conversion)": lambda: torch.sin(torch.from_numpy(x)).numpy(), "torch add (eager)": lambda: xt + yt}
    out = {}
    for name, fn in ops.items():
        fn()
        t0 = time.perf_counter()
        for _ in range(repeats):
            fn()
        out[name] = (time.perf_counter() - t0) / repeats * 1e6
    return out


_TRIG = ("sin", "cos")


def profile_dataset(env_id: str, n_traj: int = 1400, T: int = 200) -> dict[str, float]:
    """cProfile shares of the batched generation: sin/cos kernels and the kink-crossing refinement."""
    from phast_gym.systems.base import NumpyNamespace

    make_dataset(env_id, 4, T=5, cache=False)
    # NumPy's ufuncs are invisible to cProfile: route the simulator's sin/cos through Python functions named so

    def sin(x: np.ndarray) -> np.ndarray:
        return np.sin(x)

    def cos(x: np.ndarray) -> np.ndarray:
        return np.cos(x)

    saved = {name: NumpyNamespace.__dict__[name] for name in _TRIG}
    NumpyNamespace.sin, NumpyNamespace.cos = staticmethod(sin), staticmethod(cos)
    prof = cProfile.Profile()
    try:
        prof.runcall(make_dataset, env_id, n_traj, T=T, seed=42, cache=False)
    finally:
        for name, fn in saved.items():
            setattr(NumpyNamespace, name, fn)
    stats = pstats.Stats(prof).stats  # (file, line, name) -> (cc, nc, tottime, cumtime, callers)
    total = max(v[3] for k, v in stats.items() if k[2] == "make_dataset")
    trig = sum(v[2] for k, v in stats.items() if k[2].split(" ")[-1].strip("<>'").split(".")[-1] in _TRIG)
    split = sum(v[3] for k, v in stats.items() if k[2] == "split_at_crossing")
    n_rhs = sum(v[1] for k, v in stats.items() if k[2] == "rhs" and "systems" in k[0])
    return {"profiled_s": total, "trig_share": trig / total, "crossing_split_share": split / total, "rhs_calls": n_rhs}


def compiled_cost(env_id: str, n_traj: int = 1400, T: int = 200, repeats: int = 3) -> dict[str, float]:
    """The same dataset with ``backend="compiled"`` (:mod:`phast_gym.compiled`): the first call's wall time
    (it includes the compilation), the best of ``repeats`` later calls, and the largest difference to the
    NumPy backend's states."""
    t0 = time.perf_counter()
    first = make_dataset(env_id, n_traj, T=T, seed=42, cache=False, backend="compiled")
    first_s = time.perf_counter() - t0
    wall = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        make_dataset(env_id, n_traj, T=T, seed=42, cache=False, backend="compiled")
        wall = min(wall, time.perf_counter() - t0)
    ref = make_dataset(env_id, n_traj, T=T, seed=42, cache=False)
    diff = max(float(np.abs(first.q_true - ref.q_true).max()), float(np.abs(first.p - ref.p).max()))
    return {"first_call_s": first_s, "wall_s": wall, "max_abs_diff_vs_numpy": diff}


def markdown(result: dict) -> str:
    """The docs/envs.md tables of a result JSON (so the docs quote the JSON exactly)."""
    prof = all("profile" in r for r in result["rows"])
    head = "| id | steps/s (gym.make) | x Pendulum-v1 | dataset 1400 x 200 [s] (target) | traced peak [MB] | batched / single |"
    sep = "|---|---|---|---|---|---|"
    base = result.get("baseline")
    if base:
        head += f" speed-up vs `{base['ref']}`: dataset / single env |"
        sep += "---|"
    if prof:
        head += " sin/cos kernels | crossing refinement |"
        sep += "---|---|"
    load = result["machine"].get("loadavg_1min_before_after")
    lines = [f"Gymnasium `Pendulum-v1` in the same run: {result['pendulum_v1_steps_per_s']:,.0f} steps/s. "
             f"Process peak RSS: {result['process_peak_rss_mb']:.0f} MB (target < 1 GB). "
             f"1-min load average before / after: {' / '.join(f'{x:.1f}' for x in load) if load else 'not recorded'}.",
             "", head, sep]
    for r in result["rows"]:
        line = (f"| `{r['env_id']}` | {r['steps_per_s']:,.0f} | {r['ratio_vs_pendulum_v1']:.2f} | "
                f"{r['dataset_wall_s']:.2f} (<= {r['dataset_limit_s']:.0f}) | {r['dataset_peak_mb']:.0f} | {r['batched_vs_single']:.0f} |")
        if base:
            b = base["datasets"][r["env_id"]]
            line += f" {b['dataset_speedup']:.2f}x / {b['single_env_speedup']:.2f}x |"
        if prof:
            line += f" {r['profile']['trig_share']:.0%} | {r['profile']['crossing_split_share']:.0%} |"
        lines.append(line)
    lines += ["", "Targets met in this run: " + ", ".join(f"`{k}`: {v}" for k, v in result["targets_met"].items())]
    if "per_op_us_at_batch" in result:
        ops = result["per_op_us_at_batch"]
        lines += ["", f"Cost of one operation on a float64 array of {ops['batch']} samples [us]: "
                  + ", ".join(f"{k} {v:.2f}" for k, v in ops.items() if k != "batch") + "."]
    if all("compiled" in r for r in result["rows"]):
        lines += ["", "Compiled backend (`make_dataset(..., backend=\"compiled\")`, TorchInductor cache "
                  f"{result.get('inductor_cache', 'unknown')} at the start):", "",
                  "| id | first call incl. compile [s] | dataset 1400 x 200 [s] | batched / single | speed-up vs NumPy backend "
                  "| max abs diff vs NumPy |", "|---|---|---|---|---|---|"]
        for r in result["rows"]:
            c = r["compiled"]
            lines.append(f"| `{r['env_id']}` | {c['first_call_s']:.1f} | {c['wall_s']:.3f} | {c['batched_vs_single']:.0f} | "
                         f"{r['dataset_wall_s'] / c['wall_s']:.1f}x | {c['max_abs_diff_vs_numpy']:.1e} |")
    return "\n".join(lines)


def baseline_speedups(ref: str, ids: list[str], n_traj: int, T: int, repeats: int) -> dict[str, dict[str, float]]:
    """Dataset wall time of ``phast_gym`` at git revision ``ref`` vs the working tree, timed interleaved in
    this process (best of ``repeats`` each), so load changes on a shared machine hit both alike."""
    import importlib
    import subprocess

    root = Path(__file__).resolve().parents[1]
    tmp = Path(tempfile.mkdtemp())
    archive = subprocess.run(["git", "archive", ref, "phast_gym"], cwd=root, check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tmp)], input=archive, check=True)
    (tmp / "phast_gym").rename(tmp / "phast_gym_baseline")  # the package uses relative imports only
    sys.path.insert(0, str(tmp))
    old = importlib.import_module("phast_gym_baseline.datasets")
    old_env = importlib.import_module("phast_gym_baseline.env").PortHamiltonianEnv
    out = {}
    for env_id in tqdm(ids, desc=f"vs {ref}", file=sys.stderr):
        # the baseline's env, registered under another id with the same kwargs and wrappers
        spec = gym.spec(env_id)
        old_id = env_id.replace("PHAST/", "PHASTBaseline/")
        if old_id not in gym.registry:
            gym.register(id=old_id, entry_point=old_env, kwargs=dict(spec.kwargs), max_episode_steps=spec.max_episode_steps)
        best = {"baseline_s": float("inf"), "current_s": float("inf"), "baseline_steps_per_s": 0.0, "current_steps_per_s": 0.0}
        for fn in (old.make_dataset, make_dataset):  # warm imports
            fn(env_id, 4, T=5, cache=False)
        for _ in range(repeats):
            for key, fn in (("baseline_s", old.make_dataset), ("current_s", make_dataset)):
                t0 = time.perf_counter()
                fn(env_id, n_traj, T=T, seed=42, cache=False)
                best[key] = min(best[key], time.perf_counter() - t0)
            for key, eid in (("baseline_steps_per_s", old_id), ("current_steps_per_s", env_id)):
                best[key] = max(best[key], steps_per_second(eid, 2000, 1))
        out[env_id] = {**best, "dataset_speedup": best["baseline_s"] / best["current_s"],
                       "single_env_speedup": best["current_steps_per_s"] / best["baseline_steps_per_s"]}
    return out


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=5000, help="single-env steps per timing repeat")
    ap.add_argument("--n-traj", type=int, default=1400)
    ap.add_argument("--T", type=int, default=200)
    ap.add_argument("--envs", default="all", help="comma-separated ids or 'all'")
    ap.add_argument("--repeats", type=int, default=3, help="best of this many timings (single env and dataset)")
    ap.add_argument("--out", default=None, help="write the JSON results here")
    ap.add_argument("--profile", action="store_true", help="add per-env cProfile shares and per-operation costs")
    ap.add_argument("--compiled", action="store_true",
                    help="also time every dataset with backend='compiled' (torch.compile; compiles for seconds to a "
                         "minute per env unless TorchInductor's on-disk cache is warm)")
    ap.add_argument("--warm-cache", action="store_true",
                    help="with --compiled: use TorchInductor's usual on-disk cache instead of a fresh one (cold compile)")
    ap.add_argument("--baseline", default=None, metavar="GIT_REF",
                    help="also time every dataset against phast_gym at this git revision (interleaved)")
    ap.add_argument("--table", default=None, metavar="JSON", help="print the docs tables of a result file and exit")
    return ap.parse_args(argv)


def measure_env(env_id: str, args: argparse.Namespace) -> dict:
    """One env's row: single-env steps/s, the batched dataset's wall time and peak memory (+ profile / compiled)."""
    sps = steps_per_second(env_id, args.steps, args.repeats)
    wall, peak = dataset_cost(env_id, args.n_traj, args.T, args.repeats)
    batched_sps = args.n_traj * (args.T - 1) / wall
    row = {"env_id": env_id, "steps_per_s": sps, "dataset_wall_s": wall,
           "dataset_limit_s": 10.0 if "LennardJones" in env_id else 2.0, "dataset_peak_mb": peak,
           "batched_steps_per_s": batched_sps, "batched_vs_single": batched_sps / sps}
    if args.profile:
        row["profile"] = profile_dataset(env_id, args.n_traj, args.T)
    if args.compiled:
        c = compiled_cost(env_id, args.n_traj, args.T, args.repeats)
        c["batched_steps_per_s"] = args.n_traj * (args.T - 1) / c["wall_s"]
        c["batched_vs_single"] = c["batched_steps_per_s"] / sps
        row["compiled"] = c
    return row


def targets_met(rows: list[dict], peak_rss_mb: float, compiled: bool) -> dict[str, bool | None]:
    """The suite's speed and memory targets (docs/envs.md) on the measured rows."""
    pend = next((r for r in rows if r["env_id"] == "PHAST/Pendulum-v0"), None)
    targets: dict[str, bool | None] = {
        "pendulum_ratio>=0.5": None if pend is None else pend["ratio_vs_pendulum_v1"] >= 0.5,
        "datasets_within_limit": all(r["dataset_wall_s"] <= r["dataset_limit_s"] for r in rows),
        "batched>=100x": all(r["batched_vs_single"] >= 100 for r in rows),
    }
    if compiled:
        targets["batched_compiled>=100x"] = all(r["compiled"]["batched_vs_single"] >= 100 for r in rows)
    targets["peak_memory<1GB"] = peak_rss_mb < 1024
    return targets


def print_report(result: dict, args: argparse.Namespace) -> None:
    """The human-readable tables of a result (the JSON holds the same numbers)."""
    rows = result["rows"]
    print(f"Gymnasium Pendulum-v1: {result['pendulum_v1_steps_per_s']:,.0f} steps/s (reference, same run)")
    print(f"{'env':32s} {'steps/s':>9s} {'x Pend-v1':>9s} {'dataset s':>9s} {'peak MB':>8s} {'batch/single':>12s}")
    for r in rows:
        print(f"{r['env_id']:32s} {r['steps_per_s']:9,.0f} {r['ratio_vs_pendulum_v1']:9.2f} {r['dataset_wall_s']:9.2f} "
              f"{r['dataset_peak_mb']:8.0f} {r['batched_vs_single']:12.0f}")
    print(f"process peak RSS {result['process_peak_rss_mb']:.0f} MB; targets: {result['targets_met']}; "
          f"load average {result['machine']['loadavg_1min_before_after']}")
    if args.profile:
        print(f"{'env':32s} {'sin/cos share':>13s} {'crossing share':>14s} {'rhs calls':>9s}")
        for r in rows:
            pr = r["profile"]
            print(f"{r['env_id']:32s} {pr['trig_share']:13.0%} {pr['crossing_split_share']:14.0%} {pr['rhs_calls']:9d}")
        print("per-op cost [us] at batch", {k: round(v, 2) for k, v in result["per_op_us_at_batch"].items()})
    if args.compiled:
        print(f"{'env':32s} {'first call s':>12s} {'compiled s':>10s} {'batch/single':>12s} {'max diff':>9s}")
        for r in rows:
            c = r["compiled"]
            print(f"{r['env_id']:32s} {c['first_call_s']:12.1f} {c['wall_s']:10.3f} {c['batched_vs_single']:12.0f} "
                  f"{c['max_abs_diff_vs_numpy']:9.1e}")


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.table:
        print(markdown(json.loads(Path(args.table).read_text())))
        return 0
    os.environ.setdefault("PHAST_CACHE_DIR", tempfile.mkdtemp())
    if args.compiled and not args.warm_cache:
        os.environ["TORCHINDUCTOR_CACHE_DIR"] = tempfile.mkdtemp()  # before torch compiles anything: a cold compile
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    ids = phast_gym.env_ids() if args.envs == "all" else [phast_gym.resolve_env_id(e) for e in args.envs.split(",")]
    ref = steps_per_second("Pendulum-v1", args.steps, args.repeats)
    rows = [measure_env(env_id, args) for env_id in tqdm(ids, desc="envs", file=sys.stderr)]
    for r in rows:
        r["ratio_vs_pendulum_v1"] = r["steps_per_s"] / ref
    ru = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KB -> MB on Linux
    result = {
        "command": "python benchmarks/envs.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__,
                    "torch": str(torch.__version__), "torch_threads": torch.get_num_threads(),
                    "gymnasium": gym.__version__, "platform": platform.platform(),
                    "loadavg_1min_before_after": [load_before[0], os.getloadavg()[0]]},
        "pendulum_v1_steps_per_s": ref, "process_peak_rss_mb": ru, "rows": rows,
        "targets_met": targets_met(rows, ru, args.compiled),
    }
    if args.profile:
        result["per_op_us_at_batch"] = {"batch": args.n_traj, **per_op_costs(args.n_traj)}
    if args.baseline:
        result["baseline"] = {"ref": args.baseline,
                              "datasets": baseline_speedups(args.baseline, ids, args.n_traj, args.T, args.repeats)}
    if args.compiled:
        result["inductor_cache"] = "warm (reused)" if args.warm_cache else "cold (fresh directory)"
    print_report(result, args)
    if args.out:
        atomic_write_text(Path(args.out), json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
