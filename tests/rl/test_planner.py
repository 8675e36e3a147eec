"""The planning agent (issue 55): MPPI through the learned PHAST core (phast_model.control.mppi), deployed with the
learned hold (phast_model.rl.planner), and ``phast-rl --agent mpc`` through the loop, its outputs and --deploy."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from phast_model.control.mppi import LEAVE_COST, MPPI, MPPISpec, path_weights
from phast_model.rl.hold import HoldConfig
from phast_model.rl.loop import FitSpec, LoopConfig, _Data, collect_excitation, fit_world_model, run_loop
from phast_model.rl.planner import PlannerPolicy, planner_policy
from phast_model.rl.plant import Task, make_plant, quiet_metrics, record_episode

Q_STAR = np.array([math.pi])


@pytest.fixture(scope="module")
def pendulum_model():
    """PHAST fitted to one 2.5-s excitation episode of the pendulum (the planner's default start)."""
    import torch

    torch.set_num_threads(1)
    cfg = LoopConfig(episode_s=2.5, excitation_episodes=1, fit=FitSpec(epochs=30))
    plant = make_plant(cfg.plant)
    data = _Data(None, collect_excitation(cfg, plant, 0))
    return cfg, fit_world_model(cfg, data.recordings(cfg, plant), None).model


def test_spec_rejects_bad_settings() -> None:
    with pytest.raises(ValueError, match="samples"):
        MPPISpec(samples=0)
    with pytest.raises(ValueError, match="horizon_s"):
        MPPISpec(horizon_s=-1.0)
    with pytest.raises(ValueError, match="smoothing"):
        MPPISpec(smoothing=1.0)
    with pytest.raises(ValueError, match="agent_kind"):
        LoopConfig(agent_kind="ppo")


def test_a_rollout_that_left_the_model_does_not_flatten_the_weights() -> None:
    """The temperature scales the spread of the rollouts that stayed in the model's region: one sample at
    LEAVE_COST gets no weight, and the best of the others still dominates."""
    import torch

    w = path_weights(torch.tensor([1.0, 2.0, 3.0, LEAVE_COST], dtype=torch.float64), 0.1)
    assert float(w[0]) > 0.99 and float(w[3]) == 0.0


def test_cycle_spreads_the_horizon_over_the_slices(pendulum_model) -> None:
    """One MPPI update yields slices - 1 times (one slice per plant step), and changes the plan."""
    _, model = pendulum_model
    mppi = MPPI(model, MPPISpec(samples=16), Q_STAR, 10.0)
    assert mppi.horizon == 15 and math.isclose(mppi.dt, 0.1, rel_tol=1e-6)
    gen = mppi.cycle(np.zeros(2), slices=10)
    yields = 0
    with pytest.raises(StopIteration):
        while True:
            next(gen)
            yields += 1
    assert yields == 9 and float(mppi.plan.abs().max()) > 0.0


def test_mppi_swings_the_pendulum_up_in_its_model(pendulum_model) -> None:
    """Closed loop in the learned model itself: from hanging at rest, one MPPI update per planning step brings the
    model's pendulum within 0.3 rad of the upright within 3 s."""
    _, model = pendulum_model
    mppi = MPPI(model, MPPISpec(), Q_STAR, 10.0, seed=1)
    x, closest = np.zeros(2), math.pi
    for _ in range(30):
        mppi.optimize(x)
        x = mppi.predict(x, mppi.shift())
        closest = min(closest, abs(math.remainder(x[0] - math.pi, 2 * math.pi)))
    assert closest < 0.3


def test_planner_swings_the_plant_up_and_holds_quietly(pendulum_model) -> None:
    """On the plant (noisy q only): the planner swings up from hanging, hands off to the learned Energy-Casimir hold
    and the last second is quiet; no plant step plans a whole horizon (the update is sliced)."""
    cfg, model = pendulum_model
    plant = make_plant(cfg.plant)
    policy, gains = planner_policy(model, MPPISpec(), Q_STAR, cfg.plant, HoldConfig(), [0], seed=0)
    assert isinstance(policy, PlannerPolicy) and gains.k_c > 0 and policy.decision_steps == 10
    ep = record_episode(plant, policy, np.array([0.05, 0.0]), 500, 3, "evaluation")
    m = quiet_metrics(ep, Q_STAR, (0,), Task())
    assert policy.handoffs >= 1 and m.success, m


def test_the_loop_runs_the_planner_and_deploy_rebuilds_it(tmp_path) -> None:
    """``agent_kind="mpc"`` end to end on a 5-s budget: nothing trained, no policy.zip, the plant seconds counted as
    for SAC; load_controller rebuilds the planner from the run's model and config.json."""
    import torch

    from phast_model.rl.loop_report import load_controller, write_outputs

    torch.set_num_threads(1)
    cfg = LoopConfig(budget_s=5.0, episode_s=2.5, excitation_episodes=1, eval_trials=1, eval_s=3.0,
                     fit=FitSpec(epochs=20, refit_epochs=5), agent_kind="mpc")
    res = run_loop(cfg)
    assert res.agent is None and res.plant_seconds == pytest.approx(5.0)
    assert [it.agent_decisions for it in res.iterations] == [0] * len(res.iterations)
    assert res.evaluation is not None and res.evaluation.act_ms["mean"] > 0
    paths = write_outputs(res, tmp_path, {})
    assert "policy" not in paths and not (tmp_path / "policy.zip").exists()
    policy = load_controller(tmp_path)
    assert isinstance(policy, PlannerPolicy) and policy.mppi.spec == cfg.planner


def test_cli_mpc_defaults_and_the_description_of_the_plant() -> None:
    """``--agent mpc`` (the default) brings its defaults (2.5-s episodes, one excitation episode, none with
    --recordings), ``--agent sac`` its own; the description of a simulated plant takes its physical --env-kwargs
    unless --sim-kwargs is given."""
    from phast_model.cli.rl import config_from_args, parse_args

    kw = '{"cart_mass": 0.5, "pole_mass": 0.5, "length": 0.6, "actuated_dofs": [0]}'
    _, args = parse_args(["--agent", "mpc", "--env", "PHAST/WindyCartPole-v0", "--env-kwargs", kw,
                          "--max-action", "10", "--out", "x"])
    cfg = config_from_args(args)
    assert cfg.agent_kind == "mpc" and cfg.episode_s == 2.5 and cfg.excitation_episodes == 1
    assert cfg.plant.max_action == 10 and cfg.hold.lqr_ukf_p_per_inertia
    assert cfg.fit.sim_kwargs == {"cart_mass": 0.5, "pole_mass": 0.5, "length": 0.6}
    _, args = parse_args(["--out", "x"])  # the planner is the default agent
    cfg = config_from_args(args)
    assert cfg.agent_kind == "mpc" and cfg.episode_s == 2.5 and cfg.excitation_episodes == 1
    assert cfg.hold.kind == "lqr"  # the planner's hold on every plant, the pendulum too
    _, args = parse_args(["--agent", "sac", "--out", "x", "--sim-kwargs", '{"mass": 1.1}'])
    cfg = config_from_args(args)
    assert cfg.agent_kind == "sac" and cfg.episode_s == 5.0 and cfg.excitation_episodes == 2
    assert cfg.fit.sim_kwargs == {"mass": 1.1} and not cfg.hold.lqr_ukf_p_per_inertia
    spec = replace(MPPISpec(), samples=8)
    assert spec.samples == 8
