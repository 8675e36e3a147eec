"""``phast-rl``: learn a policy from seconds of plant time (the model-based RL loop of :mod:`phast_model.rl.loop`).

    phast-rl --env PHAST/Pendulum-v0 --task swingup --budget-s 5 --seed 0 --out DIR

writes ``DIR/summary.json`` (``plant_seconds``: all plant time used for learning; ``success``: the quiet criterion,
``success_angle_only`` and ``rms_torque`` of the final evaluation on the plant, ``eval_trials`` trials; per-iteration
success), ``DIR/curves.json`` + ``DIR/curves.png`` (learning curves) and ``DIR/model/`` (the world model:
``phast_model.api.load_run``).  The agent is the planner in the learned model by default (``--agent mpc``:
:mod:`phast_model.rl.planner`, nothing to train); ``--agent sac`` trains an SB3 agent in the model and writes it to
``DIR/policy.zip`` (``SAC.load``).  A thin front end over the API; ``--help`` lists the options.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import cast

import gymnasium as gym

from ..control.mppi import MPPISpec
from ..rl.hold import HOLD_KINDS, HoldConfig
from ..rl.loop import ALGOS, AgentSpec, FitSpec, LoopConfig, LoopInterrupted
from ..rl.planner import AGENTS
from ..rl.plant import TASKS, PlantSpec, Task, quiet_u_tol
from ..rl.types import Plant
from .args import json_object


def add_source_options(ap: argparse.ArgumentParser, p: PlantSpec) -> None:
    """Where the loop's data come from besides a simulated plant: a machine, recordings, an earlier run."""
    ap.add_argument("--machine", default=None,
                    help="a real machine as the plant: a factory path/to/driver.py:make or module:make returning an "
                         "object with dt, reset() -> q and step(u) -> q (a Gymnasium env with obs q and action u "
                         "does); --env then describes the rig (docs/control.md, 'A machine of your own')")
    ap.add_argument("--machine-kwargs", default="{}", help="the machine factory's keyword arguments as JSON")
    ap.add_argument("--dt", type=float, default=p.dt, help="plant step (s): the machine's dt; the agent decides every "
                                                        f"{p.decision_steps} steps")
    ap.add_argument("--recordings", default=None,
                    help="recordings made before the loop (the phast-train --recordings format, sampled at the "
                         "decision step): learned from first, their seconds counted against --budget-s")
    ap.add_argument("--offline", action="store_true",
                    help="no plant: learn the policy from --recordings alone (no plant episode, no evaluation; --env "
                         "describes the rig)")
    ap.add_argument("--deploy", default=None, metavar="RUN_DIR",
                    help="learn nothing: run the controller of an earlier phast-rl run (its agent and learned hold) on "
                         "the plant or --machine given here, --eval-trials x --eval-s, and write OUT/evaluation.json")


def add_excitation_options(ap: argparse.ArgumentParser, d: LoopConfig) -> None:
    """The random-input episodes that start the loop, and how many iterations follow (on a real rig, set the
    amplitude to what it safely takes)."""
    ap.add_argument("--excitation-episodes", type=int, default=None,
                    help="random-input plant episodes first (default: 1 with --agent mpc, "
                         f"{d.excitation_episodes} with --agent sac, none with --recordings)")
    ap.add_argument("--excitation-std", type=float, default=d.torque_std,
                    help="std of the excitation's random inputs (N m or N; clipped at --max-action)")
    ap.add_argument("--excitation-hold", type=int, default=d.hold_decisions,
                    help="decisions each random input is held")
    ap.add_argument("--max-iterations", type=int, default=d.max_iterations,
                    help="fit-train-run iterations at most (the budget usually ends the loop first)")


