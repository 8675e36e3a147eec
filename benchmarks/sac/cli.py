"""SB3 SAC vs Energy-Casimir on the torque-port damped pendulum (q-only, noisy), same regimes and metrics.

Agents (CPU, one torch thread):

* ``sac-real``: SAC trained on the real plant (the control env of :class:`ControlProtocol`, decisions
  every ``repeat`` plant steps with the torque held), observation = (sin q, cos q) of the last
  ``frames`` noisy measurements taken at the decision rate;
* ``sac-world`` (with ``--phast-run``): SAC trained inside :class:`phast_model.world.gym_env.PHASTWorldModelEnv`
  (the learned PHAST model, dt = the run's env dt = ``repeat`` plant steps; every episode starts from a
  burn-in window of ``burn_in`` real noisy measurements from a start-regime state) and deployed on the real plant.

Hyperparameters: the RL zoo's tuned Pendulum-v1 SAC (``learning_rate 1e-3``, everything else SB3's SAC
defaults; the zoo's 20k-step budget is replaced by ``--until-flat``).  With ``--until-flat`` the deterministic
policy is evaluated every ``--eval-every`` decisions on fixed seeded episodes of its training env (the real plant
for ``sac-real``, the world model for ``sac-world``; an SB3 callback, :class:`benchmarks.sac.agents.LearningCurve`)
and training stops when the learning curve is flat (:func:`benchmarks.sac.evaluation.is_flat`) or at ``--max-steps``.
A monitoring curve on the real plant (not used for stopping, not counted as training samples) is
plotted too.  Both agents are then evaluated like ``phast-control-eval`` (five regimes, success =
settled and quiet, effort ``sum_t u_t^2`` over plant steps) and compared with Energy-Casimir rows
(``--ec-estimators``) on success, effort and real-env samples.  Rows are merged into
``OUT/control_sac.json`` / ``OUT/control_sac.md`` (one process per agent is fine); learning curves go to
``OUT/curve_<agent>.json`` and ``OUT/curve_<agent>.png``.

* ``sac-gym`` (alone): the same SAC construction and training loop on a Gymnasium env (``--gym-env``, default
  ``Pendulum-v1``) as a harness check (rows in ``OUT/gym_sac.json`` / ``OUT/gym_sac.md``).

Ablations: ``--obs`` (true-velocity / true-state observations), ``--quiet-weight`` (0.5 at ``q* = 0``; 0.05 at the
upright, below :func:`benchmarks.sac.rewards.max_quiet_weight`), ``--reward precise``, ``--curve`` (fixed budget with a
learning curve); see docs/control_results/sac/DIAGNOSIS.md.

The options become a :class:`benchmarks.sac.config.SacConfig` (:func:`parse_args`), which the agents read.

    python benchmarks/control_sac.py --out OUT --agents sac-real --until-flat --reward quiet --q-star 0
    python benchmarks/control_sac.py --out OUT --agents sac-gym --steps 20000 --curve --seed 0
"""

from __future__ import annotations

import argparse
import json
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np
import torch

from phast_gym.control import START_REGIMES, ControlProtocol, evaluate_estimators, resolve_estimator_name
from phast_gym.fileio import atomic_write_text
from phast_model.rl.observation import OBS_MODES

