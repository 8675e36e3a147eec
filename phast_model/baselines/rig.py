"""The sequence baselines on a rig's recordings: ``phast-train --recordings FILE --sim SIM --model NAME``.

What a user without a model would train instead of PHAST, on the same data and scored by the same code:

* the same split as PHAST's (``--holdout-trajectories``) and the recorded inputs u;
* training windows cut from the training recordings (:func:`cut_seq_windows`): blocks of ``length`` samples, a random
  ``val_fraction`` of them held back for validation (PHAST's rule, :func:`phast_model.train.rig_fit.cut_windows`
  then a seeded split), and overlapping training windows every ``stride`` samples that avoid every validation block;
* the grid's trainer (:func:`phast_model.train.fit.fit`: teacher-forced next-step loss, AdamW with cosine decay over
  ``TrainConfig.epochs``, the best validation loss's weights, the NaN guard, checkpoints and ``resume``);
* the held-out score of PHAST and the nominal rig (:func:`phast_model.train.rig_heldout.heldout_rollouts`): each
  window's 0.1 s burn-in is the baseline's warm-up of observed positions, then it runs open loop with the recorded u;
* its own learning rate: :func:`sweep_lr` trains on a short budget at a few rates and picks by validation loss.

DHNN needs the full state: it gets (q, qdot) with qdot from Savitzky-Golay smoothing of the measured q (the whole
training recording when training; only the burn-in when scored), the estimate PHAST's window states start from
(:class:`WithVelocity`).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..identify.recordings import Recordings
from ..train.config import TrainConfig
from ..train.fit import FitResult, fit
from ..train.rig_fit import (
    BURN_IN_S,
    SMOOTH_S,
    RigData,
    build,
    check_window_room,
    nominal_config,
    rig_config,
)
from ..train.rig_heldout import heldout_rollouts, heldout_windows, nominal_entries, nominal_source, smoothed
from ..train.rig_run import RecordingsSpec, heldout_part, prepare, sim_name, spec_record
from ..world.interfaces import ForecastModel, NormalizedModel, wrap_angles
from ..world.model import PHAST
from . import BASELINES, FULL_STATE, make_baseline

#: the weights of a baseline run (a bare state dict, ``torch.load(..., weights_only=True)``)
MODEL_FILE = "baseline_model.pt"
#: the learning rates :func:`sweep_lr` tries by default (the grid's 1e-3 and a factor ~3 either side)
SWEEP_LRS = (3e-4, 1e-3, 3e-3)
#: the sweep's short budget [epochs] (a fifth of the grid's 50)
SWEEP_EPOCHS = 10
#: a baseline's default step [s]: the grid's double pendulums' (phast_gym DoublePendulum dt), where the grid's
#: sequence models are known to learn.  At a real arm's 2 ms a q-only model must resolve 1e-3 rad differences of its
#: inputs to know the velocity: on the DFKI arm the grid's GRU and LSTM then ended no better than holding q still
#: (next-step validation MSE 3.2e-5 against 5.2e-5 for holding q and 6.8e-7 for constant velocity)
GRID_STEP_S = 0.01
#: training windows per epoch: the grid's n_train (1000 trajectories, 16 minibatches of 64: 800 steps in 50 epochs)
GRID_WINDOWS = 1000


def model_names() -> tuple[str, ...]:
    """What ``--model`` takes with ``--recordings``: PHAST and every baseline of the grid."""
    return ("phast", *BASELINES)


@dataclass(frozen=True)
class BaselineConfig:
    """A baseline run: the model, the grid's :class:`TrainConfig` (``epochs``, ``batch_size``, ``lr`` ...), the
    model's step (``step_s``: every k-th recorded sample, k = step_s / dt rounded, at least 1; the input u averaged
    over the k intervals), the training window (``window_s``; None: the held-out window's burn-in plus rollout, at
    most a quarter of a training recording), the training windows per epoch (``n_windows``: their stride is the
    largest that gives at least that many) and the validation share."""

    model: str
    train: TrainConfig = field(default_factory=lambda: TrainConfig(progress=False))
    window_s: float | None = None
    step_s: float | None = GRID_STEP_S
    n_windows: int = GRID_WINDOWS
    val_fraction: float = 0.15
    model_kw: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.model not in BASELINES:
            raise ValueError(f"unknown baseline {self.model!r}; --model takes one of {', '.join(model_names())}")
        if int(self.n_windows) != self.n_windows or self.n_windows < 1:
            raise ValueError(f"n_windows must be a positive integer, got {self.n_windows!r}")
        if self.step_s is not None and not (self.step_s > 0 and math.isfinite(self.step_s)):
            raise ValueError(f"step_s must be a positive number of seconds, got {self.step_s!r}")
        if not 0.0 < self.val_fraction < 1.0:
            raise ValueError(f"val_fraction must be in (0, 1), got {self.val_fraction!r}")
        if self.window_s is not None and not (self.window_s > 0 and math.isfinite(self.window_s)):
            raise ValueError(f"window_s must be a positive number of seconds, got {self.window_s!r}")


@dataclass(frozen=True)
class SeqWindows:
    """Training or validation sequences (a :class:`phast_model.world.interfaces.Trajectories`)."""

    q: np.ndarray  # (W, L, n), or (W, L, 2n) = (q, qdot) for a full-state model
    u: np.ndarray | None  # (W, L-1, n)
    dt: float


@dataclass(frozen=True)
class BaselineWindows:
    """The training and validation sequences of a run and how they were cut."""

    train: SeqWindows
    val: SeqWindows
    length: int  # model steps per window
    stride: int  # model steps between training windows
    k: int = 1  # recorded samples per model step

    def record(self) -> dict[str, Any]:
        """config.json's and metrics.json's description of the windows."""
        return {"steps": self.length, "seconds": (self.length - 1) * self.train.dt, "stride": self.stride,
                "step_s": self.train.dt, "samples_per_step": self.k, "train": int(self.train.q.shape[0]),
                "val": int(self.val.q.shape[0])}


def velocity(q: np.ndarray, dt: float) -> np.ndarray:
    """Savitzky-Golay velocity of ``q`` (N, T, n), as PHAST's window states start from it."""
    return smoothed(q, dt)[1]


