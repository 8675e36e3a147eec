"""The cart-pole part of issue 40: its LQG floor (the quiet criterion's 2x), the LQR hold built from the learned model
(the force is on the cart only, so no Energy-Casimir hold), the cart's observation and the loop's PARTIAL
description of the cart-pole."""

from __future__ import annotations

import math

import numpy as np
import pytest

from phast_model.control import lqg_bound as lq
from phast_model.rl.plant import PlantSpec, Task, make_plant, quiet_metrics, quiet_u_tol

CARTPOLE = "PHAST/WindyCartPole-v0"


def test_lqg_floor_generalizes_the_pendulum_one() -> None:
    # the pendulum's floor is unchanged (docs/control.md "Upright under noise": 0.087 N m at sigma 0.01, gains 19.34,
    # 5.70), and the n-dof path gives the same numbers on the 1-dof plant
    pend = lq.lqg_floor("PHAST/DampedPendulum-v0", 0.01)
    assert pend["rms_torque"] == pytest.approx(0.0874, abs=5e-4)
    assert pend["k_q"] == pytest.approx(19.34, abs=0.01) and pend["k_qdot"] == pytest.approx(5.70, abs=0.01)
    a, b = lq.linearise("PHAST/DampedPendulum-v0", math.pi, 0.01)
    assert lq.torque_floor(a, b, 0.01)["rms_torque"] == pytest.approx(pend["rms_torque"], rel=1e-9)


def test_cartpole_linearisation_is_the_systems_own_physics() -> None:
    # (A, B) from Hess V, M, D and the port of the phast_gym CartPole: its continuous Jacobian equals finite
    # differences of the system's own rhs about the upright
    import scipy.linalg as sl

    from phast_gym.control.evaluation import ControlProtocol, control_system

    system = control_system(ControlProtocol(env_id=CARTPOLE, dt=0.01))
    q_star = np.array([0.0, math.pi])
    a, b = lq.linearise_system(system, q_star, 0.01, [0])
    ac = sl.logm(a).real / 0.01

    def f(x: np.ndarray, u: float) -> np.ndarray:  # (q, qdot) -> (qdot, qddot) by the system's rhs
        q, v = x[:2], x[2:]
        p = np.array(system.momentum(tuple(q), tuple(v)), dtype=float)
        (dq, dp) = system.rhs(tuple(q), tuple(p), (u, 0.0))
        h = 1e-6  # qddot = d/dt (M^-1 p) by a short forward step of (q, p)
        q1, p1 = q + h * np.array(dq, float), p + h * np.array(dp, float)
        v1 = np.array(system.velocity(tuple(q1), tuple(p1)), float)
        return np.concatenate([np.array(dq, float), (v1 - v) / h])

    x0 = np.concatenate([q_star, [0.0, 0.0]])
    e = 1e-5
    jac = np.stack([(f(x0 + e * np.eye(4)[j], 0.0) - f(x0 - e * np.eye(4)[j], 0.0)) / (2 * e) for j in range(4)], 1)
    # the pole's damping d0 + dd |sin theta| has a kink at the upright: its one-sided derivatives multiply qdot = 0
    assert np.allclose(ac, jac, atol=2e-3), (ac, jac)
    # the port: a unit force on the cart accelerates (x, theta) by M(q*)^-1 [1, 0], which the held-input B integrates
    m = np.array(system.mass_matrix(tuple(q_star)), float)
    assert (f(x0, 1.0) - f(x0, 0.0))[2:] == pytest.approx(np.linalg.solve(m, [1.0, 0.0]), rel=1e-4)
    aug = sl.logm(np.block([[a, b], [np.zeros((1, 4)), np.eye(1)]])).real / 0.01  # [[A_c, B_c], [0, 0]] (held input)
    assert aug[:2, 4] == pytest.approx([0.0, 0.0], abs=1e-6)
    assert aug[2:4, 4] == pytest.approx(np.linalg.solve(m, [1.0, 0.0]), rel=1e-3)