from . import config
from .agents import benchmark_agent
from .config import SacConfig, command_line, make_protocol, regimes_of
from .rewards import PRECISE_WELLS, QUIET_WEIGHT, REWARDS, format_wells


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
    """The benchmark's options (:func:`parse_args` checks how they combine), defaults those of :class:`SacConfig`."""
    d = {f.name: f.default for f in fields(SacConfig)}
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--agents", default=d["agents"],
                    help="comma list of sac-real, sac-world (needs --phast-run); none: Energy-Casimir rows only; "
                         "sac-gym (alone): the same SAC on the Gymnasium env --gym-env (harness check, rows in OUT/gym_sac.json)")
    ap.add_argument("--gym-env", default=d["gym_env"], help="Gymnasium env id of sac-gym")
    ap.add_argument("--gym-eval-episodes", type=int, default=d["gym_eval_episodes"],
                    help="seeded episodes of sac-gym's final evaluation")
    ap.add_argument("--curve", action="store_true", help="fixed budget --steps, with a learning curve every --eval-every")
    ap.add_argument("--obs", choices=OBS_MODES, default=d["obs"],
                    help="policy observation: frames (q-only, default); frames+qdot / state: true-velocity ablations (sac-real)")
    ap.add_argument("--quiet-weight", type=float, default=d["quiet_weight"],
                    help=f"weight of the quiet reward's torque term (default {QUIET_WEIGHT} at q* = 0, 0.05 otherwise: "
                         "upright_quiet_weight)")
    ap.add_argument("--wells", default=d["wells"],
                    help="the precise reward's angle wells DEPTH:WIDTH[,...] (rad; default "
                         f"{format_wells(PRECISE_WELLS)})")
    ap.add_argument("--mirror", action="store_true",
                    help="reflection-equivariant SAC (odd actor, invariant critics: the pendulum's q -> -q symmetry; "
                         "phast_model.rl.mirror_policy)")
    ap.add_argument("--net", default=d["net"], help="SAC hidden layer sizes, e.g. 64,64 (default: the zoo's 256,256)")
    ap.add_argument("--lr-final", type=float, default=d["lr_final"],
                    help="decay the learning rate linearly from the zoo's 1e-3 to this over the budget (default: constant)")
    ap.add_argument("--steps", type=int, default=d["steps"], help="SAC decisions per agent without --until-flat (zoo: 20k)")
    ap.add_argument("--until-flat", action="store_true", help="train until the learning curve is flat (is_flat) or --max-steps")
    ap.add_argument("--max-steps", type=int, default=d["max_steps"], help="cap on SAC decisions with --until-flat")
    ap.add_argument("--eval-every", type=int, default=d["eval_every"], help="decisions between learning-curve evaluations")
    ap.add_argument("--eval-episodes", type=int, default=d["eval_episodes"], help="fixed seeded episodes per learning-curve point")
    ap.add_argument("--flat-window", type=int, default=d["flat_window"],
                    help="K: compare the mean of the last K points with the K before")
    ap.add_argument("--flat-rel-tol", type=float, default=d["flat_rel_tol"])
    ap.add_argument("--flat-abs-tol", type=float, default=d["flat_abs_tol"])
    ap.add_argument("--reward", choices=REWARDS, default=d["reward"])
    ap.add_argument("--env", default=d["env"],
                    help="the plant (a phast_gym pendulum id; PHAST/Pendulum-v0: undamped, the swing-up task)")
    ap.add_argument("--regimes", default=d["regimes"],
                    help=f"comma list of start regimes for training, burn-ins and evaluation (default all: {','.join(START_REGIMES)}); "
                         "near_stable: swing-up from hanging")
    ap.add_argument("--sigma", type=float, default=d["sigma"])
    ap.add_argument("--trials-per-regime", type=int, default=d["trials_per_regime"])
    ap.add_argument("--repeat", type=int, default=d["repeat"], help="plant steps per SAC decision (dt 0.01 -> 0.05)")
    ap.add_argument("--episode-decisions", type=int, default=d["episode_decisions"],
                    help="training episode length in decisions (10 s)")
    ap.add_argument("--frames", type=int, default=d["frames"])
    ap.add_argument("--burn-in", type=int, default=d["burn_in"], help="real measurements per world-model episode")
    ap.add_argument("--max-action", type=float, default=d["max_action"], help="SAC torque bound (N m)")
    ap.add_argument("--phast-run", default=d["phast_run"], help="PHAST run for SAC inside PHASTWorldModelEnv")
    ap.add_argument("--ec-estimators", default=d["ec_estimators"])
    ap.add_argument("--q-star", type=float, default=d["q_star"],
                    help="target angle (pi: upright; EC gains k_c = 20, d_inj = 3)")
    ap.add_argument("--seed", type=int, default=d["seed"])
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--tables-only", action="store_true", help="only rewrite OUT/control_sac.md from OUT/control_sac.json")
    return ap


def config_from_args(args: argparse.Namespace) -> SacConfig:
    """The :class:`SacConfig` of parsed options (``--no-progress`` as ``progress``; ``--tables-only`` is
    :func:`main`'s); ValueError naming a bad combination."""
    opts = {k: v for k, v in vars(args).items() if k not in ("no_progress", "tables_only")}
    return SacConfig(**opts, progress=not args.no_progress)


