"""``phast-train``: train a PHAST model on a registered env and write a run directory.

    phast-train --env PHAST/WindyPendulum-v0 --regime partial --epochs 50 --seed 0 \\
        --n-train 1000 --out runs/windy_partial [--resume]

Writes ``model.pt``, ``config.json``, ``metrics.json`` (Table 16 keys on the test split
plus the training wall time), ``history.json``, ``checkpoint.pt`` and plots
(``rollout.png``, ``phase.png``, ``damping.png``, ``energy.png``): :func:`phast_model.runs.train_run`.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from phast_gym import env_ids
from phast_gym.datasets import PortExcitation

from ..runs import DataSpec, train_run

__all__ = ["main", "parse_args", "train_run"]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="phast-train", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--env", required=True, help=f"env id, one of {env_ids()}")
    ap.add_argument("--regime", default="partial", choices=("known", "partial", "unknown"))
    ap.add_argument("--epochs", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0, help="model / training seed")
    ap.add_argument("--data-seed", type=int, default=42, help="dataset seed (paper: 42)")
    ap.add_argument("--n-train", type=int, default=1000)
    ap.add_argument("--n-val", type=int, default=200)
    ap.add_argument("--n-test", type=int, default=200)
    ap.add_argument("--T", type=int, default=200, help="trajectory length")
    ap.add_argument("--batch-size", type=int, default=64)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--obs-noise-std", type=float, default=0.0)
    ap.add_argument("--port-excitation", type=float, default=0.0, metavar="STD",
                    help="drive the port of the data with random torques/forces of this std, held --excitation-hold "
                         "steps (default 0: free motion, as in the paper); a model meant for control needs it, since "
                         "free motion leaves the scale of H and so the input gain unidentified")
    ap.add_argument("--excitation-hold", type=int, default=5, metavar="STEPS")
    ap.add_argument("--excitation-seed", type=int, default=0)
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=JSON",
                    help="override a PHASTConfig field, e.g. --set damping_cap=1.0 --set substeps=4")
    ap.add_argument("--out", required=True, help="run directory")
    ap.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    ap.add_argument("--no-plots", action="store_true")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    ap.add_argument("--no-progress", action="store_true")
    return ap.parse_args(argv)


def _overrides(items: list[str]) -> dict[str, Any]:
    out = {}
    for it in items:
        if "=" not in it:
            raise ValueError(f"--set expects FIELD=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    import torch

    torch.set_num_threads(max(1, args.threads))
    try:
        from ..training import TrainConfig

        data = DataSpec(n_train=args.n_train, n_val=args.n_val, n_test=args.n_test, T=args.T, seed=args.data_seed,
                        obs_noise_std=args.obs_noise_std,
                        excitation=PortExcitation(args.port_excitation, args.excitation_hold, args.excitation_seed))
        train = TrainConfig(epochs=args.epochs, batch_size=args.batch_size, lr=args.lr, seed=args.seed,
                            progress=not args.no_progress)
        metrics = train_run(args.env, args.regime, args.out, data=data, train=train, overrides=_overrides(args.set),
                            resume=args.resume, plots=not args.no_plots)
    except ValueError as exc:
        print(f"phast-train: error: {exc}", file=sys.stderr)
        return 2
    keys = [metrics["benchmark_metric"], "damping_r2", "train_wall_time_s"]
    print(json.dumps({k: metrics.get(k) for k in keys if k in metrics}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