def test_cartpole_lqg_floor_and_the_quiet_criterion() -> None:
    fl = lq.lqg_floor(CARTPOLE, 0.01, actuated_dofs=[0])
    assert fl["q_star"] == [0.0, math.pi] and fl["actuated_dofs"] == [0]
    assert fl["rms_torque"] == pytest.approx(0.1936, abs=5e-4)  # docs/control.md, issue 40
    # eps -> 0: the minimum-energy limit (the cart's position left free) has converged at the default eps
    assert lq.lqg_floor(CARTPOLE, 0.01, actuated_dofs=[0], eps=1e-10)["rms_torque"] == pytest.approx(fl["rms_torque"], rel=2e-3)
    assert lq.lqg_floor(CARTPOLE, 0.05, actuated_dofs=[0])["rms_torque"] == pytest.approx(5 * fl["rms_torque"], rel=5e-3)
    # any other stabilising gain on the Kalman estimate costs more, e.g. the LQR hold's default weights (1.07x)
    import scipy.linalg as sl

    a, b = lq.linearise(CARTPOLE, [0.0, math.pi], 0.01, [0])
    x = sl.solve_discrete_are(a, b, np.diag([0.1, 1.0, 0.0, 0.0]), np.eye(1))
    k = np.linalg.solve(b.T @ x @ b + np.eye(1), b.T @ x @ a)
    lqr = lq.torque_floor(a, b, 0.01, gains=k, angle_dims=(1,))
    assert fl["rms_torque"] < lqr["rms_torque"] < 1.1 * fl["rms_torque"]
    # at sigma 0.01 the stationary LQR loop passes the criterion's 1-s windows at 2x the floor
    rate = lq.window_pass_rate(lq.closed_loop(a, b, 0.01, gains=k), u_tol=2 * fl["rms_torque"], n=2000, angle_dims=(1,))
    assert rate["pass"] > 0.95
    # phast-rl's default quiet criterion: 2x the floor on the cart-pole, the protocol's 0.25 N m on the pendulum
    assert quiet_u_tol(PlantSpec(CARTPOLE, {"actuated_dofs": [0]})) == pytest.approx(2 * fl["rms_torque"], rel=1e-9)
    assert quiet_u_tol(PlantSpec()) == 0.25


def test_cart_position_is_observed_bounded_and_odd() -> None:
    from phast_model.rl.observation import EUCLID_SCALE, ObsBuilder

    ob = ObsBuilder(2, angle_dims=(1,))
    o = ob.reset(np.array([3.0, 0.2]))
    o = ob.push(np.array([-40.0, 0.3]))
    # sin-slots (odd): tanh(x / scale) for the cart, sin theta for the pole; cos-slots (even): 0 and cos theta
    assert o[:4] == pytest.approx([math.tanh(3.0 / EUCLID_SCALE), math.sin(0.2), -1.0, math.sin(0.3)], abs=1e-6)
    assert o[4:] == pytest.approx([0.0, math.cos(0.2), 0.0, math.cos(0.3)], abs=1e-6)
    # a pendulum's observation is unchanged by naming its angle
    p = ObsBuilder(2).reset(np.array([0.4]))
    assert p == pytest.approx(ObsBuilder(2, angle_dims=(0,)).reset(np.array([0.4])))


class _ZeroAgent:
    def predict(self, obs, deterministic=True):
        return np.zeros(1, dtype=np.float32), None


@pytest.fixture(scope="module")
def cartpole_model():
    """A PHAST model of 20 s of random-force recordings of the cart-pole, fitted by the loop's rig path with the
    cart-pole's PARTIAL description (cosine potential on the pole, the cart-pole mass template)."""
    import torch

    from phast_model.rl.loop import FitSpec, LoopConfig, collect_excitation, fit_world_model
    from phast_model.rl.plant import to_recordings

    torch.set_num_threads(1)
    cfg = LoopConfig(PlantSpec(CARTPOLE, {"actuated_dofs": [0]}), Task("upright"), budget_s=20.0, episode_s=5.0,
                     excitation_episodes=4, fit=FitSpec(epochs=15))
    assert cfg.sim == "phast_model.rl.descriptions:CartPoleDescription"
    plant = make_plant(cfg.plant)
    eps = collect_excitation(cfg, plant, 0)
    recs = to_recordings(eps, cfg.plant.decision_steps, plant.system.angle_dims, [0])
    return cfg, plant, fit_world_model(cfg, recs, None).model, recs


def test_lqr_hold_from_the_learned_model_holds_the_cartpole_quietly(cartpole_model) -> None:
    from phast_model.rl.hold import HoldConfig, HybridPolicy, LQRHold, make_hold
    from phast_model.rl.plant import record_episode

    cfg, plant, model, _ = cartpole_model
    q_star = np.array([0.0, math.pi])
    hold, gains = make_hold(model, q_star, cfg.plant.dt, cfg.plant.sigma, cfg.plant.max_action, HoldConfig(), [0])
    assert isinstance(hold, LQRHold)  # the force acts on the cart only: no Energy-Casimir hold
    with pytest.raises(ValueError, match="every coordinate"):
        make_hold(model, q_star, cfg.plant.dt, cfg.plant.sigma, cfg.plant.max_action, HoldConfig(kind="energy-casimir"), [0])
    # the learned linearisation has the upright's unstable pole (true: 4.5 / s) and gains near the true LQR's
    assert 3.5 < gains.unstable_pole < 5.5
    policy = HybridPolicy(_ZeroAgent(), 3, cfg.plant.decision_steps, cfg.plant.max_action, q_star, hold, HoldConfig(),
                          plant.system.angle_dims)
    u_tol = quiet_u_tol(cfg.plant)
    x0 = np.array([0.7, math.pi + 0.1, 0.0, 0.0])  # the cart away from 0: the handoff region is on the angle only
    ep = record_episode(plant, policy, x0, 800, 3, "evaluation")
    assert policy.handoffs == 1 and policy.holding
    m = quiet_metrics(ep, q_star, (1,), Task("upright", u_tol=u_tol))
    assert m.settled and m.success, m
    assert abs(ep.x[-1, 0] - 0.7) < 1.0  # the reference is where the cart was at the handoff
    fall = record_episode(plant, HybridPolicy(_ZeroAgent(), 3, cfg.plant.decision_steps, cfg.plant.max_action, q_star,
                                           angle_dims=(1,)), x0, 300, 3, "evaluation")
    assert not quiet_metrics(fall, q_star, (1,), Task("upright")).settled


