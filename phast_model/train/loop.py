"""The one epoch loop of both trainers, parameterized by an :class:`Objective`.

The loop owns what every training run needs: seeded RNGs, the AdamW step with gradient clipping, the NaN guard,
validation and best-validation weights, the learning-rate schedule (:class:`Optim`), early stopping, a checkpoint
after every ``checkpoint_every`` epochs written atomically, an exact resume and the progress bar.  The objective owns
what is specific to a loss: its data and minibatches, the loss of a batch, the validation loss, the optimizer of each
epoch (a curriculum may start a fresh one), a start-of-epoch hook and what its checkpoint adds.  Two objectives:

* next-step prediction over whole trajectories (the env path, :class:`phast_model.train.fit.NextStep`);
* multiple shooting on windows of a rig's recordings, with each window's initial state refitted by Gauss-Newton at
  the start of every epoch (the rig path, :class:`phast_model.train.rig_fit.Shooting`).

NaN guard: a minibatch whose loss or gradient norm is not finite makes no update (``nan_skipped``); a step that
leaves non-finite parameters is rolled back to the model and optimizer of the epoch's start, and the learning rates
are multiplied by ``nan_lr_factor`` from where the schedule stands (``nan_rollbacks``); training stops once the
rollbacks exceed ``max_nan_events``.  The schedule advances after every minibatch, so a cosine decay ends where it was
planned.
"""

from __future__ import annotations

import copy
import json
import math
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import torch
from tqdm.auto import tqdm

from .checkpoint import atomic_torch_save, first_difference

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

CHECKPOINT = "checkpoint.pt"
Scheduler = torch.optim.lr_scheduler.LRScheduler | torch.optim.lr_scheduler.ReduceLROnPlateau


@dataclass
class Optim:
    """An optimizer and its learning-rate schedule: stepped after every minibatch (a cosine decay, with an optional
    warm-up) or after every epoch on the validation loss (a plateau rule, ``ReduceLROnPlateau``)."""

    opt: torch.optim.Optimizer
    sched: Scheduler

    @property
    def lr(self) -> float:
        """The first group's learning rate (what the history records)."""
        return self.opt.param_groups[0]["lr"]

    def end_batch(self) -> None:
        if not isinstance(self.sched, torch.optim.lr_scheduler.ReduceLROnPlateau):
            self.sched.step()

    def end_epoch(self, val_loss: float | None) -> None:
        if isinstance(self.sched, torch.optim.lr_scheduler.ReduceLROnPlateau) and val_loss is not None \
                and math.isfinite(val_loss):
            self.sched.step(val_loss)

    def scale_lr(self, factor: float) -> None:
        """Multiply every learning rate by ``factor``, now and for the rest of the schedule (a plateau rule has no
        base rates: it scales the current ones)."""
        if isinstance(self.sched, torch.optim.lr_scheduler.ReduceLROnPlateau):
            for g in self.opt.param_groups:
                g["lr"] *= factor
        else:
            scale_lr(self.opt, self.sched, factor)


#: an objective's minibatch (the env path: (q, u) tensors; the rig path: windows)
BatchT = TypeVar("BatchT")


