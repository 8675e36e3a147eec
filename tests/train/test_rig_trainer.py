"""The rig path's trainer (phast_model.train.rig_fit.fit_recordings, ``phast-train --recordings``): the NaN guard, checkpoints
and an exact resume, opt-in early stopping by validation, and an explicit --lr used as given in both modes."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

import phast_model.train.rig_fit as rigfit
from phast_model.cli.train import main as train_main
from phast_model.train.fit import TrainConfig
from phast_model.train.loop import OK, SKIP, finite_params, guarded_step
from phast_model.train.rig_fit import RigFit, RigTrainConfig, build, fit_recordings, load_rig_data, rig_config

SIM = "PHAST/DampedPendulum-v0"
TINY = {"window_s": 1.0, "progress": False}


def _pendulum_recordings(n_traj: int = 6, T: int = 120, dt: float = 0.05, seed: int = 0) -> dict[str, Any]:
    """A damped pendulum driven by smooth random torques (RK4 at dt / 10), q with a little noise."""
    rng = np.random.default_rng(seed)
    knots = rng.normal(0.0, 1.5, (n_traj, T // 10 + 2))
    u = np.stack([np.interp(np.arange(T - 1) / 10, np.arange(knots.shape[1]), k) for k in knots])[..., None]
    x = np.stack([rng.uniform(-1, 1, n_traj), rng.uniform(-1, 1, n_traj)], -1)
    f = lambda x, a: np.stack([x[:, 1], -9.81 * np.sin(x[:, 0]) - 0.1 * x[:, 1] + a], -1)  # noqa: E731
    q, h = [x[:, 0].copy()], dt / 10
    for k in range(T - 1):
        for _ in range(10):
            k1 = f(x, u[:, k, 0])
            k2 = f(x + h / 2 * k1, u[:, k, 0])
            k3 = f(x + h / 2 * k2, u[:, k, 0])
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + f(x + h * k3, u[:, k, 0]))
        q.append(x[:, 0].copy())
    q_arr = np.stack(q, 1)[..., None] + rng.normal(0.0, 0.002, (n_traj, T, 1))
    return {"q": q_arr, "u": u, "dt": dt, "angle_dims": np.array([0])}


@pytest.fixture(scope="module")
def recordings() -> dict[str, Any]:
    return _pendulum_recordings()


@pytest.fixture(scope="module")
def data(recordings: dict[str, Any]) -> rigfit.RigData:
    torch.set_num_threads(1)
    return load_rig_data(recordings, SIM, {}, [5])


def _fit(data: rigfit.RigData, cfg: RigTrainConfig, **kw: Any) -> RigFit:
    return fit_recordings(build(rig_config(SIM, {}, "partial", data)), data, cfg, **kw)


#: two fresh runs of the same training in one process agree to ~1e-9 relative, not bitwise (a vectorized reduction
#: rounds by the data's memory alignment); a wrong restore (optimizer, schedule, batch order, window states) moves
#: the weights by 1e-4 or more
SAME = {"rtol": 1e-7, "atol": 1e-10}


def _same_state(a: torch.nn.Module, b: torch.nn.Module) -> bool:
    sa, sb = a.state_dict(), b.state_dict()
    return sa.keys() == sb.keys() and all(torch.allclose(sa[k], sb[k], **SAME) for k in sa)


def _untimed(history: list[dict[str, float]]) -> list[dict[str, float]]:
    return [{k: v for k, v in h.items() if k != "time_s"} for h in history]


def _same_history(a: list[dict[str, float]], b: list[dict[str, float]]) -> bool:
    ua, ub = _untimed(a), _untimed(b)
    return len(ua) == len(ub) and all(x.keys() == y.keys() and all(x[k] == pytest.approx(y[k], rel=SAME["rtol"],
                                      abs=SAME["atol"]) for k in x) for x, y in zip(ua, ub))


class Crash(Exception):
    """A run killed after some epochs."""


def _crash_after(monkeypatch: pytest.MonkeyPatch, epochs: int) -> None:
    """Make the trainer die at the start of epoch ``epochs + 1`` (after ``epochs`` checkpoints)."""
    real, calls = rigfit.Shooting.begin_epoch, {"n": 0}

    def dying(*a: Any, **k: Any) -> None:
        calls["n"] += 1
        if calls["n"] > epochs:
            raise Crash
        real(*a, **k)

    monkeypatch.setattr(rigfit.Shooting, "begin_epoch", dying)


# --------------------------------------------------------------------------- NaN guard
def test_a_non_finite_loss_or_gradient_makes_no_update() -> None:
    model = torch.nn.Module()
    model.p = p = torch.nn.Parameter(torch.zeros(2))
    opt = torch.optim.AdamW([p], lr=0.1)
    assert guarded_step(opt, model, torch.sqrt(p).sum(), 10.0) == SKIP  # finite loss, infinite gradient
    assert guarded_step(opt, model, p.sum() * math.nan, 10.0) == SKIP  # non-finite loss
    assert torch.equal(p.detach(), torch.zeros(2)) and not opt.state
    assert guarded_step(opt, model, (p - 1).pow(2).sum(), 10.0) == OK and bool((p > 0).all())


def test_nan_minibatches_are_skipped_and_counted_in_the_history(data: rigfit.RigData,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    real, calls = rigfit._loss, {"train": 0}

    def flaky(model: Any, w: Any, idx: torch.Tensor | None = None) -> torch.Tensor:
        loss = real(model, w, idx)
        if idx is not None:
            calls["train"] += 1
            if calls["train"] == 2:  # the first epoch's second (of two) minibatch
                return loss * math.nan
        return loss

    monkeypatch.setattr(rigfit, "_loss", flaky)
    fit = _fit(data, RigTrainConfig(epochs=2, batch_windows=12, **TINY))
    assert calls["train"] == 4 and fit.nan_skipped == 1 and fit.nan_rollbacks == 0
    assert [h["nan_skipped"] for h in fit.history] == [1, 1]
    assert all(math.isfinite(h["train_rmse"]) for h in fit.history)
    assert finite_params(fit.model)


def test_an_epoch_ending_with_non_finite_weights_is_undone_and_the_lr_halved(data: rigfit.RigData,
                                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """One minibatch per epoch (TINY): a step that leaves NaN weights at the end of epoch 2 is rolled back to the
    weights epoch 2 started from, at half the learning rate (the shared loop's NaN guard)."""
    real_begin, real_step = rigfit.Shooting.begin_epoch, torch.optim.AdamW.step

    def record(log: list[tuple[dict[str, torch.Tensor], float]], poison_at: int | None) -> tuple[Any, Any]:
        def begin(self: rigfit.Shooting, epoch: int) -> None:
            assert self.stage is not None
            log.append(({k: v.clone() for k, v in self.model.state_dict().items()}, self.stage.optim.lr))
            real_begin(self, epoch)

        def step(opt: torch.optim.Optimizer, *a: Any, **k: Any) -> Any:
            out = real_step(opt, *a, **k)
            if len(log) == poison_at:
                with torch.no_grad():
                    next(iter(opt.param_groups[0]["params"])).fill_(math.nan)
            return out
        return begin, step

    cfg = RigTrainConfig(epochs=4, **TINY)
    ref: list[tuple[dict[str, torch.Tensor], float]] = []
    begin, step = record(ref, None)
    monkeypatch.setattr(rigfit.Shooting, "begin_epoch", begin)
    monkeypatch.setattr(torch.optim.AdamW, "step", step)
    _fit(data, cfg)
    log: list[tuple[dict[str, torch.Tensor], float]] = []
    begin, step = record(log, 2)
    monkeypatch.setattr(rigfit.Shooting, "begin_epoch", begin)
    monkeypatch.setattr(torch.optim.AdamW, "step", step)
    fit = _fit(data, cfg)
    assert fit.nan_rollbacks == 1 and [h["nan_rollbacks"] for h in fit.history] == [0, 1, 1, 1]
    assert finite_params(fit.model)
    # epoch 3 starts from the weights epoch 2 started from, on the schedule at half its learning rate
    assert all(torch.equal(log[2][0][k], log[1][0][k]) for k in log[1][0])
    assert [lr for _, lr in log[:2]] == [lr for _, lr in ref[:2]]
    assert log[2][1] == pytest.approx(0.5 * ref[2][1], rel=1e-12)
    assert log[3][1] == pytest.approx(0.5 * ref[3][1], rel=1e-9)


# --------------------------------------------------------------------------- checkpoints and resume
@pytest.mark.parametrize("warmup_epochs,crash_after,epoch_windows", [(0, 2, None), (2, 1, None), (2, 2, None),
                                                                     (0, 2, 7)],
                         ids=["final-stage", "inside-warm-up", "at-the-switch", "drawn-windows"])
def test_resume_ends_with_the_model_of_an_uninterrupted_run(data: rigfit.RigData, tmp_path: Path,
                                                            monkeypatch: pytest.MonkeyPatch, warmup_epochs: int,
                                                            crash_after: int, epoch_windows: int | None) -> None:
    """3 epochs straight against ``crash_after`` epochs, a kill and a resume: the same weights, bit for bit; the
    resume rebuilds the curriculum stage it stopped in (warm-up or final), optimizer, schedule and window states,
    and draws an epoch's windows as the uninterrupted run did."""
    warm = {"warmup_window_s": 0.5, "warmup_epochs": warmup_epochs} if warmup_epochs else {}
    cfg = RigTrainConfig(epochs=3, batch_windows=8, epoch_windows=epoch_windows, **warm, **TINY)
    straight = _fit(data, cfg, run_dir=tmp_path / "straight")
    with monkeypatch.context() as m:
        _crash_after(m, crash_after)
        with pytest.raises(Crash):
            _fit(data, cfg, run_dir=tmp_path / "killed")
    ck = torch.load(tmp_path / "killed" / rigfit.CHECKPOINT, weights_only=True)
    assert ck["epoch"] == crash_after and ck["format"] == rigfit.CHECKPOINT_FORMAT
    resumed = _fit(data, cfg, run_dir=tmp_path / "killed", resume=True)
    assert _same_state(straight.model, resumed.model)
    assert _same_history(resumed.history, straight.history)
    assert resumed.best_epoch == straight.best_epoch
    assert resumed.best_val == pytest.approx(straight.best_val, rel=SAME["rtol"])


def test_a_missing_malformed_or_foreign_checkpoint_is_a_clear_error(data: rigfit.RigData, tmp_path: Path) -> None:
    cfg = RigTrainConfig(epochs=1, **TINY)
    with pytest.raises(ValueError, match="checkpoint.pt is missing"):
        _fit(data, cfg, run_dir=tmp_path / "none", resume=True)
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / rigfit.CHECKPOINT).write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="corrupted or unreadable"):
        _fit(data, cfg, run_dir=bad, resume=True)
    torch.save({"model": {}}, bad / rigfit.CHECKPOINT)  # e.g. an --env run's checkpoint
    with pytest.raises(ValueError, match="not the checkpoint of a recordings run"):
        _fit(data, cfg, run_dir=bad, resume=True)
    _fit(data, cfg, run_dir=tmp_path / "run")
    with pytest.raises(ValueError, match="train.lr"):
        _fit(data, RigTrainConfig(epochs=1, lr=1e-3, **TINY), run_dir=tmp_path / "run", resume=True)
    other = load_rig_data(_pendulum_recordings(n_traj=7), SIM, {}, [5])
    with pytest.raises(ValueError, match="recordings changed"):
        fit_recordings(build(rig_config(SIM, {}, "partial", data)), other, cfg, run_dir=tmp_path / "run", resume=True)


