"""benchmarks.sac.world_data (benchmarks/sac_world_data.py): driven noisy plant recordings and the world model learned
from them."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

import benchmarks.sac.agents as sac
import benchmarks.sac.world_data as wd
from benchmarks.sac.cli import parse_args
from phast_gym.control import ControlProtocol
from phast_gym.control.evaluation import control_system
from phast_gym.integrate import simulate
from tests import ROOT


def test_recordings_are_the_plant_at_the_decision_rate_with_held_torques_and_noise() -> None:
    spec = wd.PlantRecording(n_traj=5, decisions=30, sigma=0.01, torque_std=20.0, hold=3, seed=4)
    rec = wd.record_plant(spec)
    assert rec["q"].shape == (5, 30, 1) and rec["u"].shape == (5, 29, 1) and rec["dt"] == pytest.approx(0.05)
    u = rec["u"][:, :, 0]
    assert np.all(np.abs(u) <= spec.max_action) and np.any(np.abs(u) == spec.max_action)  # clipped at the bound
    assert np.all(u[:, 0::3] == u[:, 1::3][:, : u[:, 0::3].shape[1]])  # held 3 samples
    # noise-free replay of the same starts and torques: the recorded q differ by the measurement noise only
    x0 = wd.start_states(spec, np.random.default_rng(spec.seed))
    x = simulate(control_system(ControlProtocol()), x0, 29 * spec.repeat, np.repeat(rec["u"], spec.repeat, axis=1))
    resid = rec["q"][:, :, 0] - x[:, :: spec.repeat, 0]
    assert 0.007 < resid.std() < 0.013 and abs(resid.mean()) < 0.005
    assert spec.real_samples == 150
    # two start regimes (of five) begin near the upright
    assert np.sum(np.cos(x0[:, 0]) < -0.6) == 2


def test_recording_spec_is_checked() -> None:
    for bad in ({"n_traj": 0}, {"decisions": 1}, {"hold": 1.5}, {"sigma": -0.1}, {"torque_std": math.nan}):
        with pytest.raises(ValueError):
            wd.PlantRecording(**bad)


def test_world_model_from_recordings_counts_its_samples(tmp_path) -> None:
    """A tiny run end to end: the run opens as sac-world's world model and its recordings count as real samples."""
    spec = wd.PlantRecording(n_traj=4, decisions=40, seed=1)
    m = wd.train_world_model(spec, tmp_path / "run", "PHAST/Pendulum-v0", {"mass": 1.1}, epochs=1, window_s=0.5,
                             holdout=(3,))
    assert math.isfinite(m["heldout"]["phast"]["rollout_rmse"])
    record = json.loads((tmp_path / "run" / wd.WORLD_DATA_FILE).read_text())
    assert record["real_samples"] == 160 and record["recording"]["n_traj"] == 4
    assert sac.world_data_samples(tmp_path / "run") == 160
    assert sac.world_data_samples(tmp_path) == 0  # no record: a model of simulated data
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "world_data.json").write_text("{}")
    with pytest.raises(ValueError, match="real_samples"):
        sac.world_data_samples(tmp_path / "bad")
    args = parse_args(["--out", str(tmp_path / "o"), "--agents", "sac-world", "--phast-run", str(tmp_path / "run"),
                          "--q-star", str(math.pi)])
    env, inner = sac.make_agent_env("sac-world", args, seed=0)
    obs, _ = env.reset(seed=0)
    obs, r, *_ = env.step(np.array([0.5], dtype=np.float32))
    assert obs.shape == (6,) and math.isfinite(r) and inner.real_samples == args.burn_in
    bad = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "sac_world_data.py"), "--out", str(tmp_path / "x"),
                          "--n-traj", "2"], capture_output=True, text=True)
    assert bad.returncode == 2 and "--n-traj must be >= 3" in bad.stderr
