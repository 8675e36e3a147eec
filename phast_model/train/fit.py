"""Generic trainer for any :class:`~phast_model.world.interfaces.ForecastModel` (PHAST and baselines).

Teacher-forced next-step loss over whole trajectories at once (paper Eq. 85, wrapped on
angles), AdamW + cosine schedule (optional linear warm-up; eps and warm-up may default from the
model's ``train_defaults``), batches of trajectories, validation every ``val_every``
epochs and at the end, best-validation selection, resumable checkpoints with optimizer,
scheduler and RNG state, and a NaN/inf guard that rolls back to the last good state and
lowers the learning rate instead of saving garbage.  Models may add losses through an
optional ``model.extra_losses(q, u, pred) -> dict[str, Tensor]`` hook (PHAST: Eq. 86-88).
"""

from __future__ import annotations

import copy
import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from tqdm.auto import tqdm

from ..world.interfaces import DataInitModel, ForecastModel, ParamGroupsModel, coordinate_error
from .checkpoint import atomic_torch_save, first_difference

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

CHECKPOINT = "checkpoint.pt"


@dataclass
class TrainConfig:
    """Training hyper-parameters (paper Appendix E, Table 13 defaults)."""

    epochs: int = 50
    batch_size: int = 64
    lr: float = 1e-3
    weight_decay: float = 1e-5
    val_every: int = 10
    seed: int = 0
    progress: bool = True
    lambda_data: float = 1.0  # weight of L_data (Eq. 85); PHAST's other weights live in its config
    skip_first: int | None = None  # predictions t < skip_first left out of the loss (None: model.loss_skip or 0)
    grad_clip: float | None = 10.0  # max grad norm (None: off)
    warmup_epochs: float | None = None  # linear lr warm-up before the cosine decay (None: model default, else 0)
    adam_eps: float | None = None  # AdamW eps (None: model default, else 1e-8); see resolved()
    max_nan_events: int = 5  # rollbacks allowed before training stops
    nan_lr_factor: float = 0.5  # lr multiplier after a rollback
    checkpoint_every: int = 1  # epochs between checkpoint writes (run_dir given)
    val_batch_size: int = 256
    dtype: str = "float32"

    def __post_init__(self) -> None:
        for name in ("epochs", "batch_size", "val_every", "checkpoint_every", "val_batch_size"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"TrainConfig.{name} must be a positive integer, got {v!r}")
        if not (self.lr > 0 and math.isfinite(self.lr)):
            raise ValueError(f"TrainConfig.lr must be positive and finite, got {self.lr!r}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"TrainConfig.dtype must be float32 or float64, got {self.dtype!r}")


@dataclass
class FitResult:
    """Outcome of :func:`fit`: the best-validation model and the training record."""

    model: ForecastModel
    history: list[dict[str, Any]] = field(default_factory=list)
    wall_time_s: float = 0.0
    best_val: float = math.inf
    best_epoch: int = -1
    nan_events: int = 0
    stopped_early: bool = False


def _tensors(ds: Any, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor | None]:
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
    """(L_data, predictions): mean squared next-step error, wrapped on angles (Eq. 85).

    ``skip_first`` leaves out predictions made from fewer than ``skip_first + 1`` samples (a q-only model
    cannot know the velocity at t = 0; fitting those steps only biases the dynamics)."""
    pred = model(q, u)
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


def _resolved(cfg: TrainConfig, model: Any, name: str, default: float) -> float:
    """A TrainConfig value, else the model's own default (``model.train_defaults[name]``, set e.g. by
    :func:`phast_model.world.regimes.build_model` for KNOWN), else ``default``."""
    v = getattr(cfg, name)
    if v is None:
        v = getattr(model, "train_defaults", {}).get(name, default)
    return float(v)


class _warmup_cosine:
    """lr factor: linear warm-up from 1/(n_warm + 1) over ``n_warm`` steps, then cosine decay to 0 at ``n_total``
    (a picklable callable, so the scheduler state stays checkpointable)."""

    def __init__(self, n_warm: int, n_total: int) -> None:
        self.n_warm, self.n_total = int(n_warm), max(int(n_total), 1)

    def __call__(self, step: int) -> float:
        if step < self.n_warm:
            return (step + 1) / (self.n_warm + 1)
        return 0.5 * (1.0 + math.cos(math.pi * min(step, self.n_total) / self.n_total))


def finite_params(model: torch.nn.Module) -> bool:
    """True when every parameter of ``model`` is finite (the NaN guard's check after a step or an epoch)."""
    return all(bool(torch.isfinite(p).all()) for p in model.parameters())


#: training-config fields that do not change what a run computes (a resume may change them)
_NOT_IDENTITY = ("progress",)


def _canonical(obj: Any) -> Any:
    return json.loads(json.dumps(obj, sort_keys=True, default=str))


def run_identity(cfg: DataclassInstance, identity: dict[str, Any] | None = None) -> dict[str, Any]:
    """What a checkpoint must match to be resumed: the training config (a :class:`TrainConfig`, or the rig path's
    :class:`phast_model.rig.fit.RigTrainConfig`; all its fields but ``progress``) and the caller's
    ``identity`` (env, regime, data, model overrides ...), as canonical JSON values."""
    train = {k: v for k, v in asdict(cfg).items() if k not in _NOT_IDENTITY}
    return _canonical({"train": train, **(identity or {})})


def check_resume(ckpt_path: str | Path, cfg: DataclassInstance, identity: dict[str, Any] | None = None,
                 ck: dict[str, Any] | None = None) -> None:
    """ValueError naming the first differing field when ``ckpt_path`` was written by another run (env, regime,
    data, training config ...); nothing to check when it does not exist.  Cheap enough to call before any work."""
    ckpt_path = Path(ckpt_path)
    if ck is None:
        if not ckpt_path.exists():
            return
        ck = load_checkpoint(ckpt_path)
    stored = ck.get("identity")
    if not isinstance(stored, str):
        raise ValueError(f"cannot resume from {ckpt_path}: it records no run identity (written by an older phast), so "
                         "it cannot be checked against this run; remove it to start over")
    diff = first_difference(json.loads(stored), run_identity(cfg, identity))
    if diff is not None:
        field_, old, new = diff
        raise ValueError(f"cannot resume from {ckpt_path}: it was written for {field_}={old!r}, this run asks for "
                         f"{field_}={new!r}; use another output directory or the original settings")


def load_checkpoint(ckpt_path: Path) -> dict[str, Any]:
    """The checkpoint at ``ckpt_path`` (``weights_only=True``) as a dict, or ValueError naming the problem."""
    from .checkpoint import torch_load

    try:
        ck = torch_load(ckpt_path)
    except ValueError as exc:
        raise ValueError(f"cannot resume: {exc}; remove it to start over") from None
    if not isinstance(ck, dict):
        raise ValueError(f"cannot resume from {ckpt_path}: not a training checkpoint")
    return ck


@dataclass
class _Split:
    """One split as tensors: q (N, T, n) and u (N, T-1, m) or None."""

    q: torch.Tensor
    u: torch.Tensor | None


@dataclass
class _Data:
    """What :func:`fit` trains and selects on: both splits as tensors, the leading predictions the loss leaves out
    and the number of batches per epoch."""

    train: _Split
    val: _Split
    skip: int
    n_batches: int


@dataclass
class _TrainState:
    """Everything a run carries from epoch to epoch; the checkpoint stores it and a resume restores it."""

    model: ForecastModel
    opt: torch.optim.Optimizer
    sched: torch.optim.lr_scheduler.LRScheduler
    gen: torch.Generator
    best_state: dict[str, Any]
    history: list[dict[str, Any]] = field(default_factory=list)
    best_val: float = math.inf
    best_epoch: int = -1
    start_epoch: int = 0
    nan_events: int = 0
    elapsed0: float = 0.0  # seconds trained before this call (a resume)
    t0: float = 0.0  # perf_counter origin of the run's clock (elapsed0 included)
    stopped: bool = False


def _data(model: ForecastModel, train: Any, val: Any, cfg: TrainConfig, dtype: torch.dtype) -> _Data:
    """Both splits as ``dtype`` tensors, checked against the model's coordinate count."""
    q_tr, u_tr = _tensors(train, dtype)
    q_va, u_va = _tensors(val, dtype)
    if q_tr.shape[-1] != model.n:
        raise ValueError(f"model has n={model.n} coordinates, training data has {q_tr.shape[-1]}")
    skip = int(cfg.skip_first if cfg.skip_first is not None else getattr(model, "loss_skip", 0))
    return _Data(_Split(q_tr, u_tr), _Split(q_va, u_va), skip, math.ceil(q_tr.shape[0] / cfg.batch_size))


def _param_groups(model: ForecastModel, lr: float) -> list[dict[str, Any]]:
    """The model's own optimizer groups (``model.param_groups``), else one group of its trainable parameters."""
    if isinstance(model, ParamGroupsModel):
        return model.param_groups(lr)
    return [{"params": [p for p in model.parameters() if p.requires_grad], "lr": lr}]


def _check_schedule_settings(warm: float, eps: float) -> None:
    """ValueError unless the resolved warm-up length (epochs) is >= 0 and AdamW's eps is positive, both finite."""
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


def _new_state(model: ForecastModel, cfg: TrainConfig, n_batches: int) -> _TrainState:
    """Where a run starts: seeded RNGs (global and batch order), a fresh AdamW and schedule, no record yet."""
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    groups = _param_groups(model, cfg.lr)
    warm, eps = _resolved(cfg, model, "warmup_epochs", 0.0), _resolved(cfg, model, "adam_eps", 1e-8)
    _check_schedule_settings(warm, eps)
    opt = torch.optim.AdamW(groups, lr=cfg.lr, weight_decay=cfg.weight_decay, eps=eps)
    sched = _scheduler(opt, warm, n_batches, cfg.epochs)
    return _TrainState(model, opt, sched, gen, best_state=copy.deepcopy(model.state_dict()))


def _restore(state: _TrainState, ckpt_path: Path, cfg: TrainConfig, identity: dict[str, Any] | None) -> None:
    """Continue ``state`` from the checkpoint at ``ckpt_path`` (checked to belong to this run)."""
    ck = load_checkpoint(ckpt_path)
    check_resume(ckpt_path, cfg, identity, ck)
    try:
        state.model.load_state_dict(ck["model"])
        state.opt.load_state_dict(ck["optimizer"])
        state.sched.load_state_dict(ck["scheduler"])
    except Exception as exc:  # noqa: BLE001 - any failure means an unusable checkpoint
        raise ValueError(f"cannot resume from {ckpt_path}: {type(exc).__name__}: {exc}") from None
    state.gen.set_state(ck["gen_state"])
    torch.set_rng_state(ck["torch_rng"])
    state.history = json.loads(ck["history"])
    state.best_val, state.best_epoch, state.best_state = float(ck["best_val"]), int(ck["best_epoch"]), ck["best_state"]
    state.start_epoch, state.nan_events, state.elapsed0 = int(ck["epoch"]), int(ck["nan_events"]), float(ck["elapsed"])


def _save_checkpoint(state: _TrainState, ckpt_path: Path | None, cfg: TrainConfig, identity: dict[str, Any] | None,
                     epoch: int, elapsed: float) -> None:
    """Write ``checkpoint.pt`` atomically (nothing without a run directory): what :func:`_restore` reads back."""
    if ckpt_path is None:
        return
    atomic_torch_save({
        "model": state.model.state_dict(), "optimizer": state.opt.state_dict(), "scheduler": state.sched.state_dict(),
        "gen_state": state.gen.get_state(), "torch_rng": torch.get_rng_state(), "history": json.dumps(state.history),
        "best_val": state.best_val, "best_epoch": state.best_epoch, "best_state": state.best_state, "epoch": epoch,
        "nan_events": state.nan_events, "elapsed": elapsed, "train_config": asdict(cfg),
        "identity": json.dumps(run_identity(cfg, identity), sort_keys=True),
    }, ckpt_path)


def _batch_loss(model: ForecastModel, qb: torch.Tensor, ub: torch.Tensor | None, cfg: TrainConfig,
                skip: int) -> torch.Tensor:
    """Weighted L_data plus the model's ``extra_losses`` (if it has the hook)."""
    loss, pred = next_step_loss(model, qb, ub, skip)
    loss = cfg.lambda_data * loss
    hook = getattr(model, "extra_losses", None)
    if hook is not None:
        for v in hook(qb, ub, pred).values():
            loss = loss + v
    return loss


def _optimizer_step(state: _TrainState, loss: torch.Tensor, grad_clip: float | None) -> bool:
    """Backward, clip and step; False (stopping there) as soon as the loss, the gradient norm or the updated
    parameters are not finite."""
    state.opt.zero_grad(set_to_none=True)
    if not bool(torch.isfinite(loss)):
        return False
    loss.backward()
    gnorm = torch.nn.utils.clip_grad_norm_(state.model.parameters(), grad_clip if grad_clip else math.inf)
    if not bool(torch.isfinite(gnorm)):
        return False
    state.opt.step()
    return finite_params(state.model)


def _roll_back(state: _TrainState, good_model: dict[str, Any], good_opt: dict[str, Any], lr_factor: float) -> None:
    """After a non-finite step: count it, restore the epoch-start model and optimizer, lower the lr (now and in
    the schedule)."""
    state.nan_events += 1
    state.model.load_state_dict(good_model)
    state.opt.load_state_dict(good_opt)
    scale_lr(state.opt, state.sched, lr_factor)


def scale_lr(opt: torch.optim.Optimizer, sched: torch.optim.lr_scheduler.LRScheduler, factor: float) -> None:
    """Multiply every group's learning rate by ``factor``, now and in the schedule's base rates."""
    for g in opt.param_groups:
        g["lr"] *= factor
    sched.base_lrs = [lr * factor for lr in sched.base_lrs]


def _train_epoch(state: _TrainState, data: _Data, cfg: TrainConfig) -> float:
    """One pass over shuffled batches with the NaN guard; the mean training loss of the good batches.  Sets
    ``state.stopped`` when the rollbacks exceed ``cfg.max_nan_events``."""
    good_model = copy.deepcopy(state.model.state_dict())
    good_opt = copy.deepcopy(state.opt.state_dict())
    perm = torch.randperm(data.train.q.shape[0], generator=state.gen)
    tot, cnt = 0.0, 0
    for b in range(data.n_batches):
        idx = perm[b * cfg.batch_size:(b + 1) * cfg.batch_size]
        qb = data.train.q[idx]
        ub = None if data.train.u is None else data.train.u[idx]
        loss = _batch_loss(state.model, qb, ub, cfg, data.skip)
        if not _optimizer_step(state, loss, cfg.grad_clip):  # roll back to the start of the epoch, lower the lr
            _roll_back(state, good_model, good_opt, cfg.nan_lr_factor)
            if state.nan_events > cfg.max_nan_events:
                state.stopped = True
                break
            continue
        state.sched.step()
        tot += float(loss.detach()) * qb.shape[0]
        cnt += qb.shape[0]
    return tot / max(cnt, 1)


def _validate_and_select(state: _TrainState, data: _Data, cfg: TrainConfig, epoch: int) -> float:
    """Validation loss of the current weights; they become the best state when finite and lower than the best."""
    vl = validation_loss(state.model, data.val.q, data.val.u, cfg.val_batch_size, data.skip)
    if math.isfinite(vl) and vl < state.best_val:
        state.best_val, state.best_epoch, state.best_state = vl, epoch, copy.deepcopy(state.model.state_dict())
    return vl


def _run_epochs(state: _TrainState, data: _Data, cfg: TrainConfig, ckpt_path: Path | None,
                identity: dict[str, Any] | None) -> None:
    """Epochs ``state.start_epoch`` .. ``cfg.epochs``: train, record, validate when due, checkpoint when due."""
    bar = tqdm(range(state.start_epoch, cfg.epochs), desc=f"fit {type(state.model).__name__}",
               disable=not cfg.progress, initial=state.start_epoch, total=cfg.epochs)
    state.model.train()
    for epoch in bar:
        train_loss = _train_epoch(state, data, cfg)
        rec: dict[str, Any] = {"epoch": epoch + 1, "train_loss": train_loss, "lr": state.opt.param_groups[0]["lr"],
                               "time_s": time.perf_counter() - state.t0, "nan_events": state.nan_events}
        if state.stopped:
            state.history.append(rec)
            break
        if (epoch + 1) % cfg.val_every == 0 or epoch + 1 == cfg.epochs:
            rec["val_loss"] = _validate_and_select(state, data, cfg, epoch + 1)
        state.history.append(rec)
        # the best validation loss so far, once there is one (validation runs every cfg.val_every epochs)
        best = {"best_val": f"{state.best_val:.3g}"} if math.isfinite(state.best_val) else {}
        bar.set_postfix(loss=f"{rec['train_loss']:.3g}", **best)
        if (epoch + 1) % cfg.checkpoint_every == 0 or epoch + 1 == cfg.epochs:
            _save_checkpoint(state, ckpt_path, cfg, identity, epoch + 1, time.perf_counter() - state.t0)
    bar.close()


def fit(model: ForecastModel, train: Any, val: Any, cfg: TrainConfig | None = None,
        run_dir: str | Path | None = None, resume: bool = False, identity: dict[str, Any] | None = None) -> FitResult:
    """Train ``model`` on ``train`` (a :class:`phast_gym.datasets.Dataset` or anything with ``q``/``u``),
    select on ``val``; returns a :class:`FitResult` whose ``.model`` holds the best-validation weights.

    With ``run_dir``, ``checkpoint.pt`` is written atomically after every ``checkpoint_every`` epochs
    and ``resume=True`` continues from it (model, optimizer, scheduler, RNG, history, best state).  The checkpoint
    records the run's identity (the training config and ``identity``: env, regime, data ...); resuming a checkpoint
    of another run is a ValueError naming the differing field (:func:`check_resume`)."""
    cfg = cfg or TrainConfig()
    dtype = torch.float32 if cfg.dtype == "float32" else torch.float64
    model = model.to(dtype)
    data = _data(model, train, val, cfg, dtype)
    ckpt_path = Path(run_dir) / CHECKPOINT if run_dir is not None else None
    resuming = resume and ckpt_path is not None and ckpt_path.exists()
    if not resuming and isinstance(model, DataInitModel):  # least-squares start of the learned physics
        model.initialize_from_data(data.train.q, data.train.u)
    state = _new_state(model, cfg, data.n_batches)
    if resuming:
        assert ckpt_path is not None  # resuming needs an existing checkpoint
        _restore(state, ckpt_path, cfg, identity)
    state.t0 = time.perf_counter() - state.elapsed0
    _run_epochs(state, data, cfg, ckpt_path, identity)
    # never validated (stopped early): validate what we have; best_val is still inf, so any finite loss is taken
    if state.best_epoch < 0 and finite_params(model):
        _validate_and_select(state, data, cfg, len(state.history))
    model.load_state_dict(state.best_state)
    model.eval()
    return FitResult(model=model, history=state.history, wall_time_s=time.perf_counter() - state.t0,
                     best_val=state.best_val, best_epoch=state.best_epoch, nan_events=state.nan_events,
                     stopped_early=state.stopped)
