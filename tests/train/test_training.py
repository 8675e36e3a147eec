"""fit / evaluate / checkpoints / load_run / world-model env / phast-train, on tiny data (fast)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from phast_gym import make_splits
from phast_model.api import load_run, predict
from phast_model.train.checkpoint import save_run
from phast_model.train.fit import TrainConfig, fit, next_step_loss
from phast_model.train.metrics import benchmark_metric, damping_scores, forecast_metrics
from phast_model.world.regimes import build_model
from tests import ROOT

torch.set_num_threads(1)
ENV = "PHAST/WindyPendulum-v0"


@pytest.fixture(scope="module")
def splits():
    return make_splits(ENV, 48, 16, 16, T=60, seed=3)


def _loss(model, ds):
    with torch.no_grad():
        return float(next_step_loss(model, torch.as_tensor(ds.q, dtype=torch.float32), None, 4)[0])


def test_short_training_lowers_loss_and_keeps_best(splits):
    model = build_model(ENV, "unknown", seed=1)
    before = _loss(model, splits["val"])
    res = fit(model, splits["train"], splits["val"], TrainConfig(epochs=6, batch_size=16, val_every=2, lr=3e-3, progress=False))
    after = _loss(res.model, splits["val"])
    assert after < 0.5 * before
    vals = [h["val_loss"] for h in res.history if "val_loss" in h]
    assert len(vals) == 3 and math.isclose(res.best_val, min(vals))
    assert res.wall_time_s > 0 and res.nan_events == 0


def test_evaluate_keys(splits):
    model = build_model(ENV, "known")
    m = forecast_metrics(model, splits["test"], horizons=(10, 50))
    for k in ("theta_wrap_mse", "mse", "rollout_theta_wrap_mse_h10", "rollout_theta_wrap_mse_h50", "rollout_takeover_mse_h10",
              "damping_r2", "damping_mae", "rollout_energy_budget_resid_h50", "rollout_passivity_violations_h50", "n_parameters"):
        assert k in m and np.isfinite(m[k]), k
    assert 0.0 <= m["rollout_passivity_violations_h50"] <= 1.0
    assert benchmark_metric(ENV) == "rollout_theta_wrap_mse_h100"
    assert benchmark_metric("PHAST/WindyCartPole-v0") == "rollout_mixed_mse_h100"


def test_resume_matches_uninterrupted(splits, tmp_path):
    cfg = TrainConfig(epochs=4, batch_size=16, val_every=2, progress=False)
    full = fit(build_model(ENV, "partial"), splits["train"], splits["val"], cfg, run_dir=tmp_path / "a")
    half = TrainConfig(**{**cfg.__dict__})
    # interrupt: run 2 epochs by stopping through a checkpoint of an identical 4-epoch schedule
    model = build_model(ENV, "partial")
    fit(model, splits["train"], splits["val"], cfg, run_dir=tmp_path / "b")  # writes checkpoint at epoch 4
    ck = torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=True)
    assert ck["epoch"] == 4
    resumed = fit(build_model(ENV, "partial"), splits["train"], splits["val"], half, run_dir=tmp_path / "b", resume=True)
    assert len(resumed.history) == 4  # nothing left to do: history restored, no extra epochs
    for a, b in zip(full.model.state_dict().values(), resumed.model.state_dict().values()):
        assert torch.allclose(a, b)


def test_resume_mid_run_is_exact(splits, tmp_path):
    cfg = TrainConfig(epochs=4, batch_size=16, val_every=2, progress=False)
    ref = fit(build_model(ENV, "known"), splits["train"], splits["val"], cfg)
    # run 2 epochs of the same 4-epoch schedule, "crash", then resume
    run = tmp_path / "r"
    model = build_model(ENV, "known")

    class Crash(Exception):
        pass

    orig = torch.optim.lr_scheduler.LRScheduler.step  # KNOWN: warm-up + cosine (LambdaLR)
    calls = {"n": 0}
    n_batches = math.ceil(48 / 16)

    def crashing_step(self, *a, **k):
        calls["n"] += 1
        if calls["n"] > 2 * n_batches:
            raise Crash
        return orig(self, *a, **k)

    torch.optim.lr_scheduler.LRScheduler.step = crashing_step
    try:
        with pytest.raises(Crash):
            fit(model, splits["train"], splits["val"], cfg, run_dir=run)
    finally:
        torch.optim.lr_scheduler.LRScheduler.step = orig
    res = fit(build_model(ENV, "known"), splits["train"], splits["val"], cfg, run_dir=run, resume=True)
    assert [h["epoch"] for h in res.history] == [1, 2, 3, 4]
    for a, b in zip(ref.model.state_dict().values(), res.model.state_dict().values()):
        assert torch.allclose(a, b, atol=1e-6)


def test_nan_guard_rolls_back(splits):
    model = build_model(ENV, "unknown")
    orig = model.forward
    calls = {"n": 0}

    def flaky(q, u=None):
        calls["n"] += 1
        out = orig(q, u)
        return out * float("nan") if calls["n"] == 2 else out

    model.forward = flaky
    res = fit(model, splits["train"], splits["val"], TrainConfig(epochs=2, batch_size=16, val_every=1, progress=False))
    assert res.nan_events == 1
    assert all(bool(torch.isfinite(p).all()) for p in res.model.parameters())
    assert res.history[-1]["lr"] >= 0 and math.isfinite(res.best_val)


def test_save_load_round_trip_and_predict(tmp_path, splits):
    model = build_model(ENV, "partial", seed=2)
    save_run(model, tmp_path)
    loaded = load_run(tmp_path)
    q = torch.as_tensor(splits["test"].q[:3], dtype=torch.float32)
    assert torch.allclose(model(q), loaded(q))
    out = predict(tmp_path, splits["test"].q[0, :10], H=5)
    assert out.shape == (5, 1)
    out_u = predict(loaded, splits["test"].q[:2, :10], u_seq=np.zeros((7, 1)))
    assert out_u.shape == (2, 7, 1)
    with pytest.raises(ValueError, match="q_history"):
        predict(loaded, np.zeros((10, 3)), H=2)


def test_corrupted_and_foreign_checkpoints(tmp_path):
    model = build_model(ENV, "known")
    save_run(model, tmp_path / "ok")
    with pytest.raises(ValueError, match="missing"):
        load_run(tmp_path / "nowhere")
    bad = tmp_path / "bad"
    save_run(model, bad)
    (bad / "model.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="corrupted"):
        load_run(bad)
    foreign = tmp_path / "foreign"
    save_run(build_model("PHAST/WindyCartPole-v0", "known"), foreign)
    (foreign / "config.json").write_text((tmp_path / "ok" / "config.json").read_text())
    with pytest.raises(ValueError, match="does not belong.*env_id='PHAST/WindyCartPole-v0'"):
        load_run(foreign)
    other = tmp_path / "other"
    other.mkdir()
    (other / "config.json").write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(ValueError, match="not a PHAST run"):
        load_run(other)
    (other / "config.json").write_text("{trunc")
    with pytest.raises(ValueError, match="corrupted"):
        load_run(other)


def test_world_model_env_passes_check_env(splits):
    from gymnasium.utils.env_checker import check_env

    from phast_model.world.gym_env import PHASTWorldModelEnv

    env = PHASTWorldModelEnv(build_model(ENV, "known"), dataset=splits["test"], max_episode_steps=20)
    check_env(env, skip_render_check=True)
    obs, info = env.reset(seed=0, options={"q_burn": splits["test"].q[1, :10]})
    assert env.observation_space.contains(obs)
    obs, r, term, trunc, info = env.step(env.action_space.sample())
    assert np.isfinite(r) and env.observation_space.contains(obs)
    env2 = PHASTWorldModelEnv(build_model(ENV, "known"), max_episode_steps=5)  # burn-in from the real env
    env2.reset(seed=1)
    with pytest.raises(ValueError):
        env2.step(np.array([np.nan], dtype=np.float32))


def test_phast_train_cli(tmp_path):
    from phast_model.cli.train import main

    out = tmp_path / "run"
    rc = main(["--env", ENV, "--regime", "partial", "--epochs", "1", "--n-train", "16", "--n-val", "8", "--n-test", "8",
               "--T", "120", "--out", str(out), "--no-progress"])
    assert rc == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert "rollout_theta_wrap_mse_h100" in metrics and "train_wall_time_s" in metrics
    for f in ("model.pt", "config.json", "rollout.png", "phase.png", "damping.png", "energy.png", "checkpoint.pt"):
        assert (out / f).exists(), f
    assert load_run(out).n == 1
    assert main(["--env", ENV, "--out", str(tmp_path / "x"), "--set", "bogus=1", "--epochs", "1", "--n-train", "8",
                 "--n-val", "4", "--n-test", "4", "--T", "40", "--no-progress", "--no-plots"]) == 2


def test_known_trainer_defaults_and_warmup(splits, tmp_path):
    from dataclasses import asdict

    from phast_model.world.model import PHASTConfig
    from phast_model.world.regimes import recipe

    # the regime recipe returns the training config beside the model config; the model carries no trainer settings
    known = recipe(ENV, "known")
    assert (known.train.adam_eps, known.train.warmup_epochs) == (1e-15, 1.0)
    assert recipe(ENV, "unknown").train == known.train  # identification settings everywhere
    assert recipe("PHAST/WindyCartPole-v0", "unknown").train == TrainConfig()  # learned M(q): the trainer's own
    assert recipe(ENV, "known", TrainConfig(adam_eps=1e-8)).train.adam_eps == 1e-8  # a value given is kept
    assert "adam_eps" not in asdict(known.model) and not hasattr(build_model(ENV, "known"), "train_defaults")
    old = {**asdict(known.model), "adam_eps": 1e-15, "warmup_epochs": 1.0}  # a config.json of an older run
    assert PHASTConfig.from_dict(old) == known.model
    model = build_model(ENV, "known")
    # 48 trajectories / 16 = 3 steps per epoch: 2 warm-up epochs = 6 steps, then cosine over 12 steps
    cfg = TrainConfig(epochs=4, batch_size=16, val_every=2, progress=False, warmup_epochs=2.0)
    res = fit(model, splits["train"], splits["val"], cfg, run_dir=tmp_path / "w")
    # the damping network gets lr x damping_lr_mult, its floor d0 the base lr (the history records group 0: d0's)
    groups = model.param_groups(cfg.lr)
    assert [g["lr"] for g in groups] == [cfg.lr, cfg.lr * model.config.damping_lr_mult]
    assert groups[0]["params"] == [model.core.damping.raw_d0] and model.config.damping_lr_mult == 100.0
    base = cfg.lr
    assert math.isclose(res.history[0]["lr"], base * 4 / 7, rel_tol=1e-6)  # linear ramp, step 3 of 6
    assert math.isclose(res.history[1]["lr"], base * 0.5, rel_tol=1e-6)  # cosine at 6 / 12
    ck = torch.load(tmp_path / "w" / "checkpoint.pt", weights_only=True)  # LambdaLR state stays loadable
    assert ck["epoch"] == 4
    with pytest.raises(ValueError, match="adam_eps"):
        fit(build_model(ENV, "known"), splits["train"], splits["val"], TrainConfig(epochs=1, progress=False, adam_eps=0.0))


def test_latent_prior_trains_only_on_first_step():
    """Predator-prey, constant prior: the t = 0 prior loss moves only the latent prior (the core sees detached
    parameters), and forward uses the prior for the first prediction only."""
    model = build_model("PHAST/PredatorPrey-v0", "partial", latent_prior="constant")
    q = torch.as_tensor(make_splits("PHAST/PredatorPrey-v0", 4, 1, 1, T=20, seed=3)["train"].q, dtype=torch.float32)
    loss = model.extra_losses(q, None, model(q))["prior"]
    loss.backward()
    grads = {k: p.grad for k, p in model.named_parameters() if p.grad is not None and bool(p.grad.abs().sum() > 0)}
    assert set(grads) == {"prior_raw"}
    base = model(q)
    with torch.no_grad():
        model.prior_raw.add_(1.0)
    moved = model(q)
    assert not torch.allclose(base[:, 0], moved[:, 0]) and torch.allclose(base[:, 1:], moved[:, 1:])


@pytest.mark.parametrize("regime", ["known", "partial", "unknown"])
def test_learned_startup_latents_touch_only_the_startup_steps(regime):
    """The default predator-prey start-up latents: their loss trains the start-up parameters alone (the field and
    its latent map stay detached), each start-up network moves its own step's prediction only, and from
    t = loss_skip on the predictions are those of the plain latent map."""
    model = build_model("PHAST/PredatorPrey-v0", regime)
    assert model.config.latent_prior == "learned" and len(model.startup_nets) == model.loss_skip - 1 == 3
    q = torch.as_tensor(make_splits("PHAST/PredatorPrey-v0", 4, 1, 1, T=20, seed=3)["train"].q, dtype=torch.float32)
    model.extra_losses(q, None, model(q))["prior"].backward()
    trained = {k.split(".")[0] for k, p in model.named_parameters() if p.grad is not None and bool(p.grad.abs().sum() > 0)}
    assert trained == {"prior_raw", "prior_net", "startup_nets"}
    base = model(q)
    for t, net in enumerate([model.prior_net, *model.startup_nets]):
        with torch.no_grad():
            net[-1].bias.add_(0.1)
        moved = model(q)
        changed = [s for s in range(q.shape[1]) if not torch.allclose(base[:, s], moved[:, s])]
        assert changed == [t], (t, changed)
        base = moved
    plain = build_model("PHAST/PredatorPrey-v0", regime, latent_prior="constant")
    plain.load_state_dict({k: v for k, v in model.state_dict().items() if k in plain.state_dict()})
    assert torch.allclose(plain(q)[:, model.loss_skip:], model(q)[:, model.loss_skip:])
    with pytest.raises(ValueError, match="latent_prior"):
        build_model("PHAST/PredatorPrey-v0", regime, latent_prior="mlp")


TINY = ["--n-train", "8", "--n-val", "4", "--n-test", "4", "--T", "40", "--no-progress", "--no-plots"]


def _train_cmd(out, *extra):
    return ["--env", ENV, "--regime", "partial", "--out", str(out), *TINY, *extra]


def test_killed_run_resumed_with_another_env_or_config_is_refused(tmp_path, capsys):
    """Kill phast-train mid-run, then --resume under another env / lr / seed / n-train: exit 2 naming the field,
    and the run directory is left as it was (no config.json written beside the old checkpoint)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from phast_model.cli.train import main

    out = tmp_path / "run"
    root = str(ROOT)
    env = {**os.environ, "PYTHONPATH": root + os.pathsep + os.environ.get("PYTHONPATH", ""), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "phast_model.cli.train", *_train_cmd(out, "--epochs", "100000")],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not (out / "checkpoint.pt").exists():
            assert proc.poll() is None and time.monotonic() < deadline, "phast-train never wrote a checkpoint"
            time.sleep(0.1)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    before = sorted(p.name for p in out.iterdir())
    for extra, field in ((["--env", "PHAST/Pendulum-v0"], "env_id"), (["--lr", "0.01"], "train.lr"),
                         (["--seed", "3"], "train.seed"), (["--n-train", "9"], "data.n_train")):
        argv = _train_cmd(out, "--epochs", "100000", "--resume")
        if extra[0] == "--env":
            argv[1] = extra[1]
        else:
            argv += extra
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"written for {field}=" in err, err
    assert sorted(p.name for p in out.iterdir()) == before and not (out / "config.json").exists()