def add_hold_options(ap: argparse.ArgumentParser) -> None:
    """The hold near the target (:class:`phast_model.rl.hold.HoldConfig`)."""
    h = HoldConfig()
    ap.add_argument("--hold", choices=HOLD_KINDS, default=h.kind,
                    help="the hold: auto = Energy-Casimir when the input acts on every coordinate, else LQR of the "
                         "learned model's linearisation")
    ap.add_argument("--lqr-angle", type=float, default=h.lqr_angle, help="LQR hold: weight on the angle errors")
    ap.add_argument("--lqr-position", type=float, default=h.lqr_position,
                    help="LQR hold: weight on the Euclidean position errors (the cart's)")
    ap.add_argument("--lqr-rate", type=float, default=h.lqr_rate, help="LQR hold: weight on every rate")
    ap.add_argument("--lqr-ukf-p-per-inertia", action=argparse.BooleanOptionalAction, default=h.lqr_ukf_p_per_inertia,
                    help="LQR hold: its UKF's momentum noise per unit of the learned mass's smallest diagonal entry")
    ap.add_argument("--hold-enter-angle", type=float, default=h.enter_angle,
                    help="handoff to the hold within this angle (rad)")
    ap.add_argument("--hold-kc-factor", type=float, default=h.kc_factor, help="hold stiffness k_c / learned m g l")
    ap.add_argument("--hold-zeta", type=float, default=h.zeta,
                    help="hold damping ratio (sets d_inj from the learned model)")


def add_planner_options(ap: argparse.ArgumentParser) -> None:
    """The agent (``--agent``) and the planner's settings (:class:`phast_model.control.mppi.MPPISpec`)."""
    s = MPPISpec()
    ap.add_argument("--agent", choices=AGENTS, default="mpc",
                    help="mpc: MPPI through the learned model every plant interval, no training (its own option "
                         "defaults: phast_model.rl.descriptions.AGENT_PRESETS); sac: an SB3 agent trained in the world "
                         "model (--algo), written to policy.zip")
    options: tuple[tuple[str, type, str], ...] = (
        ("samples", int, "input sequences sampled per decision"),
        ("horizon_s", float, "planning horizon (s)"),
        ("plan_every", int, "decisions (of --dt x 5) per planning step; the planner decides at this step"),
        ("noise", float, "input noise std / --max-action"),
        ("temperature", float, "the path-integral temperature as a fraction of the sampled costs' spread"))
    for key, kind, text in options:
        ap.add_argument("--mpc-" + key.replace("_", "-"), type=kind, default=getattr(s, key), help="MPC: " + text)


