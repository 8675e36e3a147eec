"""A trained policy evaluated: the flatness rule of a learning curve, seeded episodes, the ``phast-control-eval``
metrics on the real plant (the same initial states and noise seeds as the Energy-Casimir rows), the torque a policy
applies at rest, Gymnasium's own metric for ``sac-gym``, and the learning-curve figure.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, cast

import gymnasium as gym
import numpy as np
from stable_baselines3.common.type_aliases import PolicyPredictor

from phast_gym.control import START_REGIMES, ControlProtocol, make_control_env, start_states
from phast_gym.systems.base import wrap
from phast_model.rl.observation import ObsBuilder

from .envs import check_regimes, plant_system
from .rewards import QUIET_WEIGHT


def is_flat(curve: Sequence[float], window: int = 4, rel_tol: float = 0.05, abs_tol: float = 0.05) -> bool:
    """Flatness rule: at least ``2 window`` points and the mean of the last ``window`` evaluation returns
    improves on the mean of the ``window`` before by less than ``max(rel_tol |mean_prev|, abs_tol)``."""
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    if len(curve) < 2 * window:
        return False
    last, prev = float(np.mean(curve[-window:])), float(np.mean(curve[-2 * window:-window]))
    return last - prev < max(rel_tol * abs(prev), abs_tol)


def episode_return(model: PolicyPredictor, env: gym.Env, seed: int, options: dict | None = None) -> float:
    """Return of one deterministic episode of ``model`` in ``env`` (a FrameObs-wrapped env), summed in float64.

    Not SB3's ``evaluate_policy``: a learning-curve point is a fixed set of seeded starts (``seed`` and ``options``
    per episode: the world model's burn-in windows drawn once), which a ``VecEnv`` reset does not take per episode;
    its ``DummyVecEnv`` resets the env again after the last episode (on the world model: a fresh real burn-in,
    counted as real samples) and returns float32 rewards, whose sum differs from this one in the last digits."""
    obs, _ = env.reset(seed=seed, options=options)
    total, done = 0.0, False
    while not done:
        a, _ = model.predict(obs, deterministic=True)
        obs, r, term, trunc, _ = env.step(a)
        total += float(r)
        done = term or trunc
    return total


def evaluate_policy_on_plant(model: PolicyPredictor, protocol: ControlProtocol, sigma: float, trials: int, repeat: int, frames: int,
                             max_action: float, seed: int = 0, obs_mode: str = "frames",
                             regimes: Sequence[str] = tuple(START_REGIMES)) -> dict[str, Any]:
    """The phast-control-eval metrics for an SB3 policy on the real plant (same initial states and noise seeds).

    The frame buffer holds measurements at the decision rate (every ``repeat`` plant steps, as in training) and is
    filled with copies of the first measurement at every start.
    """
    from phast_gym.control.evaluation import stable_seed

    env = make_control_env(protocol, sigma)
    builder = ObsBuilder(frames, obs_mode, float(getattr(plant_system(env), "inertia", 1.0) or 1.0))
    chosen = check_regimes(regimes)
    states = {r: x for r, x in start_states(protocol, trials, seed).items() if r in chosen}
    succ, succ_angle, eff, fin, rms = [], [], [], [], []
    for regime, x0s in states.items():
        for i, x0 in enumerate(x0s):
            obs, info = env.reset(seed=stable_seed(seed, "noise", regime, i), options={"state": x0})
            pobs = builder.reset(obs, info["state"])
            us, errs = [], []
            u = np.zeros(1)
            for t in range(protocol.horizon):
                if t % repeat == 0:
                    if t > 0:
                        pobs = builder.push(obs, info["state"])
                    a, _ = model.predict(pobs, deterministic=True)
                    u = np.clip(a, -1, 1) * max_action
                obs, _, _, _, info = env.step(u)
                us.append(float(u[0]))
                errs.append(abs(float(wrap(info["state"][0] - protocol.q_star))))
            us_a, errs_a = np.array(us), np.array(errs)
            tail = slice(-protocol.settle_steps, None)
            settled = bool(np.all(errs_a[tail] < protocol.tol))
            u_rms = float(np.sqrt(np.mean(us_a[tail] ** 2)))
            succ.append(settled and u_rms < protocol.u_tol)
            succ_angle.append(settled)
            rms.append(u_rms)
            eff.append(float(np.sum(us_a**2)))
            fin.append(errs_a[-1])
    return {"success_rate": float(np.mean(succ)), "success_angle_rate": float(np.mean(succ_angle)), "effort": float(np.mean(eff)),
            "final_error": float(np.mean(fin)), "u_rms_final": float(np.mean(rms)),
            "trial_final_errors": [round(float(e), 5) for e in fin], "trial_u_rms_final": [round(float(r), 4) for r in rms]}


#: angle offsets (rad) from the target at which :func:`torque_at_rest` reads a policy
REST_OFFSETS = (-0.1, 0.0, 0.1)


def torque_at_rest(model: PolicyPredictor, q_star: float, frames: int, max_action: float, obs_mode: str = "frames",
                   offsets: Sequence[float] = REST_OFFSETS) -> list[float]:
    """The deterministic torque (N m) a policy applies with the pendulum at rest at ``q_star + e`` for each ``e``
    of ``offsets`` (noise-free frames).  A symmetric policy applies 0 at the target; a nonzero value there is a bias,
    and the policy then holds still where that bias balances gravity (``-m g l sin e``; DIAGNOSIS.md item 7)."""
    out = []
    for e in offsets:
        q = np.array([q_star + e])
        obs = ObsBuilder(frames, obs_mode).reset(q, np.array([q_star + e, 0.0]))
        a, _ = model.predict(obs, deterministic=True)
        out.append(round(float(np.clip(a, -1, 1)[0]) * max_action, 3))
    return out


def plot_curve(curve: dict[str, Any], path: Path) -> None:
    """Learning curve PNG: eval return on the training env (stopping rule) and on the real plant (monitoring)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    x = np.array(curve["decisions"])
    rule = curve.get("until_flat", True)
    ax.plot(x, curve["train_env_return"], "o-", ms=3, label=curve["train_env"] + (" (stopping rule)" if rule else ""))
    if curve["agent"] == "sac-world":
        ax.plot(x, curve["plant_return"], "s--", ms=3, label="real plant (monitoring)")
    ax.set_xlabel("SAC decisions (env steps)")
    ax.set_ylabel(f"mean eval return ({curve['n_eval_episodes']} episodes)")
    stop = (f"flat at {x[-1]}" if curve["flat"] else f"cap {x[-1]} (not flat)") if rule else f"fixed budget {x[-1]}"
    if curve["agent"] == "sac-gym":
        ax.set_title(f"sac-gym on {curve['train_env']}, seed {curve.get('seed', 0)}: {x[-1]} steps", fontsize=9)
    else:
        extra = "" if curve.get("obs", "frames") == "frames" else f", obs {curve['obs']}"
        if curve["reward"] != "zoo" and curve.get("quiet_weight", QUIET_WEIGHT) != QUIET_WEIGHT:
            extra += f", w {curve['quiet_weight']:g}"
        if curve.get("wells"):
            extra += f", wells {curve['wells']}"
        ax.set_title(f"{curve['agent']}, q* = {curve['q_star']:.3g}, reward {curve['reward']}{extra}: {stop}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def evaluate_gym_policy(model: PolicyPredictor, env_id: str, episodes: int, seed: int = 0, window: int = 20,
                        tol: float = 0.05) -> dict[str, float]:
    """Deterministic returns of ``model`` on ``episodes`` seeded episodes of a Gymnasium env (the zoo's metric), and for
    ``Pendulum-v1`` (observation cos, sin, thetadot; theta = 0 upright) the analogue of our success rule over the last
    ``window`` steps (1 s): the share of episodes with ``|theta| < tol`` throughout, mean final ``|theta|`` and the
    mean RMS torque over the window.  Per-episode seeds and per-step angles and torques: not SB3's
    ``evaluate_policy`` (see :func:`episode_return`)."""
    env = gym.make(env_id)
    box = cast(gym.spaces.Box, env.action_space)
    rets, settled, fin, rms = [], [], [], []
    for i in range(episodes):
        obs, _ = env.reset(seed=seed * 1000 + 50_000 + i)
        total, done, ths, us = 0.0, False, [], []
        while not done:
            a, _ = model.predict(obs, deterministic=True)
            obs, r, term, trunc, _ = env.step(a)
            total += float(r)
            ths.append(abs(math.atan2(float(obs[1]), float(obs[0]))) if len(obs) == 3 else float("nan"))
            us.append(float(np.clip(a, box.low, box.high)[0]))
            done = term or trunc
        rets.append(total)
        settled.append(bool(np.all(np.array(ths[-window:]) < tol)))
        fin.append(ths[-1])
        rms.append(float(np.sqrt(np.mean(np.square(us[-window:])))))
    return {"mean_return": float(np.mean(rets)), "std_return": float(np.std(rets)), "episodes": episodes,
            "settled_rate": float(np.mean(settled)), "final_abs_theta": float(np.mean(fin)), "u_rms_final": float(np.mean(rms))}