def test_load_run_refuses_model_pt_of_another_env_with_the_same_shapes(tmp_path):
    save_run(build_model(ENV, "partial"), tmp_path / "windy")
    save_run(build_model("PHAST/Pendulum-v0", "partial"), tmp_path / "plain")
    (tmp_path / "windy" / "model.pt").write_bytes((tmp_path / "plain" / "model.pt").read_bytes())
    with pytest.raises(ValueError, match="does not belong.*model.env_id='PHAST/Pendulum-v0'"):
        load_run(tmp_path / "windy")


@pytest.mark.parametrize("bad", [["--n-train", "0"], ["--n-val", "0"], ["--n-test", "0"], ["--n-test", "-2"],
                                 ["--obs-noise-std", "-1"], ["--obs-noise-std", "nan"], ["--obs-noise-std", "inf"]])
def test_phast_train_rejects_empty_splits_and_bad_noise_before_any_work(tmp_path, capsys, bad):
    from phast_model.cli.train import main

    out = tmp_path / "run"
    assert main(_train_cmd(out, "--epochs", "1", *bad)) == 2
    assert bad[0] in capsys.readouterr().err.replace("obs_noise_std", "--obs-noise-std")
    assert not out.exists()  # nothing trained, nothing written


def test_phast_train_refuses_an_unwritable_out_before_training(tmp_path, capsys):
    from phast_model.cli.train import main

    (tmp_path / "file").write_text("x")
    assert main(_train_cmd(tmp_path / "file", "--epochs", "1")) == 2
    assert "not a directory" in capsys.readouterr().err


