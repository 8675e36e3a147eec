"""SB3 SAC vs Energy-Casimir on the torque-port damped pendulum (q-only, noisy), same regimes and metrics.

Agents (CPU, one torch thread):

* ``sac-real``: SAC trained on the real plant (the control env of :class:`ControlProtocol`, decisions
  every ``repeat`` plant steps with the torque held), observation = (sin q, cos q) of the last
  ``frames`` noisy measurements taken at the decision rate;
* ``sac-world`` (with ``--phast-run``): SAC trained inside :class:`phast_model.world.gym_env.PHASTWorldModelEnv`
  (the learned PHAST model, dt = the run's env dt = ``repeat`` plant steps; every episode starts from a
  burn-in window of ``burn_in`` real noisy measurements from a start-regime state) and deployed on the real plant.

Hyperparameters: the RL zoo's tuned Pendulum-v1 SAC (``learning_rate 1e-3``, everything else SB3's SAC
defaults; the zoo's 20k-step budget is replaced by ``--until-flat``).  With ``--until-flat`` training
runs in chunks of ``--eval-every`` decisions; after each chunk the deterministic policy is evaluated on
fixed seeded episodes of its training env (the real plant for ``sac-real``, the world model for
``sac-world``) and training stops when the learning curve is flat (:func:`phast_model.rl.evaluation.is_flat`) or at ``--max-steps``.
A monitoring curve on the real plant (not used for stopping, not counted as training samples) is
plotted too.  Both agents are then evaluated like ``phast-control-eval`` (five regimes, success =
settled and quiet, effort ``sum_t u_t^2`` over plant steps) and compared with Energy-Casimir rows
(``--ec-estimators``) on success, effort and real-env samples.  Rows are merged into
``OUT/control_sac.json`` / ``OUT/control_sac.md`` (one process per agent is fine); learning curves go to
``OUT/curve_<agent>.json`` and ``OUT/curve_<agent>.png``.

* ``sac-gym`` (alone): the same SAC construction and training loop on a Gymnasium env (``--gym-env``, default
  ``Pendulum-v1``) as a harness check (rows in ``OUT/gym_sac.json`` / ``OUT/gym_sac.md``).

Ablations: ``--obs`` (true-velocity / true-state observations), ``--quiet-weight`` (0.5 at ``q* = 0``; 0.05 at the
upright, below :func:`phast_model.rl.rewards.max_quiet_weight`), ``--reward precise``, ``--curve`` (fixed budget with a learning curve);
see docs/control_results/sac/DIAGNOSIS.md.

    python benchmarks/control_sac.py --out OUT --agents sac-real --until-flat --reward quiet --q-star 0
    python benchmarks/control_sac.py --out OUT --agents sac-gym --steps 20000 --curve --seed 0
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

from phast_gym.control import START_REGIMES, ControlProtocol, evaluate_estimators, resolve_estimator_name
from phast_gym.fileio import atomic_write_text

from ..rl import sac
from ..rl.envs import OBS_MODES
from ..rl.rewards import PRECISE_WELLS, QUIET_WEIGHT, REWARDS, format_wells, parse_wells
from ..rl.sac import command_line, make_protocol, regimes_of, train_agent


def write_tables(out: Path, meta: dict[str, Any]) -> None:
    """``control_sac.md`` from the merged rows of ``control_sac.json``."""
    regimes = meta.get("regimes", list(START_REGIMES))
    plant = meta.get("protocol", {}).get("env_id", ControlProtocol.env_id)
    where = "" if len(regimes) == len(START_REGIMES) else f" from {', '.join(regimes)}"
    lines = [f"SAC vs Energy-Casimir on {plant}, q_star = {meta['q_star']:.6g}, sigma = {meta['sigma']:g}, "
             f"{len(regimes) * meta['trials_per_regime']} trials{where} "
             "(success: |wrap(q - q*)| < 0.05 rad and RMS torque < 0.25 N m over the last 100 plant steps)", "",
             "| Method | Success | Success (angle only) | Effort | RMS torque, last 100 | Final error | Real-env samples "
             "| SAC decisions | Flat | Train s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in meta["results"]:
        flat = "-" if r.get("flat") is None else ("yes" if r["flat"] else "no (cap)")
        lines.append(f"| {r['method']} | {r['success_rate']:.2f} | {r['success_angle_rate']:.2f} | {r['effort']:.1f} | "
                     f"{r['u_rms_final']:.3f} | {r['final_error']:.2e} | {r['real_env_samples']} | {r.get('decisions', 0)} | {flat} | "
                     f"{r['train_seconds']} |")
    lines += ["", "Real-env samples: plant measurements consumed in training (sac-real: plant steps, 0.01 s apart; "
              "sac-world: burn-in measurements, 0.05 s apart, plus the recordings its world model was trained on when "
              "it comes from benchmarks/sac_world_data.py).", "", "Commands:", ""]
    lines += [f"* `{r['method']}`: `{r['command']}`" for r in meta["results"]]
    atomic_write_text(out / "control_sac.md", "\n".join(lines) + "\n")


def parser() -> argparse.ArgumentParser:
    """The benchmark's options (:func:`parse_args` checks how they combine)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--agents", default="sac-real,sac-world",
                    help="comma list of sac-real, sac-world (needs --phast-run); none: Energy-Casimir rows only; "
                         "sac-gym (alone): the same SAC on the Gymnasium env --gym-env (harness check, rows in OUT/gym_sac.json)")
    ap.add_argument("--gym-env", default="Pendulum-v1", help="Gymnasium env id of sac-gym")
    ap.add_argument("--gym-eval-episodes", type=int, default=20, help="seeded episodes of sac-gym's final evaluation")
    ap.add_argument("--curve", action="store_true", help="fixed budget --steps, with a learning curve every --eval-every")
    ap.add_argument("--obs", choices=OBS_MODES, default="frames",
                    help="policy observation: frames (q-only, default); frames+qdot / state: true-velocity ablations (sac-real)")
    ap.add_argument("--quiet-weight", type=float, default=None,
                    help=f"weight of the quiet reward's torque term (default {QUIET_WEIGHT} at q* = 0, 0.05 otherwise: "
                         "upright_quiet_weight)")
    ap.add_argument("--wells", default=None,
                    help="the precise reward's angle wells DEPTH:WIDTH[,...] (rad; default "
                         f"{format_wells(PRECISE_WELLS)})")
    ap.add_argument("--mirror", action="store_true",
                    help="reflection-equivariant SAC (odd actor, invariant critics: the pendulum's q -> -q symmetry; "
                         "phast_model.rl.mirror_policy)")
    ap.add_argument("--net", default=None, help="SAC hidden layer sizes, e.g. 64,64 (default: the zoo's 256,256)")
    ap.add_argument("--lr-final", type=float, default=None,
                    help="decay the learning rate linearly from the zoo's 1e-3 to this over the budget (default: constant)")
    ap.add_argument("--steps", type=int, default=20000, help="SAC decisions per agent without --until-flat (zoo: 20k)")
    ap.add_argument("--until-flat", action="store_true", help="train until the learning curve is flat (is_flat) or --max-steps")
    ap.add_argument("--max-steps", type=int, default=150000, help="cap on SAC decisions with --until-flat")
    ap.add_argument("--eval-every", type=int, default=2500, help="decisions between learning-curve evaluations")
    ap.add_argument("--eval-episodes", type=int, default=10, help="fixed seeded episodes per learning-curve point")
    ap.add_argument("--flat-window", type=int, default=4, help="K: compare the mean of the last K points with the K before")
    ap.add_argument("--flat-rel-tol", type=float, default=0.05)
    ap.add_argument("--flat-abs-tol", type=float, default=0.05)
    ap.add_argument("--reward", choices=REWARDS, default="zoo")
    ap.add_argument("--env", default=ControlProtocol.env_id,
                    help="the plant (a phast_gym pendulum id; PHAST/Pendulum-v0: undamped, the swing-up task)")
    ap.add_argument("--regimes", default=None,
                    help=f"comma list of start regimes for training, burn-ins and evaluation (default all: {','.join(START_REGIMES)}); "
                         "near_stable: swing-up from hanging")
    ap.add_argument("--sigma", type=float, default=0.01)
    ap.add_argument("--trials-per-regime", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=5, help="plant steps per SAC decision (dt 0.01 -> 0.05)")
    ap.add_argument("--episode-decisions", type=int, default=200, help="training episode length in decisions (10 s)")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--burn-in", type=int, default=10, help="real measurements per world-model episode")
    ap.add_argument("--max-action", type=float, default=10.0, help="SAC torque bound (N m)")
    ap.add_argument("--phast-run", default=None, help="PHAST run for SAC inside PHASTWorldModelEnv")
    ap.add_argument("--ec-estimators", default="oracle,map,ukf")
    ap.add_argument("--q-star", type=float, default=0.0, help="target angle (pi: upright; EC gains k_c = 20, d_inj = 3)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--tables-only", action="store_true", help="only rewrite OUT/control_sac.md from OUT/control_sac.json")
    return ap


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The options of ``argv`` (default: the command line); exits with a message naming a bad one."""
    ap = parser()
    args = ap.parse_args(argv)
    agents = agents_of(args)
    for a in agents:
        if a not in ("sac-real", "sac-world", "sac-gym"):
            ap.error(f"unknown agent {a!r}")
        if a == "sac-world" and not args.phast_run:
            ap.error("sac-world needs --phast-run")
        if a == "sac-world" and args.obs != "frames":
            ap.error("sac-world observes frames only (the world model has no true state)")
    try:
        regimes_of(args)
    except ValueError as e:
        ap.error(str(e))
    if args.mirror and abs(math.sin(args.q_star)) > 1e-9:
        ap.error("--mirror needs a target the reflection q -> -q keeps: q_star 0 or pi")
    if args.net is not None and not all(h.strip().isdigit() and int(h) > 0 for h in args.net.split(",")):
        ap.error(f"--net must be positive layer sizes like 64,64, got {args.net!r}")
    if args.lr_final is not None and not (args.lr_final > 0 and math.isfinite(args.lr_final)):
        ap.error(f"--lr-final must be a positive learning rate, got {args.lr_final!r}")
    if args.wells is not None:
        if args.reward != "precise":
            ap.error("--wells shapes the precise reward only (add --reward precise)")
        try:
            parse_wells(args.wells)
        except ValueError as e:
            ap.error(str(e))
    if args.mirror and "sac-gym" in agents:
        ap.error("--mirror knows the plant agents' observations only (sac-real, sac-world)")
    if "sac-gym" in agents and len(agents) > 1:
        ap.error("sac-gym runs alone")
    return args


def agents_of(args: argparse.Namespace) -> list[str]:
    return [a for a in args.agents.split(",") if a and a != "none"]


def energy_casimir_rows(protocol: Any, args: argparse.Namespace) -> dict[str, dict[str, Any]]:
    """The Energy-Casimir reference rows, one per estimator (no real-env samples for training; the gains use the
    plant's m g l only)."""
    rows, _ = evaluate_estimators(protocol, args.ec_estimators.split(","), [args.sigma], args.trials_per_regime,
                                  seed=args.seed, progress=not args.no_progress)
    cmd = command_line(args, [])
    keys = ("success_rate", "success_angle_rate", "effort", "final_error", "u_rms_final")
    regimes = regimes_of(args)
    chosen = ("all",) if regimes == tuple(START_REGIMES) else regimes
    out: dict[str, dict[str, Any]] = {}
    for est in args.ec_estimators.split(","):
        mine = [r for r in rows if r["regime"] in chosen and r["estimator"] == resolve_estimator_name(est)]
        # equal trials per regime: the pooled mean over the chosen regimes is the mean of their means
        out[f"energy-casimir/{mine[0]['estimator']}"] = {
            "method": f"energy-casimir/{mine[0]['estimator']}",
            **{k: float(np.mean([r.get(k, float("nan")) for r in mine])) for k in keys},
            "real_env_samples": 0, "decisions": 0, "flat": None, "train_seconds": 0.0, "command": cmd}
    return out


def run_gym(args: argparse.Namespace, out: Path) -> None:
    """sac-gym: train, merge the row (one per env and seed) into ``OUT/gym_sac.json``, write ``OUT/gym_sac.md``."""
    path = out / "gym_sac.json"
    meta: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {"hyperparameters": sac.ZOO_PENDULUM_SAC, "results": []}
    row = train_agent("sac-gym", args, out)
    print({k: v for k, v in row.items() if k != "command"}, flush=True)
    rows = [r for r in meta["results"] if (r["method"], r["seed"]) != (row["method"], row["seed"])] + [row]
    meta["results"] = sorted(rows, key=lambda r: (r["method"], r["seed"]))
    atomic_write_text(path, json.dumps(meta, indent=1))
    lines = ["SB3 SAC (zoo Pendulum-v1 hyperparameters) on Gymnasium envs: deterministic return on "
             f"{row['episodes']} seeded episodes; settled: |theta| < 0.05 rad over the last 20 steps (1 s)", "",
             "| Method | Seed | Steps | Mean return | Std | Settled | Final abs(theta) | RMS torque, last 20 | Train s |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in meta["results"]:
        lines.append(f"| {r['method']} | {r['seed']} | {r['decisions']} | {r['mean_return']:.1f} | {r['std_return']:.1f} | "
                     f"{r['settled_rate']:.2f} | {r['final_abs_theta']:.3g} | {r['u_rms_final']:.3f} | {r['train_seconds']} |")
    by: dict[str, list[float]] = {}
    for r in meta["results"]:
        by.setdefault(r["method"], []).append(r["mean_return"])
    lines += [""] + [f"{m}: mean over {len(v)} seeds {np.mean(v):.1f} (min {min(v):.1f}, max {max(v):.1f})" for m, v in by.items()]
    lines += ["", "Commands:", ""] + [f"* seed {r['seed']}: `{r['command']}`" for r in meta["results"]]
    atomic_write_text(out / "gym_sac.md", "\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.tables_only:
        write_tables(Path(args.out), json.loads((Path(args.out) / "control_sac.json").read_text()))
        return
    torch.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if agents_of(args) == ["sac-gym"]:
        run_gym(args, out)
        return
    protocol = make_protocol(args.q_star, args.env)
    path = out / "control_sac.json"
    meta: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    regimes = list(regimes_of(args))
    if meta and (meta.get("q_star") != args.q_star or meta.get("sigma") != args.sigma
                 or meta.get("trials_per_regime") != args.trials_per_regime
                 or meta.get("regimes", list(START_REGIMES)) != regimes
                 or meta.get("protocol", {}).get("env_id", ControlProtocol.env_id) != args.env):
        raise SystemExit(f"{path} holds another setting (plant/q_star/sigma/trials/regimes); use another --out")
    results: dict[str, dict[str, Any]] = {r["method"]: r for r in meta.get("results", [])}
    results.update(energy_casimir_rows(protocol, args))

    def save() -> None:
        order = sorted(results.values(), key=lambda r: (not r["method"].startswith("energy"), r["method"]))
        meta.update({"q_star": args.q_star, "sigma": args.sigma, "trials_per_regime": args.trials_per_regime,
                     "regimes": regimes, "protocol": protocol.to_dict(), "hyperparameters": sac.ZOO_PENDULUM_SAC, "results": order})
        atomic_write_text(path, json.dumps(meta, indent=1))
        write_tables(out, meta)

    save()
    for name in agents_of(args):
        row = train_agent(name, args, out)
        results[row["method"]] = row
        print({k: v for k, v in row.items() if k != "command"}, flush=True)
        save()
    print((out / "control_sac.md").read_text())


if __name__ == "__main__":
    main()
