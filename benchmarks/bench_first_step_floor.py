"""Information floor of the next-step MSE rows (paper Table 4: RLC, LJ-3, heat exchange, N-body, predator-prey).

The next-step MSE (paper Eq. 90, ``phast_model.metrics.forecast_metrics`` key ``mse``) averages over t = 0..T-2, so it
includes the prediction of q_1 from q_0 alone.  No causal model can know the velocity then: the best possible
first prediction is E[q_1 | q_0], and the unavoidable part of the metric is

    floor = E_{q_0}[ Var(q_1 | q_0) ] / (T - 1)      (averaged over coordinates, like ``mse``),

because every env draws q_0 and p_0 independently (``System.sample_initial``).  This script estimates it on the
benchmark's test set by drawing ``--draws`` momenta p_0 from the env's own initial distribution for every test q_0
and stepping the env's own integrator once (``phast_gym.integrate.simulate``).  A model's ``mse`` below this floor
is impossible; a paper number below it means the paper's env or metric differs from ours.

    python benchmarks/bench_first_step_floor.py --out docs/results/first_step_floor.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from phast_gym import make_env_system, resolve_env_id
from phast_gym.datasets import make_splits
from phast_gym.fileio import atomic_write_text
from phast_gym.integrate import simulate

NEXT_STEP_ENVS = ("PHAST/RLCCircuit-v0", "PHAST/LennardJones3-v0", "PHAST/HeatExchange-v0", "PHAST/NBody3-v0",
                  "PHAST/PredatorPrey-v0")


def first_step_floor(env_id: str, n_train: int = 200, n_val: int = 50, n_test: int = 50, T: int = 200,
                     data_seed: int = 42, draws: int = 256, seed: int = 0) -> dict[str, float]:
    """Floor of the t = 0 term of the next-step MSE on the test split (see module docstring)."""
    env_id = resolve_env_id(env_id)
    if draws < 2:
        raise ValueError(f"draws must be >= 2, got {draws!r}")
    test = make_splits(env_id, n_train, n_val, n_test, T=T, seed=data_seed)["test"]
    system = make_env_system(env_id)
    n = system.n
    q0 = np.asarray(test.q_true[:, 0])  # (N, n)
    p0 = system.sample_initial(np.random.default_rng(seed), q0.shape[0] * draws)[:, n:]  # independent of q0
    x0 = np.concatenate([np.repeat(q0, draws, 0), p0], 1)
    q1 = simulate(system, x0, 1)[:, 1, :n].reshape(q0.shape[0], draws, n)
    var = q1.var(1, ddof=1).mean()  # E_q0 Var(q1 | q0), per coordinate
    return {"env": env_id, "first_step_var": float(var), "floor_mse": float(var / (T - 1)), "T": T,
            "n_test": int(q0.shape[0]), "draws": int(draws)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--envs", default=",".join(NEXT_STEP_ENVS), help="comma-separated env ids")
    ap.add_argument("--n-train", type=int, default=200)
    ap.add_argument("--n-val", type=int, default=50)
    ap.add_argument("--n-test", type=int, default=50)
    ap.add_argument("--T", type=int, default=200)
    ap.add_argument("--data-seed", type=int, default=42)
    ap.add_argument("--draws", type=int, default=256, help="momenta drawn per test q_0")
    ap.add_argument("--out", default=None, help="JSON output path (default: print only)")
    a = ap.parse_args(argv)
    rows = [first_step_floor(e, a.n_train, a.n_val, a.n_test, a.T, a.data_seed, a.draws) for e in a.envs.split(",") if e]
    for r in rows:
        print(f"{r['env']:28s} floor of next-step mse (t = 0 term) = {r['floor_mse']:.3g}")
    if a.out:
        atomic_write_text(Path(a.out), json.dumps({"command": "python benchmarks/bench_first_step_floor.py " + " ".join(
            argv if argv is not None else sys.argv[1:]), "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
