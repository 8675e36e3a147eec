"""The env contract of docs/envs.md: spaces, reset, wrapping, noise, info, bad input, kwargs."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import phast_gym
from phast_gym.systems import SCALAR

ALL = phast_gym.env_ids()


def _zero(env: gym.Env) -> np.ndarray:
    return np.zeros(env.action_space.shape, dtype=env.action_space.dtype)


def test_fourteen_ids_registered() -> None:
    assert len(ALL) == 14
    for env_id in ALL:
        assert env_id in gym.registry
        assert gym.spec(env_id).max_episode_steps == 200


@pytest.mark.parametrize("env_id", ALL)
def test_spaces_reset_and_info(env_id: str) -> None:
    env = gym.make(env_id)
    u = env.unwrapped
    obs, info = env.reset(seed=0)
    assert obs.shape == (u.n,) and obs.dtype == np.float32
    assert env.action_space.shape == (u.n,)
    assert set(info) >= {"state", "energy", "damping", "t"}
    assert info["state"].shape == (2 * u.n,) and info["damping"].shape == (u.n,) and info["t"] == 0.0
    obs, reward, terminated, truncated, info = env.step(_zero(env))
    assert np.isfinite(reward) and not terminated and not truncated
    assert math.isclose(info["t"], u.dt)
    assert info["action_clipped"] is False
    q, p = list(info["state"][: u.n]), list(info["state"][u.n:])
    assert math.isclose(info["energy"], u.system.energy(q, p, SCALAR), rel_tol=1e-12)
    assert np.allclose(info["damping"], u.system.damping(q, SCALAR))
    assert env.metadata["render_fps"] == round(1 / u.dt)


@pytest.mark.parametrize("env_id", ALL)
def test_reset_seeding_is_reproducible(env_id: str) -> None:
    env = gym.make(env_id)
    a = [env.reset(seed=3)[1]["state"]] + [env.step(_zero(env))[4]["state"] for _ in range(3)]
    b = [env.reset(seed=3)[1]["state"]] + [env.step(_zero(env))[4]["state"] for _ in range(3)]
    c = env.reset(seed=4)[1]["state"]
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert not np.array_equal(a[0], c)


def test_reset_options_state_and_time_restart() -> None:
    env = gym.make("PHAST/WindyCartPole-v0")
    x0 = np.array([0.1, -0.4, 0.3, -0.2])
    env.reset(seed=0)
    env.step(_zero(env))
    obs, info = env.reset(options={"state": x0})
    assert np.array_equal(info["state"], x0) and info["t"] == 0.0
    assert np.allclose(obs, x0[:2].astype(np.float32))
    with pytest.raises(ValueError, match="length 2n"):
        env.reset(options={"state": [0.0, 1.0]})
    with pytest.raises(ValueError, match="finite"):
        env.reset(options={"state": [0.0, np.nan, 0.0, 0.0]})


def test_initial_state_distribution_windy_pendulum() -> None:
    system = phast_gym.make_env_system("PHAST/WindyPendulum-v0")
    x = system.sample_initial(np.random.default_rng(0), 20000)
    assert x[:, 0].min() >= -math.pi and x[:, 0].max() <= math.pi
    assert abs(x[:, 1].std() - 4.0) < 0.1 and abs(x[:, 1].mean()) < 0.1


def test_lennard_jones_initial_triangle() -> None:
    s = phast_gym.make_env_system("PHAST/LennardJones3-v0")
    tri = s.triangle()
    side = np.linalg.norm(tri[0] - tri[1])
    assert math.isclose(side, 2 ** (1 / 6), rel_tol=1e-12)
    assert np.allclose(tri.mean(0), 0.0, atol=1e-12)
    assert math.isclose(math.degrees(math.atan2(tri[0, 1], tri[0, 0])), 90.0)


def test_angles_wrapped_state_unwrapped() -> None:
    env = gym.make("PHAST/WindyDoublePendulum-v0", dtype=np.float64)
    x0 = [3 * math.pi + 0.1, -5 * math.pi - 0.2, 0.0, 0.0]
    obs, info = env.reset(options={"state": x0})
    assert np.allclose(obs, [-math.pi + 0.1, math.pi - 0.2])
    assert np.all(obs >= -math.pi) and np.all(obs < math.pi)
    assert info["state"][0] == x0[0]
    # Euclidean coordinates are never wrapped
    env = gym.make("PHAST/WindyCartPole-v0", dtype=np.float64)
    obs, _ = env.reset(options={"state": [7.5, 4.0, 0.0, 0.0]})
    assert np.allclose(obs, [7.5, 4.0 - 2 * math.pi])


def test_observation_noise_statistics() -> None:
    env = gym.make("PHAST/Oscillator-v0", obs_noise_std=0.1, dtype=np.float64)
    obs = np.array([env.reset(seed=s, options={"state": [1.0, -1.0, 0.0, 0.0]})[0] for s in range(2000)])
    assert np.allclose(obs.mean(0), [1.0, -1.0], atol=0.01)
    assert np.allclose(obs.std(0), 0.1, rtol=0.06)
    env_clean = gym.make("PHAST/Oscillator-v0")
    assert np.array_equal(env_clean.reset(seed=0)[0], env_clean.reset(seed=0)[0])


def test_observe_qp() -> None:
    env = gym.make("PHAST/WindyPendulum-v0", observe="qp", dtype=np.float64)
    obs, info = env.reset(options={"state": [2 * math.pi + 0.5, -1.5]})
    assert env.observation_space.shape == (2,)
    assert np.allclose(obs, [0.5, -1.5])


@pytest.mark.parametrize("bad", [np.array([np.nan]), np.array([np.inf]), np.zeros(2), np.zeros((1, 1)), "a", None,
                                 np.array([1.0 + 2.0j]), [1.0 + 0.0j], "1.5", ["1.5"], np.array(["1.5"])])
def test_bad_action_raises_and_leaves_env_unchanged(bad) -> None:
    env = gym.make("PHAST/WindyPendulum-v0")
    env.reset(seed=0)
    env.step(np.zeros(1, dtype=np.float32))
    u = env.unwrapped
    before = (u.state.copy(), u._t, env.get_wrapper_attr("_elapsed_steps"))
    with pytest.raises(ValueError, match="action"):
        env.step(bad)
    after = (u.state, u._t, env.get_wrapper_attr("_elapsed_steps"))
    assert np.array_equal(before[0], after[0]) and before[1:] == after[1:]


def test_out_of_range_action_is_clipped_and_flagged() -> None:
    a = gym.make("PHAST/Pendulum-v0", dtype=np.float64)
    b = gym.make("PHAST/Pendulum-v0", dtype=np.float64)
    a.reset(options={"state": [0.2, 0.0]})
    b.reset(options={"state": [0.2, 0.0]})
    _, _, _, _, ia = a.step(np.array([500.0]))
    _, _, _, _, ib = b.step(np.array([50.0]))
    assert ia["action_clipped"] and not ib["action_clipped"]
    assert np.array_equal(ia["state"], ib["state"])


def test_in_range_action_applied_exactly_and_reward() -> None:
    env = gym.make("PHAST/Pendulum-v0", dtype=np.float64, target=[math.pi]).unwrapped
    env.reset(options={"state": [0.3, 0.0]})
    _, r, _, _, info = env.step(np.array([2.0]))
    q, p = info["state"]
    err = (q - math.pi + math.pi) % (2 * math.pi) - math.pi
    assert math.isclose(r, -(err**2 + 0.1 * p**2 + 0.001 * 4.0), rel_tol=1e-12)


@pytest.mark.parametrize(
    "kwargs",
    [{"mass": -1.0}, {"length": 0.0}, {"gamma": -0.1}, {"no_such_param": 1.0}, {"actuated_dofs": [3]},
     {"obs_noise_std": -0.1}, {"observe": "p"}, {"max_action": 0.0}, {"render_mode": "ansi"}, {"target": [0.0, 1.0]},
     {"mass": float("nan")}, {"mass": "heavy"}, {"target": [float("nan")]}, {"target": ["up"]}, {"actuated_dofs": [0.5]},
     {"actuated_dofs": [True]}],
)
def test_bad_kwargs_raise_at_make(kwargs) -> None:
    with pytest.raises(ValueError):
        gym.make("PHAST/WindyPendulum-v0", **kwargs)


def test_physical_kwargs_change_the_physics() -> None:
    env = gym.make("PHAST/Pendulum-v0", length=2.0, dtype=np.float64).unwrapped
    assert env.system.inertia == 4.0 and math.isclose(env.system.mgl, 2 * 9.81)
    env = gym.make("PHAST/Pendulum-v0", inertia=0.5).unwrapped
    assert env.system.inertia == 0.5
    env = gym.make("PHAST/WindyCartPole-v0", damping="scalar").unwrapped
    d = env.system.damping([0.0, 0.5], SCALAR)
    assert d[0] == d[1]


def test_actuated_dofs_restricts_the_port() -> None:
    env = gym.make("PHAST/WindyCartPole-v0", actuated_dofs=[0], dtype=np.float64).unwrapped
    assert env.action_space.shape == (1,)
    x0 = np.array([0.0, 0.3, 0.0, 0.0])
    env.reset(options={"state": x0})
    _, _, _, _, info = env.step(np.array([5.0]))
    ref = gym.make("PHAST/WindyCartPole-v0", dtype=np.float64).unwrapped
    ref.reset(options={"state": x0})
    _, _, _, _, iref = ref.step(np.array([5.0, 0.0]))
    assert np.allclose(info["state"], iref["state"], atol=0, rtol=0)


def test_truncation_after_200_steps() -> None:
    env = gym.make("PHAST/RLCCircuit-v0")
    env.reset(seed=0)
    for k in range(200):
        *_, truncated, _ = env.step(_zero(env))
        assert truncated == (k == 199)


def test_predator_prey_populations_nonnegative() -> None:
    env = gym.make("PHAST/PredatorPrey-v0", dtype=np.float64)
    env.reset(options={"state": [1e-3, 30.0]})
    for _ in range(50):
        _, _, _, _, info = env.step(np.array([-5.0]))
        assert np.all(info["state"] >= 0) and np.isfinite(info["energy"])


def test_langevin_temperature_is_seeded() -> None:
    env = gym.make("PHAST/LennardJones3-v0", temperature=0.5)
    s1 = [env.reset(seed=1)[1]["state"]] + [env.step(_zero(env))[4]["state"] for _ in range(5)]
    s2 = [env.reset(seed=1)[1]["state"]] + [env.step(_zero(env))[4]["state"] for _ in range(5)]
    assert all(np.array_equal(a, b) for a, b in zip(s1, s2))
    cold = gym.make("PHAST/LennardJones3-v0")
    cold.reset(seed=1)
    assert not np.array_equal(cold.step(_zero(cold))[4]["state"], s1[1])


@pytest.mark.parametrize("env_id", ALL)
def test_render_rgb_array(env_id: str) -> None:
    env = gym.make(env_id, render_mode="rgb_array")
    env.reset(seed=0)
    env.step(env.action_space.sample())
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert frame.std() > 0  # something is drawn


def test_render_shows_the_port_and_follows_the_state() -> None:
    from phast_gym.render import render_frame

    system = phast_gym.make_env_system("PHAST/Pendulum-v0")
    still = render_frame(system, [0.5])
    pushed = render_frame(system, [0.5], u=[20.0])
    moved = render_frame(system, [2.0])
    assert not np.array_equal(still, pushed)  # the torque arc is drawn
    assert not np.array_equal(still, moved)
    assert np.array_equal(still, render_frame(system, [0.5]))  # deterministic
    with pytest.raises(ValueError, match="q must have"):
        render_frame(system, [0.1, 0.2])
    with pytest.raises(ValueError, match="u must have"):
        render_frame(system, [0.1], u=[1.0, 2.0])


def test_render_fps_follows_dt() -> None:
    for env_id in ("PHAST/Pendulum-v0", "PHAST/DoublePendulum-v0"):
        env = gym.make(env_id)
        assert env.metadata["render_fps"] == round(1.0 / env.unwrapped.dt)


def test_reset_to_a_singular_state_raises_and_keeps_the_env() -> None:
    """Coincident Lennard-Jones particles: a clear ValueError before anything is assigned; the env still steps."""
    env = gym.make("PHAST/LennardJones3-v0").unwrapped
    env.reset(seed=0)
    env.step(_zero(env))
    before = (env.state.copy(), env._t)
    with pytest.raises(ValueError, match="outside the domain of lennard_jones3"):
        env.reset(options={"state": np.zeros(12)})
    assert np.array_equal(env.state, before[0]) and env._t == before[1]
    obs, *_ = env.step(_zero(env))
    assert np.all(np.isfinite(obs))
