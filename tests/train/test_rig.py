"""PHAST on recordings of a rig (phast_model.rig, rig_run, ``phast-train --recordings``): data checks, the
multiple-shooting fit recovering a hidden Coulomb friction, the held-out score, the run directory and the world env."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from phast_model.bench.reality import make_reality
from phast_model.cli.train import main as train_main
from phast_model.mismatch.vocabulary.terms import Term
from phast_model.train.rig_fit import RigTrainConfig, build, fit_recordings, load_rig_data, nominal_config, rig_config
from phast_model.train.rig_heldout import heldout_rollouts

SIM = "PHAST/DampedPendulum-v0"
COULOMB = 0.4


@pytest.fixture(scope="module")
def recordings() -> dict:
    """A damped pendulum driven by smooth torques, with a hidden Coulomb friction of 0.4 N m."""
    return make_reality(SIM, [Term("coulomb_friction", 0, COULOMB)], n_traj=10, T=240, noise_std=0.002, seed=3,
                        u_std=1.5)


@pytest.fixture(scope="module")
def trained(recordings: dict) -> tuple:
    torch.set_num_threads(1)
    data = load_rig_data(recordings, SIM, {}, [8, 9])
    cfg = rig_config(SIM, {}, "partial", data, friction_laws=["coulomb", "viscous"])
    fit = fit_recordings(build(cfg), data, RigTrainConfig(epochs=30, window_s=1.0, lr=4e-2, progress=False))
    return data, cfg, fit


def test_shooting_fit_finds_the_hidden_coulomb_friction(trained: tuple) -> None:
    data, cfg, fit = trained
    c = {k: v.detach() for k, v in fit.model.friction.coefficients().items()}
    assert abs(float(c["coulomb"][0]) - COULOMB) < 0.3 * COULOMB, c
    assert fit.history[-1]["train_rmse"] < 0.3 * fit.history[0]["train_rmse"]


def test_heldout_score_beats_the_nominal_rig_by_the_same_code(trained: tuple) -> None:
    data, cfg, fit = trained
    scores, rolls, w = heldout_rollouts({"phast": fit.model, "nominal": build(nominal_config(cfg))}, data.heldout, 2.0)
    assert scores["n_windows"] == w.q.shape[0] >= 2
    assert scores["phast"]["rollout_rmse"] < 0.5 * scores["nominal"]["rollout_rmse"]
    assert rolls["phast"].shape == tuple(w.q.shape)


def test_compared_systems_are_scored_on_the_same_windows(trained: tuple) -> None:
    """compare=: a phast_gym System scored by the same windows, burn-in and error. The true system (the rig plus its
    hidden Coulomb friction) predicts at about the noise level; the nominal rig as a System scores like the nominal
    PHAST model (the same physics, each with its own state fit to the burn-in)."""
    from phast_gym import make_env_system
    from phast_model.mismatch.vocabulary.terms import AugmentedSystem

    data, cfg, fit = trained
    rig = make_env_system(SIM)
    truth = AugmentedSystem(make_env_system(SIM), [Term("coulomb_friction", 0, COULOMB)], coulomb_eps=1e-3)
    scores, rolls, w = heldout_rollouts({"phast": fit.model, "nominal": build(nominal_config(cfg))}, data.heldout, 2.0,
                                        compare={"truth": truth, "nominal system": rig})
    assert rolls["truth"].shape == rolls["phast"].shape == tuple(w.q.shape)
    assert len(scores["truth"]["per_window_rmse"]) == scores["n_windows"]
    assert scores["truth"]["rollout_rmse"] < min(0.01, scores["phast"]["rollout_rmse"])
    assert scores["nominal system"]["rollout_rmse"] == pytest.approx(scores["nominal"]["rollout_rmse"], rel=0.25)
    with pytest.raises(ValueError, match="already a scored model"):
        heldout_rollouts({"phast": fit.model}, data.heldout, 2.0, compare={"phast": rig})
    with pytest.raises(TypeError, match="must be a phast_gym System"):
        heldout_rollouts({"phast": fit.model}, data.heldout, 2.0, compare={"unbuilt": type(rig)})


def test_recordings_with_the_wrong_input_width_are_refused(recordings: dict) -> None:
    bad = {**recordings, "u": np.concatenate([recordings["u"], recordings["u"]], -1)}
    with pytest.raises(ValueError, match="'u' has m=2 inputs"):
        load_rig_data(bad, SIM, {}, [9])


def test_free_motion_recordings_are_accepted(recordings: dict) -> None:
    free = {k: v for k, v in recordings.items() if k != "u"}
    data = load_rig_data(free, SIM, {}, [9])
    assert data.train.u is None and not data.driven


def test_too_short_for_a_burn_in_and_a_window_is_a_clear_error(tmp_path, recordings: dict, capsys) -> None:  # noqa: ANN001
    path = tmp_path / "rec.npz"
    np.savez(path, **recordings)
    rc = train_main(["--recordings", str(path), "--sim", SIM, "--holdout-trajectories", "9", "--rollout-window-s", "60",
                     "--out", str(tmp_path / "run"), "--no-progress"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "too short" in err and "burn-in" in err
    assert not (tmp_path / "run" / "model.pt").exists()


def test_malformed_compare_flags_are_clear_errors(tmp_path, recordings: dict, capsys) -> None:  # noqa: ANN001
    path = tmp_path / "rec.npz"
    np.savez(path, **recordings)
    base = ["--recordings", str(path), "--sim", SIM, "--holdout-trajectories", "8,9", "--out", str(tmp_path / "r")]
    for extra, message in ((["--compare", "nameonly"], "NAME=VALUE"), (["--compare-kwargs", "x={}"], "no --compare gives"),
                           (["--compare", "a=PHAST/Nope-v0"], "Nope")):
        assert train_main(base + extra) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_unknown_env_or_rig_is_one_line(tmp_path, capsys) -> None:  # noqa: ANN001
    assert train_main(["--env", "PHAST/Nope-v0", "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "PHAST/Pendulum-v0" in err
    np.savez(tmp_path / "rec.npz", q=np.zeros((2, 100, 1)), dt=0.05)
    assert train_main(["--recordings", str(tmp_path / "rec.npz"), "--sim", "PHAST/Nope-v0", "--holdout-trajectories",
                       "1", "--out", str(tmp_path / "r2")]) == 2
    assert "PHAST/Pendulum-v0" in capsys.readouterr().err


def test_cli_run_directory_opens_with_load_run_and_the_world_env(tmp_path, recordings: dict) -> None:  # noqa: ANN001
    from phast_model.api import load_run
    from phast_model.world.gym_env import PHASTWorldModelEnv

    path = tmp_path / "rec.npz"
    np.savez(path, **recordings)
    out = tmp_path / "run"
    rc = train_main(["--recordings", str(path), "--sim", SIM, "--holdout-trajectories", "8,9", "--rollout-window-s", "2",
                     "--window-s", "1.0", "--epochs", "3", "--regime", "partial", "--out", str(out), "--no-progress",
                     "--compare", "undamped=PHAST/Pendulum-v0", "--compare-kwargs", "undamped={}"])
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())
    h = m["heldout"]
    assert math.isfinite(h["undamped"]["rollout_rmse"]) and h["undamped_over_nominal"] > 0
    assert math.isfinite(h["phast"]["rollout_rmse"]) and math.isfinite(h["nominal"]["rollout_rmse"])
    assert h["burn_in_s"] == 0.1 and h["window_s"] == 2.0
    assert set(m["friction"]) == {"coulomb", "viscous"}
    assert (out / "heldout_rollout.png").exists() and (out / "friction.png").exists()
    model = load_run(out)
    assert model.config.sim == SIM and model.dt == pytest.approx(0.05)
    env = PHASTWorldModelEnv(model, burn_in=5)
    bound = float(np.max(np.abs(recordings["u"])))
    assert env.action_space.high[0] == pytest.approx(bound, rel=1e-6)
    obs, _ = env.reset(options={"q_burn": recordings["q"][0, :5]})
    obs, r, term, trunc, info = env.step(np.array([0.5]))
    assert obs.shape == (1,) and np.isfinite(r)
    with pytest.raises(ValueError, match="q_burn"):
        env.reset()


def test_known_regime_learns_only_the_friction(recordings: dict) -> None:
    data = load_rig_data(recordings, SIM, {}, [9])
    model = build(rig_config(SIM, {}, "known", data))
    names = {n for n, p in model.named_parameters() if p.requires_grad}
    assert names == {"core.friction.raw"}


def test_window_warmup_trains_short_windows_first_and_keeps_the_best_of_the_final_length(recordings: dict) -> None:
    """--warmup-window-s: the first epochs on short windows; the best model is chosen on the final windows only."""
    with pytest.raises(ValueError, match="warmup_epochs"):
        RigTrainConfig(epochs=3, warmup_window_s=0.2, warmup_epochs=3)
    with pytest.raises(ValueError, match="warmup_window_s"):
        RigTrainConfig(epochs=3, warmup_window_s=-1.0, warmup_epochs=1)
    with pytest.raises(ValueError, match="needs warmup_window_s"):
        RigTrainConfig(epochs=3, warmup_epochs=1)
    torch.set_num_threads(1)
    data = load_rig_data(recordings, SIM, {}, [9])
    model = build(rig_config(SIM, {}, "unknown", data, init_from="none"))  # the curriculum alone, no start to compete
    fit = fit_recordings(model, data, RigTrainConfig(epochs=4, window_s=1.0, warmup_window_s=0.25, warmup_epochs=2,
                                                     progress=False))
    assert [h["epoch"] for h in fit.history] == [1, 2, 3, 4]
    assert fit.best_epoch in (3, 4)
    assert fit.best_val == pytest.approx(min(h["val_rmse"] for h in fit.history[2:]))


def test_the_verdict_says_whether_the_run_learned_the_rig(trained: tuple) -> None:
    """A run that fits its training windows near the noise and beats the nominal model is 'converged'; one stuck far
    above the noise and the nominal model says 'did not converge' with its numbers; one that converged but predicts
    the held-out recordings worse says so."""
    from phast_model.train.rig_fit import window_rmse
    from phast_model.train.rig_run import FitLevels, _noise, verdict

    data, cfg, fit = trained
    nominal = build(nominal_config(cfg))
    scores, _, _ = heldout_rollouts({"phast": fit.model, "nominal": nominal}, data.heldout, 2.0)
    ratio = scores["phast"]["rollout_rmse"] / scores["nominal"]["rollout_rmse"]
    train_cfg = RigTrainConfig(epochs=30, window_s=1.0, lr=4e-2, progress=False)
    levels = FitLevels(_noise(data.train), window_rmse(nominal, data, train_cfg))
    assert levels.noise == pytest.approx(0.002, rel=0.3)
    assert fit.best_val < 0.5 * levels.nominal  # the hidden Coulomb friction: the nominal rig misfits its windows
    ok = verdict(fit.best_val, len(fit.history), levels, ratio)
    assert ok["converged"] and ok["better_than_nominal"] and ok["message"].startswith("converged: training RMSE")
    stuck = verdict(1.35, 116, FitLevels(0.001, 0.004), 84.1)
    assert not stuck["converged"]
    assert stuck["message"].startswith("did not converge: training RMSE 1.35 after 116 epochs (the nominal model 0.004")
    worse = verdict(0.003, 60, FitLevels(0.001, 0.004), 1.91)
    assert worse["converged"] and not worse["better_than_nominal"]
    assert worse["message"].startswith("worse than the nominal model: held-out rollout RMSE 1.91x")
    assert verdict(0.02, 60, FitLevels(0.0001, 0.05), 0.4)["converged"]  # model error above the noise, below nominal
    assert not verdict(float("nan"), 3, FitLevels(0.001, 0.004), float("nan"))["converged"]
