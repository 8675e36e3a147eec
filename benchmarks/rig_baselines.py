"""The sequence baselines on the real rigs' recordings, each at its own learning rate (issue 54).

For each model: a learning-rate sweep (:data:`phast_model.baselines.rig.SWEEP_LRS`, each trained for
:data:`~phast_model.baselines.rig.SWEEP_EPOCHS` epochs, chosen by the validation windows' loss), then the run at the
grid's budget with the chosen rate, scored on the same held-out windows as PHAST and the nominal rig
(:func:`phast_model.baselines.rig.train_baseline_run`).  Results are merged into ``--json`` under ``rig -> model``
(a rerun of one model replaces its entry only).

    python benchmarks/rig_baselines.py --rig arm --models gru,lstm,transformer --seed 0 --out runs/rig_baselines \\
        --json docs/rig_results/baselines_seed0.json

Rigs (PHAST's documented commands, docs/rig_world_model.md): ``arm``, the DFKI arm C.0 (runs 2, 4, 6 held out in
1-s windows; the CLI command at the top of that page); ``pendulum``, the real pendulum arm (segments 5-6 held out
whole, at 5 ms: ``examples/real_pendulum_world_model.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("PHAST_REAL_DATA", "/work/shared/data/real"))
ARM_KWARGS = {"coordinates": "relative", "mass1": 0.64, "mass2": 0.56, "length1": 0.2, "length2": 0.3, "com1": 0.2,
              "com2": 0.32, "inertia1": 0.027, "inertia2": 0.054}


def rig_spec(rig: str) -> tuple[Any, str]:
    """The rig's :class:`RecordingsSpec` (PHAST's split and held-out windows) and the equivalent CLI arguments."""
    from phast_model.train.rig_run import RecordingsSpec

    if rig == "arm":
        path = DATA / "dfki_double_pendulum_c0.npz"
        cli = (f"--recordings {path} --sim PHAST/DoublePendulum-v0 --sim-kwargs '{json.dumps(ARM_KWARGS)}' "
               "--holdout-trajectories 2,4,6 --rollout-window-s 1")
        return RecordingsSpec(str(path), "PHAST/DoublePendulum-v0", ARM_KWARGS, "partial", (2, 4, 6), 1.0), cli
    if rig == "pendulum":
        sys.path.insert(0, str(ROOT / "examples"))
        from real_pendulum_mismatch import load

        rec, kwargs = load(DATA / "multiarm_single_pendulum.npz")
        cli = "(Python only: the example's loader sets the angle offset) holdout 4,5, whole recordings, --decimate 5"
        return RecordingsSpec(rec, "PHAST/Pendulum-v0", kwargs, "partial", (4, 5), None, decimate=5), cli
    raise ValueError(f"unknown rig {rig!r}; one of arm, pendulum")


def run_model(rig: str, model: str, seed: int, out: Path) -> dict[str, Any]:
    """Sweep, train and score one baseline; the entry stored in the results JSON."""
    from phast_model.baselines.rig import SWEEP_LRS, BaselineConfig, train_baseline_run
    from phast_model.train.config import TrainConfig
    from phast_model.train.provenance import code_commit

    spec, cli = rig_spec(rig)
    t0 = time.perf_counter()
    m = train_baseline_run(spec, out / rig / f"{model}_seed{seed}",
                           BaselineConfig(model, TrainConfig(seed=seed, progress=False)), sweep=SWEEP_LRS)
    h = m["heldout"]
    return {"model": model, "seed": seed, "over_nominal": h[f"{model}_over_nominal"],
            "heldout_rmse": h[model]["rollout_rmse"], "nominal_rmse": h["nominal"]["rollout_rmse"],
            "n_windows": h["n_windows"], "lr": m["lr"], "lr_sweep": m["lr_sweep"], "best_epoch": m["best_epoch"],
            "epochs_run": m["epochs_run"], "best_val_loss": m["best_val_loss"], "params": m["params"],
            "windows": m["windows"], "train_wall_time_s": m["train_wall_time_s"],
            "sweep_wall_time_s": m["lr_sweep"]["wall_time_s"], "total_wall_time_s": time.perf_counter() - t0,
            "commit": code_commit(short=True, dirty=True),
            "command": f"phast-train {cli} --model {model} --seed {seed} --lr-sweep "
                       f"{','.join(f'{x:g}' for x in SWEEP_LRS)} --out OUT"}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rig", choices=("arm", "pendulum"), required=True)
    ap.add_argument("--models", default="gru,lstm,transformer", help="comma-separated baselines")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("runs/rig_baselines"), help="run directories")
    ap.add_argument("--json", type=Path, default=None, help="merge the results into this JSON file")
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args(argv)
    import torch

    from phast_gym.fileio import atomic_write_json

    torch.set_num_threads(max(1, args.threads))
    for model in [m.strip() for m in args.models.split(",") if m.strip()]:
        entry = run_model(args.rig, model, args.seed, args.out)
        print(json.dumps({k: entry[k] for k in ("model", "over_nominal", "lr", "train_wall_time_s",
                                                "total_wall_time_s")}), flush=True)
        if args.json:
            stored = json.loads(args.json.read_text()) if args.json.exists() else {}
            stored.setdefault(args.rig, {})[model] = entry
            atomic_write_json(args.json, stored)
    return 0


if __name__ == "__main__":
    sys.exit(main())
