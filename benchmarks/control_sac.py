"""SB3 SAC vs Energy-Casimir on the torque-port damped pendulum (q-only, noisy), same regimes and metrics.

Agents (CPU, one torch thread):

* ``sac-real``: SAC trained on the real plant (the control env of :class:`ControlProtocol`, decisions
  every ``repeat`` plant steps with the torque held), observation = (sin q, cos q) of the last
  ``frames`` noisy measurements taken at the decision rate;
* ``sac-world`` (with ``--phast-run``): SAC trained inside :class:`phast_model.world_env.PHASTWorldModelEnv`
  (the learned PHAST model, dt = the run's env dt = ``repeat`` plant steps; every episode starts from a
  burn-in window of ``burn_in`` real noisy measurements from a start-regime state) and deployed on the real plant.

Hyperparameters: the RL zoo's tuned Pendulum-v1 SAC (``learning_rate 1e-3``, everything else SB3's SAC
defaults; the zoo's 20k-step budget is replaced by ``--until-flat``).  With ``--until-flat`` training
runs in chunks of ``--eval-every`` decisions; after each chunk the deterministic policy is evaluated on
fixed seeded episodes of its training env (the real plant for ``sac-real``, the world model for
``sac-world``) and training stops when the learning curve is flat (:func:`is_flat`) or at ``--max-steps``.
A monitoring curve on the real plant (not used for stopping, not counted as training samples) is
plotted too.  Both agents are then evaluated like ``phast-control-eval`` (five regimes, success =
settled and quiet, effort ``sum_t u_t^2`` over plant steps) and compared with Energy-Casimir rows
(``--ec-estimators``) on success, effort and real-env samples.  Rows are merged into
``OUT/control_sac.json`` / ``OUT/control_sac.md`` (one process per agent is fine); learning curves go to
``OUT/curve_<agent>.json`` and ``OUT/curve_<agent>.png``.

    python benchmarks/control_sac.py --out OUT --agents sac-real --until-flat --reward quiet --q-star 0
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections import deque
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from phast_gym.control import START_REGIMES, ControlProtocol, evaluate_estimators, make_control_env, sample_start_states, start_states
from phast_gym.fileio import atomic_write_text
from phast_gym.systems.base import SCALAR, wrap

#: the RL zoo's tuned SAC hyperparameters for Pendulum-v1 (rl-baselines3-zoo hyperparams/sac.yml: ``policy MlpPolicy,
#: learning_rate 1e-3, n_timesteps 20000``); the rest are SB3's SAC defaults, written out so the JSON records them.
ZOO_PENDULUM_SAC: dict[str, Any] = {
    "learning_rate": 1e-3, "buffer_size": 1_000_000, "learning_starts": 100, "batch_size": 256, "tau": 0.005,
    "gamma": 0.99, "train_freq": 1, "gradient_steps": 1, "ent_coef": "auto", "use_sde": False,
    "policy_kwargs": {"net_arch": [256, 256]},
}

REWARDS = ("zoo", "quiet")
#: the quiet reward's extra torque weight and the angle scale of the region where it applies
QUIET_WEIGHT, QUIET_SCALE = 0.5, 0.3


def pendulum_reward(err: float, v: float, u: float, kind: str = "zoo") -> float:
    """Per-step reward from the wrapped angle error ``err`` (rad), velocity ``v`` and torque ``u`` (N m).

    ``zoo``: the Gymnasium Pendulum shape ``-(err^2 + 0.1 v^2 + 0.001 u^2)``.
    ``quiet``: that minus ``QUIET_WEIGHT u^2 exp(-(err / QUIET_SCALE)^2)``: a torque penalty that is 500x larger
    near the target, so holding the target with a quiet actuator (the success rule's RMS torque) pays.
    """
    r = -(err * err + 0.1 * v * v + 0.001 * u * u)
    if kind == "quiet":
        r -= QUIET_WEIGHT * u * u * math.exp(-((err / QUIET_SCALE) ** 2))
    elif kind != "zoo":
        raise ValueError(f"reward must be one of {REWARDS}, got {kind!r}")
    return r


def is_flat(curve: Sequence[float], window: int = 4, rel_tol: float = 0.05, abs_tol: float = 0.05) -> bool:
    """Flatness rule: at least ``2 window`` points and the mean of the last ``window`` evaluation returns
    improves on the mean of the ``window`` before by less than ``max(rel_tol |mean_prev|, abs_tol)``."""
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    if len(curve) < 2 * window:
        return False
    last, prev = float(np.mean(curve[-window:])), float(np.mean(curve[-2 * window:-window]))
    return last - prev < max(rel_tol * abs(prev), abs_tol)


def stack_frames(buf: Sequence[np.ndarray]) -> np.ndarray:
    """(sin q, cos q) of the buffered measurements, oldest first."""
    q = np.concatenate([np.asarray(b, dtype=np.float64).reshape(-1) for b in buf])
    return np.concatenate([np.sin(q), np.cos(q)]).astype(np.float32)


class FrameObs(gym.ObservationWrapper):
    """q-only observation -> (sin q, cos q) of the last ``frames`` measurements (velocity is implicit).

    At reset the buffer is cleared and filled with ``frames`` copies of the first measurement.
    """

    def __init__(self, env: gym.Env, frames: int = 3) -> None:
        super().__init__(env)
        self.frames = frames
        self._buf: deque[np.ndarray] = deque(maxlen=frames)
        self.observation_space = gym.spaces.Box(-1.0, 1.0, shape=(2 * frames,), dtype=np.float32)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(**kwargs)
        self._buf.clear()
        self._buf.extend([np.asarray(obs, dtype=np.float64)] * self.frames)
        return stack_frames(self._buf), info

    def observation(self, obs: np.ndarray) -> np.ndarray:
        self._buf.append(np.asarray(obs, dtype=np.float64))
        return stack_frames(self._buf)


class RepeatRegimeEnv(gym.Wrapper):
    """Hold each action for ``repeat`` plant steps (mean reward over them); reset from the start-regime mix.

    Resets draw from an own generator (seeded by ``seed`` or the first ``reset(seed=...)``), so a training
    run is reproducible; ``reset(options={"state": x0})`` starts from ``x0``.  ``plant_steps`` counts the
    plant steps (real-env samples) consumed.
    """

    def __init__(self, env: gym.Env, repeat: int, episode_decisions: int, max_action: float, q_star: float = 0.0,
                 reward: str = "zoo", seed: int | None = None) -> None:
        super().__init__(env)
        if reward not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {reward!r}")
        self.q_star, self.reward_kind = q_star, reward
        self.repeat, self.episode_decisions = repeat, episode_decisions
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=env.action_space.shape, dtype=np.float32)
        self.max_action = max_action
        self._rng = np.random.default_rng(seed)
        self._k = 0
        self.plant_steps = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        options = dict(options or {})
        if options.get("state") is None:
            regime = list(START_REGIMES)[int(self._rng.integers(len(START_REGIMES)))]
            options["state"] = sample_start_states(self.env.unwrapped.system, regime, self._rng, 1)[0]
        self._k = 0
        return self.env.reset(seed=int(self._rng.integers(2**31)), options=options)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        u = np.clip(np.asarray(action, dtype=np.float64), -1, 1) * self.max_action
        total = 0.0
        system = self.env.unwrapped.system
        us, errs = [], []
        for _ in range(self.repeat):
            obs, _, term, trunc, info = self.env.step(u)
            x = info["state"]
            (v,) = system.velocity([float(x[0])], [float(x[1])], SCALAR)
            err = float(wrap(x[0] - self.q_star))
            total += pendulum_reward(err, v, float(u[0]), self.reward_kind)
            us.append(float(u[0]))
            errs.append(abs(err))
            self.plant_steps += 1
            if term:
                break
        self._k += 1
        info = {**info, "plant_u": us, "plant_err": errs}
        return obs, total / len(us), term, trunc or self._k >= self.episode_decisions, info


class RegimeWorldEnv(gym.Wrapper):
    """World-model env: actions in [-1, 1] scaled to the torque bound, the chosen reward recomputed from the model's
    q and velocity estimate, observations with ``sigma`` measurement noise added (as on the plant), and every episode
    started from ``burn_in`` real noisy zero-torque measurements (run dt) from a start-regime state.

    ``real_samples`` counts the real measurements consumed by burn-ins.
    """

    def __init__(self, env: gym.Env, max_action: float, q_star: float, reward: str, sigma: float, burn_in: int,
                 seed: int | None = None) -> None:
        super().__init__(env)
        if reward not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {reward!r}")
        self.max_action, self.q_star, self.reward_kind, self.sigma, self.burn_in = max_action, q_star, reward, sigma, burn_in
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=env.action_space.shape, dtype=np.float32)
        self._rng = np.random.default_rng(seed)
        self._plant = make_control_env(ControlProtocol(dt=float(env.unwrapped.real.dt), horizon=10**9), sigma)
        self.real_samples = 0

    def burn_in_window(self, rng: np.random.Generator) -> np.ndarray:
        """``burn_in`` noisy zero-torque measurements of the real plant from a random start-regime state."""
        regime = list(START_REGIMES)[int(rng.integers(len(START_REGIMES)))]
        x0 = sample_start_states(self._plant.unwrapped.system, regime, rng, 1)[0]
        obs, _ = self._plant.reset(seed=int(rng.integers(2**31)), options={"state": x0})
        qs = [np.asarray(obs, dtype=np.float64)]
        for _ in range(self.burn_in - 1):
            obs, *_ = self._plant.step(np.zeros(1))
            qs.append(np.asarray(obs, dtype=np.float64))
        self.real_samples += self.burn_in
        return np.array(qs)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        options = dict(options or {})
        if options.get("q_burn") is None:
            options["q_burn"] = self.burn_in_window(self._rng)
        obs, info = self.env.reset(seed=int(self._rng.integers(2**31)), options=options)
        return self._noisy(obs), info

    def _noisy(self, obs: np.ndarray) -> np.ndarray:
        return np.asarray(obs, dtype=np.float64) + self.sigma * self._rng.standard_normal(np.shape(obs))

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        u = np.clip(np.asarray(action, dtype=np.float64), -1, 1) * self.max_action
        obs, r, term, trunc, info = self.env.step(u.astype(np.float32))
        if not term:
            err = float(wrap(float(obs[0]) - self.q_star))
            r = pendulum_reward(err, float(info["velocity"][0]), float(u[0]), self.reward_kind)
        return self._noisy(obs), float(r), term, trunc, info


def episode_return(model: Any, env: gym.Env, seed: int, options: dict | None = None) -> float:
    """Return of one deterministic episode of ``model`` in ``env`` (a FrameObs-wrapped env)."""
    obs, _ = env.reset(seed=seed, options=options)
    total, done = 0.0, False
    while not done:
        a, _ = model.predict(obs, deterministic=True)
        obs, r, term, trunc, _ = env.step(a)
        total += float(r)
        done = term or trunc
    return total


def evaluate_policy_on_plant(model: Any, protocol: ControlProtocol, sigma: float, trials: int, repeat: int, frames: int,
                             max_action: float, seed: int = 0) -> dict[str, float]:
    """The phast-control-eval metrics for an SB3 policy on the real plant (same initial states and noise seeds).

    The frame buffer holds measurements at the decision rate (every ``repeat`` plant steps, as in training) and is
    filled with copies of the first measurement at every start.
    """
    from phast_gym.control.evaluation import _stable_seed

    env = make_control_env(protocol, sigma)
    states = start_states(protocol, trials, seed)
    succ, succ_angle, eff, fin, rms = [], [], [], [], []
    for regime, x0s in states.items():
        for i, x0 in enumerate(x0s):
            obs, info = env.reset(seed=_stable_seed(seed, "noise", regime, i), options={"state": x0})
            buf: deque[np.ndarray] = deque([obs] * frames, maxlen=frames)
            us, errs = [], []
            u = np.zeros(1)
            for t in range(protocol.horizon):
                if t % repeat == 0:
                    if t > 0:
                        buf.append(obs)
                    a, _ = model.predict(stack_frames(buf), deterministic=True)
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
            "final_error": float(np.mean(fin)), "u_rms_final": float(np.mean(rms))}


def plot_curve(curve: dict[str, Any], path: Path) -> None:
    """Learning curve PNG: eval return on the training env (stopping rule) and on the real plant (monitoring)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 3.8))
    x = np.array(curve["decisions"])
    ax.plot(x, curve["train_env_return"], "o-", ms=3, label=f"{curve['train_env']} (stopping rule)")
    if curve["agent"] != "sac-real":
        ax.plot(x, curve["plant_return"], "s--", ms=3, label="real plant (monitoring)")
    ax.set_xlabel("SAC decisions (env steps)")
    ax.set_ylabel(f"mean eval return ({curve['n_eval_episodes']} episodes)")
    stop = f"flat at {x[-1]}" if curve["flat"] else f"cap {x[-1]} (not flat)"
    ax.set_title(f"{curve['agent']}, q* = {curve['q_star']:.3g}, reward {curve['reward']}: {stop}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def make_agent_env(name: str, args: argparse.Namespace, seed: int) -> tuple[gym.Env, gym.Env]:
    """(FrameObs env, inner env with the sample counter) of an agent's training environment."""
    if name == "sac-real":
        inner: gym.Env = RepeatRegimeEnv(make_control_env(ControlProtocol(horizon=10**9), args.sigma), args.repeat,
                                         args.episode_decisions, args.max_action, args.q_star, args.reward, seed=seed)
        return FrameObs(inner, args.frames), inner
    from phast_model.world_env import PHASTWorldModelEnv

    wm = PHASTWorldModelEnv(args.phast_run, burn_in=args.burn_in, max_episode_steps=args.episode_decisions,
                            target=np.array([args.q_star]))
    if abs(wm.real.dt - ControlProtocol.dt * args.repeat) > 1e-9:
        raise ValueError(f"world model dt {wm.real.dt} != repeat * plant dt {ControlProtocol.dt * args.repeat}")
    inner = RegimeWorldEnv(wm, args.max_action, args.q_star, args.reward, args.sigma, args.burn_in, seed=seed)
    return FrameObs(inner, args.frames), inner


def train_agent(name: str, args: argparse.Namespace, out: Path) -> dict[str, Any]:
    """Train one agent (until flat or a fixed budget), write its learning curve, return its result row."""
    from stable_baselines3 import SAC
    from tqdm.auto import tqdm

    t0 = time.time()
    train_env, counter = make_agent_env(name, args, args.seed)
    eval_env, eval_inner = make_agent_env(name, args, args.seed + 1)
    plant_eval, _ = make_agent_env("sac-real", args, args.seed + 2)
    n_eval = args.eval_episodes
    eval_seeds = [args.seed * 1000 + 10_000 + i for i in range(n_eval)]
    # fixed evaluation starts: the same seeded states (plant) or burn-ins (world model, drawn once: real samples)
    if name == "sac-real":
        eval_opts: list[dict | None] = [None] * n_eval
    else:
        eval_opts = [{"q_burn": eval_inner.burn_in_window(np.random.default_rng(s))} for s in eval_seeds]
    hp = dict(ZOO_PENDULUM_SAC)
    model = SAC("MlpPolicy", train_env, seed=args.seed, verbose=0, **hp)
    budget = args.max_steps if args.until_flat else args.steps
    chunk = args.eval_every if args.until_flat else budget
    curve: dict[str, Any] = {"agent": name, "q_star": args.q_star, "reward": args.reward, "sigma": args.sigma,
                             "train_env": "real plant" if name == "sac-real" else "PHAST world model",
                             "n_eval_episodes": n_eval, "rule": {"window": args.flat_window, "rel_tol": args.flat_rel_tol,
                                                                 "abs_tol": args.flat_abs_tol},
                             "decisions": [], "train_env_return": [], "plant_return": [], "real_env_samples": [],
                             "seconds": [], "flat": False}
    bar = tqdm(total=budget, desc=f"{name} decisions", disable=args.no_progress)
    done = 0
    while done < budget:
        n = min(chunk, budget - done)
        model.learn(total_timesteps=n, reset_num_timesteps=done == 0, progress_bar=False)
        done += n
        bar.update(n)
        if not args.until_flat:
            break
        ret = float(np.mean([episode_return(model, eval_env, s, o) for s, o in zip(eval_seeds, eval_opts)]))
        plant = ret if name == "sac-real" else float(np.mean([episode_return(model, plant_eval, s) for s in eval_seeds]))
        real = counter.plant_steps if name == "sac-real" else counter.real_samples + eval_inner.real_samples
        for k, v in (("decisions", done), ("train_env_return", ret), ("plant_return", plant), ("real_env_samples", int(real)),
                     ("seconds", round(time.time() - t0, 1))):
            curve[k].append(v)
        bar.set_postfix(ret=f"{ret:.2f}", plant=f"{plant:.2f}")
        atomic_write_text(out / f"curve_{name}_{args.reward}.json", json.dumps(curve, indent=1))  # partial curve
        if is_flat(curve["train_env_return"], args.flat_window, args.flat_rel_tol, args.flat_abs_tol):
            curve["flat"] = True
            break
    bar.close()
    secs = time.time() - t0
    real = counter.plant_steps if name == "sac-real" else counter.real_samples + eval_inner.real_samples
    protocol = make_protocol(args.q_star)
    m = evaluate_policy_on_plant(model, protocol, args.sigma, args.trials_per_regime, args.repeat, args.frames,
                                 args.max_action, args.seed)
    tag = f"{name}/{args.reward}"
    row = {"method": tag, **m, "real_env_samples": int(real), "decisions": done, "flat": curve["flat"] if args.until_flat else None,
           "train_seconds": round(secs, 1), "command": command_line(args, [name])}
    if args.until_flat:
        atomic_write_text(out / f"curve_{name}_{args.reward}.json", json.dumps(curve, indent=1))
        plot_curve(curve, out / f"curve_{name}_{args.reward}.png")
    return row


def make_protocol(q_star: float) -> ControlProtocol:
    """The evaluation protocol; upright (q_star = pi) uses the upright Energy-Casimir gains k_c = 20, d_inj = 3."""
    upright = abs(math.cos(q_star) + 1) < 1e-9
    return ControlProtocol(q_star=q_star, k_c=20.0 if upright else ControlProtocol.k_c,
                           d_inj=3.0 if upright else ControlProtocol.d_inj)


def command_line(args: argparse.Namespace, agents: Sequence[str] | None = None) -> str:
    """The command that reproduces ``args`` (with ``agents`` in place of ``--agents``)."""
    parts = ["python benchmarks/control_sac.py"]
    for k, v in vars(args).items():
        if k == "agents" and agents is not None:
            v = ",".join(agents) or "none"
        if v is None or v is False or k in ("no_progress", "tables_only"):
            continue
        parts.append(f"--{k.replace('_', '-')}" + ("" if v is True else f" {v}"))
    return " ".join(parts)


def write_tables(out: Path, meta: dict[str, Any]) -> None:
    """``control_sac.md`` from the merged rows of ``control_sac.json``."""
    lines = [f"SAC vs Energy-Casimir, q_star = {meta['q_star']:.6g}, sigma = {meta['sigma']:g}, {5 * meta['trials_per_regime']} trials "
             "(success: |wrap(q - q*)| < 0.05 rad and RMS torque < 0.25 N m over the last 100 plant steps)", "",
             "| Method | Success | Success (angle only) | Effort | RMS torque, last 100 | Final error | Real-env samples "
             "| SAC decisions | Flat | Train s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in meta["results"]:
        flat = "-" if r.get("flat") is None else ("yes" if r["flat"] else "no (cap)")
        lines.append(f"| {r['method']} | {r['success_rate']:.2f} | {r['success_angle_rate']:.2f} | {r['effort']:.1f} | "
                     f"{r['u_rms_final']:.3f} | {r['final_error']:.2e} | {r['real_env_samples']} | {r.get('decisions', 0)} | {flat} | "
                     f"{r['train_seconds']} |")
    lines += ["", "Real-env samples: plant measurements consumed in training (sac-real: plant steps, 0.01 s apart; "
              "sac-world: burn-in measurements, 0.05 s apart).", "", "Commands:", ""]
    lines += [f"* `{r['method']}`: `{r['command']}`" for r in meta["results"]]
    atomic_write_text(out / "control_sac.md", "\n".join(lines) + "\n")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--agents", default="sac-real,sac-world",
                    help="comma list of sac-real, sac-world (needs --phast-run); none: Energy-Casimir rows only")
    ap.add_argument("--steps", type=int, default=20000, help="SAC decisions per agent without --until-flat (zoo: 20k)")
    ap.add_argument("--until-flat", action="store_true", help="train until the learning curve is flat (is_flat) or --max-steps")
    ap.add_argument("--max-steps", type=int, default=150000, help="cap on SAC decisions with --until-flat")
    ap.add_argument("--eval-every", type=int, default=2500, help="decisions between learning-curve evaluations")
    ap.add_argument("--eval-episodes", type=int, default=10, help="fixed seeded episodes per learning-curve point")
    ap.add_argument("--flat-window", type=int, default=4, help="K: compare the mean of the last K points with the K before")
    ap.add_argument("--flat-rel-tol", type=float, default=0.05)
    ap.add_argument("--flat-abs-tol", type=float, default=0.05)
    ap.add_argument("--reward", choices=REWARDS, default="zoo")
    ap.add_argument("--sigma", type=float, default=0.01)
    ap.add_argument("--trials-per-regime", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=5, help="plant steps per SAC decision (dt 0.01 -> 0.05)")
    ap.add_argument("--episode-decisions", type=int, default=200, help="training episode length in decisions (10 s)")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--burn-in", type=int, default=10, help="real measurements per world-model episode")
    ap.add_argument("--max-action", type=float, default=10.0, help="SAC torque bound (N m)")
    ap.add_argument("--phast-run", default=None, help="PHAST run for SAC inside PHASTWorldModelEnv")
    ap.add_argument("--ec-estimators", default="oracle,map,ekf")
    ap.add_argument("--q-star", type=float, default=0.0, help="target angle (pi: upright; EC gains k_c = 20, d_inj = 3)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-progress", action="store_true")
    ap.add_argument("--tables-only", action="store_true", help="only rewrite OUT/control_sac.md from OUT/control_sac.json")
    args = ap.parse_args(argv)
    for a in agents_of(args):
        if a not in ("sac-real", "sac-world"):
            ap.error(f"unknown agent {a!r}")
        if a == "sac-world" and not args.phast_run:
            ap.error("sac-world needs --phast-run")
    return args


def agents_of(args: argparse.Namespace) -> list[str]:
    return [a for a in args.agents.split(",") if a and a != "none"]


def energy_casimir_rows(protocol: Any, args: argparse.Namespace) -> dict[str, dict[str, Any]]:
    """The Energy-Casimir reference rows, one per estimator (no real-env samples for training; the gains use the
    plant's m g l only)."""
    rows, _ = evaluate_estimators(protocol, args.ec_estimators.split(","), [args.sigma], args.trials_per_regime,
                                  seed=args.seed, progress=not args.no_progress)
    cmd = command_line(args, [])
    keys = ("success_rate", "success_angle_rate", "effort", "final_error")
    return {f"energy-casimir/{r['estimator']}": {
        "method": f"energy-casimir/{r['estimator']}", **{k: r[k] for k in keys},
        "u_rms_final": r.get("u_rms_final", float("nan")), "real_env_samples": 0, "decisions": 0, "flat": None,
        "train_seconds": 0.0, "command": cmd} for r in rows if r["regime"] == "all"}


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.tables_only:
        write_tables(Path(args.out), json.loads((Path(args.out) / "control_sac.json").read_text()))
        return
    torch.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    protocol = make_protocol(args.q_star)
    path = out / "control_sac.json"
    meta: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    if meta and (meta.get("q_star") != args.q_star or meta.get("sigma") != args.sigma
                 or meta.get("trials_per_regime") != args.trials_per_regime):
        raise SystemExit(f"{path} holds another setting (q_star/sigma/trials); use another --out")
    results: dict[str, dict[str, Any]] = {r["method"]: r for r in meta.get("results", [])}
    results.update(energy_casimir_rows(protocol, args))

    def save() -> None:
        order = sorted(results.values(), key=lambda r: (not r["method"].startswith("energy"), r["method"]))
        meta.update({"q_star": args.q_star, "sigma": args.sigma, "trials_per_regime": args.trials_per_regime,
                     "protocol": protocol.to_dict(), "hyperparameters": ZOO_PENDULUM_SAC, "results": order})
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
