"""SB3 SAC trained on the plant (``sac-real``), inside a PHAST world model (``sac-world``) or on a Gymnasium env
(``sac-gym``): the agents' environments and SAC from the benchmark's options (:class:`.config.SacConfig`), the
training (until the learning curve is flat or a fixed budget: :class:`LearningCurve`, an SB3 callback) and the
result row (``benchmarks/control_sac.py``).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import TimeLimit
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.monitor import Monitor

from phast_gym.control import ControlProtocol, make_control_env
from phast_gym.fileio import atomic_write_text

from .config import (
    SacConfig,
    command_line,
    curve_stem,
    make_protocol,
    method_tag,
    quiet_weight_of,
    regimes_of,
    reward_of,
    sac_hyperparameters,
    wells_of,
)
from .envs import FrameObs, RegimeWorldEnv, RepeatRegimeEnv
from .evaluation import REST_OFFSETS, episode_return, evaluate_gym_policy, evaluate_policy_on_plant, is_flat, plot_curve, torque_at_rest
from .rewards import format_wells

#: the env under an agent's observation wrapper, which counts the samples it consumed (:func:`env_samples`)
InnerEnv = Monitor | RepeatRegimeEnv | RegimeWorldEnv


class LinearDecay:
    """A learning rate going linearly from ``start`` to ``final`` over ``budget`` decisions of ``model`` (counted by
    its ``num_timesteps``), then held.  SB3's ``LinearSchedule`` gives the same rates through
    ``progress_remaining = 1 - t / budget``, whose ``1 - (1 - t / budget)`` differs from ``t / budget`` in the last
    bits: the documented runs used this one."""

    def __init__(self, start: float, final: float, budget: int, model: SAC) -> None:
        self.start, self.final, self.budget, self.model = start, final, max(int(budget), 1), model

    def __call__(self, _progress_remaining: float) -> float:
        frac = min(self.model.num_timesteps / self.budget, 1.0)
        return self.start + (self.final - self.start) * frac


def make_agent_env(name: str, cfg: SacConfig, seed: int) -> tuple[gym.Env, InnerEnv]:
    """(observation env, inner env with the sample counter) of an agent's training environment."""
    if name == "sac-gym":
        env = Monitor(gym.make(cfg.gym_env))  # counts the env steps (SB3 would add the same Monitor)
        return env, env
    if name == "sac-real":
        inner: InnerEnv = RepeatRegimeEnv(make_control_env(ControlProtocol(cfg.env, horizon=10**9), cfg.sigma),
                                          cfg.repeat, cfg.max_action, cfg.q_star, reward_of(cfg), seed=seed,
                                          regimes=regimes_of(cfg))
        return FrameObs(TimeLimit(inner, cfg.episode_decisions), cfg.frames, cfg.obs), inner
    from phast_model.world.gym_env import PHASTWorldModelEnv

    assert cfg.phast_run is not None  # SacConfig requires it of sac-world
    # env_id: the plant, which also serves a model of its recordings (sac_world_data.py) that names no simulator
    wm = PHASTWorldModelEnv(cfg.phast_run, env_id=cfg.env, burn_in=cfg.burn_in,
                            max_episode_steps=cfg.episode_decisions, target=np.array([cfg.q_star]))
    real: Any = wm.real  # the plant env: env_id names it
    if abs(real.dt - ControlProtocol.dt * cfg.repeat) > 1e-9:
        raise ValueError(f"world model dt {real.dt} != repeat * plant dt {ControlProtocol.dt * cfg.repeat}")
    inner = RegimeWorldEnv(wm, cfg.max_action, cfg.q_star, reward_of(cfg), cfg.sigma, cfg.burn_in, seed=seed,
                           regimes=regimes_of(cfg), plant_env_id=cfg.env)
    return FrameObs(inner, cfg.frames), inner


def env_samples(inner: InnerEnv) -> int:
    """Samples an agent's training env consumed: env steps (``sac-gym``), real burn-in measurements (``sac-world``),
    plant steps (``sac-real``)."""
    if isinstance(inner, Monitor):
        return inner.get_total_steps()
    return inner.real_samples if isinstance(inner, RegimeWorldEnv) else inner.plant_steps


