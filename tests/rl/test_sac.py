"""Fast tests of the SAC benchmark (benchmarks.sac, benchmarks/control_sac.py): flatness rule, rewards, frame stack,
seeded resets, the options as a dataclass, a tiny end-to-end run."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from gymnasium.wrappers import TimeLimit

import benchmarks.sac.config as sac_module
import benchmarks.sac.world_data as wd
import phast_gym  # noqa: F401  (registers the ids)
from benchmarks.sac.cli import main, parse_args
from benchmarks.sac.config import curve_stem, method_tag, quiet_weight_of
from benchmarks.sac.envs import FrameObs, RepeatRegimeEnv
from benchmarks.sac.evaluation import evaluate_policy_on_plant, is_flat
from benchmarks.sac.rewards import (
    PRECISE_WEIGHT,
    PRECISE_WELLS,
    QUIET_WEIGHT,
    Well,
    format_wells,
    max_quiet_weight,
    parse_wells,
    pendulum_reward,
    upright_quiet_weight,
)
from phast_gym.control import ControlProtocol, make_control_env
from phast_gym.reward import regulation_reward
from phast_gym.systems.base import wrap
from phast_model.rl.observation import ObsBuilder


def test_is_flat_on_synthetic_curves() -> None:
    rising = list(np.linspace(-300, -20, 12))
    assert not is_flat(rising, window=4)
    plateau = list(np.linspace(-300, -50, 6)) + [-20.0, -19.5, -20.3, -19.8, -20.1, -19.9, -20.2, -20.0]
    assert is_flat(plateau, window=4)
    assert not is_flat(plateau[:7], window=4)  # fewer than 2K points
    # a falling (unlearning) curve is flat too: no improvement
    assert is_flat([-10.0] * 4 + [-30.0] * 4, window=4)
    # the absolute floor: returns near 0 where a relative tolerance would never be met
    assert is_flat([-0.02, -0.01, -0.03, -0.02, -0.01, -0.02, -0.01, -0.02], window=4, rel_tol=0.05, abs_tol=0.05)
    assert not is_flat([-10.0] * 4 + [-9.0] * 4, window=4, rel_tol=0.05, abs_tol=0.05)  # 10% better
    with pytest.raises(ValueError):
        is_flat([1.0], window=0)


def test_rewards() -> None:
    assert pendulum_reward(0.5, 1.0, 2.0, "zoo") == pytest.approx(-(0.25 + 0.1 + 0.004))
    for e, v, u in ((0.3, -2.7, 1.1), (3.0, 7.0, -2.0)):  # zoo is the suite's standard reward, to the bit
        assert pendulum_reward(e, v, u, "zoo") == regulation_reward(e * e, v * v, u * u)
    # quiet: far from the target it is the zoo reward, at the target torque costs QUIET_WEIGHT u^2 more
    assert pendulum_reward(math.pi, 0.0, 2.0, "quiet") == pytest.approx(pendulum_reward(math.pi, 0.0, 2.0, "zoo"), abs=1e-20)
    assert pendulum_reward(0.0, 0.0, 2.0, "quiet") == pytest.approx(-(0.004 + QUIET_WEIGHT * 4.0))
    assert pendulum_reward(0.0, 0.0, 0.0, "quiet") == 0.0
    with pytest.raises(ValueError):
        pendulum_reward(0.0, 0.0, 0.0, "nope")


def test_frame_stack_reset_and_decision_rate() -> None:
    env = RepeatRegimeEnv(make_control_env(ControlProtocol(horizon=10**9), 0.0), repeat=5, max_action=10.0, seed=0)
    fo = FrameObs(TimeLimit(env, 3), frames=3)
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
    assert trunc  # episode_decisions: Gymnasium's TimeLimit
    # a second reset forgets the previous episode's frames
    obs, _ = fo.reset(options={"state": np.array([-1.0, 0.0])})
    assert np.allclose(obs[:3], math.sin(-1.0))


def test_seeded_resets_are_reproducible() -> None:
    def starts(seed: int) -> list[float]:
        env = RepeatRegimeEnv(make_control_env(ControlProtocol(horizon=10**9), 0.01), 5, 10.0, seed=seed)
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

    m = evaluate_policy_on_plant(Recorder(), protocol, 0.0, 1, repeat=5, frames=3, max_action=10.0)
    assert set(m) >= {"success_rate", "success_angle_rate", "effort", "final_error", "u_rms_final"}
    assert m["effort"] == pytest.approx(50 * 1.0)  # u = 1 N m for 50 plant steps
    first = seen[:10]  # the first regime's episode: 50 / 5 decisions
    # replay the same episode through the training wrappers
    from phast_gym.control import start_states
    from phast_gym.control.evaluation import stable_seed

    x0 = next(iter(start_states(protocol, 1, 0).values()))[0]
    fo = FrameObs(RepeatRegimeEnv(make_control_env(ControlProtocol(horizon=10**9), 0.0), 5, 10.0), 3)
    obs, _ = fo.reset(seed=stable_seed(0, "noise", "near_stable", 0), options={"state": x0})
    for k in range(10):
        assert np.allclose(first[k], obs, atol=1e-6), k
        obs, *_ = fo.step(np.array([0.1], dtype=np.float32))


def test_tiny_end_to_end(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("stable_baselines3")
    monkeypatch.setattr(sac_module, "ZOO_PENDULUM_SAC", {**sac_module.ZOO_PENDULUM_SAC, "policy_kwargs": {"net_arch": [16, 16]},
                                                 "batch_size": 32, "learning_starts": 50})
    monkeypatch.setattr(sys, "argv", ["control_sac.py", "--out", str(tmp_path), "--agents", "sac-real", "--until-flat",
                                      "--max-steps", "300", "--eval-every", "100", "--eval-episodes", "1", "--flat-window", "1",
                                      "--flat-abs-tol", "1e9", "--episode-decisions", "20", "--trials-per-regime", "1",
                                      "--ec-estimators", "oracle", "--reward", "quiet", "--no-progress"])
    main()
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


# --- issue 29, item 1: the upright (q_star = pi) diagnosis (docs/control_results/sac/DIAGNOSIS.md) -------------------

def test_plant_angle_convention_and_upright_reward() -> None:
    """q = 0 hangs (stable), q = pi is upright (unstable); the reward's error is wrap(q - q_star) at q_star = pi."""
    env = make_control_env(ControlProtocol(horizon=10**9), 0.0)
    system = env.unwrapped.system
    assert system.mgl == pytest.approx(9.81) and system.inertia == pytest.approx(1.0)
    assert system.mgl < 10.0  # the 10 N m bound can hold the pendulum at any angle
    for q0, centre, stays in ((0.3, 0.0, True), (math.pi - 0.01, math.pi, False)):  # 2 s at u = 0
        env.reset(seed=0, options={"state": np.array([q0, 0.0])})
        qs = np.array([env.step(np.zeros(1))[4]["state"][0] for _ in range(200)])
        assert bool(np.max(np.abs(wrap(qs - centre))) < 0.31) is stays, q0
    upright = RepeatRegimeEnv(make_control_env(ControlProtocol(horizon=10**9), 0.0), 5, 10.0, q_star=math.pi)
    for q0, err in ((math.pi, 0.0), (-math.pi + 0.01, 0.01), (math.pi - 0.01, 0.01), (0.0, math.pi)):
        upright.reset(seed=0, options={"state": np.array([q0, 0.0])})
        _, r, *_, info = upright.step(np.zeros(1))
        assert info["plant_err"][0] == pytest.approx(err, abs=1e-4), q0  # same error on both sides of the +-pi cut
        assert r == pytest.approx(-(err**2), abs=2e-3 + 0.2 * err**2)


