"""Demo stage (world model): identify the windy pendulum's damping field from positions only.

PHAST KNOWN is given the pendulum's potential and mass and learns the damping D(theta) = 0.3 + 0.5 |sin theta|
(the wind) from q-only trajectories; the stage plots the learned field against the true one and a rollout.
Budget: 400 training trajectories x 30 epochs (about 30-60 s on 2 shared CPU cores) instead of the paper's
1000 x 50; the full protocol is ``benchmarks/phast_windy.py``.
Run alone: ``python examples/demo_world_model.py --out demo_out``.
"""

from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np
import torch

from phast_gym.systems import NUMPY, split, stack
from phast_model.train.checkpoint import load_model
from phast_model.train.fit import TrainConfig
from phast_model.train.runs import DataSpec, train_run

ENV = "PHAST/WindyPendulum-v0"


def damping_figure(run_dir: pathlib.Path, path: pathlib.Path) -> pathlib.Path:
    """Learned D(theta) of the trained run against the env's true damping."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    model = load_model(run_dir)
    theta = np.linspace(-np.pi, np.pi, 361)
    true = np.asarray(stack(model.system.damping(split(theta[:, None]), NUMPY)))[..., 0]
    with torch.no_grad():
        learned = model.damping_diag(torch.as_tensor(theta[:, None], dtype=torch.float32)).numpy()[:, 0]
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(theta, true, "k-", lw=2, label="true D(theta) = 0.3 + 0.5 |sin theta|")
    ax.plot(theta, learned, "C1--", lw=2, label="PHAST KNOWN, learned from q only")
    ax.set_xlabel("theta [rad]")
    ax.set_ylabel("damping D(theta)")
    ax.set_title("Windy pendulum: identified damping field")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def run(out_dir: pathlib.Path) -> dict:
    """Train KNOWN, evaluate on 100 test trajectories, write the run (and its plots) into ``out_dir``; headline
    numbers."""
    torch.set_num_threads(1)
    run_dir = pathlib.Path(out_dir)
    m = train_run(ENV, "known", run_dir, data=DataSpec(n_train=400, n_val=100, n_test=100),
                  train=TrainConfig(epochs=30, seed=0, progress=False))
    fig = damping_figure(run_dir, run_dir / "damping_field.png")
    return {
        "env": ENV,
        "regime": "known",
        "damping_r2": round(m["damping_r2"], 3),
        "damping_mae": float(f"{m['damping_mae']:.3g}"),
        "rollout_theta_wrap_mse_h100": float(f"{m['rollout_theta_wrap_mse_h100']:.3g}"),
        "train_wall_time_s": round(m["train_wall_time_s"], 1),
        "figure": str(fig),
        "rollout_figure": str(run_dir / "rollout.png"),
    }


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="demo_out")
    args = ap.parse_args()
    print(json.dumps(run(pathlib.Path(args.out) / "world_model"), indent=2))
