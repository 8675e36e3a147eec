"""Generic trainer for any :class:`~phast_model.interfaces.ForecastModel` (PHAST and baselines).

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
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from .checkpoint import atomic_torch_save
from .interfaces import ForecastModel, coordinate_error

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
    :func:`phast_model.regimes.build_model` for KNOWN), else ``default``."""
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


def _finite_params(model: torch.nn.Module) -> bool:
    return all(bool(torch.isfinite(p).all()) for p in model.parameters())


#: TrainConfig fields that do not change what a run computes (a resume may change them)
_NOT_IDENTITY = ("progress",)


def _canonical(obj: Any) -> Any:
    return json.loads(json.dumps(obj, sort_keys=True, default=str))


def run_identity(cfg: TrainConfig, identity: dict[str, Any] | None = None) -> dict[str, Any]:
    """What a checkpoint must match to be resumed: the training config (but ``progress``) and the caller's
    ``identity`` (env, regime, data, model overrides ...), as canonical JSON values."""
    train = {k: v for k, v in asdict(cfg).items() if k not in _NOT_IDENTITY}
    return _canonical({"train": train, **(identity or {})})


#: fields compared (and so named) first: the ones a person recognizes
_FIRST = ("env_id", "regime", "model", "data", "train")


def first_difference(stored: Any, wanted: Any, prefix: str = "") -> tuple[str, Any, Any] | None:
    """(dotted field, stored value, wanted value) of the first field where two JSON values differ (env, regime,
    model, data and training fields first), else None."""
    if isinstance(stored, dict) and isinstance(wanted, dict):
        for k in sorted(set(stored) | set(wanted), key=lambda k: (k not in _FIRST, _FIRST.index(k) if k in _FIRST else 0, k)):
            d = first_difference(stored.get(k, "<absent>"), wanted.get(k, "<absent>"), f"{prefix}{k}.")
            if d is not None:
                return d
        return None
    return None if stored == wanted else (prefix.rstrip("."), stored, wanted)


def check_resume(ckpt_path: str | Path, cfg: TrainConfig, identity: dict[str, Any] | None = None,
                 ck: dict[str, Any] | None = None) -> None:
    """ValueError naming the first differing field when ``ckpt_path`` was written by another run (env, regime,
    data, training config ...); nothing to check when it does not exist.  Cheap enough to call before any work."""
    ckpt_path = Path(ckpt_path)
    if ck is None:
        if not ckpt_path.exists():
            return
        ck = _load_checkpoint(ckpt_path)
    stored = ck.get("identity")
    if not isinstance(stored, str):
        raise ValueError(f"cannot resume from {ckpt_path}: it records no run identity (written by an older phast), so "
                         "it cannot be checked against this run; remove it to start over")
    diff = first_difference(json.loads(stored), run_identity(cfg, identity))
    if diff is not None:
        field_, old, new = diff
        raise ValueError(f"cannot resume from {ckpt_path}: it was written for {field_}={old!r}, this run asks for "
                         f"{field_}={new!r}; use another output directory or the original settings")