def sac_model(cfg: SacConfig, train_env: gym.Env, budget: int) -> tuple[SAC, dict[str, Any]]:
    """The SB3 SAC of ``cfg`` on ``train_env`` (the mirror-equivariant policy with ``mirror``, a learning rate
    decaying over ``budget`` decisions with ``lr_final``) and its hyperparameters."""
    hp = sac_hyperparameters(cfg)
    policy_cls: Any = "MlpPolicy"
    if cfg.mirror:
        from phast_model.rl.mirror_policy import MirrorSACPolicy, mirror_signs

        policy_cls = MirrorSACPolicy
        hp["policy_kwargs"] = {**hp["policy_kwargs"], "mirror": mirror_signs(cfg.frames, velocity=cfg.obs == "frames+qdot",
                                                                            state=cfg.obs == "state")}
    model = SAC(policy_cls, train_env, seed=cfg.seed, verbose=0, **hp)
    if cfg.lr_final is not None:
        model.lr_schedule = LinearDecay(float(hp["learning_rate"]), cfg.lr_final, budget, model)
    return model, hp


def new_curve(name: str, cfg: SacConfig) -> dict[str, Any]:
    """An agent's empty learning curve, with the settings it is measured under."""
    train_env_name = {"sac-real": "real plant", "sac-world": "PHAST world model"}.get(name, cfg.gym_env)
    return {"agent": name, "q_star": cfg.q_star, "reward": cfg.reward, "sigma": cfg.sigma,
            "obs": cfg.obs, "quiet_weight": quiet_weight_of(cfg), "seed": cfg.seed,
            "wells": format_wells(wells_of(cfg)) if cfg.reward == "precise" else None,
            "until_flat": bool(cfg.until_flat),
            "train_env": train_env_name,
            "n_eval_episodes": cfg.eval_episodes, "rule": {"window": cfg.flat_window, "rel_tol": cfg.flat_rel_tol,
                                                           "abs_tol": cfg.flat_abs_tol},
            "decisions": [], "train_env_return": [], "plant_return": [], "real_env_samples": [],
            "seconds": [], "flat": False}


class CurveFlat(Exception):
    """Raised by :class:`LearningCurve` to end ``learn`` where the learning curve became flat."""


class LearningCurve(BaseCallback):
    """The learning curve of one agent, an SB3 callback: every ``cfg.eval_every`` decisions and at the end of the
    budget, the policy's mean return (``evaluate``: on the training env, and on the plant) and the real samples so far
    (``samples``) join ``curve``, written to ``path`` after each point; with ``cfg.until_flat`` training ends once
    the curve is flat (:func:`.evaluation.is_flat`).

    A point is taken when the rollout of the next decision starts (``_on_rollout_start``), i.e. after the gradient
    step of the decision it is counted at, and stopping raises :class:`CurveFlat` there: ``_on_step`` returning False
    would end ``learn`` only after the next decision has stepped the plant.  Both keep the numbers of the runs that
    trained in chunks of ``eval_every`` decisions (one ``learn`` per chunk).  SAC's ``train_freq`` is 1 (a rollout
    per decision), so every multiple of ``eval_every`` is seen."""

    def __init__(self, cfg: SacConfig, curve: dict[str, Any], evaluate: Callable[[], tuple[float, float]],
                 samples: Callable[[], int], path: Path, bar: Any, t0: float) -> None:
        super().__init__()
        self.cfg, self.curve, self.evaluate, self.samples, self.path, self.bar = cfg, curve, evaluate, samples, path, bar
        self.t0 = t0  # the agent's start (time.time()): the curve's seconds include setting it up
        self.last = 0  # decisions at the last point

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        if self.num_timesteps >= self.last + self.cfg.eval_every:
            self.point()
            if self.curve["flat"]:
                raise CurveFlat

    def _on_training_end(self) -> None:
        if self.num_timesteps > self.last:  # the budget's end
            self.point()

    def point(self) -> None:
        """Evaluate the policy now, append the point, write the partial curve, apply the stopping rule."""
        done, cfg = self.num_timesteps, self.cfg
        self.bar.update(done - self.last)
        self.last = done
        ret, plant = self.evaluate()
        for k, v in (("decisions", done), ("train_env_return", ret), ("plant_return", plant),
                     ("real_env_samples", self.samples()), ("seconds", round(time.time() - self.t0, 1))):
            self.curve[k].append(v)
        self.bar.set_postfix(ret=f"{ret:.2f}", plant=f"{plant:.2f}")
        atomic_write_text(self.path, json.dumps(self.curve, indent=1))  # partial curve
        if cfg.until_flat and is_flat(self.curve["train_env_return"], cfg.flat_window, cfg.flat_rel_tol, cfg.flat_abs_tol):
            self.curve["flat"] = True


