"""The one epoch loop (phast_model.train.loop.train_loop) and its two objectives: a fake objective shows the loop's
contract (checkpoints, exact resume, the NaN guard, early stopping, a plateau schedule), the env path (NextStep) and the
rig path (Shooting) both train through it, and the parameter groups are decided in one place."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
import torch

import phast_model.train.loop as loop
from phast_model.train.groups import param_groups
from phast_model.train.loop import LoopConfig, NanCounts, Optim, train_loop

torch.set_num_threads(1)


class Line:
    """A fake objective: least squares of y = 2 x + 1 by a torch.nn.Linear, in minibatches of 4."""

    checkpoint_format, kind = "fake-checkpoint", "a fake run"

    def __init__(self, plateau: bool = False, poison: set[int] | None = None, val: list[float] | None = None) -> None:
        torch.manual_seed(0)
        self.model = torch.nn.Linear(1, 1)
        self.x = torch.linspace(-1, 1, 16).unsqueeze(-1)
        self.y = 2 * self.x + 1
        self.plateau, self.poison, self.val = plateau, poison or set(), list(val or [])
        self.steps, self.begun, self.nan_loss_at = 0, [], 0

    def optimizer(self, epoch: int, current: Optim | None) -> Optim:
        if current is not None:
            return current
        opt = torch.optim.AdamW(param_groups(self.model, 0.05), lr=0.05)
        opt.register_step_post_hook(lambda *_: self.model.weight.data.fill_(math.nan) if self.steps in self.poison
                                    else None)  # this step leaves NaN weights
        if self.plateau:
            return Optim(opt, torch.optim.lr_scheduler.ReduceLROnPlateau(opt, factor=0.5, patience=0))
        return Optim(opt, torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=4 * 10))

    def begin_epoch(self, epoch: int) -> None:
        self.begun.append(epoch)

    def batches(self, gen: torch.Generator) -> Any:
        perm = torch.randperm(16, generator=gen)
        return [perm[i:i + 4] for i in range(0, 16, 4)]

    def loss(self, idx: torch.Tensor) -> tuple[torch.Tensor, int]:
        self.steps += 1
        loss = ((self.model(self.x[idx]) - self.y[idx]) ** 2).mean()
        return loss * math.nan if self.steps == self.nan_loss_at else loss, len(idx)

    def validation_loss(self) -> float:
        if self.val:
            return self.val.pop(0)
        with torch.no_grad():
            return float(((self.model(self.x) - self.y) ** 2).mean())

    def record(self, epoch: int, train_loss: float, val_loss: float | None, lr: float, time_s: float,
               guard: NanCounts) -> dict[str, Any]:
        return {"epoch": epoch, "train": train_loss, "val": val_loss, "lr": lr, "skipped": guard.skipped,
                "rollbacks": guard.rollbacks}

    def state(self) -> dict[str, Any]:
        return {"steps": self.steps}

    def load_state(self, saved: dict[str, Any]) -> None:
        self.steps = int(saved["steps"])


def _cfg(**kw: Any) -> LoopConfig:
    return LoopConfig(**{"epochs": 10, "progress": False, **kw})


def _run_cfg() -> Any:
    from dataclasses import make_dataclass

    return make_dataclass("FakeConfig", [("lr", float, 0.05)])()


def test_the_loop_trains_selects_and_resumes_a_fake_objective_exactly(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    whole = train_loop(Line(), _cfg(), _run_cfg())
    assert len(whole.history) == 10 and whole.history[-1]["val"] < 0.5 * whole.history[0]["val"]
    assert whole.best_epoch == min(range(10), key=lambda i: whole.history[i]["val"]) + 1
    assert not whole.model.training and whole.nan.total == 0

    real, calls = loop._epoch, {"n": 0}

    def dying(*a: Any, **k: Any) -> None:
        calls["n"] += 1
        if calls["n"] > 4:
            raise KeyboardInterrupt
        real(*a, **k)

    monkeypatch.setattr(loop, "_epoch", dying)
    with pytest.raises(KeyboardInterrupt):
        train_loop(Line(), _cfg(), _run_cfg(), tmp_path / "ck.pt")
    monkeypatch.setattr(loop, "_epoch", real)
    ck = torch.load(tmp_path / "ck.pt", weights_only=True)
    assert ck["epoch"] == 4 and ck["format"] == "fake-checkpoint" and ck["steps"] == 16  # the objective's state too
    obj = Line()
    resumed = train_loop(obj, _cfg(), _run_cfg(), tmp_path / "ck.pt", resume=True)
    assert obj.begun == list(range(4, 10)) and obj.steps == 40
    assert all(torch.equal(a, b) for a, b in zip(whole.model.state_dict().values(), resumed.model.state_dict().values()))
    assert resumed.history == whole.history
    with pytest.raises(ValueError, match="not the checkpoint of a fake run"):
        other = Line()
        other.checkpoint_format = "other"
        train_loop(other, _cfg(), _run_cfg(), tmp_path / "ck.pt", resume=True)


def test_the_nan_guard_skips_bad_minibatches_and_rolls_back_bad_steps() -> None:
    obj = Line()
    obj.nan_loss_at = 2
    res = train_loop(obj, _cfg(epochs=2), _run_cfg())
    assert res.nan.skipped == 1 and res.nan.rollbacks == 0 and res.history[0]["skipped"] == 1
    res = train_loop(Line(poison={3}), _cfg(epochs=2), _run_cfg())
    assert res.nan.rollbacks == 1 and loop.finite_params(res.model)
    ref = train_loop(Line(), _cfg(epochs=2), _run_cfg())
    assert res.history[0]["lr"] == pytest.approx(0.5 * ref.history[0]["lr"], rel=1e-12)  # halved from there on
    stopped = train_loop(Line(poison=set(range(1, 100))), _cfg(epochs=5, max_nan_events=2), _run_cfg())
    assert stopped.stopped and stopped.nan.rollbacks == 3 and len(stopped.history) == 1


def test_patience_and_the_plateau_schedule() -> None:
    res = train_loop(Line(plateau=True, val=[4.0, 1.0, 2.0, 3.0, 0.5]), _cfg(epochs=5, patience=2), _run_cfg())
    assert res.stopped and len(res.history) == 4 and res.best_epoch == 2 and res.best_val == 1.0
    assert [h["lr"] / res.history[0]["lr"] for h in res.history] == pytest.approx([1, 1, 0.5, 0.25])
    late = train_loop(Line(val=[0.1, 0.1, 5.0, 6.0, 7.0, 8.0]), _cfg(epochs=6, patience=2, select_from=2), _run_cfg())
    assert late.stopped and late.best_epoch == 3 and len(late.history) == 5  # patience counts from select_from


def test_both_trainers_run_through_the_one_loop(monkeypatch: pytest.MonkeyPatch) -> None:
    """The env path (next-step) and the rig path (multiple shooting) are objectives of the same loop function."""
    from phast_gym import make_splits
    from phast_model.train.fit import NextStep, TrainConfig, fit
    from phast_model.train.rig_fit import RigTrainConfig, Shooting, build, fit_recordings, load_rig_data, rig_config
    from phast_model.world.regimes import build_model
    from tests.train.test_rig_trainer import SIM, _pendulum_recordings

    seen: list[str] = []
    real = loop._epoch
    monkeypatch.setattr(loop, "_epoch", lambda state, obj, cfg, epoch: (seen.append(type(obj).__name__),
                                                                         real(state, obj, cfg, epoch))[1])
    splits = make_splits("PHAST/Pendulum-v0", 8, 4, 4, T=30, seed=3)
    fit(build_model("PHAST/Pendulum-v0", "partial"), splits["train"], splits["val"],
        TrainConfig(epochs=1, batch_size=8, progress=False))
    data = load_rig_data(_pendulum_recordings(n_traj=3, T=60), SIM, {}, [2])
    fit_recordings(build(rig_config(SIM, {}, "partial", data)), data, RigTrainConfig(epochs=1, window_s=1.0,
                                                                                     progress=False))
    assert seen == ["NextStep", "Shooting"] and NextStep.kind != Shooting.kind
    # everything the env path's loop has, the rig path's config sets too
    for name in ("grad_clip", "max_nan_events", "nan_lr_factor", "seed", "progress", "epochs"):
        assert hasattr(RigTrainConfig(), name) and hasattr(TrainConfig(), name)


def _old_rig_groups(model: Any, lr: float, mult: float) -> list[tuple[list[int], float]]:
    """The rig path's parameter groups before the shared helper (phast_model/train/rig_fit.py, issue 39), as a reference."""
    from phast_model.components.rigid_body import LearnedBodies

    fric = {id(p) for p in model.friction.parameters()} if model.friction is not None else set()
    fric |= {id(p) for m in model.modules() if isinstance(m, LearnedBodies) for p in m.relative_parameters()}
    out = []
    for p in model.parameters():
        if not p.requires_grad:
            continue
        p_lr = lr * mult if id(p) in fric else lr
        if id(p) not in fric and p.numel() <= 16:
            p_lr *= min(1.0, max(float(p.detach().abs().mean()), 1e-3))
        out.append(([id(p)], p_lr))
    return out


@pytest.mark.parametrize("regime", ["known", "partial", "unknown"])
def test_one_function_decides_the_parameter_groups_of_both_paths(regime: str) -> None:
    from phast_model.train.rig_fit import build, load_rig_data, rig_config
    from phast_model.world.regimes import build_model
    from tests.train.test_rig_trainer import SIM, _pendulum_recordings

    data = load_rig_data(_pendulum_recordings(n_traj=3, T=60), SIM, {}, [2])
    rig = build(rig_config(SIM, {}, regime, data))
    got = [([id(p) for p in g["params"]], g["lr"]) for g in param_groups(rig, 2e-2, 5.0)]
    assert got == _old_rig_groups(rig, 2e-2, 5.0)  # the same groups and learning rates, bit for bit
    env = build_model("PHAST/Pendulum-v0", regime)
    assert [([id(p) for p in g["params"]], g["lr"]) for g in param_groups(env, 1e-3)] == \
        [([id(p) for p in g["params"]], g["lr"]) for g in env.param_groups(1e-3)]
