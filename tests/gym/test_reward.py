"""The reward is one function (phast_gym.reward.regulation_reward): the real env and the world-model env call it."""

from __future__ import annotations

import ast
import math

import gymnasium as gym
import numpy as np

import phast_gym  # noqa: F401  (registers the ids)
from phast_gym.reward import ACTION_WEIGHT, VELOCITY_WEIGHT, regulation_reward
from phast_gym.systems import SCALAR, wrap
from tests import ROOT


def test_the_standard_reward():
    assert (VELOCITY_WEIGHT, ACTION_WEIGHT) == (0.1, 0.001)
    assert regulation_reward(0.25, 1.0, 4.0) == -(0.25 + 0.1 * 1.0 + 0.001 * 4.0)
    assert regulation_reward(0.0, 0.0, 0.0) == 0.0


def test_the_reward_module_is_numpy_only():
    tree = ast.parse((ROOT / "phast_gym" / "reward.py").read_text())
    imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not any(m.split(".")[0] == "torch" for m in imported)


def test_the_real_env_pays_the_standard_reward():
    env = gym.make("PHAST/DoublePendulum-v0").unwrapped
    env.reset(seed=1)
    rng = np.random.default_rng(0)
    for _ in range(20):
        a = rng.uniform(env.action_space.low, env.action_space.high).astype(env.action_space.dtype)
        _, r, *_ = env.step(a)
        q, p = env._q, env._p
        v = env.system.velocity(q, p, SCALAR)
        err = 0.0
        for qi, ti, ang in zip(q, env.target, env._angle):
            e = (qi - ti + math.pi) % (2 * math.pi) - math.pi if ang else qi - ti
            err += e * e
        u = [float(x) for x in a]
        assert r == regulation_reward(err, sum(x * x for x in v), sum(x * x for x in u))


def test_the_world_model_env_pays_the_standard_reward():
    from phast_model.world.gym_env import PHASTWorldModelEnv
    from phast_model.world.regimes import build_model

    env = PHASTWorldModelEnv(build_model("PHAST/WindyPendulum-v0", "known"), max_episode_steps=5)
    env.reset(seed=0)
    a = np.array([0.5])
    q, r, _, _, info = env.step(a)
    e = np.asarray(env._hist[0, -1].numpy(), dtype=np.float64) - env.target
    for i in env.model.angle_dims:
        e[i] = wrap(e[i])
    v = info["velocity"]
    assert r == regulation_reward(float(e @ e), float(v @ v), float(a @ a))