def static_hold_cost(e: np.ndarray, weight: float, mgl: float = 9.81) -> np.ndarray:
    """Per-step quiet-reward cost of holding the pendulum still at an error e from the upright (u = m g l sin e)."""
    return np.array([-pendulum_reward(float(x), 0.0, mgl * math.sin(float(x)), "quiet", weight) for x in e])


def test_quiet_weight_bound_at_the_upright() -> None:
    """The old quiet weight (0.5) makes holding 0.6-0.7 rad off the upright cheaper than holding 0.3 rad off: a spurious
    optimum (the measured upright quiet policies ended 0.62 rad off with RMS torque 6.3 N m ~ m g l sin 0.62 = 5.7);
    below max_quiet_weight the cost rises monotonically with the error."""
    e = np.linspace(1e-3, 1.2, 600)
    bound = max_quiet_weight(9.81)
    assert bound == pytest.approx(math.exp(2) / 9.81**2)
    old = static_hold_cost(e, QUIET_WEIGHT)
    assert not np.all(np.diff(old) > 0)
    local_min = e[1:-1][(old[1:-1] < old[:-2]) & (old[1:-1] < old[2:])]
    assert len(local_min) == 1 and 0.6 < local_min[0] < 0.75
    assert np.interp(0.3, e, old) > 2.5 * np.interp(0.68, e, old)
    for w in (0.99 * bound, upright_quiet_weight(9.81)):
        assert np.all(np.diff(static_hold_cost(e, w)) > 0), w
    assert not np.all(np.diff(static_hold_cost(e, 1.3 * bound)) > 0)