class Objective(Protocol[BatchT]):
    """What :func:`train_loop` trains: a loss over minibatches of some data, with a validation loss.

    ``model`` is trained; ``checkpoint_format`` names the kind of run in its checkpoint (a resume checks it),
    ``kind`` in words ("a recordings run")."""

    checkpoint_format: str
    kind: str

    @property
    def model(self) -> torch.nn.Module:
        """The model trained."""

    def optimizer(self, epoch: int, current: Optim | None) -> Optim:
        """The optimizer and schedule that train ``epoch`` (0-based): ``current``, or a fresh one where the
        objective starts one (the first epoch; a curriculum's next stage).  A resume calls it with the last epoch
        the checkpoint trained and ``current=None``, then loads the optimizer's and schedule's state."""

    def begin_epoch(self, epoch: int) -> None:
        """Start-of-epoch work before the minibatches (the rig's window-state refits)."""

    def batches(self, gen: torch.Generator) -> Iterable[BatchT]:
        """This epoch's minibatches, shuffled with ``gen``."""

    def loss(self, batch: BatchT) -> tuple[torch.Tensor, int]:
        """(the loss to minimize, the batch's size: its weight in the epoch's mean)."""

    def validation_loss(self) -> float:
        """The selection criterion on the validation data, current weights."""

    def record(self, epoch: int, train_loss: float, val_loss: float | None, lr: float, time_s: float,
               guard: NanCounts) -> dict[str, Any]:
        """The history entry of ``epoch`` (1-based); ``train_loss`` is NaN when no step was taken."""

    def state(self) -> dict[str, Any]:
        """What the checkpoint adds (tensors and plain values; the rig's window states)."""

    def load_state(self, saved: dict[str, Any]) -> None:
        """Restore :meth:`state` from a checkpoint (ValueError when it does not fit this run)."""


@dataclass
class NanCounts:
    """The NaN guard's record: minibatch steps skipped, epochs' steps rolled back."""

    skipped: int = 0
    rollbacks: int = 0

    @property
    def total(self) -> int:
        return self.skipped + self.rollbacks


@dataclass(frozen=True)
class LoopConfig:
    """The loop's settings (each trainer derives them from its own config)."""

    epochs: int
    seed: int = 0
    grad_clip: float | None = 10.0  # max gradient norm (None: off)
    max_nan_events: int | None = 5  # rollbacks allowed before training stops (None: no limit)
    nan_lr_factor: float = 0.5
    val_every: int = 1  # validation every this many epochs, and after the last
    select_from: int = 0  # the first (0-based) epoch whose validation may select the model and counts for patience
    patience: int | None = None  # stop when validation has not improved for this many epochs (None: never)
    checkpoint_every: int = 1
    progress: bool = True
    desc: str = "fit"


@dataclass
class LoopResult:
    """What :func:`train_loop` returns; ``model`` holds the best-validation weights (in eval mode)."""

    model: torch.nn.Module
    history: list[dict[str, Any]] = field(default_factory=list)
    best_val: float = math.inf
    best_epoch: int = -1
    wall_time_s: float = 0.0
    nan: NanCounts = field(default_factory=NanCounts)
    stopped: bool = False  # by the NaN guard's limit or by patience


@dataclass
class _State:
    """Everything a run carries from epoch to epoch; the checkpoint stores it and a resume restores it."""

    gen: torch.Generator
    best_state: dict[str, torch.Tensor]
    optim: Optim | None = None
    history: list[dict[str, Any]] = field(default_factory=list)
    best_val: float = math.inf
    best_epoch: int = -1
    start_epoch: int = 0
    nan: NanCounts = field(default_factory=NanCounts)
    stopped: bool = False
    elapsed0: float = 0.0  # seconds trained before this call (a resume)
    t0: float = 0.0  # perf_counter origin of the run's clock (elapsed0 included)


# --------------------------------------------------------------------------- helpers both trainers use
def finite_params(model: torch.nn.Module) -> bool:
    """True when every parameter of ``model`` is finite (the NaN guard's check after a step)."""
    return all(bool(torch.isfinite(p).all()) for p in model.parameters())


def scale_lr(opt: torch.optim.Optimizer, sched: torch.optim.lr_scheduler.LRScheduler, factor: float) -> None:
    """Multiply every group's learning rate by ``factor``, now and in the schedule's base rates."""
    for g in opt.param_groups:
        g["lr"] *= factor
    sched.base_lrs = [lr * factor for lr in sched.base_lrs]


#: training-config fields that do not change what a run computes (a resume may change them)
_NOT_IDENTITY = ("progress",)


def _canonical(obj: object) -> Any:
    return json.loads(json.dumps(obj, sort_keys=True, default=str))


