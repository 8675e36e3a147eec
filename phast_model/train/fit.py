"""The env path's trainer for any :class:`~phast_model.world.interfaces.ForecastModel` (PHAST and baselines).

Teacher-forced next-step loss over whole trajectories at once (paper Eq. 85, wrapped on angles; the objective
:class:`NextStep`), trained by the shared epoch loop :func:`phast_model.train.loop.train_loop`: AdamW + cosine
schedule (optional linear warm-up), batches of trajectories, validation every ``val_every`` epochs and at the end,
best-validation selection, resumable checkpoints with optimizer, scheduler and RNG state, and the NaN guard (a
non-finite minibatch skipped, a step leaving non-finite weights rolled back with a lower learning rate).  Models may
add losses through an optional ``model.extra_losses(q, u, pred) -> dict[str, Tensor]`` hook (PHAST: Eq. 86-88).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..world.interfaces import DataInitModel, ForecastModel, LossForwardModel, Trajectories, coordinate_error
from .config import TrainConfig
from .groups import param_groups
from .loop import (
    CHECKPOINT,
    LoopConfig,
    NanCounts,
    Optim,
    check_resume,
    finite_params,
    load_checkpoint,
    run_identity,
    scale_lr,
    train_loop,
)

__all__ = ["CHECKPOINT", "FitResult", "NextStep", "TrainConfig", "check_resume", "finite_params", "fit",
           "load_checkpoint", "next_step_loss", "run_identity", "scale_lr", "validation_loss"]

#: the ``format`` entry of an env run's checkpoint.pt
CHECKPOINT_FORMAT = "phast-checkpoint"


@dataclass
class FitResult:
    """Outcome of :func:`fit`: the best-validation model and the training record (``nan_events``: minibatches the
    NaN guard skipped plus steps it rolled back)."""

    model: ForecastModel
    history: list[dict[str, Any]] = field(default_factory=list)
    wall_time_s: float = 0.0
    best_val: float = math.inf
    best_epoch: int = -1
    nan_events: int = 0
    stopped_early: bool = False


def _tensors(ds: Trajectories, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Dataset -> (q (N, T, n), u (N, T-1, m) or None)."""
    q = torch.as_tensor(np.asarray(ds.q), dtype=dtype)
    u = getattr(ds, "u", None)
    u = None if u is None or np.size(u) == 0 else torch.as_tensor(np.asarray(u), dtype=dtype)
    if q.ndim != 3:
        raise ValueError(f"dataset q must be (N, T, n), got shape {tuple(q.shape)}")
    if not torch.isfinite(q).all():
        raise ValueError("dataset q contains NaN/inf")
    return q, u


def next_step_loss(model: ForecastModel, q: torch.Tensor, u: torch.Tensor | None,
                   skip_first: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """(L_data, predictions): mean squared next-step error, wrapped on angles (Eq. 85), of the model's
    ``loss_forward`` when it has one (PHAST: from its training velocity estimate, ``PHASTConfig.train_velocity``),
    else of its teacher-forced ``forward``.

    ``skip_first`` leaves out predictions made from fewer than ``skip_first + 1`` samples (a q-only model
    cannot know the velocity at t = 0; fitting those steps only biases the dynamics)."""
    pred = model.loss_forward(q, u) if isinstance(model, LossForwardModel) else model(q, u)
    s = min(int(skip_first), q.shape[1] - 2)
    err = coordinate_error(pred[:, s:-1], q[:, s + 1:], model.angle_dims)
    return (err * err).mean(), pred


@torch.no_grad()
def validation_loss(model: ForecastModel, q: torch.Tensor, u: torch.Tensor | None, batch_size: int = 256,
                    skip_first: int = 0) -> float:
    """Teacher-forced next-step MSE over a whole split (the selection criterion)."""
    was = model.training
    model.eval()
    tot, cnt = 0.0, 0
    for i in range(0, q.shape[0], batch_size):
        qb = q[i:i + batch_size]
        loss, _ = next_step_loss(model, qb, None if u is None else u[i:i + batch_size], skip_first)
        tot += float(loss) * qb.shape[0]
        cnt += qb.shape[0]
    model.train(was)
    return tot / max(cnt, 1)


class _warmup_cosine:
    """lr factor: linear warm-up from 1/(n_warm + 1) over ``n_warm`` steps, then cosine decay to 0 at ``n_total``
    (a picklable callable, so the scheduler state stays checkpointable)."""

    def __init__(self, n_warm: int, n_total: int) -> None:
        self.n_warm, self.n_total = int(n_warm), max(int(n_total), 1)

    def __call__(self, step: int) -> float:
        if step < self.n_warm:
            return (step + 1) / (self.n_warm + 1)
        return 0.5 * (1.0 + math.cos(math.pi * min(step, self.n_total) / self.n_total))


def _check_schedule_settings(warm: float, eps: float) -> None:
    """ValueError unless the warm-up length (epochs) is >= 0 and AdamW's eps is positive, both finite."""
    if warm < 0 or not math.isfinite(warm):
        raise ValueError(f"warmup_epochs must be >= 0 and finite, got {warm!r}")
    if not (eps > 0 and math.isfinite(eps)):
        raise ValueError(f"adam_eps must be positive and finite, got {eps!r}")


def _scheduler(opt: torch.optim.Optimizer, warm: float, n_batches: int,
               epochs: int) -> torch.optim.lr_scheduler.LRScheduler:
    """Per-batch cosine decay to 0 over ``epochs``, after a linear warm-up over ``warm`` epochs when positive."""
    if warm > 0:
        return torch.optim.lr_scheduler.LambdaLR(opt, _warmup_cosine(round(warm * n_batches), epochs * n_batches))
    return torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs * n_batches)


