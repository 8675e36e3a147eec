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


def _mean_return(env: gym.Env, policy, episodes: int = 10, seed: int = 100) -> float:
    """Mean undiscounted return of ``policy(obs) -> action`` over episodes from fixed reset seeds."""
    total = 0.0
    for i in range(episodes):
        obs, _ = env.reset(seed=seed + i)
        done = False
        while not done:
            obs, r, terminated, truncated, _ = env.step(policy(obs))
            total += float(r)
            done = terminated or truncated
    return total / episodes


def test_sb3_learns_to_damp_the_pendulum() -> None:
    """SB3's SAC trains on a PHAST env through the Gymnasium API and learns: 1000 steps on the damped pendulum
    (full-state observation, 100-step episodes, the env's regulation reward) give a policy whose mean return beats
    a random policy and cuts the cost of the passive (zero-torque) plant by more than 30 %."""
    from stable_baselines3 import SAC

    env = gym.make("PHAST/DampedPendulum-v0", observe="qp", max_episode_steps=100)
    model = SAC("MlpPolicy", env, learning_starts=100, batch_size=64, seed=0, verbose=0, device="cpu")
    model.learn(total_timesteps=1000)
    rng = np.random.default_rng(0)
    space = env.action_space
    trained = _mean_return(env, lambda o: model.predict(o, deterministic=True)[0])
    random = _mean_return(env, lambda o: rng.uniform(space.low, space.high).astype(space.dtype))
    passive = _mean_return(env, lambda o: np.zeros(space.shape, dtype=space.dtype))
    assert random < passive < 0
    assert trained > random and trained > 0.7 * passive, (trained, random, passive)


def _run(code: str) -> str:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_make_with_module_prefix_without_import() -> None:
    assert _run("import gymnasium as gym; e = gym.make('phast_gym:PHAST/WindyPendulum-v0'); print(e.reset(seed=0)[0].shape)") == "(1,)"


def test_phast_gym_does_not_import_torch() -> None:
    """phast_gym is numpy-only (the compiled backend is opt-in behind ``phast_gym.compiled``): every env
    stepped, every env's batched dataset above any batch-size threshold, the paper-sized 1400 x 200
    windy-pendulum dataset, the numpy port estimators and the control tables, all in a fresh process without torch."""
    code = """
import sys
import gymnasium as gym
import phast_gym
from phast_gym.control import ControlProtocol, estimator_names, make_control_env, make_estimator
for env_id in phast_gym.env_ids():
    e = gym.make(env_id)
    e.reset(seed=0)
    for _ in range(3):
        e.step(e.action_space.sample())
    e.close()
    phast_gym.make_dataset(env_id, 300, T=3, cache=False)
phast_gym.make_dataset('PHAST/WindyPendulum-v0', n_traj=1400, T=200, seed=42, cache=False)
system = make_control_env(ControlProtocol()).unwrapped.system
for name in estimator_names():
    make_estimator(name, system, 0.01)
from phast_gym.control import evaluate_estimators
from phast_gym.control.report import results_markdown
rows, _ = evaluate_estimators(ControlProtocol(horizon=20, settle_steps=5), ["fd"], [0.0], 1, progress=False)
assert "| 0.00 |" in results_markdown(rows, ControlProtocol())
print(sorted(m for m in sys.modules if m == 'torch' or m.startswith(('torch.', 'phast_model'))))
"""
    assert _run(code) == "[]"


def test_phast_gym_does_not_know_phast_model() -> None:
    """Layers point one way: phast_model builds on phast_gym, so no phast_gym module names phast_model
    (its torch estimators are declared from phast_model's side, see ``register_estimator_provider``)."""
    from pathlib import Path

    root = Path(phast_gym.__file__).parent
    offenders = [str(f.relative_to(root)) for f in sorted(root.rglob("*.py")) if "phast_model" in f.read_text()]
    assert offenders == []


def test_estimators_declared_by_phast_model_are_the_ones_it_registers() -> None:
    pytest.importorskip("torch")
    import phast_model
    from phast_gym.control import estimator_names
    from phast_gym.control.estimators import ESTIMATORS, PROVIDERS

    declared = {k for k, v in PROVIDERS.items() if v == "phast_model.control"}
    assert declared == set(phast_model.CONTROL_ESTIMATORS) and declared <= set(estimator_names())
    import phast_model.control  # noqa: F401

    assert declared == set(ESTIMATORS) - {"oracle", "fd", "map", "ekf", "ukf"}