def parse(argv: list[str] | None = None) -> tuple[SacConfig, argparse.Namespace]:
    """The config and the parsed options of ``argv`` (default: the command line); exits with a message naming a bad
    one."""
    ap = parser()
    args = ap.parse_args(argv)
    try:
        return config_from_args(args), args
    except ValueError as e:
        ap.error(str(e))


def parse_args(argv: list[str] | None = None) -> SacConfig:
    """The :class:`SacConfig` of ``argv`` (default: the command line); exits with a message naming a bad option."""
    return parse(argv)[0]


def energy_casimir_rows(protocol: ControlProtocol, cfg: SacConfig) -> dict[str, dict[str, Any]]:
    """The Energy-Casimir reference rows, one per estimator (no real-env samples for training; the gains use the
    plant's m g l only)."""
    rows, _ = evaluate_estimators(protocol, cfg.ec_estimators.split(","), [cfg.sigma], cfg.trials_per_regime,
                                  seed=cfg.seed, progress=cfg.progress)
    cmd = command_line(cfg, [])
    keys = ("success_rate", "success_angle_rate", "effort", "final_error", "u_rms_final")
    regimes = regimes_of(cfg)
    chosen = ("all",) if regimes == tuple(START_REGIMES) else regimes
    out: dict[str, dict[str, Any]] = {}
    for est in cfg.ec_estimators.split(","):
        mine = [r for r in rows if r["regime"] in chosen and r["estimator"] == resolve_estimator_name(est)]
        # equal trials per regime: the pooled mean over the chosen regimes is the mean of their means
        out[f"energy-casimir/{mine[0]['estimator']}"] = {
            "method": f"energy-casimir/{mine[0]['estimator']}",
            **{k: float(np.mean([r.get(k, float("nan")) for r in mine])) for k in keys},
            "real_env_samples": 0, "decisions": 0, "flat": None, "train_seconds": 0.0, "command": cmd}
    return out


def run_gym(cfg: SacConfig, out: Path) -> None:
    """sac-gym: train, merge the row (one per env and seed) into ``OUT/gym_sac.json``, write ``OUT/gym_sac.md``."""
    path = out / "gym_sac.json"
    meta: dict[str, Any] = (json.loads(path.read_text()) if path.exists()
                            else {"hyperparameters": config.ZOO_PENDULUM_SAC, "results": []})
    row = benchmark_agent("sac-gym", cfg, out)
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
    cfg, args = parse(argv)
    if args.tables_only:
        write_tables(Path(cfg.out), json.loads((Path(cfg.out) / "control_sac.json").read_text()))
        return
    torch.set_num_threads(1)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    if cfg.agent_names == ["sac-gym"]:
        run_gym(cfg, out)
        return
    protocol = make_protocol(cfg.q_star, cfg.env)
    path = out / "control_sac.json"
    meta: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    regimes = list(regimes_of(cfg))
    if meta and (meta.get("q_star") != cfg.q_star or meta.get("sigma") != cfg.sigma
                 or meta.get("trials_per_regime") != cfg.trials_per_regime
                 or meta.get("regimes", list(START_REGIMES)) != regimes
                 or meta.get("protocol", {}).get("env_id", ControlProtocol.env_id) != cfg.env):
        raise SystemExit(f"{path} holds another setting (plant/q_star/sigma/trials/regimes); use another --out")
    results: dict[str, dict[str, Any]] = {r["method"]: r for r in meta.get("results", [])}
    results.update(energy_casimir_rows(protocol, cfg))

    def save() -> None:
        order = sorted(results.values(), key=lambda r: (not r["method"].startswith("energy"), r["method"]))
        meta.update({"q_star": cfg.q_star, "sigma": cfg.sigma, "trials_per_regime": cfg.trials_per_regime,
                     "regimes": regimes, "protocol": protocol.to_dict(), "hyperparameters": config.ZOO_PENDULUM_SAC,
                     "results": order})
        atomic_write_text(path, json.dumps(meta, indent=1))
        write_tables(out, meta)

    save()
    for name in cfg.agent_names:
        row = benchmark_agent(name, cfg, out)
        results[row["method"]] = row
        print({k: v for k, v in row.items() if k != "command"}, flush=True)
        save()
    print((out / "control_sac.md").read_text())
