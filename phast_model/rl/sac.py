"""SB3 SAC trained on the plant (``sac-real``), inside a PHAST world model (``sac-world``) or on a Gymnasium env
(``sac-gym``): the agents' environments and hyperparameters from the benchmark's options, the training loop (until
the learning curve is flat or a fixed budget) and the result row (``benchmarks/control_sac.py``).

The options are the ``argparse.Namespace`` of :func:`phast_model.cli.control_sac.parse_args`.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

import gymnasium as gym
import numpy as np

from phast_gym.control import START_REGIMES, ControlProtocol, make_control_env
from phast_gym.fileio import atomic_write_text
from phast_gym.systems.base import wrap

from .envs import FrameObs, RegimeWorldEnv, RepeatRegimeEnv, StepCounter, check_regimes
from .evaluation import REST_OFFSETS, episode_return, evaluate_gym_policy, evaluate_policy_on_plant, is_flat, plot_curve, torque_at_rest
from .rewards import PRECISE_WELLS, QUIET_WEIGHT, Reward, Well, format_wells, parse_wells, upright_quiet_weight

#: the RL zoo's tuned SAC hyperparameters for Pendulum-v1 (rl-baselines3-zoo hyperparams/sac.yml: ``policy MlpPolicy,
#: learning_rate 1e-3, n_timesteps 20000``); the rest are SB3's SAC defaults, written out so the JSON records them.
ZOO_PENDULUM_SAC: dict[str, Any] = {
    "learning_rate": 1e-3, "buffer_size": 1_000_000, "learning_starts": 100, "batch_size": 256, "tau": 0.005,
    "gamma": 0.99, "train_freq": 1, "gradient_steps": 1, "ent_coef": "auto", "use_sde": False,
    "policy_kwargs": {"net_arch": [256, 256]},
}


def sac_hyperparameters(args: argparse.Namespace) -> dict[str, Any]:
    """:data:`ZOO_PENDULUM_SAC` with ``--net`` (hidden layer sizes) in place of its ``net_arch``."""
    hp = dict(ZOO_PENDULUM_SAC)
    if getattr(args, "net", None):
        hp["policy_kwargs"] = {**hp["policy_kwargs"], "net_arch": [int(h) for h in args.net.split(",")]}
    return hp


class LinearDecay:
    """A learning rate going linearly from ``start`` to ``final`` over ``budget`` decisions of ``model`` (counted by
    its ``num_timesteps``, so training in chunks of ``learn`` calls follows one schedule), then held."""

    def __init__(self, start: float, final: float, budget: int, model: Any) -> None:
        self.start, self.final, self.budget, self.model = start, final, max(int(budget), 1), model

    def __call__(self, _progress_remaining: float) -> float:
        frac = min(self.model.num_timesteps / self.budget, 1.0)
        return self.start + (self.final - self.start) * frac


def make_agent_env(name: str, args: argparse.Namespace, seed: int) -> tuple[gym.Env, Any]:
    """(observation env, inner env with the sample counter) of an agent's training environment."""
    if name == "sac-gym":
        env = StepCounter(gym.make(args.gym_env))
        return env, env
    if name == "sac-real":
        inner: Any = RepeatRegimeEnv(make_control_env(ControlProtocol(args.env, horizon=10**9), args.sigma), args.repeat,
                                         args.episode_decisions, args.max_action, args.q_star, reward_of(args), seed=seed,
                                         regimes=regimes_of(args))
        return FrameObs(inner, args.frames, args.obs), inner
    from ..world.gym_env import PHASTWorldModelEnv

    # env_id: the plant, which also serves a model of its recordings (sac_world_data.py) that names no simulator
    wm = PHASTWorldModelEnv(args.phast_run, env_id=args.env, burn_in=args.burn_in,
                            max_episode_steps=args.episode_decisions, target=np.array([args.q_star]))
    real: Any = wm.real  # the plant env: env_id names it
    if abs(real.dt - ControlProtocol.dt * args.repeat) > 1e-9:
        raise ValueError(f"world model dt {real.dt} != repeat * plant dt {ControlProtocol.dt * args.repeat}")
    inner = RegimeWorldEnv(wm, args.max_action, args.q_star, reward_of(args), args.sigma, args.burn_in, seed=seed,
                           regimes=regimes_of(args), plant_env_id=args.env)
    return FrameObs(inner, args.frames), inner