def step_samples(cfg: BaselineConfig, dt: float) -> int:
    """Recorded samples per model step (at least 1)."""
    return 1 if cfg.step_s is None else max(1, int(round(cfg.step_s / dt)))


def coarsen(rec: Recordings, k: int) -> Recordings:
    """Every ``k``-th sample of q, u averaged over each k intervals (the mean input over the model's step: a sequence
    model's input, not a simulation's)."""
    if k == 1:
        return rec
    q = rec.q[:, ::k]
    u = None
    if rec.u is not None:
        steps = q.shape[1] - 1
        u = rec.u[:, : steps * k].reshape(rec.n_traj, steps, k, -1).mean(2)
    return replace(rec, q=q, u=u, dt=rec.dt * k, t=None, origin=None)


def window_length(cfg: BaselineConfig, rec: Recordings, heldout: Recordings, rollout_window_s: float | None,
                  k: int) -> int:
    """Model steps per training window of ``rec`` (already at the model's step, k recorded samples): ``cfg.window_s``,
    else the held-out window's burn-in plus rollout (the length the model is scored on), at most a quarter of a
    training recording (room for validation blocks)."""
    if cfg.window_s is not None:
        length = max(5, int(round(cfg.window_s / rec.dt)) + 1)
    else:
        w = heldout_windows(heldout, rollout_window_s, BURN_IN_S)
        length = min(-(-(w.burn + w.H - 1) // k) + 1, max(5, rec.T // 4))
    check_window_room(rec, length, "one training window of a baseline")
    return length


def cut_seq_windows(rec: Recordings, length: int, cfg: BaselineConfig, seed: int, k: int = 1) -> BaselineWindows:
    """Blocks of ``length`` samples of ``rec`` (at the model's step, ``k`` recorded samples); a seeded random
    ``cfg.val_fraction`` of them (at least one) for validation; training windows every ``stride`` samples wherever
    they overlap no validation block, the largest stride that gives ``cfg.n_windows`` windows (or every start)."""
    blocks = [(i, s) for i in range(rec.n_traj) for s in range(0, rec.T - length + 1, length)]
    if len(blocks) < 2:
        raise ValueError(f"{rec.source}: the training recordings hold {len(blocks)} window(s) of {length} samples; a "
                         "baseline needs two (training and validation): give a shorter --window-s")
    n_val = min(len(blocks) - 1, max(1, int(round(cfg.val_fraction * len(blocks)))))
    perm = np.random.default_rng(seed).permutation(len(blocks))
    val = [blocks[j] for j in sorted(perm[:n_val])]
    free = np.ones((rec.n_traj, rec.T), dtype=bool)
    for i, s in val:
        free[i, s:s + length] = False
    starts = [(i, s) for i in range(rec.n_traj) for s in range(rec.T - length + 1) if free[i, s:s + length].all()]
    if not starts:
        raise ValueError(f"{rec.source}: no training window of {length} samples is left beside the validation blocks")
    stride = max(1, len(starts) // cfg.n_windows)
    train = [(i, s) for i, s in starts if s % stride == 0]
    full = cfg.model in FULL_STATE
    x = np.concatenate([rec.q, velocity(rec.q, rec.dt)], -1) if full else rec.q
    return BaselineWindows(_take(x, rec, train, length), _take(x, rec, val, length), length, stride, k)


def _take(x: np.ndarray, rec: Recordings, where: list[tuple[int, int]], length: int) -> SeqWindows:
    q = np.stack([x[i, s:s + length] for i, s in where])
    u = None if rec.u is None else np.stack([rec.u[i, s:s + length - 1] for i, s in where])
    return SeqWindows(q, u, float(rec.dt))


class WithVelocity(ForecastModel):
    """The q-only face of a full-state model (DHNN on (q, qdot)): the velocity is estimated from the observed q by
    :func:`velocity` (at a rollout: from the warm-up only), so it is scored on positions like every other model."""

    def __init__(self, inner: ForecastModel, dt: float) -> None:
        super().__init__(inner.n // 2, inner.m, inner.angle_dims)
        self.inner, self.dt = inner, float(dt)

    def _state(self, q: torch.Tensor) -> torch.Tensor:
        v = velocity(q.detach().cpu().double().numpy(), self.dt)
        return torch.cat([q, torch.as_tensor(v).to(q)], -1)

    def forward(self, q: torch.Tensor, u: torch.Tensor | None = None) -> torch.Tensor:
        return self.inner(self._state(q), u)[..., : self.n]

    @torch.no_grad()
    def rollout(self, q_burn: torch.Tensor, u: torch.Tensor | None, H: int) -> torch.Tensor:
        return self.inner.rollout(self._state(q_burn), u, H)[..., : self.n]


class Coarse(ForecastModel):
    """A model stepping every ``k`` recorded samples, scored on the recorded grid: the warm-up's every k-th sample
    (ending at its last), u averaged over each step, the rollout linearly interpolated back to every sample."""

    def __init__(self, inner: ForecastModel, k: int) -> None:
        super().__init__(inner.n, inner.m, inner.angle_dims)
        self.inner, self.k = inner, int(k)

    @torch.no_grad()
    def rollout(self, q_burn: torch.Tensor, u: torch.Tensor | None, H: int) -> torch.Tensor:
        k, K = self.k, q_burn.shape[1]
        first = (K - 1) % k
        steps = -(-H // k)
        uc = None
        if u is not None:
            up = torch.cat([u, u.new_zeros(u.shape[0], max(0, K - 1 + steps * k - u.shape[1]), u.shape[2])], 1)
            uc = up[:, first: K - 1 + steps * k].reshape(u.shape[0], -1, k, u.shape[-1]).mean(2)
        pred = self.inner.rollout(q_burn[:, first::k], uc, steps)
        path = torch.cat([q_burn[:, -1:], pred.to(q_burn.dtype)], 1)  # at recorded samples K-1, K-1+k, ...
        if self.angle_dims:  # unwrapped along time before interpolating
            d = list(self.angle_dims)
            step = wrap_angles(path[:, 1:] - path[:, :-1], self.angle_dims)[..., d]
            path[:, 1:, d] = path[:, :1, d] + torch.cumsum(step, 1)
        t = torch.arange(1, H + 1, device=path.device)
        i, f = t // k, ((t % k).to(path.dtype) / k)[None, :, None]
        out = path[:, i] * (1 - f) + path[:, torch.clamp(i + 1, max=path.shape[1] - 1)] * f
        return wrap_angles(out, self.angle_dims)


@dataclass(frozen=True)
class BaselineData:
    """Everything a baseline run trains and is scored on: the checked recordings spec (its rig path resolved), the
    training and held-out recordings on their uniform grid (PHAST's :class:`RigData`), the windows, the input width."""

    spec: RecordingsSpec
    rig: RigData
    windows: BaselineWindows
    m: int

    @property
    def train(self) -> Recordings:
        return self.rig.train

    @property
    def heldout(self) -> Recordings:
        return heldout_part(self.rig)

    @property
    def n(self) -> int:
        return self.rig.train.n


def prepare_baseline(spec: RecordingsSpec, cfg: BaselineConfig) -> BaselineData:
    """Load and check the recordings as PHAST's run does (:func:`phast_model.train.rig_run.prepare`), then cut the
    baseline's training and validation windows; ValueError before any training."""
    spec = replace(spec, sim=sim_name(spec.sim))
    rig = prepare(spec)
    k = step_samples(cfg, rig.dt)
    coarse = coarsen(rig.train, k)
    length = window_length(cfg, coarse, heldout_part(rig), spec.rollout_window_s, k)
    windows = cut_seq_windows(coarse, length, cfg, cfg.train.seed, k)
    return BaselineData(spec, rig, windows, 0 if rig.train.u is None else rig.train.n)


def build_baseline(cfg: BaselineConfig, data: BaselineData) -> ForecastModel:
    """The baseline (seeded by ``cfg.train.seed``), its normalization fitted to the training windows (as the grid's
    :func:`phast_model.bench.runner.build_run_model` does); DHNN on (q, qdot), stepping at the recordings' dt."""
    torch.manual_seed(cfg.train.seed)
    full = cfg.model in FULL_STATE
    kw = {"dt": float(data.windows.train.dt), **cfg.model_kw} if full else dict(cfg.model_kw)
    n = 2 * data.n if full else data.n
    model = make_baseline(cfg.model, n, data.m, tuple(data.train.angle_dims), **kw)
    if isinstance(model, NormalizedModel):
        model.fit_normalizer(data.windows.train.q, data.windows.train.u)
    return model


def train_baseline(cfg: BaselineConfig, data: BaselineData, run_dir: Path | None = None, resume: bool = False,
                   identity: dict[str, Any] | None = None) -> FitResult:
    """The grid's trainer (:func:`phast_model.train.fit.fit`) on the training windows, selected on the validation
    windows."""
    model = build_baseline(cfg, data)
    return fit(model, data.windows.train, data.windows.val, cfg.train, run_dir=run_dir, resume=resume,
               identity=identity)


@dataclass(frozen=True)
class LrSweep:
    """A learning-rate sweep: each rate's best validation loss after ``epochs`` epochs, the rate chosen (the lowest
    finite loss) and the sweep's wall time."""

    lrs: tuple[float, ...]
    val_loss: tuple[float, ...]
    epochs: int
    chosen: float
    wall_time_s: float


def sweep_lr(cfg: BaselineConfig, data: BaselineData, lrs: tuple[float, ...] = SWEEP_LRS,
             epochs: int = SWEEP_EPOCHS) -> LrSweep:
    """Train ``cfg``'s baseline for ``epochs`` epochs (cosine over them, validated at the end) at each rate of
    ``lrs`` and pick the rate of the lowest validation loss (the held-out recordings play no part)."""
    if not lrs:
        raise ValueError("the learning-rate sweep needs at least one rate")
    t0 = time.perf_counter()
    losses = []
    for lr in lrs:
        short = replace(cfg, train=replace(cfg.train, lr=float(lr), epochs=int(epochs), val_every=int(epochs)))
        best = train_baseline(short, data).best_val
        losses.append(best if math.isfinite(best) else math.inf)
    chosen = float(lrs[int(np.argmin(losses))])
    return LrSweep(tuple(float(x) for x in lrs), tuple(losses), int(epochs), chosen, time.perf_counter() - t0)


def train_baseline_run(spec: RecordingsSpec, out: str | Path, cfg: BaselineConfig, plots: bool = True,
                       resume: bool = False, sweep: tuple[float, ...] | None = None) -> dict[str, Any]:
    """Train ``cfg``'s baseline on ``spec``'s recordings and write the run directory ``out``: ``config.json``,
    ``metrics.json`` (``heldout.<model>`` beside ``heldout.nominal``, scored on the same windows), ``history.json``,
    ``checkpoint.pt``, :data:`MODEL_FILE` and ``heldout_rollout.png``.  ``sweep``: learning rates to try first
    (:func:`sweep_lr`); the rate chosen trains the run and is recorded."""
    from phast_gym.fileio import dir_lock, ensure_writable_dir

    data = prepare_baseline(spec, cfg)
    out = ensure_writable_dir(out, "--out")
    with dir_lock(out):
        lr_sweep = sweep_lr(cfg, data, sweep) if sweep else None
        if lr_sweep is not None:
            cfg = replace(cfg, train=replace(cfg.train, lr=lr_sweep.chosen))
        record = _config_record(cfg, data)
        res = train_baseline(cfg, data, out, resume, identity={k: v for k, v in record.items() if k != "train"})
        nominal, compare = nominal_entries(_nominal(data), data.spec.sim, data.spec.compare)
        scores, rolls, windows = heldout_rollouts(nominal, data.heldout, data.spec.rollout_window_s, compare=compare,
                                                  forecasters={cfg.model: scored_model(cfg, res.model, data)})
        metrics = _metrics(cfg, data, res, scores, lr_sweep)
        _write(out, res, record, metrics)
        if plots:
            from ..train.rig_plots import plot_heldout

            plot_heldout(windows, rolls, data.heldout.dt, out / "heldout_rollout.png")
    return metrics


def scored_model(cfg: BaselineConfig, model: ForecastModel, data: BaselineData) -> ForecastModel:
    """The trained model as scored on the recorded grid: DHNN's velocity estimated from q, a coarser step
    interpolated back (:class:`WithVelocity`, :class:`Coarse`)."""
    step = data.windows.train.dt
    model = WithVelocity(model, step) if cfg.model in FULL_STATE else model
    return Coarse(model, data.windows.k) if data.windows.k > 1 else model


def _nominal(data: BaselineData) -> PHAST:
    """The rig as a model (its V and M, no learned friction), built as PHAST's run builds it: the reference of every
    recordings run."""
    spec, rig = data.spec, data.rig
    bound = list(spec.action_bound) if spec.action_bound else [max(b, 1e-6) for b in rig.u_bound]
    return build(nominal_config(rig_config(spec.sim, spec.sim_kwargs, spec.regime, rig, action_bound=bound)))


def _config_record(cfg: BaselineConfig, data: BaselineData) -> dict[str, Any]:
    """config.json: the model, its widths, the training config, the windows and the recordings spec."""
    full = cfg.model in FULL_STATE
    return {"model": cfg.model, "model_kw": dict(cfg.model_kw), "n": data.n, "m": data.m,
            "angle_dims": list(data.train.angle_dims), "full_state": full,
            "velocity_estimate": f"Savitzky-Golay over {SMOOTH_S:g} s of q" if full else None,
            "train": asdict(cfg.train), "windows": data.windows.record(), "val_fraction": cfg.val_fraction,
            "recordings": spec_record(data.spec, str(data.rig.source))}


def _metrics(cfg: BaselineConfig, data: BaselineData, res: FitResult, scores: dict[str, Any],
             lr_sweep: LrSweep | None) -> dict[str, Any]:
    """metrics.json: the held-out scores (``heldout.<model>``, ``heldout.nominal`` and their ratio), the learning
    rate and its sweep, the training record."""
    nom, own = scores["nominal"]["rollout_rmse"], scores[cfg.model]["rollout_rmse"]
    ratio = own / nom if nom > 0 else float("nan")
    return {"model": cfg.model, "sim": data.spec.sim, "recordings": str(data.rig.source),
            "holdout_trajectories": list(data.rig.holdout),
            "dt": data.train.dt, "train_trajectories": int(data.train.n_traj), "train_samples": int(data.train.T),
            "windows": data.windows.record(), "heldout": {**scores, f"{cfg.model}_over_nominal": ratio},
            "nominal_simulated_by": nominal_source(data.spec.sim),
            "lr": cfg.train.lr, "lr_sweep": None if lr_sweep is None else asdict(lr_sweep),
            "params": int(res.model.n_parameters()), "train_wall_time_s": res.wall_time_s,
            "best_val_loss": res.best_val, "best_epoch": res.best_epoch, "epochs_run": len(res.history),
            "nan_events": res.nan_events, "better_than_nominal": bool(math.isfinite(ratio) and ratio < 1.0)}


def _write(out: Path, res: FitResult, record: dict[str, Any], metrics: dict[str, Any]) -> None:
    from phast_gym.fileio import atomic_write_json

    from ..train.checkpoint import atomic_torch_save
    from ..train.runs import HISTORY_FILE, METRICS_FILE

    atomic_torch_save(res.model.state_dict(), out / MODEL_FILE)
    atomic_write_json(out / "config.json", record)
    atomic_write_json(out / METRICS_FILE, metrics)
    atomic_write_json(out / HISTORY_FILE, res.history)


def baseline_summary(metrics: dict[str, Any]) -> dict[str, Any]:
    """The headline numbers of a baseline run (what the CLI prints)."""
    name, h = metrics["model"], metrics["heldout"]
    return {f"heldout_{name}_rmse": h[name]["rollout_rmse"], "heldout_nominal_rmse": h["nominal"]["rollout_rmse"],
            f"{name}_over_nominal": h[f"{name}_over_nominal"], "lr": metrics["lr"],
            "train_wall_time_s": metrics["train_wall_time_s"], "best_epoch": metrics["best_epoch"]}


__all__ = ["BaselineConfig", "BaselineData", "Coarse", "LrSweep", "MODEL_FILE", "SWEEP_EPOCHS", "SWEEP_LRS",
           "WithVelocity", "baseline_summary", "build_baseline", "coarsen", "cut_seq_windows", "model_names",
           "prepare_baseline", "scored_model", "sweep_lr", "train_baseline", "train_baseline_run"]
