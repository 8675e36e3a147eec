"""Fast tests of benchmarks/control_sac.py: flatness rule, rewards, frame stack, seeded resets, a tiny end-to-end run."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from repo_scripts import load_script

import phast_gym  # noqa: F401  (registers the ids)
from phast_gym.control import ControlProtocol, make_control_env

cs = load_script("benchmarks/control_sac.py")


def test_is_flat_on_synthetic_curves() -> None:
    rising = list(np.linspace(-300, -20, 12))
    assert not cs.is_flat(rising, window=4)
    plateau = list(np.linspace(-300, -50, 6)) + [-20.0, -19.5, -20.3, -19.8, -20.1, -19.9, -20.2, -20.0]
    assert cs.is_flat(plateau, window=4)
    assert not cs.is_flat(plateau[:7], window=4)  # fewer than 2K points
    # a falling (unlearning) curve is flat too: no improvement
    assert cs.is_flat([-10.0] * 4 + [-30.0] * 4, window=4)
    # the absolute floor: returns near 0 where a relative tolerance would never be met
    assert cs.is_flat([-0.02, -0.01, -0.03, -0.02, -0.01, -0.02, -0.01, -0.02], window=4, rel_tol=0.05, abs_tol=0.05)
    assert not cs.is_flat([-10.0] * 4 + [-9.0] * 4, window=4, rel_tol=0.05, abs_tol=0.05)  # 10% better
    with pytest.raises(ValueError):
        cs.is_flat([1.0], window=0)


def test_rewards() -> None:
    assert cs.pendulum_reward(0.5, 1.0, 2.0, "zoo") == pytest.approx(-(0.25 + 0.1 + 0.004))
    # quiet: far from the target it is the zoo reward, at the target torque costs QUIET_WEIGHT u^2 more
    assert cs.pendulum_reward(math.pi, 0.0, 2.0, "quiet") == pytest.approx(cs.pendulum_reward(math.pi, 0.0, 2.0, "zoo"), abs=1e-20)
    assert cs.pendulum_reward(0.0, 0.0, 2.0, "quiet") == pytest.approx(-(0.004 + cs.QUIET_WEIGHT * 4.0))
    assert cs.pendulum_reward(0.0, 0.0, 0.0, "quiet") == 0.0
    with pytest.raises(ValueError):
        cs.pendulum_reward(0.0, 0.0, 0.0, "nope")


def test_frame_stack_reset_and_decision_rate() -> None:
    env = cs.RepeatRegimeEnv(make_control_env(ControlProtocol(horizon=10**9), 0.0), repeat=5, episode_decisions=3,
                             max_action=10.0, seed=0)
    fo = cs.FrameObs(env, frames=3)
    x0 = np.array([0.4, 0.0])
    obs, _ = fo.reset(seed=1, options={"state": x0})
    # filled with copies of the first measurement
    assert np.allclose(obs, np.concatenate([np.sin([0.4] * 3), np.cos([0.4] * 3)]))
    obs1, *_ = fo.step(np.zeros(1))
    obs2, *_ = fo.step(np.zeros(1))
    # decision-rate frames: after two decisions the oldest frame is still q0 and the newest moved
    assert obs2[0] == pytest.approx(math.sin(0.4))
    assert obs2[2] != pytest.approx(obs2[1])
    assert env.plant_steps == 10
    _, _, _, trunc, _ = fo.step(np.zeros(1))
    assert trunc  # episode_decisions
    # a second reset forgets the previous episode's frames
    obs, _ = fo.reset(options={"state": np.array([-1.0, 0.0])})
    assert np.allclose(obs[:3], math.sin(-1.0))


def test_seeded_resets_are_reproducible() -> None:
    def starts(seed: int) -> list[float]:
        env = cs.RepeatRegimeEnv(make_control_env(ControlProtocol(horizon=10**9), 0.01), 5, 200, 10.0, seed=seed)
        return [float(env.reset()[0][0]) for _ in range(4)]

    assert starts(3) == starts(3)
    assert starts(3) != starts(4)


def test_plant_evaluation_frames_match_training() -> None:
    """evaluate_policy_on_plant feeds the policy exactly the FrameObs observations of training (decision rate)."""
    protocol = ControlProtocol(horizon=50, settle_steps=10)
    seen: list[np.ndarray] = []

    class Recorder:
        def predict(self, obs: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
            seen.append(np.array(obs))
            return np.array([0.1], dtype=np.float32), None

    m = cs.evaluate_policy_on_plant(Recorder(), protocol, 0.0, 1, repeat=5, frames=3, max_action=10.0)
    assert set(m) >= {"success_rate", "success_angle_rate", "effort", "final_error", "u_rms_final"}
    assert m["effort"] == pytest.approx(50 * 1.0)  # u = 1 N m for 50 plant steps
    first = seen[:10]  # the first regime's episode: 50 / 5 decisions
    # replay the same episode through the training wrappers
    from phast_gym.control import start_states
    from phast_gym.control.evaluation import _stable_seed

    x0 = next(iter(start_states(protocol, 1, 0).values()))[0]
    fo = cs.FrameObs(cs.RepeatRegimeEnv(make_control_env(ControlProtocol(horizon=10**9), 0.0), 5, 10, 10.0), 3)
    obs, _ = fo.reset(seed=_stable_seed(0, "noise", "near_stable", 0), options={"state": x0})
    for k in range(10):
        assert np.allclose(first[k], obs, atol=1e-6), k
        obs, *_ = fo.step(np.array([0.1], dtype=np.float32))


def test_tiny_end_to_end(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("stable_baselines3")
    monkeypatch.setattr(cs, "ZOO_PENDULUM_SAC", {**cs.ZOO_PENDULUM_SAC, "policy_kwargs": {"net_arch": [16, 16]},
                                                 "batch_size": 32, "learning_starts": 50})
    monkeypatch.setattr(sys, "argv", ["control_sac.py", "--out", str(tmp_path), "--agents", "sac-real", "--until-flat",
                                      "--max-steps", "300", "--eval-every", "100", "--eval-episodes", "1", "--flat-window", "1",
                                      "--flat-abs-tol", "1e9", "--episode-decisions", "20", "--trials-per-regime", "1",
                                      "--ec-estimators", "oracle", "--reward", "quiet", "--no-progress"])
    cs.main()
    meta = json.loads((tmp_path / "control_sac.json").read_text())
    methods = [r["method"] for r in meta["results"]]
    assert methods == ["energy-casimir/oracle", "sac-real/quiet"]
    row = meta["results"][1]
    # abs_tol 1e9 and window 1: flat at the second evaluation
    assert row["flat"] is True and row["decisions"] == 200
    assert row["real_env_samples"] == 5 * 200
    curve = json.loads((tmp_path / "curve_sac-real_quiet.json").read_text())
    assert curve["decisions"] == [100, 200] and len(curve["train_env_return"]) == 2
    assert (tmp_path / "curve_sac-real_quiet.png").stat().st_size > 0
    assert "--agents sac-real" in row["command"] and "sac-real/quiet" in (tmp_path / "control_sac.md").read_text()