class NextStep:
    """The env path's objective: the weighted next-step loss L_data plus the model's ``extra_losses`` over
    minibatches of whole trajectories; validation by the teacher-forced next-step MSE of the validation split."""

    checkpoint_format, kind = CHECKPOINT_FORMAT, "an --env run"

    def __init__(self, model: ForecastModel, train: Trajectories, val: Trajectories, cfg: TrainConfig,
                 dtype: torch.dtype) -> None:
        self.model, self.cfg = model, cfg
        self.q, self.u = _tensors(train, dtype)
        self.q_val, self.u_val = _tensors(val, dtype)
        if self.q.shape[-1] != model.n:
            raise ValueError(f"model has n={model.n} coordinates, training data has {self.q.shape[-1]}")
        self.skip = int(cfg.skip_first if cfg.skip_first is not None else getattr(model, "loss_skip", 0))
        self.n_batches = math.ceil(self.q.shape[0] / cfg.batch_size)

    def optimizer(self, epoch: int, current: Optim | None) -> Optim:
        """One AdamW (eps ``adam_eps``, default 1e-8) with its per-batch cosine decay (after ``warmup_epochs`` of
        linear warm-up, default none) for the whole run."""
        if current is not None:
            return current
        cfg = self.cfg
        warm = 0.0 if cfg.warmup_epochs is None else float(cfg.warmup_epochs)
        eps = 1e-8 if cfg.adam_eps is None else float(cfg.adam_eps)
        _check_schedule_settings(warm, eps)
        opt = torch.optim.AdamW(param_groups(self.model, cfg.lr), lr=cfg.lr, weight_decay=cfg.weight_decay, eps=eps)
        return Optim(opt, _scheduler(opt, warm, self.n_batches, cfg.epochs))

    def begin_epoch(self, epoch: int) -> None:
        return None

    def batches(self, gen: torch.Generator) -> Iterator[tuple[torch.Tensor, torch.Tensor | None]]:
        perm = torch.randperm(self.q.shape[0], generator=gen)
        bs = self.cfg.batch_size
        for b in range(self.n_batches):
            idx = perm[b * bs:(b + 1) * bs]
            yield self.q[idx], None if self.u is None else self.u[idx]

    def loss(self, batch: tuple[torch.Tensor, torch.Tensor | None]) -> tuple[torch.Tensor, int]:
        """Weighted L_data plus the model's ``extra_losses`` (if it has the hook)."""
        qb, ub = batch
        loss, pred = next_step_loss(self.model, qb, ub, self.skip)
        loss = self.cfg.lambda_data * loss
        hook = getattr(self.model, "extra_losses", None)
        if hook is not None:
            for v in hook(qb, ub, pred).values():
                loss = loss + v
        return loss, qb.shape[0]

    def validation_loss(self) -> float:
        return validation_loss(self.model, self.q_val, self.u_val, self.cfg.val_batch_size, self.skip)

    def record(self, epoch: int, train_loss: float, val_loss: float | None, lr: float, time_s: float,
               guard: NanCounts) -> dict[str, float]:
        rec: dict[str, float] = {"epoch": epoch, "train_loss": train_loss, "lr": lr, "time_s": time_s,
                               "nan_events": guard.total}
        if val_loss is not None:
            rec["val_loss"] = val_loss
        return rec

    def state(self) -> dict[str, object]:
        return {}

    def load_state(self, saved: Mapping[str, object]) -> None:
        return None


def loop_config(cfg: TrainConfig, desc: str = "fit") -> LoopConfig:
    """The shared loop's settings of a :class:`TrainConfig` (no early stopping: the best validation of ``epochs``)."""
    return LoopConfig(epochs=cfg.epochs, seed=cfg.seed, grad_clip=cfg.grad_clip, max_nan_events=cfg.max_nan_events,
                      nan_lr_factor=cfg.nan_lr_factor, val_every=cfg.val_every, checkpoint_every=cfg.checkpoint_every,
                      progress=cfg.progress, desc=desc)


def fit(model: ForecastModel, train: Trajectories, val: Trajectories, cfg: TrainConfig | None = None,
        run_dir: str | Path | None = None, resume: bool = False,
        identity: Mapping[str, object] | None = None) -> FitResult:
    """Train ``model`` on ``train`` (a :class:`phast_gym.datasets.Dataset` or anything with ``q``/``u``),
    select on ``val``; returns a :class:`FitResult` whose ``.model`` holds the best-validation weights.

    ``cfg`` is used as given (a regime's trainer settings come from :func:`phast_model.world.regimes.recipe`).  With
    ``run_dir``, ``checkpoint.pt`` is written atomically after every ``checkpoint_every`` epochs and ``resume=True``
    continues from it when it exists (model, optimizer, scheduler, RNG, history, best state).  The checkpoint
    records the run's identity (the training config and ``identity``: env, regime, data ...); resuming a checkpoint
    of another run is a ValueError naming the differing field (:func:`check_resume`)."""
    cfg = cfg or TrainConfig()
    dtype = torch.float32 if cfg.dtype == "float32" else torch.float64
    model = model.to(dtype)
    obj = NextStep(model, train, val, cfg, dtype)
    ckpt_path = Path(run_dir) / CHECKPOINT if run_dir is not None else None
    resuming = resume and ckpt_path is not None and ckpt_path.exists()
    if not resuming and isinstance(model, DataInitModel):  # least-squares start of the learned physics
        model.initialize_from_data(obj.q, obj.u)
    res = train_loop(obj, loop_config(cfg, f"fit {type(model).__name__}"), cfg, ckpt_path, resuming, identity)
    return FitResult(model=model, history=res.history, wall_time_s=res.wall_time_s, best_val=res.best_val,
                     best_epoch=res.best_epoch, nan_events=res.nan.total, stopped_early=res.stopped)
