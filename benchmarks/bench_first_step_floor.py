"""Information floor of the next-step MSE rows (paper Table 4: RLC, LJ-3, heat exchange, N-body, predator-prey).

The next-step MSE (paper Eq. 90, ``phast_model.train.metrics.forecast_metrics`` key ``mse``) averages over t = 0..T-2, so it
includes the prediction of q_1 from q_0 alone.  No causal model can know the velocity then: the best possible
first prediction is E[q_1 | q_0], and the unavoidable part of the metric is

    floor = E_{q_0}[ Var(q_1 | q_0) ] / (T - 1)      (averaged over coordinates, like ``mse``),

because every env draws q_0 and p_0 independently (``System.sample_initial``).  This script estimates it
(:func:`phast_model.bench.floor.first_step_floor`) on the benchmark's test set by drawing ``--draws`` momenta p_0
from the env's own initial distribution for every test q_0 and stepping the env's own integrator once
(``phast_gym.integrate.simulate``).  A model's ``mse`` below this floor is impossible; a paper number below it
means the paper's env or metric differs from ours.

    python benchmarks/bench_first_step_floor.py --out docs/results/first_step_floor.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from phast_gym.fileio import atomic_write_text
from phast_model.bench.floor import NEXT_STEP_ENVS, first_step_floor


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