def build_parser() -> argparse.ArgumentParser:
    d, a, f, p = LoopConfig(), AgentSpec(), FitSpec(), PlantSpec()
    ap = argparse.ArgumentParser(prog="phast-rl", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--env", default=p.env_id,
                    help="the plant: a phast_gym env id, or a rig of your own as a phast_gym System subclass, "
                         "path/to/rig.py:Class (docs/describe_your_rig.md); some plants bring their own option "
                         "defaults (the cart-pole: --max-action 30 and longer agent training; "
                         "phast_model.rl.descriptions.PRESETS), which options given here override")
    add_source_options(ap, p)
    ap.add_argument("--task", choices=TASKS, default="swingup",
                    help="swingup: from hanging; upright: from near the top")
    ap.add_argument("--env-kwargs", default="{}",
                    help='the plant env\'s kwargs as JSON, e.g. \'{"actuated_dofs": [0]}\'')
    ap.add_argument("--budget-s", type=float, default=d.budget_s, help="plant seconds allowed for learning")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True, help="output directory")
    ap.add_argument("--sim", default=None, help="the rig description (env id or path.py:Class; default: --env)")
    ap.add_argument("--regime", choices=("known", "partial", "unknown"), default=f.regime,
                    help="world-model regime of the rig path (partial: the description's templates, refitted; unknown: "
                         "a neural V and M, which seconds of data near the start do not determine at the target: 0.00 "
                         "on the pendulum swing-up at 30 s, docs/control.md)")
    ap.add_argument("--sim-kwargs", default="{}",
                    help="the rig description's parameters as JSON, e.g. '{\"mass\": 1.1}' (default, without --sim "
                         "and --machine: the plant's physical --env-kwargs)")
    ap.add_argument("--u-tol", type=float, default=None,
                    help="quiet criterion: largest RMS input over the last second (default: 0.25 N m for a pendulum, "
                         "else 2x the plant's LQG floor at --sigma: 0.387 N for the cart-pole, force on the cart)")
    ap.add_argument("--sigma", type=float, default=p.sigma, help="q measurement noise of the plant (rad)")
    ap.add_argument("--max-action", type=float, default=p.max_action, help="input bound (N m or N)")
    ap.add_argument("--episode-s", type=float, default=d.episode_s, help="seconds per plant episode used for learning")
    add_excitation_options(ap, d)
    ap.add_argument("--policy-episodes", type=int, default=d.policy_episodes, help="plant episodes per iteration")
    add_planner_options(ap)
    ap.add_argument("--algo", choices=ALGOS, default=a.algo)
    ap.add_argument("--agent-steps", type=int, default=a.steps, help="agent decisions of the first training")
    ap.add_argument("--refit-steps", type=int, default=a.refit_steps, help="agent decisions of each later training")
    ap.add_argument("--final-steps", type=int, default=a.final_steps,
                    help="agent decisions of the last training, the one after the budget is spent (default: "
                         "--refit-steps)")
    ap.add_argument("--hold-goal", action=argparse.BooleanOptionalAction, default=a.hold_goal,
                    help="world-model episodes end with the best reward where the hold takes over (the agent brings "
                         "the plant into the hold's region)")
    ap.add_argument("--keep-best", action=argparse.BooleanOptionalAction, default=a.keep_best,
                    help="deploy the weights of each training's best world-model evaluation, not the last ones")
    ap.add_argument("--eval-every", type=int, default=a.eval_every, help="decisions between world-model evaluations")
    ap.add_argument("--episode-decisions", type=int, default=a.episode_decisions,
                    help="decisions per world-model episode of the agent")
    ap.add_argument("--velocity-weight", type=float, default=a.velocity_weight, help="reward weight on |qdot|^2")
    ap.add_argument("--position-weight", type=float, default=a.position_weight,
                    help="reward weight on the squared Euclidean errors (the cart's position)")
    ap.add_argument("--no-recenter", action="store_true",
                    help="world-model episodes start where the recordings were (default: the cart's position moved to "
                         "0)")
    ap.add_argument("--fit-epochs", type=int, default=f.epochs)
    ap.add_argument("--refit-epochs", type=int, default=f.refit_epochs)
    ap.add_argument("--eval-trials", type=int, default=d.eval_trials, help="final evaluation episodes on the plant")
    ap.add_argument("--eval-s", type=float, default=d.eval_s, help="seconds per final evaluation episode")
    ap.add_argument("--no-hold", action="store_true", help="no hold near the target (the agent alone)")
    add_hold_options(ap)
    ap.add_argument("--no-mirror", action="store_true", help="an unconstrained SAC policy (no reflection symmetry)")
    ap.add_argument("--no-progress", action="store_true")
    return ap