def test_default_quiet_weight_by_target() -> None:
    """--quiet-weight defaults to QUIET_WEIGHT at the hanging target (the q* = 0 results are unchanged) and to the
    upright weight (below the bound) at q* = pi."""
    hang = parse_args(["--out", "x", "--agents", "none", "--reward", "quiet", "--q-star", "0"])
    up = parse_args(["--out", "x", "--agents", "none", "--reward", "quiet", "--q-star", str(math.pi)])
    assert quiet_weight_of(hang) == QUIET_WEIGHT
    assert quiet_weight_of(up) == pytest.approx(upright_quiet_weight(9.81)) == pytest.approx(0.05)
    assert quiet_weight_of(up) < max_quiet_weight(9.81)
    explicit = parse_args(["--out", "x", "--agents", "none", "--q-star", str(math.pi), "--quiet-weight", "0.5"])
    assert quiet_weight_of(explicit) == 0.5
    assert method_tag("sac-real", hang) == "sac-real/quiet" and curve_stem("sac-real", hang) == "curve_sac-real_quiet"
    assert method_tag("sac-real", up) == "sac-real/quiet/w0.05" and method_tag("sac-real", explicit) == "sac-real/zoo"


def test_state_observation_ablation_matches_evaluation() -> None:
    """obs 'state' = (sin q, cos q, qdot) of the true state, the same in training and in the plant evaluation."""
    protocol = ControlProtocol(horizon=30, settle_steps=10)
    seen: list[np.ndarray] = []

    class Recorder:
        def predict(self, obs: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
            seen.append(np.array(obs))
            return np.array([0.2], dtype=np.float32), None

    evaluate_policy_on_plant(Recorder(), protocol, 0.01, 1, repeat=5, frames=3, max_action=10.0, obs_mode="state")
    from phast_gym.control import start_states
    from phast_gym.control.evaluation import stable_seed

    x0 = next(iter(start_states(protocol, 1, 0).values()))[0]
    fo = FrameObs(RepeatRegimeEnv(make_control_env(ControlProtocol(horizon=10**9), 0.01), 5, 10.0), 3, "state")
    assert fo.observation_space.shape == (3,)
    obs, info = fo.reset(seed=stable_seed(0, "noise", "near_stable", 0), options={"state": x0})
    assert np.allclose(obs, [math.sin(x0[0]), math.cos(x0[0]), x0[1]], atol=1e-6)
    for k in range(6):
        assert np.allclose(seen[k], obs, atol=1e-6), k
        obs, _, _, _, info = fo.step(np.array([0.2], dtype=np.float32))  # the Recorder's action
        q, p = info["state"]
        assert np.allclose(obs, [math.sin(q), math.cos(q), p], atol=1e-6)  # I = 1: qdot = p
    plus = ObsBuilder(3, "frames+qdot")
    assert plus.size == 7 and plus.reset(np.array([0.1]), np.array([0.1, 2.0]))[-1] == pytest.approx(2.0)
    with pytest.raises(ValueError):
        ObsBuilder(3, "nope")


def test_sac_gym_tiny(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """sac-gym: the same SAC construction and training loop on Gymnasium's Pendulum-v1 (rows in gym_sac.json)."""
    pytest.importorskip("stable_baselines3")
    monkeypatch.setattr(sac_module, "ZOO_PENDULUM_SAC", {**sac_module.ZOO_PENDULUM_SAC, "policy_kwargs": {"net_arch": [16, 16]},
                                                 "batch_size": 32, "learning_starts": 50})
    main(["--out", str(tmp_path), "--agents", "sac-gym", "--steps", "200", "--curve", "--eval-every", "100",
             "--eval-episodes", "1", "--gym-eval-episodes", "2", "--no-progress"])
    meta = json.loads((tmp_path / "gym_sac.json").read_text())
    (row,) = meta["results"]
    assert row["method"] == "sac-gym/Pendulum-v1" and row["decisions"] == 200 and row["real_env_samples"] == 200
    assert row["episodes"] == 2 and -2000 < row["mean_return"] <= 0 and 0 <= row["settled_rate"] <= 1
    curve = json.loads((tmp_path / "curve_sac-gym_Pendulum-v1_s0.json").read_text())
    assert curve["decisions"] == [100, 200] and curve["flat"] is False
    assert "sac-gym/Pendulum-v1" in (tmp_path / "gym_sac.md").read_text()
    with pytest.raises(SystemExit):
        parse_args(["--out", "x", "--agents", "sac-gym,sac-real"])


def test_precise_reward() -> None:
    """precise = quiet minus a narrow angle well (depth PRECISE_WEIGHT, width the 0.05 rad tolerance): much steeper than
    err^2 at a few 0.01 rad, unchanged far away, and its static holding cost at the upright is monotone."""
    w = upright_quiet_weight(9.81)
    assert pendulum_reward(0.0, 0.0, 0.0, "precise", w) == 0.0
    assert pendulum_reward(math.pi, 0.0, 0.0, "precise", w) == pytest.approx(
        pendulum_reward(math.pi, 0.0, 0.0, "quiet", w) - PRECISE_WEIGHT)
    d = 1e-4
    slope = lambda kind, e: (pendulum_reward(e, 0.0, 0.0, kind, w) - pendulum_reward(e + d, 0.0, 0.0, kind, w)) / d  # noqa: E731
    assert slope("precise", 0.03) > 20 * slope("zoo", 0.03)
    e = np.linspace(1e-3, 1.2, 600)
    assert np.all(np.diff([-pendulum_reward(float(x), 0.0, 9.81 * math.sin(float(x)), "precise", w) for x in e]) > 0)


def test_wells_shape_the_precise_reward_and_are_validated() -> None:
    """--wells replaces the precise reward's one narrow well: a second, wider well pulls at 0.2 rad, where the narrow
    one is flat; bad specifications are refused with a message naming the item."""
    wide = parse_wells("0.1:0.05,0.5:0.2")
    assert wide == (Well(0.1, 0.05), Well(0.5, 0.2))
    assert format_wells(wide) == "0.1:0.05,0.5:0.2"
    assert parse_wells(format_wells(PRECISE_WELLS)) == PRECISE_WELLS
    # far from the target each well adds its full depth
    far = pendulum_reward(math.pi, 0.0, 0.0, "precise", 0.0, wide)
    assert far == pytest.approx(pendulum_reward(math.pi, 0.0, 0.0, "zoo") - 0.6)
    d = 1e-4
    slope = lambda wells, e: (pendulum_reward(e, 0.0, 0.0, "precise", 0.0, wells)  # noqa: E731
                              - pendulum_reward(e + d, 0.0, 0.0, "precise", 0.0, wells)) / d
    assert slope(PRECISE_WELLS, 0.2) < 1.1 * 2 * 0.2  # the narrow well is flat at 0.2 rad: err^2 alone
    assert slope(wide, 0.2) > 5 * slope(PRECISE_WELLS, 0.2)
    for bad, word in (("0.1", "DEPTH:WIDTH"), ("a:b", "DEPTH:WIDTH"), ("0.1:0", "width > 0"), ("-1:0.1", "depth >= 0")):
        with pytest.raises(ValueError, match=word):
            parse_wells(bad)
    args = parse_args(["--out", "x", "--agents", "sac-real", "--reward", "precise", "--wells", "0.1:0.05,0.5:0.2"])
    assert method_tag("sac-real", args) == "sac-real/precise/wells=0.1:0.05,0.5:0.2"
    assert method_tag("sac-real", parse_args(["--out", "x", "--agents", "sac-real", "--reward", "precise"])) == \
        "sac-real/precise"
    for argv in (["--wells", "0.1:0.05"], ["--reward", "precise", "--wells", "0.1"]):
        with pytest.raises(SystemExit):
            parse_args(["--out", "x", "--agents", "sac-real", *argv])


def test_swing_up_setting_end_to_end(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """--env / --regimes: sac-world on the undamped plant from hanging only, in a world model of plant recordings
    (benchmarks/sac_world_data.py): its recordings count as real samples, evaluation and Energy-Casimir rows use the
    chosen regime only, per-trial errors and the policy are written."""
    pytest.importorskip("stable_baselines3")
    spec = wd.PlantRecording(n_traj=3, decisions=40, seed=2)
    wd.train_world_model(spec, tmp_path / "wm", "PHAST/Pendulum-v0", {}, epochs=1, window_s=0.5, holdout=(2,))
    monkeypatch.setattr(sac_module, "ZOO_PENDULUM_SAC", {**sac_module.ZOO_PENDULUM_SAC, "policy_kwargs": {"net_arch": [16, 16]},
                                                 "batch_size": 32, "learning_starts": 50})
    out = tmp_path / "out"
    argv = ["--out", str(out), "--agents", "sac-world", "--phast-run", str(tmp_path / "wm"), "--env", "PHAST/Pendulum-v0",
            "--regimes", "near_stable", "--q-star", str(math.pi), "--steps", "100", "--curve", "--eval-every", "100",
            "--eval-episodes", "1", "--episode-decisions", "20", "--trials-per-regime", "2", "--ec-estimators", "oracle",
            "--reward", "precise", "--quiet-weight", "0", "--net", "8,8", "--lr-final", "1e-4", "--mirror", "--no-progress"]
    main(argv)
    meta = json.loads((out / "control_sac.json").read_text())
    assert meta["regimes"] == ["near_stable"] and meta["protocol"]["env_id"] == "PHAST/Pendulum-v0"
    ec, sac = meta["results"]
    assert ec["method"] == "energy-casimir/oracle" and sac["method"] == "sac-world/precise/w0/net8x8/lrf0.0001/mirror"
    assert sac["hyperparameters"]["policy_kwargs"]["net_arch"] == [8, 8]
    assert sac["hyperparameters"]["learning_rate_final"] == 1e-4
    assert len(sac["trial_final_errors"]) == 2 and sac["world_model_samples"] == 120
    rest = sac["torque_at_rest"]  # the mirrored policy: no torque at the target at rest, odd around it
    assert list(rest) == ["-0.1", "+0", "+0.1"] and rest["+0"] == 0.0 and rest["-0.1"] == -rest["+0.1"]
    # recordings + training burn-ins (a reset per 20-decision episode and one at the start) + 1 evaluation burn-in
    assert sac["real_env_samples"] == 120 + 10 * (sac["decisions"] // 20 + 1) + 10
    assert "--regimes near_stable" in sac["command"]
    from stable_baselines3 import SAC

    policy = SAC.load(sac["policy"])  # deployable as saved, at the final learning rate
    assert policy.lr_schedule(1.0) == pytest.approx(1e-4) and policy.actor.latent_pi[0].out_features == 8
    assert type(policy.policy).__name__ == "MirrorSACPolicy"
    assert "from near_stable" in (out / "control_sac.md").read_text()
    with pytest.raises(SystemExit, match="another setting"):
        main([a if a != "near_stable" else "near_unstable" for a in argv])
    with pytest.raises(SystemExit):
        parse_args(["--out", "x", "--regimes", "upside_down"])
    with pytest.raises(SystemExit):
        parse_args(["--out", "x", "--mirror", "--q-star", "1.0"])  # the reflection does not keep q* = 1
    with pytest.raises(SystemExit):
        parse_args(["--out", "x", "--agents", "sac-gym", "--mirror"])  # Pendulum-v1's observation is not ours
