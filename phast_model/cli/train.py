"""``phast-train``: train a PHAST model on a registered env, or on a rig's recordings, and write a run directory.

    phast-train --env PHAST/WindyPendulum-v0 --regime partial --epochs 50 --seed 0 \\
        --n-train 1000 --out runs/windy_partial [--resume]
    phast-train --recordings arm.npz --sim PHAST/DoublePendulum-v0 --sim-kwargs '{"coordinates": "relative"}' \\
        --holdout-trajectories 2,4,6 --rollout-window-s 1 --regime partial --out runs/arm

With ``--recordings`` (the ``phast-mismatch`` format: q, t or dt, u, angle_dims, angle_offset) the rig ``--sim``
(an env id or ``path/to/rig.py:Class``) gives the V and M templates and the port; the model learns joint friction
and is scored on the held-out recordings against the nominal rig (``metrics.json["heldout"]``):
:func:`phast_model.train.rig_run.train_recordings_run`.  It writes ``checkpoint.pt`` after every epoch too, and
``--resume`` continues from it; ``--patience N`` stops once the validation windows' RMSE has not improved for N epochs.
``--model NAME`` trains a sequence baseline of the grid instead (gru, lstm, transformer, s5, linoss, dlinoss, vpt,
dhnn) on windows of the training recordings, by the grid's trainer, and scores it on the same held-out windows
(``metrics.json["heldout"][NAME]`` beside ``nominal``): :func:`phast_model.baselines.rig.train_baseline_run`.

Writes ``model.pt``, ``config.json``, ``metrics.json`` (Table 16 keys on the test split
plus the training wall time), ``history.json``, ``checkpoint.pt`` and plots
(``rollout.png``, ``phase.png``, ``damping.png``, ``energy.png``): :func:`phast_model.train.runs.train_run`.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import TYPE_CHECKING, Any

from phast_gym import env_ids
from phast_gym.datasets import PortExcitation

from ..train.runs import DataSpec, train_run
from .args import json_object

if TYPE_CHECKING:
    from phast_gym.systems.base import System

    from ..train.rig_run import RecordingsSpec

__all__ = ["main", "parse_args", "train_run"]

#: the defaults --help shows for the two modes (TrainConfig's and RigTrainConfig's; written out so --help needs no
#: torch, and a test checks they are the configs' own); a flag not given leaves the config's default in place
ENV_DEFAULTS: dict[str, Any] = {"lr": 1e-3, "epochs": 50, "batch_size": 64}
RIG_DEFAULTS: dict[str, Any] = {"lr": 2e-2, "epochs": 150, "batch_windows": 64, "window_s": 0.15, "patience": 12}
ENV_LR, RECORDINGS_LR = ENV_DEFAULTS["lr"], RIG_DEFAULTS["lr"]
#: what --model takes with --recordings (written out so --help needs no torch; a test checks it against the grid's
#: registry, phast_model.baselines.rig.model_names)
MODELS = ("phast", "gru", "lstm", "transformer", "s5", "linoss", "dlinoss", "vpt", "dhnn")
#: flags of the PHAST recordings path that a baseline run does not take
PHAST_ONLY = {"patience": "--patience", "schedule": "--schedule", "state_iters": "--state-iters",
              "warmup_window_s": "--warmup-window-s", "warmup_epochs": "--warmup-epochs", "set": "--set"}


def _baseline_args(rec: argparse._ArgumentGroup) -> None:
    """The flags of a baseline run on recordings (``--model NAME``)."""
    rec.add_argument("--model", default=None, metavar="NAME",
                     help=f"what to train: {', '.join(MODELS)} (default phast; a baseline of the grid is trained on "
                          "windows of --window-s seconds (default: the held-out window) by the grid's trainer, "
                          f"--epochs default {ENV_DEFAULTS['epochs']}, --lr default {ENV_LR:g}, and scored on the same "
                          "held-out windows as PHAST)")
    rec.add_argument("--step-s", type=float, default=None, metavar="S",
                     help="a baseline --model's step: every k-th recorded sample, k = S / dt, u averaged over it "
                          "(default 0.01, the grid's double pendulums' step; 0: the recorded step)")
    rec.add_argument("--lr-sweep", default=None, metavar="LR,LR,...",
                     help="with a baseline --model: train a short budget at each rate first and keep the rate of the "
                          "lowest validation loss (e.g. 3e-4,1e-3,3e-3)")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="phast-train", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--env", help=f"env id, one of {env_ids()} (or --recordings)")
    rec = ap.add_argument_group("recordings of a rig (instead of --env)")
    rec.add_argument("--recordings", metavar="FILE",
                     help=".npz / .csv recordings or a folder of .csv logs (the phast-mismatch "
                                                         "format; logs of different lengths are cut into equal pieces)")
    rec.add_argument("--sim",
                     help="the rig: an env id, path/to/rig.py:Class or a MuJoCo model file robot.xml / robot.urdf "
                                   "(with --recordings)")
    rec.add_argument("--sim-kwargs", default="{}", metavar="JSON", help="the rig's constructor kwargs (JSON object)")
    rec.add_argument("--holdout-trajectories", metavar="I,J",
                     help="0-based trajectories held out for the score (log indices for "
                                                                   "logs of different lengths: all of a log's pieces)")
    rec.add_argument("--rollout-window-s", type=float, default=None, metavar="S",
                     help="held-out open-loop windows of S seconds, each after a 0.1 s burn-in (default: whole "
                          "recordings)")
    rec.add_argument("--window-s", type=float, default=None, metavar="S",
                     help=f"training window: PHAST's multiple-shooting window (default {RIG_DEFAULTS['window_s']:g}); "
                          "a baseline --model's sequence length (default: the held-out burn-in plus window)")
    rec.add_argument("--warmup-window-s", type=float, default=None, metavar="S",
                     help="train the first --warmup-epochs epochs on windows of S seconds (a curriculum for an "
                          "all-neural start)")
    rec.add_argument("--warmup-epochs", type=int, default=None, metavar="E")
    rec.add_argument("--state-iters", type=int, default=None, metavar="K",
                     help="Gauss-Newton iterations of the window states per epoch (3 for long windows)")
    rec.add_argument("--decimate", type=int, default=1, metavar="K",
                     help="keep every K-th sample (free-motion recordings sampled much faster than the dynamics)")
    rec.add_argument("--compare", action="append", default=[], metavar="NAME=SIM",
                     help="another model of the rig scored on the same held-out windows (an env id or "
                          "path/to/rig.py:Class, e.g. an identified model); repeatable")
    rec.add_argument("--compare-kwargs", action="append", default=[], metavar="NAME=JSON",
                     help="constructor kwargs of a --compare model (JSON object; default: --sim-kwargs)")
    rec.add_argument("--action-bound", type=float, nargs="+", default=None, metavar="U",
                     help="the world env's torque bound per input (default: the largest recorded |u|)")
    rec.add_argument("--patience", type=int, default=None, metavar="N",
                     help="early stopping: stop when the validation windows' RMSE has not improved for N epochs (the "
                          f"best-validation weights are kept either way; default {RIG_DEFAULTS['patience']}; 0: run "
                          "every epoch)")
    _baseline_args(rec)
    rec.add_argument("--schedule", choices=("plateau", "cosine"), default=None,
                     help="learning-rate schedule: 'plateau' (the default) halves the rates when the validation RMSE "
                          "stalls, so the model is chosen by validation, not by --epochs; 'cosine' decays them over "
                          "exactly --epochs epochs")
    ap.add_argument("--regime", default="partial", choices=("known", "partial", "unknown"))
    ap.add_argument("--epochs", type=int, default=None,
                    help=f"training epochs (default {ENV_DEFAULTS['epochs']} with --env; with --recordings a cap, "
                         f"default {RIG_DEFAULTS['epochs']}, as early stopping chooses the model)")
    ap.add_argument("--seed", type=int, default=0, help="model / training seed")
    ap.add_argument("--data-seed", type=int, default=42, help="dataset seed (paper: 42)")
    ap.add_argument("--n-train", type=int, default=1000)
    ap.add_argument("--n-val", type=int, default=200)
    ap.add_argument("--n-test", type=int, default=200)
    ap.add_argument("--T", type=int, default=200, help="trajectory length")
    ap.add_argument("--batch-size", type=int, default=None,
                    help=f"minibatch size: trajectories with --env (default {ENV_DEFAULTS['batch_size']}), shooting "
                         f"windows with --recordings (default {RIG_DEFAULTS['batch_windows']})")
    ap.add_argument("--lr", type=float, default=None,
                    help=f"learning rate (default: {ENV_LR:g} with --env, {RECORDINGS_LR:g} with --recordings; a value "
                         "given is used as given in both)")
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
    ap.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt (written after every epoch)")
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


def _int_list(text: str | None, flag: str) -> tuple[int, ...] | None:
    if text is None:
        return None
    try:
        return tuple(int(x) for x in text.replace(" ", "").split(",") if x != "")
    except ValueError:
        raise ValueError(f"{flag} expects comma-separated integers, got {text!r}") from None



def _named(items: list[str], flag: str) -> dict[str, str]:
    """``NAME=VALUE`` items (repeatable flag) as a dict; ValueError on a malformed or repeated name."""
    out: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise ValueError(f"{flag} takes NAME=VALUE, got {item!r}")
        if name.strip() in out:
            raise ValueError(f"{flag}: {name.strip()!r} given twice")
        out[name.strip()] = value.strip()
    return out


def _compared_systems(args: argparse.Namespace) -> dict[str, System] | None:
    """The ``--compare`` models, built with their ``--compare-kwargs`` (default: the rig's ``--sim-kwargs``)."""
    from ..identify.mujoco_sim import mujoco_simulated
    from ..identify.simulators import is_model_file, load_simulator

    sims, kwargs = _named(args.compare, "--compare"), _named(args.compare_kwargs, "--compare-kwargs")
    unknown = sorted(set(kwargs) - set(sims))
    if unknown:
        raise ValueError(f"--compare-kwargs names {unknown}, which no --compare gives")
    default = json_object(args.sim_kwargs, "--sim-kwargs")
    out: dict[str, System] = {}
    for name, sim in sims.items():
        if is_model_file(sim):  # a model file is scored as MuJoCo simulates it (what the file means)
            out[name] = mujoco_simulated(sim)
        else:
            out[name] = load_simulator(sim, json_object(kwargs[name], f"--compare-kwargs {name}") if name in kwargs
                                       else default).build()
    return out or None


def _model(args: argparse.Namespace) -> str:
    """The ``--model`` asked for (default phast); ValueError naming the choices."""
    name = (args.model or "phast").lower().replace("-", "").replace("_", "")
    if name not in MODELS:
        raise ValueError(f"unknown --model {args.model!r}; one of {', '.join(MODELS)}")
    if args.env is not None and name != "phast":
        raise ValueError(f"--model {name} trains a baseline on --recordings; on an --env the grid trains the "
                         f"baselines: phast-bench --envs {args.env} --models {name}")
    if name == "phast" and (args.lr_sweep is not None or args.step_s is not None):
        raise ValueError("--lr-sweep and --step-s apply to a baseline --model (PHAST's rig trainer steps at the "
                         "recorded dt and has its own default rate)")
    return name


def _float_list(text: str, flag: str) -> tuple[float, ...]:
    try:
        out = tuple(float(x) for x in text.replace(" ", "").split(",") if x != "")
    except ValueError:
        raise ValueError(f"{flag} expects comma-separated numbers, got {text!r}") from None
    if not out or not all(x > 0 for x in out):
        raise ValueError(f"{flag} expects positive learning rates, got {text!r}")
    return out


def _baseline_main(args: argparse.Namespace, name: str, spec: RecordingsSpec) -> dict[str, Any]:
    """``--recordings --model NAME``: a baseline of the grid trained on the training recordings' windows and scored on
    the held-out windows beside the nominal rig; returns what to print."""
    from dataclasses import replace

    from ..baselines.rig import BaselineConfig, baseline_summary, train_baseline_run
    from ..train.config import TrainConfig

    given = [flag for key, flag in PHAST_ONLY.items() if getattr(args, key) not in (None, [])]
    if given:
        raise ValueError(f"{', '.join(given)} apply to PHAST's recordings trainer, not to --model {name}")
    flags = {k: v for k, v in {"epochs": args.epochs, "lr": args.lr, "batch_size": args.batch_size}.items()
             if v is not None}  # a flag not given keeps the grid's TrainConfig default
    cfg = BaselineConfig(name, TrainConfig(seed=args.seed, progress=not args.no_progress, **flags), args.window_s)
    if args.step_s is not None:
        cfg = replace(cfg, step_s=args.step_s or None)  # 0: the recorded step
    sweep = None if args.lr_sweep is None else _float_list(args.lr_sweep, "--lr-sweep")
    if sweep is not None and args.lr is not None:
        raise ValueError("give either --lr or --lr-sweep, not both")
    metrics = train_baseline_run(spec, args.out, cfg, plots=not args.no_plots, resume=args.resume, sweep=sweep)
    return baseline_summary(metrics)


def _recordings_main(args: argparse.Namespace) -> dict[str, Any]:
    """The ``--recordings`` path: checks, training, held-out score; returns what to print."""
    from ..train.rig_fit import RigTrainConfig
    from ..train.rig_run import RecordingsSpec, heldout_summary, train_recordings_run

    if args.env is not None:
        raise ValueError("give either --env or --recordings, not both")
    name = _model(args)
    if not args.sim:
        raise ValueError("--recordings needs --sim (an env id or path/to/rig.py:Class)")
    spec = RecordingsSpec(args.recordings, args.sim, json_object(args.sim_kwargs, "--sim-kwargs"), args.regime,
                          _int_list(args.holdout_trajectories, "--holdout-trajectories"), args.rollout_window_s,
                          tuple(args.action_bound) if args.action_bound else None, args.decimate,
                          compare=_compared_systems(args))
    if name != "phast":
        return _baseline_main(args, name, spec)
    given = {"epochs": args.epochs, "window_s": args.window_s, "lr": args.lr, "batch_windows": args.batch_size,
             "state_iters": args.state_iters, "warmup_window_s": args.warmup_window_s,
             "warmup_epochs": args.warmup_epochs, "schedule": args.schedule}
    flags = {k: v for k, v in given.items() if v is not None}  # a flag not given keeps RigTrainConfig's default
    if args.lr is not None:
        flags["lr_mult"] = 1.0  # as given, also after UNKNOWN's start from the recorded motion
    if args.patience is not None:
        flags["patience"] = args.patience or None  # 0: every epoch
    train = RigTrainConfig(seed=args.seed, progress=not args.no_progress, **flags)
    metrics = train_recordings_run(spec, args.out, train, _overrides(args.set), plots=not args.no_plots,
                                   resume=args.resume)
    if not (metrics["verdict"]["converged"] and metrics["verdict"]["better_than_nominal"]):
        print(f"phast-train: warning: {metrics['verdict']['message']}", file=sys.stderr)
    return heldout_summary(metrics)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    import gymnasium as gym
    import torch

    torch.set_num_threads(max(1, args.threads))
    if args.recordings is not None:
        try:
            print(json.dumps(_recordings_main(args)))
        except (ValueError, gym.error.Error) as exc:
            print(f"phast-train: error: {exc}", file=sys.stderr)
            return 2
        return 0
    if args.env is None:
        print("phast-train: error: give --env (a registered env id) or --recordings FILE --sim SIM", file=sys.stderr)
        return 2
    try:
        _model(args)
    except ValueError as exc:
        print(f"phast-train: error: {exc}", file=sys.stderr)
        return 2
    if args.patience is not None or args.schedule is not None:
        print("phast-train: error: --patience and --schedule apply to --recordings runs (an --env run keeps its best "
              "validation epoch of --epochs)", file=sys.stderr)
        return 2
    try:
        from ..train.fit import TrainConfig

        data = DataSpec(n_train=args.n_train, n_val=args.n_val, n_test=args.n_test, T=args.T, seed=args.data_seed,
                        obs_noise_std=args.obs_noise_std,
                        excitation=PortExcitation(args.port_excitation, args.excitation_hold, args.excitation_seed))
        given = {"epochs": args.epochs, "batch_size": args.batch_size, "lr": args.lr}
        env_flags = {k: ENV_DEFAULTS[k] if v is None else v for k, v in given.items()}
        train = TrainConfig(**env_flags, seed=args.seed, progress=not args.no_progress)
        metrics = train_run(args.env, args.regime, args.out, data=data, train=train, overrides=_overrides(args.set),
                            resume=args.resume, plots=not args.no_plots)
    except (ValueError, gym.error.Error) as exc:
        print(f"phast-train: error: {exc}", file=sys.stderr)
        return 2
    keys = [metrics["benchmark_metric"], "damping_r2", "train_wall_time_s"]
    print(json.dumps({k: metrics.get(k) for k in keys if k in metrics}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