def config_from_args(args: argparse.Namespace) -> LoopConfig:
    """The loop's config; ValueError naming the bad option."""
    h = HoldConfig()
    if args.offline and args.machine:
        raise ValueError("--offline learns without a plant; --machine names one: give one of them")
    if args.offline and args.deploy:
        raise ValueError("--deploy runs a controller on a plant; --offline has none")
    plant = PlantSpec(args.env, json_object(args.env_kwargs, "--env-kwargs"), dt=args.dt, sigma=args.sigma,
                      max_action=args.max_action, machine=args.machine,
                      machine_kwargs=json_object(args.machine_kwargs, "--machine-kwargs"))
    agent = AgentSpec(algo=args.algo, steps=args.agent_steps, refit_steps=args.refit_steps,
                      final_steps=args.final_steps, keep_best=args.keep_best, hold_goal=args.hold_goal,
                      eval_every=args.eval_every,
                      mirror=not args.no_mirror, episode_decisions=args.episode_decisions,
                      velocity_weight=args.velocity_weight, position_weight=args.position_weight,
                      recenter=not args.no_recenter)
    sim_kwargs = json_object(args.sim_kwargs, "--sim-kwargs")
    if args.sim is None and args.sim_kwargs.strip() == "{}" and args.machine is None:
        sim_kwargs = plant.physical_kwargs  # the description of a simulated plant: its class with its parameters
    fit = FitSpec(args.sim, sim_kwargs, args.regime, epochs=args.fit_epochs, refit_epochs=args.refit_epochs)
    planner = MPPISpec(samples=args.mpc_samples, horizon_s=args.mpc_horizon_s, plan_every=args.mpc_plan_every,
                       noise=args.mpc_noise, temperature=args.mpc_temperature)
    u_tol = args.u_tol
    if u_tol is None:
        try:
            u_tol = quiet_u_tol(plant)
        except (KeyError, TypeError, ValueError, gym.error.Error):  # a bad --env / --env-kwargs: check_plant says why
            u_tol = Task().u_tol
    excitation = args.excitation_episodes
    if excitation is None:
        excitation = 0 if args.recordings else getattr(args, "excitation_default", LoopConfig().excitation_episodes)
    return LoopConfig(plant, Task(args.task, u_tol=u_tol), args.budget_s, args.seed, args.episode_s, excitation,
                      args.policy_episodes, eval_trials=args.eval_trials, eval_s=args.eval_s, fit=fit, agent=agent,
                      recordings=args.recordings, offline=args.offline, torque_std=args.excitation_std,
                      hold_decisions=args.excitation_hold, max_iterations=args.max_iterations,
                      hold=HoldConfig(enabled=not args.no_hold, kind=args.hold, kc_factor=args.hold_kc_factor,
                                      zeta=args.hold_zeta, lqr_angle=args.lqr_angle, lqr_position=args.lqr_position,
                                      lqr_rate=args.lqr_rate, enter_angle=args.hold_enter_angle,
                                      exit_angle=max(h.exit_angle, args.hold_enter_angle),
                                      lqr_ukf_p_per_inertia=args.lqr_ukf_p_per_inertia),
                      agent_kind=args.agent, planner=planner)


def check_plant(cfg: LoopConfig) -> Plant:
    """Build the plant once, before any work (unknown env ids, bad kwargs, a machine that does not load fail here);
    the loop then runs on it."""
    from ..rl.plant import make_plant

    try:
        plant = make_plant(cfg.plant)
    except (KeyError, TypeError, ValueError, gym.error.Error) as e:
        if cfg.plant.machine is not None and str(e).startswith("machine "):
            raise ValueError(f"--machine: {e}") from None
        raise ValueError(f"--env {cfg.plant.env_id} with --env-kwargs {json.dumps(cfg.plant.env_kwargs)}: "
                         f"{e}") from None
    if not plant.system.angle_dims:
        raise ValueError(f"--env {cfg.plant.env_id} has no angle coordinate: the tasks swing an angle up")
    return plant


def deploy(cfg: LoopConfig, plant: Plant, run_dir: str, out: Path, command: str) -> int:
    """``--deploy``: the controller of the run in ``run_dir`` on ``plant`` for the final evaluation's trials, written to
    ``out/evaluation.json``; ValueError when the run does not fit the plant (step, coordinates, inputs)."""
    from dataclasses import asdict

    from phast_gym.fileio import atomic_write_json

    from ..rl.loop import evaluate
    from ..rl.loop_report import load_config, load_controller

    run = load_config(run_dir)
    if abs(run.plant.dt - plant.dt) > 1e-9 * max(1.0, plant.dt):
        raise ValueError(f"--deploy {run_dir}: its controller steps every {run.plant.dt:g} s, the plant every "
                         f"{plant.dt:g} s")
    policy = load_controller(run_dir)
    if policy.hold is not None and int(policy.hold.system.n) != plant.n:
        raise ValueError(f"--deploy {run_dir}: its model has n={policy.hold.system.n} coordinates, the plant {plant.n}")
    act = int(cast(gym.spaces.Box, policy.agent.action_space).shape[0])
    if act != plant.m:
        raise ValueError(f"--deploy {run_dir}: its agent gives {act} inputs, the plant takes {plant.m}")
    ev = evaluate(cfg, plant, policy, cfg.task.target(plant.system))
    atomic_write_json(out / "evaluation.json", {**asdict(ev), "run": str(run_dir), "command": command,
                                                "env": cfg.plant.env_id, "machine": cfg.plant.machine})
    print(json.dumps({"success": ev.success, "success_angle_only": ev.success_angle_only, "rms_torque": ev.rms_torque,
                      "trials": ev.trials, "controller_ms": ev.act_ms}))
    return 0


