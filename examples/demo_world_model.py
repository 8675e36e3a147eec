"""Demo stage (world model): train PHAST PARTIAL on the windy pendulum and plot a rollout vs the truth.

Budget: 400 training trajectories x 30 epochs (about 30-60 s on 2 shared CPU cores) instead of the
paper's 1000 x 50; the full protocol is ``benchmarks/phast_windy.py``.
Run alone: ``python examples/demo_world_model.py --out demo_out``.
"""

from __future__ import annotations

import argparse
import json
import pathlib

import torch

from phast_model.cli.train import train_run

ENV = "PHAST/WindyPendulum-v0"


def run(out_dir: pathlib.Path) -> dict:
    """Train, evaluate on 100 test trajectories, write ``out_dir/world_model/`` (run dir + plots); headline numbers."""
    torch.set_num_threads(1)
    run_dir = pathlib.Path(out_dir) / "world_model"
    m = train_run(ENV, "partial", run_dir, epochs=30, seed=0, n_train=400, n_val=100, n_test=100, progress=False)
    return {
        "env": ENV,
        "regime": "partial",
        "rollout_theta_wrap_mse_h100": round(m["rollout_theta_wrap_mse_h100"], 4),
        "theta_wrap_mse": float(f"{m['theta_wrap_mse']:.3g}"),
        "damping_r2": round(m["damping_r2"], 3),
        "train_wall_time_s": round(m["train_wall_time_s"], 1),
        "figure": str(run_dir / "rollout.png"),
    }


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="demo_out")
    args = ap.parse_args()
    print(json.dumps(run(pathlib.Path(args.out)), indent=2))