def _cli(rec: Path, out: Path, *extra: str) -> list[str]:
    return ["--recordings", str(rec), "--sim", SIM, "--holdout-trajectories", "5", "--rollout-window-s", "2",
            "--window-s", "1.0", "--epochs", "3", "--out", str(out), "--no-progress", "--no-plots", *extra]


def _model_tensors(run: Path) -> dict[str, torch.Tensor]:
    return torch.load(run / "model.pt", weights_only=True)


def test_cli_resume_continues_a_killed_recordings_run_exactly(recordings: dict[str, Any], tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch, capsys: Any) -> None:
    rec = tmp_path / "rec.npz"
    np.savez(rec, **recordings)
    assert train_main(_cli(rec, tmp_path / "straight")) == 0
    with monkeypatch.context() as m:
        _crash_after(m, 2)
        with pytest.raises(Crash):
            train_main(_cli(rec, tmp_path / "killed"))
    assert not (tmp_path / "killed" / "model.pt").exists() and (tmp_path / "killed" / "checkpoint.pt").exists()
    assert train_main(_cli(rec, tmp_path / "killed", "--resume")) == 0
    a, b = _model_tensors(tmp_path / "straight"), _model_tensors(tmp_path / "killed")
    assert a.keys() == b.keys() and all(torch.allclose(a[k], b[k], **SAME) for k in a)
    metrics = json.loads((tmp_path / "killed" / "metrics.json").read_text())
    assert metrics["epochs_run"] == 3 and metrics["nan_skipped"] == 0 and not metrics["stopped_early"]
    capsys.readouterr()
    for out, extra, message in ((tmp_path / "fresh", (), "is missing"), (tmp_path / "killed", ("--lr", "0.001"), "train.lr"),
                                (tmp_path / "killed", ("--regime", "known"), "regime")):
        assert train_main(_cli(rec, out, "--resume", *extra)) == 2
        assert message in capsys.readouterr().err
    (tmp_path / "killed" / "checkpoint.pt").write_bytes(b"")
    assert train_main(_cli(rec, tmp_path / "killed", "--resume")) == 2
    assert "empty" in capsys.readouterr().err