def quiet_weight_of(args: argparse.Namespace) -> float:
    """``--quiet-weight``, or its default: :data:`QUIET_WEIGHT` at the hanging target ``q_star = 0`` (no holding torque
    needed), :func:`upright_quiet_weight` of the plant's ``m g l`` at any other target (see :func:`max_quiet_weight`)."""
    w = getattr(args, "quiet_weight", None)
    if w is not None:
        return float(w)
    if abs(float(wrap(float(args.q_star)))) < 1e-9:
        return QUIET_WEIGHT
    from phast_gym.control.evaluation import control_system

    return upright_quiet_weight(float(cast(Any, control_system(ControlProtocol(getattr(args, "env", ControlProtocol.env_id)))).mgl))


def regimes_of(args: argparse.Namespace) -> tuple[str, ...]:
    """``--regimes`` (start regimes of training, burn-ins and evaluation), or all of :data:`START_REGIMES`."""
    text = getattr(args, "regimes", None)
    return tuple(START_REGIMES) if text is None else check_regimes(text.split(","))


def wells_of(args: argparse.Namespace) -> tuple[Well, ...]:
    """``--wells`` (the ``precise`` reward's angle wells), or :data:`PRECISE_WELLS`."""
    text = getattr(args, "wells", None)
    return PRECISE_WELLS if text is None else parse_wells(text)


def reward_of(args: argparse.Namespace) -> Reward:
    """``--reward`` with its quiet weight and wells."""
    return Reward(args.reward, quiet_weight_of(args), wells_of(args))


def method_tag(name: str, args: argparse.Namespace) -> str:
    """Row name: ``agent/reward``, plus the non-default observation and quiet weight; ``sac-gym/<env id>``."""
    if name == "sac-gym":
        return f"sac-gym/{args.gym_env}"
    tag = f"{name}/{args.reward}"
    if args.reward != "zoo" and quiet_weight_of(args) != QUIET_WEIGHT:
        tag += f"/w{quiet_weight_of(args):g}"
    if args.reward == "precise" and wells_of(args) != PRECISE_WELLS:
        tag += f"/wells={format_wells(wells_of(args))}"
    if args.obs != "frames":
        tag += f"/obs={args.obs}"
    if getattr(args, "net", None):
        tag += "/net" + "x".join(h.strip() for h in args.net.split(","))
    if getattr(args, "lr_final", None) is not None:
        tag += f"/lrf{args.lr_final:g}"
    if getattr(args, "mirror", False):
        tag += "/mirror"
    return tag


def curve_stem(name: str, args: argparse.Namespace) -> str:
    """File stem of an agent's learning curve (``curve_<agent>_<reward>`` as before for the default options)."""
    if name == "sac-gym":
        return f"curve_sac-gym_{args.gym_env}_s{args.seed}"
    tag = method_tag(name, args).replace("/", "_").replace("=", "-")
    return "curve_" + re.sub(r"[^A-Za-z0-9._+-]", "-", tag.replace(",", "+"))  # portable file names


def sac_model(args: argparse.Namespace, train_env: gym.Env, budget: int) -> tuple[Any, dict[str, Any]]:
    """The SB3 SAC of ``args`` on ``train_env`` (the mirror-equivariant policy with ``--mirror``, a learning rate
    decaying over ``budget`` decisions with ``--lr-final``) and its hyperparameters."""
    from stable_baselines3 import SAC

    hp = sac_hyperparameters(args)
    policy_cls: Any = "MlpPolicy"
    if getattr(args, "mirror", False):
        from .mirror_policy import MirrorSACPolicy, mirror_signs

        policy_cls = MirrorSACPolicy
        hp["policy_kwargs"] = {**hp["policy_kwargs"], "mirror": mirror_signs(args.frames, velocity=args.obs == "frames+qdot",
                                                                            state=args.obs == "state")}
    model = SAC(policy_cls, train_env, seed=args.seed, verbose=0, **hp)
    if args.lr_final is not None:
        model.lr_schedule = LinearDecay(float(hp["learning_rate"]), args.lr_final, budget, model)
    return model, hp


