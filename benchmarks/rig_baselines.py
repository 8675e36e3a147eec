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
whole, at 5 ms: ``examples/real_pendulum_world_model.py``); ``synthetic_arm`` and ``synthetic_arm_large``, the arm's
nominal rig simulated at 10 ms with smooth random torques (9 or 99 recordings of 6 s, 3 held out): where the models
are known to learn, to tell a bug from a lack of data.
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
RIGS = ("arm", "pendulum", "synthetic_arm", "synthetic_arm_large")
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
    if rig.startswith("synthetic_arm"):  # the arm's nominal rig simulated (the sanity check: the grid's ground)
        from phast_model.bench.reality import make_reality

        n_traj = 99 if rig.endswith("large") else 9
        rec = make_reality("PHAST/DoublePendulum-v0", true_kwargs=ARM_KWARGS, n_traj=n_traj, T=600, noise_std=2e-4,
                           seed=0, u_std=0.1, x0_scale=0.2)  # the arm's ranges: |q| up to 1.1 and 1.8 rad
        cli = f"(Python only: {n_traj} simulated recordings of the arm's nominal rig at 10 ms, 6 s each)"
        return RecordingsSpec(rec, "PHAST/DoublePendulum-v0", ARM_KWARGS, "partial", (2, 4, 6), 1.0), cli
    raise ValueError(f"unknown rig {rig!r}; one of {', '.join(RIGS)}")


def run_model(rig: str, model: str, seed: int, out: Path, lrs: tuple[float, ...] | None = None) -> dict[str, Any]:
    """Sweep (``lrs``, default :data:`~phast_model.baselines.rig.SWEEP_LRS`), train and score one baseline; the
    entry stored in the results JSON."""
    from phast_model.baselines.rig import SWEEP_LRS, BaselineConfig, train_baseline_run
    from phast_model.train.config import TrainConfig
    from phast_model.train.provenance import code_commit

    spec, cli = rig_spec(rig)
    lrs = lrs or SWEEP_LRS
    commit = code_commit(short=True, dirty=True)
    t0 = time.perf_counter()
    m = train_baseline_run(spec, out / rig / f"{model}_seed{seed}",
                           BaselineConfig(model, TrainConfig(seed=seed, progress=False)), sweep=lrs)
    h = m["heldout"]
    return {"model": model, "seed": seed, "over_nominal": h[f"{model}_over_nominal"],
            "heldout_rmse": h[model]["rollout_rmse"], "nominal_rmse": h["nominal"]["rollout_rmse"],
            "n_windows": h["n_windows"], "lr": m["lr"], "lr_sweep": m["lr_sweep"], "best_epoch": m["best_epoch"],
            "epochs_run": m["epochs_run"], "best_val_loss": m["best_val_loss"], "params": m["params"],
            "windows": m["windows"], "train_wall_time_s": m["train_wall_time_s"],
            "sweep_wall_time_s": m["lr_sweep"]["wall_time_s"], "total_wall_time_s": time.perf_counter() - t0,
            "commit": commit,
            "command": f"phast-train {cli} --model {model} --seed {seed} --lr-sweep "
                       f"{','.join(f'{x:g}' for x in lrs)} --out OUT"}


def hold_reference(rig: str) -> dict[str, Any]:
    """The held-out RMSE of holding q at the burn-in's last sample (a model that learned nothing), over the nominal's
    RMSE on the same windows (``heldout_rollouts``'s ``nominal``)."""
    import torch

    from phast_model.train.rig_heldout import heldout_windows
    from phast_model.train.rig_run import prepare
    from phast_model.world.interfaces import coordinate_error

    spec, _ = rig_spec(rig)
    held = prepare(spec).heldout
    assert held is not None
    w = heldout_windows(held, spec.rollout_window_s)
    err = coordinate_error(w.q[:, w.burn - 1: w.burn].expand(-1, w.H, -1), w.q[:, w.burn:], tuple(held.angle_dims))
    return {"rollout_rmse": float(torch.sqrt((err**2).mean())), "n_windows": int(w.q.shape[0])}


def merge(path: Path, rig: str, key: str, value: dict[str, Any]) -> None:
    """Store ``value`` at ``rig -> key`` of the results JSON, keeping every other entry."""
    from phast_gym.fileio import atomic_write_json

    stored = json.loads(path.read_text()) if path.exists() else {}
    stored.setdefault(rig, {})[key] = value
    atomic_write_json(path, stored)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rig", choices=RIGS, required=True,
                    help="arm, pendulum: the real rigs; synthetic_arm(_large): 9 (99) simulated recordings of the "
                         "arm's nominal rig, 3 held out (the nominal model is exact there: read the RMSE, not the ratio)")
    ap.add_argument("--models", default="gru,lstm,transformer", help="comma-separated baselines")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("runs/rig_baselines"), help="run directories")
    ap.add_argument("--json", type=Path, default=None, help="merge the results into this JSON file")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--lrs", default=None, help="the sweep's learning rates, comma-separated (default 3e-4,1e-3,3e-3)")
    ap.add_argument("--hold", action="store_true",
                    help="store only the reference of holding q still (hold_last_q: no training)")
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(max(1, args.threads))
    if args.hold:
        ref = hold_reference(args.rig)
        print(json.dumps(ref))
        if args.json:
            merge(args.json, args.rig, "hold_last_q", ref)
        return 0
    for model in [m.strip() for m in args.models.split(",") if m.strip()]:
        lrs = tuple(float(x) for x in args.lrs.split(",")) if args.lrs else None
        entry = run_model(args.rig, model, args.seed, args.out, lrs)
        print(json.dumps({k: entry[k] for k in ("model", "over_nominal", "lr", "train_wall_time_s",
                                                "total_wall_time_s")}), flush=True)
        if args.json:
            merge(args.json, args.rig, model, entry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