def test_world_env_recenters_the_cart_weights_the_reward_and_ends_runaway_rollouts(cartpole_model) -> None:
    from phast_gym.reward import regulation_reward
    from phast_model.rl.world_env import WorldTask, WorldTaskEnv, burn_in_pool

    cfg, plant, model, recs = cartpole_model
    assert np.abs(recs["q"][:, :, 0]).max() > 1.0  # the excitation's cart drifts
    pool = burn_in_pool(recs["q"], model.observer.window)
    q_star = np.array([0.0, math.pi])
    task = WorldTask(q_star, 10.0, 0.0, 20, recenter=True)
    env = WorldTaskEnv(model, pool, task, seed=0, actuated=[0])
    for _ in range(5):
        _, info = env.reset()
        assert abs(info["burn_in"][-1, 0]) < 1e-12  # the window's cart ends at 0 (the pole is untouched)
    # default weights: the suite's regulation reward on the model's q and velocity estimate
    env = WorldTaskEnv(model, pool, task, seed=1, actuated=[0])
    env.reset()
    _, r, _, _, info = env.step(np.array([0.5]))
    q = env.world._hist[0, -1].numpy()
    e = np.array([q[0], math.remainder(q[1] - math.pi, 2 * math.pi)])
    v = info["velocity"]
    assert r == pytest.approx(regulation_reward(float(e @ e), float(v @ v), 25.0), rel=1e-6)
    # a rollout that leaves the region ends with the worst reward for every decision left
    env.x_max = 1e-9
    env.reset()
    _, r, term, _, _ = env.step(np.array([1.0]))
    assert term and r == -env.reward_floor * 20


def test_world_episodes_end_at_the_best_reward_where_the_hold_takes_over(cartpole_model) -> None:
    """With a goal, the agent's episode ends once the model's pole is within the hold's region (angle and rate), and
    the decisions left count 0, the best per-step reward; elsewhere the goal changes nothing."""
    from phast_model.rl.hold import HoldConfig
    from phast_model.rl.world_env import WorldTask, WorldTaskEnv, burn_in_pool

    cfg, plant, model, recs = cartpole_model
    pool = burn_in_pool(recs["q"], model.observer.window)
    q_star = np.array([0.0, math.pi])
    everywhere = HoldConfig(enter_angle=4.0, enter_rate=1e9, exit_angle=4.0)
    nowhere = HoldConfig(enter_angle=1e-9, enter_rate=1e-9)
    wide = WorldTaskEnv(model, pool, WorldTask(q_star, 10.0, 0.0, 20, goal=everywhere), seed=0, actuated=[0])
    wide.reset()
    _, r, term, _, _ = wide.step(np.array([0.0]))
    assert term and -50 < r < 0  # this decision's own reward, nothing for the decisions left
    tight = WorldTaskEnv(model, pool, WorldTask(q_star, 10.0, 0.0, 20, goal=nowhere), seed=0, actuated=[0])
    plain = WorldTaskEnv(model, pool, WorldTask(q_star, 10.0, 0.0, 20), seed=0, actuated=[0])
    tight.reset()
    plain.reset()
    for _ in range(3):
        a, b = tight.step(np.array([0.3])), plain.step(np.array([0.3]))
        assert not a[2] and a[1] == pytest.approx(b[1])


def test_the_cartpole_brings_its_own_loop_defaults_and_the_command_line_wins() -> None:
    from phast_model.cli.rl import config_from_args, parse_args
    from phast_model.rl.descriptions import loop_preset

    base = ["--env-kwargs", '{"actuated_dofs": [0]}', "--out", "unused"]
    _, args = parse_args(["--env", CARTPOLE, *base])
    cfg = config_from_args(args)
    assert cfg.plant.max_action == 30.0 and cfg.agent.refit_steps == 8000 and cfg.agent.final_steps == 20000
    assert cfg.agent.keep_best and cfg.agent.hold_goal and cfg.agent.episode_decisions == 100
    _, args = parse_args(["--env", CARTPOLE, *base, "--max-action", "20", "--no-hold-goal"])
    cfg = config_from_args(args)
    assert cfg.plant.max_action == 20.0 and not cfg.agent.hold_goal and cfg.agent.refit_steps == 8000
    assert loop_preset("PHAST/Pendulum-v0") == {} and loop_preset("no-such-env") == {}
    _, args = parse_args(["--env", "PHAST/Pendulum-v0", "--out", "unused"])
    agent = config_from_args(args).agent
    assert agent.final_steps is None and not agent.keep_best and not agent.hold_goal and agent.refit_steps == 4000
