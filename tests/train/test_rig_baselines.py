"""The grid's sequence baselines on a rig's recordings (phast_model.baselines.rig, ``phast-train --recordings --model
NAME``): windows that keep validation apart, the held-out score on PHAST's windows beside the nominal rig, the
learning-rate sweep, DHNN's velocity estimate and the command line's errors."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from phast_model.baselines.rig import (
    BaselineConfig,
    WithVelocity,
    cut_seq_windows,
    model_names,
    prepare_baseline,
    sweep_lr,
    train_baseline,
    train_baseline_run,
)
from phast_model.bench.reality import make_reality
from phast_model.cli import train as cli
from phast_model.identify.recordings import Recordings
from phast_model.train.config import TrainConfig
from phast_model.train.rig_fit import build, load_rig_data, nominal_config, rig_config
from phast_model.train.rig_heldout import heldout_rollouts
from phast_model.train.rig_run import RecordingsSpec

SIM = "PHAST/DampedPendulum-v0"


@pytest.fixture(scope="module")
def recordings() -> dict:
    """A damped pendulum driven by smooth torques: 6 recordings of 4 s at 20 ms."""
    torch.set_num_threads(1)
    return make_reality(SIM, n_traj=6, T=200, noise_std=0.002, seed=1, u_std=1.5)


@pytest.fixture(scope="module")
def npz(recordings: dict, tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "rec.npz"
    np.savez(path, **recordings)
    return path


def _cli(npz: Path, out: Path, *extra: str) -> int:
    return cli.main(["--recordings", str(npz), "--sim", SIM, "--holdout-trajectories", "4,5", "--rollout-window-s",
                     "1", "--out", str(out), "--no-progress", *extra])


def test_a_baseline_is_scored_on_phasts_heldout_windows_beside_the_nominal_rig(npz: Path, recordings: dict,
                                                                              tmp_path: Path) -> None:
    assert _cli(npz, tmp_path / "gru", "--model", "gru", "--epochs", "2") == 0
    run = tmp_path / "gru"
    for name in ("config.json", "metrics.json", "history.json", "checkpoint.pt", "baseline_model.pt",
                 "heldout_rollout.png"):
        assert (run / name).exists(), name
    metrics = json.loads((run / "metrics.json").read_text())
    held = metrics["heldout"]
    assert math.isfinite(held["gru"]["rollout_rmse"]) and math.isfinite(held["nominal"]["rollout_rmse"])
    assert len(held["gru"]["per_window_rmse"]) == len(held["nominal"]["per_window_rmse"]) == held["n_windows"] > 0
    assert held["gru_over_nominal"] == pytest.approx(held["gru"]["rollout_rmse"] / held["nominal"]["rollout_rmse"])
    assert metrics["lr"] == TrainConfig().lr and metrics["lr_sweep"] is None
    assert len(json.loads((run / "history.json").read_text())) == metrics["epochs_run"] == 2
    # the nominal rig is scored as PHAST's run scores it: the same windows, the same number
    data = load_rig_data(recordings, SIM, {}, [4, 5])
    nominal = build(nominal_config(rig_config(SIM, {}, "partial", data, action_bound=[1.0])))
    direct, _, _ = heldout_rollouts({"nominal": nominal}, data.heldout, 1.0)
    assert held["nominal"]["rollout_rmse"] == pytest.approx(direct["nominal"]["rollout_rmse"], rel=1e-9)
    assert held["n_windows"] == direct["n_windows"] and held["burn_in_samples"] == direct["burn_in_samples"]
    state = torch.load(run / "baseline_model.pt", weights_only=True)
    assert isinstance(state, dict) and state


def test_validation_blocks_never_reach_a_training_window() -> None:
    T, N = 100, 3
    q = (np.arange(N)[:, None] * 1000 + np.arange(T)[None, :]).astype(float)[..., None]  # each sample its own value
    rec = Recordings(q, 0.01, None, (), "ramps")
    w = cut_seq_windows(rec, 20, BaselineConfig("gru", val_fraction=0.2, n_windows=40), seed=0)
    seen_val = set(w.val.q[..., 0].ravel().tolist())
    seen_train = set(w.train.q[..., 0].ravel().tolist())
    assert w.val.q.shape == (3, 20, 1) and not seen_val & seen_train
    assert w.stride >= 2 and w.train.q.shape[0] >= 40  # overlapping training windows, as many as asked for


def test_the_sweep_picks_the_lowest_validation_loss_and_the_run_records_it(recordings: dict, tmp_path: Path) -> None:
    spec = RecordingsSpec(recordings, SIM, {}, "partial", (4, 5), 1.0)
    cfg = BaselineConfig("dhnn", TrainConfig(epochs=1, progress=False, batch_size=16), model_kw={"hidden": 16})
    data = prepare_baseline(spec, cfg)
    assert data.windows.train.q.shape[-1] == 2  # (q, qdot): the velocity from smoothing the measured q
    sweep = sweep_lr(cfg, data, (1e-4, 1e-2), epochs=1)
    assert sweep.chosen == sweep.lrs[int(np.argmin(sweep.val_loss))] and all(map(math.isfinite, sweep.val_loss))
    metrics = train_baseline_run(spec, tmp_path / "dhnn", cfg, plots=False, sweep=(1e-4, 1e-2))
    assert metrics["lr"] == metrics["lr_sweep"]["chosen"] and list(metrics["lr_sweep"]["lrs"]) == [1e-4, 1e-2]
    assert math.isfinite(metrics["heldout"]["dhnn"]["rollout_rmse"])
    scored = WithVelocity(train_baseline(cfg, data).model, data.train.dt)
    roll = scored.rollout(torch.as_tensor(data.heldout.q[:, :10], dtype=torch.float32), None, 5)
    assert roll.shape == (2, 5, 1)  # scored on positions only


@pytest.mark.parametrize(("extra", "message"), [
    (["--model", "gpt"], "unknown --model 'gpt'; one of phast, gru, lstm"),
    (["--model", "gru", "--patience", "3"], "--patience apply to PHAST's recordings trainer"),
    (["--model", "gru", "--lr", "1e-3", "--lr-sweep", "1e-3,3e-3"], "either --lr or --lr-sweep"),
    (["--model", "gru", "--lr-sweep", "fast"], "--lr-sweep expects comma-separated numbers"),
    (["--lr-sweep", "1e-3"], "--lr-sweep and --step-s apply to a baseline --model"),
])
def test_bad_model_flags_are_clear_errors(npz: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          extra: list[str], message: str) -> None:
    assert _cli(npz, tmp_path / "run", *extra) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "run" / "metrics.json").exists()


def test_a_baseline_on_an_env_points_to_the_grid(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["--env", "PHAST/Pendulum-v0", "--model", "lstm", "--out", str(tmp_path / "x")]) == 2
    assert "phast-bench --envs PHAST/Pendulum-v0 --models lstm" in capsys.readouterr().err


def test_the_command_line_lists_every_baseline_of_the_grid() -> None:
    assert cli.MODELS == model_names()


class _ConstantVelocity(torch.nn.Module):
    """A stand-in model: q continues at the warm-up's last velocity (checks the coarse step's bookkeeping)."""

    n, m, angle_dims = 1, 0, (0,)

    def rollout(self, q_burn: torch.Tensor, u: torch.Tensor | None, H: int) -> torch.Tensor:
        from phast_model.world.interfaces import wrap_angles

        v = wrap_angles(q_burn[:, -1] - q_burn[:, -2], (0,))
        return q_burn[:, -1:] + v[:, None] * torch.arange(1, H + 1, dtype=q_burn.dtype)[None, :, None]


@pytest.mark.parametrize("k", [1, 3, 5])
def test_a_coarser_step_is_scored_on_every_recorded_sample(k: int) -> None:
    from phast_model.baselines.rig import Coarse
    from phast_model.world.interfaces import wrap_angles

    ramp = 0.4 * torch.arange(40, dtype=torch.float64)[None, :, None] - 3.0  # crosses +-pi several times
    q = wrap_angles(ramp, (0,))
    out = Coarse(_ConstantVelocity(), k).rollout(q[:, :11], None, 23)  # type: ignore[arg-type]
    assert torch.allclose(wrap_angles(out - ramp[:, 11:34], (0,)), torch.zeros(1, 23, 1, dtype=torch.float64),
                          atol=1e-9)