def new_curve(name: str, args: argparse.Namespace) -> dict[str, Any]:
    """An agent's empty learning curve, with the settings it is measured under."""
    train_env_name = {"sac-real": "real plant", "sac-world": "PHAST world model"}.get(name, args.gym_env)
    return {"agent": name, "q_star": args.q_star, "reward": args.reward, "sigma": args.sigma,
            "obs": args.obs, "quiet_weight": quiet_weight_of(args), "seed": args.seed,
            "wells": format_wells(wells_of(args)) if args.reward == "precise" else None,
            "until_flat": bool(args.until_flat),
            "train_env": train_env_name,
            "n_eval_episodes": args.eval_episodes, "rule": {"window": args.flat_window, "rel_tol": args.flat_rel_tol,
                                                            "abs_tol": args.flat_abs_tol},
            "decisions": [], "train_env_return": [], "plant_return": [], "real_env_samples": [],
            "seconds": [], "flat": False}


def final_metrics(model: Any, name: str, args: argparse.Namespace) -> dict[str, Any]:
    """The trained policy's metrics: Gymnasium's return for ``sac-gym``, else the phast-control-eval metrics on the
    plant and the torque it applies at rest near the target."""
    if name == "sac-gym":
        return evaluate_gym_policy(model, args.gym_env, args.gym_eval_episodes, args.seed)
    m: dict[str, Any] = evaluate_policy_on_plant(model, make_protocol(args.q_star, args.env), args.sigma,
                                                 args.trials_per_regime, args.repeat, args.frames, args.max_action,
                                                 args.seed, args.obs, regimes_of(args))
    m["torque_at_rest"] = dict(zip((f"{e:+g}" for e in REST_OFFSETS),
                                   torque_at_rest(model, args.q_star, args.frames, args.max_action, args.obs)))
    return m


def save_policy(model: Any, args: argparse.Namespace, out: Path, stem: str) -> Path:
    """Save the trained agent, deployable with ``SAC.load`` (no replay buffer), at its final learning rate."""
    if args.lr_final is not None:  # the schedule holds the model: save the final rate instead
        from stable_baselines3.common.utils import FloatSchedule

        model.learning_rate, model.lr_schedule = args.lr_final, FloatSchedule(args.lr_final)
    policy = out / f"policy_{stem.removeprefix('curve_')}_s{args.seed}.zip"
    model.save(policy)
    return policy