# --------------------------------------------------------------------------- early stopping
def test_patience_stops_once_validation_stalls_and_keeps_the_best_weights(data: rigfit.RigData, tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(ValueError, match="patience"):
        RigTrainConfig(patience=0)
    assert RigTrainConfig().schedule == "plateau" and RigTrainConfig().patience is not None  # chosen by validation
    real, seen = rigfit._loss, []
    vals = {"left": [4.0, 1.0, 2.0, 3.0, 0.5, 0.25]}  # the validation MSE of each epoch

    def scripted(model: Any, w: Any, idx: torch.Tensor | None = None) -> torch.Tensor:
        if idx is not None:
            return real(model, w, idx)
        seen.append({k: v.clone() for k, v in model.state_dict().items()})
        return torch.tensor(vals["left"].pop(0), dtype=torch.float64)

    monkeypatch.setattr(rigfit, "_loss", scripted)
    fit = _fit(data, RigTrainConfig(epochs=6, patience=2, **TINY), run_dir=tmp_path)
    assert fit.stopped_early and len(fit.history) == 4 and fit.best_epoch == 2 and fit.best_val == 1.0
    assert all(torch.equal(v, seen[1][k]) for k, v in fit.model.state_dict().items())
    again = _fit(data, RigTrainConfig(epochs=6, patience=2, **TINY), run_dir=tmp_path, resume=True)
    assert again.stopped_early and _untimed(again.history) == _untimed(fit.history)  # a stopped run stays stopped
    vals["left"] = [4.0, 1.0, 2.0, 3.0, 0.5, 0.25]
    whole = _fit(data, RigTrainConfig(epochs=6, patience=None, **TINY))  # patience None: every epoch
    assert not whole.stopped_early and len(whole.history) == 6 and whole.best_epoch == 6


def test_the_plateau_schedule_lowers_the_rates_when_validation_stalls(data: rigfit.RigData,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    real, vals = rigfit._loss, iter([4.0, 1.0, 2.0, 3.0, 0.5, 0.6, 0.7, 0.8])

    def scripted(model: Any, w: Any, idx: torch.Tensor | None = None) -> torch.Tensor:
        return real(model, w, idx) if idx is not None else torch.tensor(next(vals), dtype=torch.float64)

    monkeypatch.setattr(rigfit, "_loss", scripted)
    cfg = RigTrainConfig(epochs=8, patience=None, plateau_epochs=2, plateau_factor=0.25, **TINY)
    history = _fit(data, cfg).history
    lrs = [h["lr"] / history[0]["lr"] for h in history]
    # epochs 3-4 do not improve on epoch 2: the rates drop after epoch 4; 5 improves; 6-7 stall: drop after 7
    assert lrs == pytest.approx([1, 1, 1, 0.25, 0.25, 0.25, 0.0625, 0.0625], rel=1e-12)
    with pytest.raises(ValueError, match="schedule"):
        RigTrainConfig(schedule="step")


def test_the_cosine_schedule_decays_over_exactly_the_epochs(data: rigfit.RigData) -> None:
    fit = _fit(data, RigTrainConfig(epochs=3, schedule="cosine", patience=None, **TINY))
    assert len(fit.history) == 3 and fit.history[-1]["lr"] == pytest.approx(0.0, abs=1e-12)


def test_patience_counts_from_the_final_window_length_after_a_warm_up(data: rigfit.RigData,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    real, vals = rigfit._loss, iter([0.1, 0.1, 5.0, 6.0, 7.0, 8.0])

    def scripted(model: Any, w: Any, idx: torch.Tensor | None = None) -> torch.Tensor:
        return real(model, w, idx) if idx is not None else torch.tensor(next(vals), dtype=torch.float64)

    monkeypatch.setattr(rigfit, "_loss", scripted)
    fit = _fit(data, RigTrainConfig(epochs=6, patience=2, warmup_window_s=0.5, warmup_epochs=2, **TINY))
    assert fit.stopped_early and len(fit.history) == 5 and fit.best_epoch == 3


# --------------------------------------------------------------------------- flags
def test_an_explicit_lr_is_used_as_given_in_both_modes(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: Any) -> None:
    import phast_model.cli.train as cli
    import phast_model.train.rig_run as rigrun

    got: list[Any] = []

    def capture(*a: Any, **k: Any) -> Any:
        got.append(k.get("train", a[2] if len(a) > 2 else None))
        raise ValueError("captured")

    monkeypatch.setattr(rigrun, "train_recordings_run", capture)
    monkeypatch.setattr(cli, "train_run", capture)
    base = ["--recordings", "r.npz", "--sim", SIM, "--out", str(tmp_path / "r")]
    for extra in ([], ["--lr", "1e-3"], ["--lr", "0.05"], ["--patience", "3"], ["--batch-size", "16"]):
        assert train_main(base + extra) == 2
    assert [t.lr for t in got] == [RigTrainConfig().lr, 1e-3, 0.05, RigTrainConfig().lr, RigTrainConfig().lr]
    assert [t.patience for t in got] == [RigTrainConfig().patience] * 3 + [3, RigTrainConfig().patience]
    assert [t.batch_windows for t in got] == [RigTrainConfig().batch_windows] * 4 + [16]  # --batch-size reaches the windows
    got.clear()
    env = ["--env", "PHAST/Pendulum-v0", "--out", str(tmp_path / "e")]
    for extra in ([], ["--lr", "2e-2"]):
        assert train_main(env + extra) == 2
    assert [t.lr for t in got] == [TrainConfig().lr, 2e-2]
    assert train_main(env + ["--patience", "3"]) == 2  # --env has no early stopping: refused, not ignored
    assert "--patience and --schedule apply to --recordings" in capsys.readouterr().err
    assert cli.ENV_LR == TrainConfig().lr and cli.RECORDINGS_LR == RigTrainConfig().lr
    assert cli.ENV_DEFAULTS == {k: getattr(TrainConfig(), k) for k in cli.ENV_DEFAULTS}  # --help shows the configs' own
    assert cli.RIG_DEFAULTS == {k: getattr(RigTrainConfig(), k) for k in cli.RIG_DEFAULTS}
    with pytest.raises(SystemExit):
        cli.parse_args(["--help"])
    assert "default: 0.001 with --env, 0.02 with --recordings" in " ".join(capsys.readouterr().out.split())


def test_an_epoch_trains_on_a_draw_of_epoch_windows_whose_states_are_fitted_first(data: rigfit.RigData) -> None:
    """``epoch_windows``: each epoch's minibatches come from a fresh draw of that many training windows (the same
    draw for the same seed and epoch), and only the drawn windows' states are refitted before it."""
    model = build(rig_config(SIM, {}, "partial", data))
    cfg = RigTrainConfig(epochs=3, batch_windows=4, epoch_windows=6, **TINY)
    obj = rigfit.Shooting(model, data, cfg)
    obj.optimizer(0, None)
    st = obj.stage
    assert st is not None and st.train.q.shape[0] > 6 and st.n_batches == 2
    before = st.train.X.clone()
    obj.begin_epoch(0)
    drawn = st.drawn
    assert drawn is not None and len(drawn) == 6 and int(st.fitted.sum()) == 6
    moved = (st.train.X != before).any(-1)
    assert not moved[~st.fitted].any()  # windows not drawn keep their states
    batches = list(obj.batches(torch.Generator().manual_seed(0)))
    assert sorted(torch.cat(batches).tolist()) == drawn.tolist()
    obj.begin_epoch(1)
    assert not torch.equal(st.drawn, drawn) and int(st.fitted.sum()) > 6
    again = rigfit.Shooting(model, data, cfg)
    again.optimizer(0, None)
    again.begin_epoch(1)
    assert again.stage is not None and torch.equal(again.stage.drawn, st.drawn)
    with pytest.raises(ValueError, match="epoch_windows"):
        RigTrainConfig(epoch_windows=0)