def final_metrics(model: SAC, name: str, cfg: SacConfig) -> dict[str, Any]:
    """The trained policy's metrics: Gymnasium's return for ``sac-gym``, else the phast-control-eval metrics on the
    plant and the torque it applies at rest near the target."""
    if name == "sac-gym":
        return evaluate_gym_policy(model, cfg.gym_env, cfg.gym_eval_episodes, cfg.seed)
    m: dict[str, Any] = evaluate_policy_on_plant(model, make_protocol(cfg.q_star, cfg.env), cfg.sigma,
                                                 cfg.trials_per_regime, cfg.repeat, cfg.frames, cfg.max_action,
                                                 cfg.seed, cfg.obs, regimes_of(cfg))
    m["torque_at_rest"] = dict(zip((f"{e:+g}" for e in REST_OFFSETS),
                                   torque_at_rest(model, cfg.q_star, cfg.frames, cfg.max_action, cfg.obs)))
    return m


def save_policy(model: SAC, cfg: SacConfig, out: Path, stem: str) -> Path:
    """Save the trained agent, deployable with ``SAC.load`` (no replay buffer), at its final learning rate."""
    if cfg.lr_final is not None:  # the schedule holds the model: save the final rate instead
        from stable_baselines3.common.utils import FloatSchedule

        model.learning_rate, model.lr_schedule = cfg.lr_final, FloatSchedule(cfg.lr_final)
    policy = out / f"policy_{stem.removeprefix('curve_')}_s{cfg.seed}.zip"
    model.save(policy)
    return policy


def benchmark_agent(name: str, cfg: SacConfig, out: Path) -> dict[str, Any]:
    """Train one agent (until flat or a fixed budget; with ``until_flat`` or ``curve`` a learning curve every
    ``eval_every`` decisions: :class:`LearningCurve`), write its learning curve, return its result row."""
    from tqdm.auto import tqdm

    t0 = time.time()
    train_env, counter = make_agent_env(name, cfg, cfg.seed)
    eval_env, eval_inner = make_agent_env(name, cfg, cfg.seed + 1)
    plant_eval = None if name != "sac-world" else make_agent_env("sac-real", cfg, cfg.seed + 2)[0]
    eval_seeds = [cfg.seed * 1000 + 10_000 + i for i in range(cfg.eval_episodes)]
    world = isinstance(eval_inner, RegimeWorldEnv)  # sac-world
    world_data = world_data_samples(str(cfg.phast_run)) if world else 0  # the world model's own training recordings
    # fixed evaluation starts: the same seeded states (plant, Gymnasium env) or burn-ins (world model, drawn once:
    # real samples)
    eval_opts: list[dict | None] = [None] * cfg.eval_episodes
    if isinstance(eval_inner, RegimeWorldEnv):
        eval_opts = [{"q_burn": eval_inner.burn_in_window(np.random.default_rng(s))} for s in eval_seeds]
    budget = cfg.max_steps if cfg.until_flat else cfg.steps
    model, hp = sac_model(cfg, train_env, budget)
    stem = curve_stem(name, cfg)
    curve = new_curve(name, cfg)

    def real_samples() -> int:
        return env_samples(counter) + (eval_inner.real_samples + world_data if isinstance(eval_inner, RegimeWorldEnv) else 0)

    def evaluate() -> tuple[float, float]:
        ret = float(np.mean([episode_return(model, eval_env, s, o) for s, o in zip(eval_seeds, eval_opts)]))
        plant = ret if plant_eval is None else float(np.mean([episode_return(model, plant_eval, s) for s in eval_seeds]))
        return ret, plant

    bar = tqdm(total=budget, desc=f"{name} decisions", disable=not cfg.progress)
    record = cfg.until_flat or cfg.curve  # curve: a learning curve at a fixed budget (no stopping rule)
    try:
        callback = LearningCurve(cfg, curve, evaluate, real_samples, out / f"{stem}.json", bar, t0) if record else None
        model.learn(total_timesteps=budget, callback=callback, progress_bar=False)
        if not record:
            bar.update(budget)
    except CurveFlat:
        pass
    bar.close()
    secs, real = time.time() - t0, real_samples()
    m = final_metrics(model, name, cfg)
    row = {"method": method_tag(name, cfg), **m, "real_env_samples": real, "world_model_samples": world_data,
           "hyperparameters": {**hp, "learning_rate_final": cfg.lr_final},
           "decisions": model.num_timesteps,
           "flat": curve["flat"] if cfg.until_flat else None, "train_seconds": round(secs, 1), "seed": cfg.seed,
           "command": command_line(cfg, [name])}
    if record:
        atomic_write_text(out / f"{stem}.json", json.dumps(curve, indent=1))
        plot_curve(curve, out / f"{stem}.png")
    if name != "sac-gym":
        row["policy"] = str(save_policy(model, cfg, out, stem))
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
