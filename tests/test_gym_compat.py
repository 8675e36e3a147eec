"""Gymnasium and Stable-Baselines3 citizenship of every PHAST/* id."""

from __future__ import annotations

import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env

import phast_gym

ALL = phast_gym.env_ids()


@pytest.mark.parametrize("env_id", ALL)
def test_gymnasium_env_checker(env_id: str) -> None:
    env = gym.make(env_id, render_mode="rgb_array").unwrapped
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check_env(env)
    # advice tolerated: "normalize your Box action space" (physical units are the point of the suite;
    # Pendulum-v1 triggers it too) and "infinite Box bounds" (positions, charges, populations are unbounded)
    advisory = ("symmetric and normalized", "is -infinity", "is infinity")
    other = [str(w.message) for w in caught if not any(a in str(w.message) for a in advisory)]
    assert other == [], other


@pytest.mark.parametrize("env_id", ALL)
def test_sb3_env_checker(env_id: str) -> None:
    from stable_baselines3.common.env_checker import check_env

    check_env(gym.make(env_id), warn=True)


def test_sync_and_async_vector_envs() -> None:
    for cls in (gym.vector.SyncVectorEnv, gym.vector.AsyncVectorEnv):
        venv = cls([lambda: gym.make("PHAST/WindyPendulum-v0") for _ in range(2)])
        obs, info = venv.reset(seed=[0, 1])
        assert obs.shape == (2, 1) and info["state"].shape == (2, 2)
        for _ in range(3):
            obs, rew, term, trunc, info = venv.step(np.zeros((2, 1), dtype=np.float32))
        assert obs.shape == (2, 1) and rew.shape == (2,)
        venv.close()
    venv = gym.make_vec("PHAST/WindyCartPole-v0", num_envs=3, vectorization_mode="sync")
    obs, _ = venv.reset(seed=0)
    assert obs.shape == (3, 2)


def test_sb3_learns_a_few_hundred_steps() -> None:
    from stable_baselines3 import PPO

    env = gym.make("PHAST/WindyPendulum-v0")
    model = PPO("MlpPolicy", env, n_steps=128, batch_size=64, n_epochs=1, seed=0, verbose=0, device="cpu")
    model.learn(total_timesteps=256)
    action, _ = model.predict(env.reset(seed=0)[0], deterministic=True)
    assert env.action_space.contains(action)


def _run(code: str) -> str:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_make_with_module_prefix_without_import() -> None:
    assert _run("import gymnasium as gym; e = gym.make('phast_gym:PHAST/WindyPendulum-v0'); print(e.reset(seed=0)[0].shape)") == "(1,)"


def test_phast_gym_does_not_import_torch() -> None:
    code = ("import sys, gymnasium as gym, phast_gym; e = gym.make('PHAST/WindyCartPole-v0'); e.reset(seed=0);"
            "e.step(e.action_space.sample()); phast_gym.make_dataset('PHAST/Pendulum-v0', 2, T=5, cache=False);"
            "print('torch' in sys.modules)")
    assert _run(code) == "False"