def _load_checkpoint(ckpt_path: Path) -> dict[str, Any]:
    from .checkpoint import torch_load

    try:
        ck = torch_load(ckpt_path)
    except ValueError as exc:
        raise ValueError(f"cannot resume: {exc}; remove it to start over") from None
    if not isinstance(ck, dict):
        raise ValueError(f"cannot resume from {ckpt_path}: not a training checkpoint")
    return ck


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
    q_tr, u_tr = _tensors(train, dtype)
    q_va, u_va = _tensors(val, dtype)
    if q_tr.shape[-1] != model.n:
        raise ValueError(f"model has n={model.n} coordinates, training data has {q_tr.shape[-1]}")
    skip = int(cfg.skip_first if cfg.skip_first is not None else getattr(model, "loss_skip", 0))
    ckpt_path = Path(run_dir) / CHECKPOINT if run_dir is not None else None
    resuming = resume and ckpt_path is not None and ckpt_path.exists()
    if not resuming and hasattr(model, "initialize_from_data"):  # least-squares start of the learned physics
        model.initialize_from_data(q_tr, u_tr)
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    groups = model.param_groups(cfg.lr) if hasattr(model, "param_groups") else [
        {"params": [p for p in model.parameters() if p.requires_grad], "lr": cfg.lr}]
    n_batches = math.ceil(q_tr.shape[0] / cfg.batch_size)
    warm, eps = (_resolved(cfg, model, k, d) for k, d in (("warmup_epochs", 0.0), ("adam_eps", 1e-8)))
    if warm < 0 or not math.isfinite(warm):
        raise ValueError(f"warmup_epochs must be >= 0 and finite, got {warm!r}")
    if not (eps > 0 and math.isfinite(eps)):
        raise ValueError(f"adam_eps must be positive and finite, got {eps!r}")
    opt = torch.optim.AdamW(groups, lr=cfg.lr, weight_decay=cfg.weight_decay, eps=eps)
    if warm > 0:  # linear warm-up over ``warm`` epochs, then the same cosine decay to 0
        sched = torch.optim.lr_scheduler.LambdaLR(opt, _warmup_cosine(round(warm * n_batches), cfg.epochs * n_batches))
    else:
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.epochs * n_batches)
    history: list[dict[str, Any]] = []
    best_val, best_epoch, best_state = math.inf, -1, copy.deepcopy(model.state_dict())
    start_epoch, nan_events, elapsed0 = 0, 0, 0.0
    if resuming:
        ck = _load_checkpoint(ckpt_path)
        check_resume(ckpt_path, cfg, identity, ck)
        try:
            model.load_state_dict(ck["model"])
            opt.load_state_dict(ck["optimizer"])
            sched.load_state_dict(ck["scheduler"])
        except Exception as exc:  # noqa: BLE001 - any failure means an unusable checkpoint
            raise ValueError(f"cannot resume from {ckpt_path}: {type(exc).__name__}: {exc}") from None
        gen.set_state(ck["gen_state"])
        torch.set_rng_state(ck["torch_rng"])
        history = json.loads(ck["history"])
        best_val, best_epoch, best_state = float(ck["best_val"]), int(ck["best_epoch"]), ck["best_state"]
        start_epoch, nan_events, elapsed0 = int(ck["epoch"]), int(ck["nan_events"]), float(ck["elapsed"])

    def save_ckpt(epoch: int, elapsed: float) -> None:
        if ckpt_path is None:
            return
        atomic_torch_save({
            "model": model.state_dict(), "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
            "gen_state": gen.get_state(), "torch_rng": torch.get_rng_state(), "history": json.dumps(history),
            "best_val": best_val, "best_epoch": best_epoch, "best_state": best_state, "epoch": epoch,
            "nan_events": nan_events, "elapsed": elapsed, "train_config": asdict(cfg),
            "identity": json.dumps(run_identity(cfg, identity), sort_keys=True),
        }, ckpt_path)

    t0 = time.perf_counter() - elapsed0
    stopped = False
    bar = tqdm(range(start_epoch, cfg.epochs), desc=f"fit {type(model).__name__}", disable=not cfg.progress,
               initial=start_epoch, total=cfg.epochs)
    model.train()
    for epoch in bar:
        good_model = copy.deepcopy(model.state_dict())
        good_opt = copy.deepcopy(opt.state_dict())
        perm = torch.randperm(q_tr.shape[0], generator=gen)
        tot, cnt = 0.0, 0
        for b in range(n_batches):
            idx = perm[b * cfg.batch_size:(b + 1) * cfg.batch_size]
            qb = q_tr[idx]
            ub = None if u_tr is None else u_tr[idx]
            loss, pred = next_step_loss(model, qb, ub, skip)
            loss = cfg.lambda_data * loss
            hook = getattr(model, "extra_losses", None)
            if hook is not None:
                for v in hook(qb, ub, pred).values():
                    loss = loss + v
            opt.zero_grad(set_to_none=True)
            bad = not bool(torch.isfinite(loss))
            if not bad:
                loss.backward()
                gnorm = torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip if cfg.grad_clip else math.inf)
                bad = not bool(torch.isfinite(gnorm))
            if not bad:
                opt.step()
                bad = not _finite_params(model)
            if bad:  # roll back to the start of the epoch and lower the lr
                nan_events += 1
                model.load_state_dict(good_model)
                opt.load_state_dict(good_opt)
                for g in opt.param_groups:
                    g["lr"] *= cfg.nan_lr_factor
                sched.base_lrs = [lr * cfg.nan_lr_factor for lr in sched.base_lrs]
                if nan_events > cfg.max_nan_events:
                    stopped = True
                    break
                continue
            sched.step()
            tot += float(loss.detach()) * qb.shape[0]
            cnt += qb.shape[0]
        rec: dict[str, Any] = {"epoch": epoch + 1, "train_loss": tot / max(cnt, 1), "lr": opt.param_groups[0]["lr"],
                               "time_s": time.perf_counter() - t0, "nan_events": nan_events}
        if stopped:
            history.append(rec)
            break
        if (epoch + 1) % cfg.val_every == 0 or epoch + 1 == cfg.epochs:
            vl = validation_loss(model, q_va, u_va, cfg.val_batch_size, skip)
            rec["val_loss"] = vl
            if math.isfinite(vl) and vl < best_val:
                best_val, best_epoch, best_state = vl, epoch + 1, copy.deepcopy(model.state_dict())
        history.append(rec)
        bar.set_postfix(loss=f"{rec['train_loss']:.3g}", val=f"{best_val:.3g}")
        if (epoch + 1) % cfg.checkpoint_every == 0 or epoch + 1 == cfg.epochs:
            save_ckpt(epoch + 1, time.perf_counter() - t0)
    bar.close()
    if best_epoch < 0:  # never validated (stopped early): validate what we have if it is finite
        if _finite_params(model):
            vl = validation_loss(model, q_va, u_va, cfg.val_batch_size, skip)
            if math.isfinite(vl):
                best_val, best_epoch, best_state = vl, len(history), copy.deepcopy(model.state_dict())
    model.load_state_dict(best_state)
    model.eval()
    return FitResult(model=model, history=history, wall_time_s=time.perf_counter() - t0, best_val=best_val,
                     best_epoch=best_epoch, nan_events=nan_events, stopped_early=stopped)