def run_identity(cfg: DataclassInstance, identity: Mapping[str, object] | None = None) -> dict[str, Any]:
    """What a checkpoint must match to be resumed: the training config (a :class:`TrainConfig`, or the rig path's
    :class:`phast_model.train.rig_fit.RigTrainConfig`; all its fields but ``progress``) and the caller's
    ``identity`` (env, regime, data, model overrides ...), as canonical JSON values."""
    train = {k: v for k, v in asdict(cfg).items() if k not in _NOT_IDENTITY}
    return _canonical({"train": train, **(identity or {})})


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


def check_resume(ckpt_path: str | Path, cfg: DataclassInstance, identity: Mapping[str, object] | None = None,
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


# --------------------------------------------------------------------------- the NaN guard
OK, SKIP, ROLL_BACK = "ok", "skip", "roll back"


def guarded_step(opt: torch.optim.Optimizer, model: torch.nn.Module, loss: torch.Tensor,
                 grad_clip: float | None) -> str:
    """Backward, clip and step: OK; SKIP (no update) when the loss or the gradient norm is not finite; ROLL_BACK
    when the step left non-finite parameters."""
    opt.zero_grad(set_to_none=True)
    if not bool(torch.isfinite(loss)):
        return SKIP
    loss.backward()
    gnorm = torch.nn.utils.clip_grad_norm_(model.parameters(), grad_clip if grad_clip else math.inf)
    if not bool(torch.isfinite(gnorm)):
        opt.zero_grad(set_to_none=True)
        return SKIP
    opt.step()
    return OK if finite_params(model) else ROLL_BACK


def _roll_back(model: torch.nn.Module, optim: Optim, good_model: dict[str, torch.Tensor], good_opt: dict[str, Any],
               factor: float) -> None:
    """Restore the model and optimizer of the epoch's start and continue the schedule from where it stands at
    ``factor`` x its learning rates."""
    lrs = [g["lr"] for g in optim.opt.param_groups]
    model.load_state_dict(good_model)
    optim.opt.load_state_dict(good_opt)
    for g, lr in zip(optim.opt.param_groups, lrs):
        g["lr"] = lr
    optim.scale_lr(factor)


def _train_pass(state: _State, obj: Objective, optim: Optim, cfg: LoopConfig) -> float:
    """One guarded pass over the objective's minibatches: the mean loss of the steps taken (NaN when none was).
    Sets ``state.stopped`` when the rollbacks exceed ``cfg.max_nan_events``."""
    model = obj.model
    good_model, good_opt = copy.deepcopy(model.state_dict()), copy.deepcopy(optim.opt.state_dict())
    tot, cnt = 0.0, 0
    for batch in obj.batches(state.gen):
        loss, size = obj.loss(batch)
        outcome = guarded_step(optim.opt, model, loss, cfg.grad_clip)
        if outcome == OK:
            tot += float(loss.detach()) * size
            cnt += size
        elif outcome == SKIP:
            state.nan.skipped += 1
        else:
            _roll_back(model, optim, good_model, good_opt, cfg.nan_lr_factor)
            state.nan.rollbacks += 1
            if cfg.max_nan_events is not None and state.nan.rollbacks > cfg.max_nan_events:
                state.stopped = True
                break
        optim.end_batch()
    return tot / cnt if cnt else math.nan


# --------------------------------------------------------------------------- checkpoints
def _save(state: _State, obj: Objective, path: Path | None, run_cfg: DataclassInstance,
          identity: Mapping[str, object] | None, epoch: int) -> None:
    """Write the checkpoint atomically (nothing without a run directory): what :func:`_restore` reads back; plain
    Python values and tensors only, so it loads with ``weights_only=True``."""
    if path is None or state.optim is None:
        return
    atomic_torch_save({
        "format": obj.checkpoint_format, "epoch": epoch, "model": obj.model.state_dict(),
        "optimizer": state.optim.opt.state_dict(), "scheduler": state.optim.sched.state_dict(),
        "gen_state": state.gen.get_state(), "torch_rng": torch.get_rng_state(), "history": json.dumps(state.history),
        "best_val": state.best_val, "best_epoch": state.best_epoch, "best_state": state.best_state,
        "nan_skipped": state.nan.skipped, "nan_rollbacks": state.nan.rollbacks, "stopped": state.stopped,
        "elapsed": time.perf_counter() - state.t0, "train_config": asdict(run_cfg),
        "identity": json.dumps(run_identity(run_cfg, identity), sort_keys=True), **obj.state(),
    }, path)


def _model_state(saved: object, model: torch.nn.Module, what: str) -> dict[str, torch.Tensor]:
    """A state dict of the checkpoint, checked to fit ``model`` (the same entries, each of the same shape)."""
    ref = model.state_dict()
    if not (isinstance(saved, dict) and saved.keys() == ref.keys()
            and all(isinstance(v, torch.Tensor) and v.shape == ref[k].shape for k, v in saved.items())):
        raise ValueError(f"its {what} does not fit the model")
    return saved


def _load(state: _State, obj: Objective, ck: dict[str, Any], epochs: int) -> None:
    """Set ``state`` (and the objective) to what the checkpoint ``ck`` recorded at the end of its last epoch."""
    epoch = int(ck["epoch"])
    if not 1 <= epoch <= epochs:
        raise ValueError(f"its epoch {epoch} is outside 1..{epochs}")
    obj.model.load_state_dict(ck["model"])
    optim = obj.optimizer(epoch - 1, None)
    optim.opt.load_state_dict(ck["optimizer"])
    optim.sched.load_state_dict(ck["scheduler"])
    obj.load_state(ck)
    state.optim, state.best_state = optim, _model_state(ck["best_state"], obj.model, "best state")
    state.gen.set_state(ck["gen_state"])
    torch.set_rng_state(ck["torch_rng"])
    state.history = json.loads(ck["history"])
    state.best_val, state.best_epoch, state.start_epoch = float(ck["best_val"]), int(ck["best_epoch"]), epoch
    state.nan = NanCounts(int(ck["nan_skipped"]), int(ck["nan_rollbacks"]))
    state.stopped, state.elapsed0 = bool(ck["stopped"]), float(ck["elapsed"])


def _restore(state: _State, obj: Objective, path: Path, run_cfg: DataclassInstance,
             identity: Mapping[str, object] | None, epochs: int) -> None:
    """Continue from the checkpoint at ``path``; ValueError when it is unreadable, of another kind of run or of
    another run (:func:`check_resume` names the differing field)."""
    ck = load_checkpoint(path)
    if ck.get("format") != obj.checkpoint_format:
        raise ValueError(f"cannot resume from {path}: not the checkpoint of {obj.kind} "
                         f"(format {ck.get('format')!r}, expected {obj.checkpoint_format!r})")
    check_resume(path, run_cfg, identity, ck)
    try:
        _load(state, obj, ck, epochs)
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        text = (str(exc).splitlines() or [""])[0]
        raise ValueError(f"cannot resume from {path}: {type(exc).__name__}: {text}") from None


# --------------------------------------------------------------------------- the loop
def _select(state: _State, obj: Objective, val: float, epoch: int) -> None:
    """The current weights become the best state when ``val`` is finite and lower than the best so far."""
    if math.isfinite(val) and val < state.best_val:
        state.best_val, state.best_epoch, state.best_state = val, epoch, copy.deepcopy(obj.model.state_dict())


def _patience_spent(state: _State, cfg: LoopConfig, epoch: int) -> bool:
    """True when validation has not improved for ``cfg.patience`` epochs counted from ``cfg.select_from``."""
    if cfg.patience is None or epoch < cfg.select_from:
        return False
    return epoch + 1 - max(state.best_epoch, cfg.select_from) >= cfg.patience


def _epoch(state: _State, obj: Objective, cfg: LoopConfig, epoch: int) -> None:
    """Epoch ``epoch`` (0-based): its optimizer, the start-of-epoch hook, a guarded pass, validation when due (the
    plateau rule's step, the best state) and the history record."""
    state.optim = optim = obj.optimizer(epoch, state.optim)
    obj.begin_epoch(epoch)
    train = _train_pass(state, obj, optim, cfg)
    time_s = time.perf_counter() - state.t0
    val = None
    if not state.stopped and ((epoch + 1) % cfg.val_every == 0 or epoch + 1 == cfg.epochs):
        val = obj.validation_loss()
        optim.end_epoch(val)
        if epoch >= cfg.select_from:
            _select(state, obj, val, epoch + 1)
    state.history.append(obj.record(epoch + 1, train, val, optim.lr, time_s, state.nan))


def _run_epochs(state: _State, obj: Objective, cfg: LoopConfig, save: Callable[[int], None]) -> None:
    """Epochs ``state.start_epoch`` .. ``cfg.epochs`` (none once stopped), checkpoints when due."""
    todo = range(cfg.epochs if state.stopped else state.start_epoch, cfg.epochs)
    bar = tqdm(todo, desc=cfg.desc, disable=not cfg.progress, initial=state.start_epoch, total=cfg.epochs)
    obj.model.train()
    for epoch in bar:
        _epoch(state, obj, cfg, epoch)
        if state.stopped:  # the NaN guard's limit: no checkpoint of this epoch
            break
        best = {"best_val": f"{state.best_val:.3g}"} if math.isfinite(state.best_val) else {}
        bar.set_postfix(**best)
        state.stopped = _patience_spent(state, cfg, epoch)
        if (epoch + 1) % cfg.checkpoint_every == 0 or epoch + 1 == cfg.epochs or state.stopped:
            save(epoch + 1)
        if state.stopped:
            break
    bar.close()


def train_loop(obj: Objective, cfg: LoopConfig, run_cfg: DataclassInstance, ckpt_path: Path | None = None,
               resume: bool = False, identity: Mapping[str, object] | None = None) -> LoopResult:
    """Train ``obj.model`` on the objective ``obj`` for up to ``cfg.epochs`` epochs; returns a :class:`LoopResult`
    whose model holds the best-validation weights.

    ``run_cfg`` is the trainer's own config (recorded in the checkpoint with ``identity``; a resume of another run's
    checkpoint is a ValueError naming the differing field).  With ``ckpt_path`` a checkpoint is written there
    atomically after every ``cfg.checkpoint_every`` epochs (model, optimizer and schedule, RNG states, history, best
    state, NaN counts, the objective's :meth:`~Objective.state`), and ``resume=True`` continues from it (it must
    exist) to the model an uninterrupted run ends with."""
    model = obj.model
    torch.manual_seed(cfg.seed)
    state = _State(torch.Generator().manual_seed(cfg.seed), best_state=copy.deepcopy(model.state_dict()))
    if resume:
        if ckpt_path is None:
            raise ValueError("resume needs a run directory (the directory of checkpoint.pt)")
        _restore(state, obj, ckpt_path, run_cfg, identity, cfg.epochs)
    state.t0 = time.perf_counter() - state.elapsed0
    _run_epochs(state, obj, cfg, lambda epoch: _save(state, obj, ckpt_path, run_cfg, identity, epoch))
    # never validated (stopped by the NaN guard first): validate what there is; any finite loss is taken
    if state.best_epoch < 0 and finite_params(model):
        _select(state, obj, obj.validation_loss(), len(state.history))
    model.load_state_dict(state.best_state)
    model.eval()
    return LoopResult(model, state.history, state.best_val, state.best_epoch, time.perf_counter() - state.t0,
                      state.nan, state.stopped)