@pytest.mark.parametrize("content", [b"", "half"])
def test_empty_or_truncated_checkpoints_give_a_reason(tmp_path, content):
    save_run(build_model(ENV, "known"), tmp_path)
    data = (tmp_path / "model.pt").read_bytes()
    (tmp_path / "model.pt").write_bytes(data[: len(data) // 2] if content == "half" else content)
    reason = "truncated" if content == "half" else "empty"
    with pytest.raises(ValueError, match=f"corrupted or unreadable checkpoint .*{reason}"):
        load_run(tmp_path)
    (tmp_path / "checkpoint.pt").write_bytes((tmp_path / "model.pt").read_bytes())
    cfg = TrainConfig(epochs=1, progress=False)
    with pytest.raises(ValueError, match=f"cannot resume: .*{reason}"):
        fit(build_model(ENV, "known"), make_splits(ENV, 4, 2, 2, T=20, seed=3)["train"],
            make_splits(ENV, 4, 2, 2, T=20, seed=3)["val"], cfg, run_dir=tmp_path, resume=True)


def test_phast_train_port_excitation_is_part_of_the_run_identity(tmp_path):
    from phast_model.cli.train import main

    out = tmp_path / "run"
    assert main(_train_cmd(out, "--epochs", "1", "--port-excitation", "1.5", "--no-plots")) == 0
    data = json.loads((out / "config.json").read_text())["data"]
    assert data["port_excitation"] == {"std": 1.5, "hold": 5, "seed": 0}
    assert main(_train_cmd(tmp_path / "free", "--epochs", "1", "--no-plots")) == 0
    assert "port_excitation" not in json.loads((tmp_path / "free" / "config.json").read_text())["data"]
    assert main(_train_cmd(tmp_path / "bad", "--epochs", "1", "--port-excitation", "-1")) == 2
    assert not (tmp_path / "bad").exists()


def test_identification_settings_on_every_partial_and_constant_mass_unknown_row():
    """A trainable observer absorbs D under the one-step loss (docs/results.md, section 0): PARTIAL everywhere and
    UNKNOWN with a constant M freeze it, fix dt and take 4 substeps; UNKNOWN with a learned M(q) keeps its own."""
    from phast_gym import env_ids, make_env_system
    from phast_model.world.data_init import MIN_D0
    from phast_model.world.regimes import IDENTIFICATION, default_config

    for env in env_ids():
        system = make_env_system(env)
        if not system.hamiltonian_system:
            continue
        ident = [default_config(env, "partial")] + ([default_config(env, "unknown")] if system.separable else [])
        for cfg in ident:
            assert cfg.substeps == 4 and cfg.canonicalizer == "mass", (env, cfg.regime)
            assert all(getattr(cfg, k) == v for k, v in IDENTIFICATION.items()), (env, cfg.regime)
        if system.separable:
            assert ident[-1].d0 == MIN_D0 and ident[-1].learn_d0
        else:
            cfg = default_config(env, "unknown")
            assert cfg.observer_trainable and cfg.learn_dt and cfg.roll_mode == "observer", env


def test_damping_scores_r2_undefined_for_constant_truth():
    """Eq. 92-93: R^2 of a varying truth is the usual ratio; for a constant or zero true D it is NaN (not the
    -1e13 a round-off denominator gives) while the MAE still scores the fit."""
    rng = np.random.default_rng(0)
    d = 0.3 + 0.5 * np.abs(np.sin(rng.uniform(-3, 3, (40, 1))))
    d_hat = d + 0.01 * rng.normal(size=d.shape)
    s = damping_scores(d_hat, d)
    assert math.isclose(s["damping_r2"], 1 - ((d_hat - d) ** 2).sum() / ((d - d.mean()) ** 2).sum(), rel_tol=1e-12)
    assert 0.99 < s["damping_r2"] < 1.0
    for truth in (np.full((40, 1), 0.5), np.zeros((40, 2))):
        s = damping_scores(truth + 1e-3, truth)
        assert math.isnan(s["damping_r2"])
        assert math.isclose(s["damping_mae"], 1e-3, rel_tol=1e-9)


@pytest.mark.parametrize(("env", "regime"), [("PHAST/WindyPendulum-v0", "unknown"), ("PHAST/WindyCartPole-v0", "unknown"),
                                             ("PHAST/PredatorPrey-v0", "known"), ("PHAST/PredatorPrey-v0", "unknown")])
def test_predict_next_on_a_prefix_is_forwards_prediction(env, regime):
    """``predict_next(q[:, :t+1])`` (rollouts, ``phast_model.api.predict``) equals forward's teacher-forced
    prediction at t for every prefix length, the start-up steps (shorter backward differences, the predator-prey
    start-up latents) and a perturbed TCN head included."""
    torch.manual_seed(0)
    model = build_model(env, regime).eval()
    with torch.no_grad():
        for p in model.parameters():  # leave the zero-initialized corrections (TCN head, start-up nets) non-trivial
            p.add_(0.01 * torch.randn_like(p))
    q = torch.as_tensor(make_splits(env, 3, 1, 1, T=16, seed=5)["train"].q, dtype=torch.float32)
    with torch.no_grad():
        full = model(q)
        for t in range(q.shape[1]):
            assert torch.allclose(model.predict_next(q[:, :t + 1]), full[:, t], atol=1e-5), t


def test_train_run_python_api_takes_typed_data_and_train_specs(tmp_path):
    from phast_gym.datasets import PortExcitation
    from phast_model.train.runs import DataSpec, train_run

    data = DataSpec(n_train=8, n_val=4, n_test=4, T=120, seed=5)
    # the record of a free-motion run has exactly the keys a run written before DataSpec had, so its resumes match
    assert data.identity() == {"n_train": 8, "n_val": 4, "n_test": 4, "T": 120, "seed": 5, "obs_noise_std": 0.0}
    assert "port_excitation" not in DataSpec(excitation=PortExcitation(0.0)).identity()
    assert DataSpec(excitation=PortExcitation(1.5)).identity()["port_excitation"] == {"std": 1.5, "hold": 5, "seed": 0}
    m = train_run(ENV, "known", tmp_path / "run", data=data, train=TrainConfig(epochs=1, seed=3, progress=False),
                  plots=False)
    cfg = json.loads((tmp_path / "run" / "config.json").read_text())
    assert cfg["data"] == data.identity() and cfg["train"]["seed"] == 3 and math.isfinite(m["benchmark_value"])
    for bad, match in (({"n_val": 0}, "--n-val"), ({"T": 1}, "--T"), ({"obs_noise_std": float("nan")}, "obs_noise_std")):
        with pytest.raises(ValueError, match=match):
            DataSpec(**bad)
