"""SB3 SAC vs Energy-Casimir on the torque-port damped pendulum (q-only, noisy), same regimes and metrics.

Agents (small budget, CPU):

* ``sac-real``: SAC trained on the real plant (the control env of :class:`ControlProtocol`, decisions
  every ``repeat`` plant steps with the torque held), observation = (sin q, cos q) of the last
  ``frames`` noisy measurements;
* ``sac-world`` (with ``--phast-run``): SAC trained inside :class:`phast_model.world_env.PHASTWorldModelEnv`
  (the learned PHAST model, dt = the run's env dt = ``repeat`` plant steps) and deployed on the real plant.

Both are evaluated like ``phast-control-eval`` (five regimes, success = settled and quiet, effort
``sum_t u_t^2`` over plant steps) and compared with Energy-Casimir rows (``--ec-estimators``) on
success, effort and the number of real-env samples each method consumed.  Writes
``OUT/control_sac.json`` and ``OUT/control_sac.md``.

    python benchmarks/control_sac.py --out docs/control_results/sac --steps 15000 --phast-run RUN
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections import deque
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from phast_gym.control import START_REGIMES, ControlProtocol, evaluate_estimators, make_control_env, sample_start_states, start_states
from phast_gym.fileio import atomic_write_text
from phast_gym.systems.base import SCALAR, wrap


class FrameObs(gym.ObservationWrapper):
    """q-only observation -> (sin q, cos q) of the last ``frames`` measurements (velocity is implicit)."""

    def __init__(self, env: gym.Env, frames: int = 3) -> None:
        super().__init__(env)
        self.frames = frames
        self._buf: deque[np.ndarray] = deque(maxlen=frames)
        self.observation_space = gym.spaces.Box(-1.0, 1.0, shape=(2 * frames,), dtype=np.float32)

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(**kwargs)
        self._buf.clear()
        self._buf.extend([np.asarray(obs, dtype=np.float64)] * self.frames)
        return self._stack(), info

    def observation(self, obs: np.ndarray) -> np.ndarray:
        self._buf.append(np.asarray(obs, dtype=np.float64))
        return self._stack()

    def _stack(self) -> np.ndarray:
        q = np.concatenate(list(self._buf))
        return np.concatenate([np.sin(q), np.cos(q)]).astype(np.float32)


class RepeatRegimeEnv(gym.Wrapper):
    """Hold each action for ``repeat`` plant steps (summing rewards); reset from the regime mix."""

    def __init__(self, env: gym.Env, repeat: int, episode_decisions: int, max_action: float, q_star: float = 0.0) -> None:
        super().__init__(env)
        self.q_star = q_star
        self.repeat, self.episode_decisions = repeat, episode_decisions
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=env.action_space.shape, dtype=np.float32)
        self.max_action = max_action
        self._k = 0
        self.plant_steps = 0

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        rng = np.random.default_rng(seed if seed is not None else int(np.random.SeedSequence().generate_state(1)[0]))
        regime = list(START_REGIMES)[int(rng.integers(len(START_REGIMES)))]
        x0 = sample_start_states(self.env.unwrapped.system, regime, rng, 1)[0]
        self._k = 0
        return self.env.reset(seed=int(rng.integers(2**31)), options={"state": x0, **(options or {})})

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        u = np.clip(np.asarray(action, dtype=np.float64), -1, 1) * self.max_action
        total = 0.0
        system = self.env.unwrapped.system
        for _ in range(self.repeat):
            obs, _, term, trunc, info = self.env.step(u)
            # the env's reward shape -(|wrap(q - q*)|^2 + 0.1 |qdot|^2 + 0.001 |u|^2), centred on q_star
            x = info["state"]
            (v,) = system.velocity([float(x[0])], [float(x[1])], SCALAR)
            total += -(float(wrap(x[0] - self.q_star)) ** 2 + 0.1 * v * v + 0.001 * float(u @ u))
            self.plant_steps += 1
        self._k += 1
        return obs, total, term, trunc or self._k >= self.episode_decisions, info


class ScaledWorldEnv(gym.Wrapper):
    """World-model env with actions in [-1, 1] scaled to the torque bound."""

    def __init__(self, env: gym.Env, max_action: float) -> None:
        super().__init__(env)
        self.max_action = max_action
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=env.action_space.shape, dtype=np.float32)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        return self.env.step((np.clip(action, -1, 1) * self.max_action).astype(np.float32))


def evaluate_policy_on_plant(model: Any, protocol: ControlProtocol, sigma: float, trials: int, repeat: int, frames: int,
                             max_action: float, seed: int = 0) -> dict[str, float]:
    """The phast-control-eval metrics for an SB3 policy on the real plant (same initial states and noise seeds)."""
    from phast_gym.control.evaluation import _stable_seed

    env = make_control_env(protocol, sigma)
    states = start_states(protocol, trials, seed)
    succ, eff, fin = [], [], []
    for regime, x0s in states.items():
        for i, x0 in enumerate(x0s):
            obs, info = env.reset(seed=_stable_seed(seed, "noise", regime, i), options={"state": x0})
            buf = deque([obs] * frames, maxlen=frames)
            us, errs = [], []
            u = np.zeros(1)
            for t in range(protocol.horizon):
                if t % repeat == 0:
                    q = np.concatenate(list(buf))
                    a, _ = model.predict(np.concatenate([np.sin(q), np.cos(q)]).astype(np.float32), deterministic=True)
                    u = np.clip(a, -1, 1) * max_action
                obs, _, _, _, info = env.step(u)
                buf.append(obs)
                us.append(float(u[0]))
                errs.append(abs(float(wrap(info["state"][0] - protocol.q_star))))
            us_a, errs_a = np.array(us), np.array(errs)
            tail = slice(-protocol.settle_steps, None)
            succ.append(bool(np.all(errs_a[tail] < protocol.tol)) and float(np.sqrt(np.mean(us_a[tail] ** 2))) < protocol.u_tol)
            eff.append(float(np.sum(us_a**2)))
            fin.append(errs_a[-1])
    return {"success_rate": float(np.mean(succ)), "effort": float(np.mean(eff)), "final_error": float(np.mean(fin))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--steps", type=int, default=15000, help="SAC decisions (env steps) per agent")
    ap.add_argument("--sigma", type=float, default=0.01)
    ap.add_argument("--trials-per-regime", type=int, default=4)
    ap.add_argument("--repeat", type=int, default=5, help="plant steps per SAC decision (dt 0.01 -> 0.05)")
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--max-action", type=float, default=10.0, help="SAC torque bound (N m)")
    ap.add_argument("--phast-run", default=None, help="PHAST run for SAC inside PHASTWorldModelEnv")
    ap.add_argument("--ec-estimators", default="oracle,map,ekf")
    ap.add_argument("--q-star", type=float, default=0.0, help="target angle (pi: upright; EC gains k_c = 20, d_inj = 3)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    from stable_baselines3 import SAC

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    upright = abs(math.cos(args.q_star) + 1) < 1e-9
    protocol = ControlProtocol(q_star=args.q_star, k_c=20.0 if upright else ControlProtocol.k_c,
                               d_inj=3.0 if upright else ControlProtocol.d_inj)
    results: list[dict[str, Any]] = []

    # Energy-Casimir reference rows (no real-env samples for training; the gains use the plant's m g l only)
    rows, _ = evaluate_estimators(protocol, args.ec_estimators.split(","), [args.sigma], args.trials_per_regime, seed=args.seed)
    for r in rows:
        if r["regime"] == "all":
            results.append({"method": f"energy-casimir/{r['estimator']}", "success_rate": r["success_rate"], "effort": r["effort"],
                            "final_error": r["final_error"], "real_env_samples": 0, "train_seconds": 0.0})

    agents = [("sac-real", None)] + ([("sac-world", args.phast_run)] if args.phast_run else [])
    for name, run in agents:
        t0 = time.time()
        if run is None:
            env = RepeatRegimeEnv(make_control_env(ControlProtocol(horizon=10**9), args.sigma), args.repeat, 200, args.max_action,
                                  args.q_star)
            train_env = FrameObs(env, args.frames)
        else:
            from phast_model.world_env import PHASTWorldModelEnv

            wm = PHASTWorldModelEnv(run, burn_in=10, max_episode_steps=200, obs_noise_std=args.sigma,
                                    target=np.array([args.q_star]))
            if abs(wm.real.dt - protocol.dt * args.repeat) > 1e-9:
                raise ValueError(f"world model dt {wm.real.dt} != repeat * plant dt {protocol.dt * args.repeat}")
            train_env = FrameObs(gym.wrappers.TimeLimit(ScaledWorldEnv(wm, args.max_action), 200), args.frames)
        model = SAC("MlpPolicy", train_env, seed=args.seed, verbose=0, learning_starts=1000, batch_size=128,
                    policy_kwargs={"net_arch": [64, 64]})
        model.learn(total_timesteps=args.steps, progress_bar=False)
        secs = time.time() - t0
        # world-model burn-ins come from real-env steps: 10 per episode
        real = env.plant_steps if run is None else (args.steps // 200 + 1) * 10
        m = evaluate_policy_on_plant(model, protocol, args.sigma, args.trials_per_regime, args.repeat, args.frames, args.max_action,
                                     args.seed)
        results.append({"method": name, **m, "real_env_samples": int(real), "train_seconds": round(secs, 1)})
        print(results[-1], flush=True)

    meta = {"command": "python benchmarks/control_sac.py " + " ".join(f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items()
                                                                     if v is not None),
            "protocol": protocol.to_dict(), "sigma": args.sigma, "trials_per_regime": args.trials_per_regime, "results": results}
    atomic_write_text(out / "control_sac.json", json.dumps(meta, indent=1))
    lines = [f"SAC vs Energy-Casimir, sigma = {args.sigma:g}, {5 * args.trials_per_regime} trials ({meta['command']})", "",
             "| Method | Success | Effort | Final error | Real-env samples (plant steps) | Train s |", "|---|---|---|---|---|---|"]
    for r in results:
        lines.append(f"| {r['method']} | {r['success_rate']:.2f} | {r['effort']:.1f} | {r['final_error']:.2e} | {r['real_env_samples']} | "
                     f"{r['train_seconds']} |")
    atomic_write_text(out / "control_sac.md", "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
