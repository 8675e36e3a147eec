"""Demo stage: generate datasets of five systems and plot trajectories and phase portraits.

Uses :func:`phast_gym.make_dataset` (batched, cached) exactly as training does, and saves
``OUT/trajectories.png``: for each system the observed q over time (what a q-only model sees)
and the true phase portrait q vs p (what it has to infer).

Run alone: ``python examples/demo_datasets.py --out demo_out/datasets`` (a few seconds).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from phast_gym import make_dataset  # noqa: E402
from phast_gym.systems import break_at_wraps  # noqa: E402

SYSTEMS = (
    ("PHAST/WindyPendulum-v0", 0, "theta"),
    ("PHAST/WindyCartPole-v0", 1, "theta"),
    ("PHAST/DampedDoublePendulum-v0", 0, "theta1"),
    ("PHAST/RLCCircuit-v0", 0, "charge qC"),
    ("PHAST/PredatorPrey-v0", 0, "prey n1"),
)


def run(out_dir: pathlib.Path, n_traj: int = 64, n_plot: int = 5) -> dict:
    """Generate ``n_traj`` trajectories (T = 200) per system, plot ``n_plot`` of them."""
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(2, len(SYSTEMS), figsize=(4.0 * len(SYSTEMS), 7.0))
    stats = {}
    t0 = time.perf_counter()
    for col, (env_id, dim, label) in enumerate(SYSTEMS):
        ds = make_dataset(env_id, n_traj, T=200, seed=42)
        t = np.arange(ds.T) * ds.dt
        ax_t, ax_p = axes[0, col], axes[1, col]
        for i in range(n_plot):
            y = break_at_wraps(ds.q[i, :, dim]) if dim in ds.angle_dims else ds.q[i, :, dim]
            ax_t.plot(t, y, lw=1.0)
            ax_p.plot(ds.q_true[i, :, dim], ds.p[i, :, dim], lw=1.0)
            ax_p.plot(ds.q_true[i, 0, dim], ds.p[i, 0, dim], "k.", ms=5)
        name = env_id.split("/")[1]
        ax_t.set_title(f"{name}\nobserved {label}" + (" (wrapped)" if dim in ds.angle_dims else ""), fontsize=10)
        ax_t.set_xlabel("t [s]")
        ax_p.set_title(f"true phase portrait ({label} vs p)", fontsize=10)
        ax_p.set_xlabel(label + (" (unwrapped)" if dim in ds.angle_dims else ""))
        ax_p.set_ylabel("predators n2" if "Predator" in env_id else "p")
        stats[name] = {"n_traj": ds.n_traj, "T": ds.T, "dt": ds.dt, "q_std": float(ds.q.std()),
                       "mean_damping": float(ds.damping.mean())}
    fig.suptitle("phast_gym datasets: what a q-only model observes (top) and the hidden (q, p) dynamics (bottom)")
    fig.tight_layout()
    path = out_dir / "trajectories.png"
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return {"systems": len(SYSTEMS), "n_traj": n_traj, "generate_and_plot_s": round(time.perf_counter() - t0, 2),
            "figure": str(path), "stats": stats}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="demo_out/datasets")
    ap.add_argument("--n-traj", type=int, default=64)
    args = ap.parse_args()
    print(json.dumps(run(pathlib.Path(args.out), n_traj=args.n_traj), indent=2))


if __name__ == "__main__":
    main()