def keep_recordings(stop: LoopInterrupted, out: Path) -> int:
    """The loop stopped early: write what the plant recorded to ``out/recordings.npz`` and say how to continue."""
    from ..rl.loop_report import save_recordings

    path = save_recordings(stop.recordings, out)
    print(f"phast-rl: stopped after {stop.seconds:g} s of plant time ({stop}); what the plant recorded is in {path}: "
          f"continue with --recordings {path}", file=sys.stderr)
    return 130 if isinstance(stop.cause, KeyboardInterrupt) else 2


def parse_args(argv: list[str] | None = None) -> tuple[argparse.ArgumentParser, argparse.Namespace]:
    """The parser and the arguments, with the plant's option defaults (:func:`phast_model.rl.descriptions.loop_preset`)
    in place of the loop's where the command line does not give the option."""
    from ..rl.descriptions import loop_preset

    ap = build_parser()
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--env", default=ap.get_default("env"))
    pre.add_argument("--agent", default=ap.get_default("agent"))
    known, _ = pre.parse_known_args(argv)
    ap.set_defaults(**loop_preset(known.env, known.agent))
    return ap, ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    ap, args = parse_args(argv)
    try:
        cfg = config_from_args(args)
        plant = check_plant(cfg)
        from phast_gym.fileio import ensure_writable_dir

        out = ensure_writable_dir(args.out, "--out")
    except ValueError as e:
        ap.error(str(e))
    command = "phast-rl " + " ".join(shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv))
    if args.deploy is not None:
        try:
            return deploy(cfg, plant, args.deploy, out, command)
        except ValueError as e:
            print(f"phast-rl: error: {e}", file=sys.stderr)
            return 2
        finally:
            plant.close()  # a machine's motor off
    import torch
    from tqdm.auto import tqdm

    from ..rl.loop import run_loop
    from ..rl.loop_report import write_outputs

    torch.set_num_threads(1)
    bar = tqdm(total=cfg.budget_s, desc="plant seconds", unit="s", disable=args.no_progress, file=sys.stderr)

    def progress(stage: str, used: float) -> None:
        if args.no_progress:  # a plain log line per stage (nohup runs)
            print(f"[plant {used:.2f} s] {stage}", file=sys.stderr, flush=True)
            return
        bar.n = round(used, 2)
        bar.set_postfix_str(stage)
        bar.refresh()

    try:
        result = run_loop(cfg, progress, plant)
    except ValueError as e:
        bar.close()
        print(f"phast-rl: error: {e}", file=sys.stderr)
        return 2
    except LoopInterrupted as e:
        bar.close()
        return keep_recordings(e, out)
    bar.close()
    write_outputs(result, out, {"command": command, "env": cfg.plant.env_id, "machine": cfg.plant.machine,
                                 "agent": cfg.agent_kind,
                                 "recordings": cfg.recordings, "offline": cfg.offline, "task": cfg.task.name,
                                 "seed": cfg.seed})
    s = result.summary()
    print(json.dumps({k: s[k] for k in ("plant_seconds", "prior_seconds",
                                        "success", "success_angle_only", "rms_torque", "iteration_success",
                                        "wall_s", "controller_ms")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