def train_agent(name: str, args: argparse.Namespace, out: Path) -> dict[str, Any]:
    """Train one agent (until flat or a fixed budget), write its learning curve, return its result row."""
    from tqdm.auto import tqdm

    t0 = time.time()
    train_env, counter = make_agent_env(name, args, args.seed)
    eval_env, eval_inner = make_agent_env(name, args, args.seed + 1)
    plant_eval: Any = None if name != "sac-world" else make_agent_env("sac-real", args, args.seed + 2)[0]
    eval_seeds = [args.seed * 1000 + 10_000 + i for i in range(args.eval_episodes)]
    world = name == "sac-world"
    world_data = world_data_samples(args.phast_run) if world else 0  # the world model's own training recordings
    # fixed evaluation starts: the same seeded states (plant, Gymnasium env) or burn-ins (world model, drawn once:
    # real samples)
    if not world:
        eval_opts: list[dict | None] = [None] * args.eval_episodes
    else:
        eval_opts = [{"q_burn": eval_inner.burn_in_window(np.random.default_rng(s))} for s in eval_seeds]
    budget = args.max_steps if args.until_flat else args.steps
    model, hp = sac_model(args, train_env, budget)
    record = args.until_flat or args.curve  # --curve: a learning curve at a fixed budget (no stopping rule)
    chunk = args.eval_every if record else budget
    stem = curve_stem(name, args)
    curve = new_curve(name, args)

    def real_samples() -> int:
        return int(counter.plant_steps if not world else counter.real_samples + eval_inner.real_samples + world_data)

    bar = tqdm(total=budget, desc=f"{name} decisions", disable=args.no_progress)
    done = 0
    while done < budget:
        n = min(chunk, budget - done)
        model.learn(total_timesteps=n, reset_num_timesteps=done == 0, progress_bar=False)
        done += n
        bar.update(n)
        if not record:
            break
        ret = float(np.mean([episode_return(model, eval_env, s, o) for s, o in zip(eval_seeds, eval_opts)]))
        plant = ret if not world else float(np.mean([episode_return(model, plant_eval, s) for s in eval_seeds]))
        for k, v in (("decisions", done), ("train_env_return", ret), ("plant_return", plant), ("real_env_samples", real_samples()),
                     ("seconds", round(time.time() - t0, 1))):
            curve[k].append(v)
        bar.set_postfix(ret=f"{ret:.2f}", plant=f"{plant:.2f}")
        atomic_write_text(out / f"{stem}.json", json.dumps(curve, indent=1))  # partial curve
        if args.until_flat and is_flat(curve["train_env_return"], args.flat_window, args.flat_rel_tol, args.flat_abs_tol):
            curve["flat"] = True
            break
    bar.close()
    secs = time.time() - t0
    real = real_samples()
    m = final_metrics(model, name, args)
    row = {"method": method_tag(name, args), **m, "real_env_samples": real, "world_model_samples": world_data,
           "hyperparameters": {**hp, "learning_rate_final": args.lr_final},
           "decisions": done,
           "flat": curve["flat"] if args.until_flat else None, "train_seconds": round(secs, 1), "seed": args.seed,
           "command": command_line(args, [name])}
    if record:
        atomic_write_text(out / f"{stem}.json", json.dumps(curve, indent=1))
        plot_curve(curve, out / f"{stem}.png")
    if name != "sac-gym":
        row["policy"] = str(save_policy(model, args, out, stem))
    return row


def world_data_samples(run: str | Path) -> int:
    """Real samples behind a world-model run: ``real_samples`` of the ``world_data.json`` that
    ``benchmarks/sac_world_data.py`` writes beside a model of plant recordings; 0 without one (a model trained on
    simulated data, ``phast-train --env``: its samples are simulator outputs, reported separately)."""
    path = Path(run) / "world_data.json"
    if not path.exists():
        return 0
    try:
        return int(json.loads(path.read_text())["real_samples"])
    except (ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{path}: no integer 'real_samples' ({e})") from None


def make_protocol(q_star: float, env_id: str = ControlProtocol.env_id) -> ControlProtocol:
    """The evaluation protocol of plant ``env_id``; upright (q_star = pi) uses the upright Energy-Casimir gains
    k_c = 20, d_inj = 3."""
    upright = abs(math.cos(q_star) + 1) < 1e-9
    return ControlProtocol(env_id, q_star=q_star, k_c=20.0 if upright else ControlProtocol.k_c,
                           d_inj=3.0 if upright else ControlProtocol.d_inj)


#: options that only the plant agents (sac-real / sac-world) and the Energy-Casimir rows read
SAC_PLANT_ONLY = ("env", "regimes", "wells", "obs", "reward", "quiet_weight", "sigma", "trials_per_regime", "repeat",
                  "episode_decisions", "frames", "burn_in",
                  "max_action", "phast_run", "ec_estimators", "q_star")


def command_line(args: argparse.Namespace, agents: Sequence[str] | None = None) -> str:
    """The command that reproduces ``args`` (with ``agents`` in place of ``--agents``)."""
    parts = ["python benchmarks/control_sac.py"]
    for k, v in vars(args).items():
        if k == "agents" and agents is not None:
            v = ",".join(agents) or "none"
        if v is None or v is False or k in ("no_progress", "tables_only"):
            continue
        gym_only = agents is not None and list(agents) == ["sac-gym"]
        if agents is not None and ((k in ("gym_env", "gym_eval_episodes") and not gym_only) or (k in SAC_PLANT_ONLY and gym_only)):
            continue  # options the command's agents do not read
        parts.append(f"--{k.replace('_', '-')}" + ("" if v is True else f" {v}"))
    return " ".join(parts)
