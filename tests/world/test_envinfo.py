"""The per-env registry phast_model.world.envinfo.ENV_INFO and the views derived from it (regimes, metrics, bench)."""

from __future__ import annotations

import pytest

from phast_gym import env_ids, make_env_system
from phast_model.bench.paper import PAPER, PAPER_FULL_STATE, TABLE4_ENVS
from phast_model.train.metrics import benchmark_metric
from phast_model.world import envinfo
from phast_model.world.envinfo import ENV_INFO, EnvInfo
from phast_model.world.regimes import default_config

W, X, R, N = "rollout_theta_wrap_mse_h100", "rollout_mixed_mse_h100", "rollout_mse_h100", "mse"

#: env id -> (benchmark_metric, PARTIAL template, template_dims, mass, mass_template, paper table), as before the
#: registry (regimes.TEMPLATES / MASS_TEMPLATES, metrics._HEADLINE, bench.paper.PAPER)
BEFORE = {
    "PHAST/Pendulum-v0": (W, "cosine", [0], "lowrank", None, "Table 17"),
    "PHAST/DampedPendulum-v0": (W, "cosine", [0], "lowrank", None, "Table 17"),
    "PHAST/WindyPendulum-v0": (W, "cosine", [0], "lowrank", None, "Table 17"),
    "PHAST/WindyCartPole-v0": (X, "cosine", [1], "template", "cartpole", "Table 3"),
    "PHAST/Oscillator-v0": (R, "quadratic", None, "lowrank", None, "Table 19"),
    "PHAST/DampedOscillator-v0": (R, "quadratic", None, "lowrank", None, "Table 19"),
    "PHAST/DoublePendulum-v0": (W, "cosine", [0, 1], "template", "double_pendulum", "Table 18"),
    "PHAST/DampedDoublePendulum-v0": (W, "cosine", [0, 1], "template", "double_pendulum", "Table 18"),
    "PHAST/WindyDoublePendulum-v0": (W, "cosine", [0, 1], "template", "double_pendulum", None),
    "PHAST/RLCCircuit-v0": (N, "quadratic", None, "lowrank", None, "Table 20"),
    "PHAST/LennardJones3-v0": (N, "lennard_jones", None, "lowrank", None, "Table 21"),
    "PHAST/HeatExchange-v0": (N, "quadratic", None, "lowrank", None, "Table 22"),
    "PHAST/NBody3-v0": (N, "gravity", None, "lowrank", None, "Table 23"),
    "PHAST/PredatorPrey-v0": (N, None, None, "none", None, "Table 24"),
}


def test_every_env_id_has_exactly_one_entry() -> None:
    assert [info.env_id for info in envinfo._ENTRIES] == env_ids()
    assert all(key == info.env_id for key, info in ENV_INFO.items())
    assert list(BEFORE) == env_ids()


@pytest.mark.parametrize("env_id", list(BEFORE))
def test_derived_views_are_unchanged(env_id: str) -> None:
    metric, template, dims, mass, mass_template, table = BEFORE[env_id]
    assert benchmark_metric(env_id) == metric
    cfg = default_config(env_id, "partial")
    assert (cfg.template, cfg.template_dims, cfg.mass, cfg.mass_template) == (template, dims, mass, mass_template)
    row = PAPER.get(env_id)
    assert (row.table if row else None) == table
    assert row is None or row.metric == metric


def test_paper_rows() -> None:
    assert TABLE4_ENVS == tuple(e for e in env_ids() if e != "PHAST/WindyDoublePendulum-v0")
    assert PAPER["PHAST/WindyCartPole-v0"].benchmark == "Cart-Pole (windy)"
    assert PAPER["PHAST/RLCCircuit-v0"].params["lstm"] == 50497
    assert PAPER_FULL_STATE.metric == W and PAPER_FULL_STATE.table == "Table 25"


def test_mass_template_follows_the_system_params() -> None:
    """The relative-coordinate double pendulum picks its own mass template through the registry."""
    cfg = default_config("PHAST/DoublePendulum-v0", "partial", coordinates="relative")
    assert cfg.mass_template == "double_pendulum_relative"
    assert ENV_INFO["PHAST/WindyDoublePendulum-v0"].partial_mass_template(
        make_env_system("PHAST/WindyDoublePendulum-v0", coordinates="relative")) == "double_pendulum_relative"
    with pytest.raises(ValueError, match="no PARTIAL mass template"):
        EnvInfo("PHAST/WindyCartPole-v0", W).partial_mass_template(make_env_system("PHAST/WindyCartPole-v0"))
