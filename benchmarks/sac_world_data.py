"""A PHAST world model of the control plant from a few minutes of driven, noisy, q-only recordings (issue 29).

Writes ``OUT/`` (the run directory, usable as ``control_sac.py --phast-run OUT``), ``OUT/recordings.npz`` and
``OUT/world_data.json`` (the recording protocol and ``real_samples``, which ``control_sac.py`` adds to
``sac-world``'s real-env samples).  How the plant is recorded and the model learned: :mod:`benchmarks.sac.world_data`.

    python benchmarks/sac_world_data.py --out runs/damped_rec16 --n-traj 16
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> None:
    from benchmarks.sac.world_data import PlantRecording, train_world_model

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="run directory (then: control_sac.py --phast-run OUT)")
    d = PlantRecording()
    ap.add_argument("--n-traj", type=int, default=d.n_traj, help="recorded trajectories (the last two are held out)")
    ap.add_argument("--decisions", type=int, default=d.decisions, help="samples per trajectory, 0.05 s apart")
    ap.add_argument("--sigma", type=float, default=d.sigma, help="q measurement noise (rad)")
    ap.add_argument("--torque-std", type=float, default=d.torque_std, help="std of the random torques (N m)")
    ap.add_argument("--hold", type=int, default=d.hold, help="samples each random torque is held")
    ap.add_argument("--seed", type=int, default=0, help="recording seed (also the training seed)")
    ap.add_argument("--env", default=d.env_id, help="the plant recorded (PHAST/Pendulum-v0: undamped)")
    ap.add_argument("--regimes", default=",".join(d.regimes),
                    help="start regimes the recordings cycle through (near_stable: from hanging)")
    ap.add_argument("--sim", default="PHAST/Pendulum-v0", help="the rig description (its template)")
    ap.add_argument("--sim-kwargs", default='{"mass": 1.1}', help="the description's parameters (JSON)")
    ap.add_argument("--epochs", type=int, default=60)
    ap.add_argument("--window-s", type=float, default=0.5, help="multiple-shooting window (s)")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    try:
        spec = PlantRecording(n_traj=args.n_traj, decisions=args.decisions, sigma=args.sigma, torque_std=args.torque_std,
                              hold=args.hold, seed=args.seed, env_id=args.env, regimes=tuple(args.regimes.split(",")))
        kwargs = json.loads(args.sim_kwargs)
    except (ValueError, json.JSONDecodeError) as e:
        ap.error(str(e))
    if spec.n_traj < 3:
        ap.error("--n-traj must be >= 3 (two trajectories are held out)")
    holdout = (spec.n_traj - 2, spec.n_traj - 1)
    m = train_world_model(spec, Path(args.out), args.sim, kwargs, args.epochs, args.window_s, holdout, args.seed,
                          progress=not args.no_progress)
    h = m["heldout"]
    print(json.dumps({"real_samples": spec.real_samples, "heldout_rollout_rmse": h["phast"]["rollout_rmse"],
                      "nominal_rollout_rmse": h["nominal"]["rollout_rmse"], "friction": m["friction"],
                      "train_wall_time_s": m["train_wall_time_s"]}, indent=1))


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository root: benchmarks.sac
    main()
