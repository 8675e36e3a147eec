"""``phast-train --recordings``: a run directory of a world model learned from a rig's recordings.

:func:`train_recordings_run` checks everything first (recordings, rig, held-out indices, room for the held-out
windows), trains by multiple shooting (:func:`phast_model.train.rig_fit.fit_recordings`), scores PHAST and the nominal
rig on the held-out recordings by the same code (:func:`phast_model.train.rig_heldout.heldout_rollouts`) and writes
``model.pt`` + ``config.json`` (opened by :func:`phast_model.api.load_run` and
:class:`phast_model.world.gym_env.PHASTWorldModelEnv`), ``metrics.json`` (key ``heldout``), ``history.json``,
``checkpoint.pt`` (written after every epoch; ``resume=True`` continues from it) and the plots ``heldout_rollout.png``
and ``friction.png``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.systems import System

from ..identify.recordings import Recordings
from ..identify.signals import estimate_noise
from ..train.runs import HISTORY_FILE, METRICS_FILE
from .rig_fit import (
    BURN_IN_S,
    RigData,
    RigFit,
    RigTrainConfig,
    build,
    fit_recordings,
    load_rig_data,
    nominal_config,
    rig_config,
    window_rmse,
)
from .rig_heldout import heldout_rollouts, heldout_windows, nominal_entries, nominal_source


@dataclass(frozen=True)
class RecordingsSpec:
    """What a recordings run learns from: the file, the rig (env id or ``path.py:Class``) with its kwargs, the regime,
    the held-out trajectories and the held-out window length (None: whole recordings)."""

    recordings: str | dict[str, Any]  # a path, or the arrays themselves
    sim: str
    sim_kwargs: dict[str, Any]
    regime: str = "partial"
    holdout: tuple[int, ...] | None = None
    rollout_window_s: float | None = None
    action_bound: tuple[float, ...] | None = None  # the world env's torque bound (None: the largest recorded |u|)
    decimate: int = 1  # keep every k-th sample (free motion only)
    #: other models of the rig scored on the same held-out windows (``heldout.<name>``): phast_gym systems, e.g. the
    #: phast-mismatch augmented model (``Report.augmented_system``) or an identified model written as a rig
    compare: Mapping[str, System] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        w = self.rollout_window_s
        if w is not None and not (w > 0 and math.isfinite(w)):
            raise ValueError(f"--rollout-window-s must be a positive number of seconds, got {w!r}")


def sim_name(sim: str) -> str:
    """A rig file path made absolute, so the run opens from any working directory."""
    path, sep, cls = sim.rpartition(":")
    if sep and path.endswith(".py"):
        return f"{Path(path).resolve()}:{cls}"
    return sim


def _source(recordings: str | dict[str, Any]) -> Any:
    return recordings if isinstance(recordings, dict) else str(recordings)


def prepare(spec: RecordingsSpec) -> RigData:
    """Load and check the recordings; ValueError (a message naming the problem) before any training."""
    data = load_rig_data(_source(spec.recordings), spec.sim, spec.sim_kwargs,
                         list(spec.holdout) if spec.holdout else None, spec.decimate)
    heldout_windows(heldout_part(data), spec.rollout_window_s, BURN_IN_S)  # room for a burn-in plus one window
    return data


def heldout_part(data: RigData) -> Recordings:
    """The held-out recordings (ValueError without them: the score needs recordings the model is not trained on)."""
    if data.heldout is None:
        raise ValueError("give --holdout-trajectories: the held-out score needs recordings the model is not trained on")
    return data.heldout


def train_recordings_run(spec: RecordingsSpec, out: str | Path, train: RigTrainConfig | None = None,
                         overrides: dict[str, Any] | None = None, plots: bool = True,
                         resume: bool = False) -> dict[str, Any]:
    """Train on ``spec``'s recordings and write the run directory ``out``; returns the metrics written.  ``resume``
    continues from ``out/checkpoint.pt`` (ValueError when it is missing, unreadable or of another run: another
    recordings spec, model config or training config)."""
    from phast_gym.fileio import dir_lock, ensure_writable_dir

    train = train or RigTrainConfig()
    spec = replace(spec, sim=sim_name(spec.sim))
    data = prepare(spec)
    heldout = heldout_part(data)
    bound = list(spec.action_bound) if spec.action_bound else [max(b, 1e-6) for b in data.u_bound]
    cfg = rig_config(spec.sim, spec.sim_kwargs, spec.regime, data, seed=train.seed, action_bound=bound,
                     **(overrides or {}))
    out = ensure_writable_dir(out, "--out")
    with dir_lock(out):
        model = build(cfg)
        identity = {"model": cfg.to_dict(), "recordings": spec_record(spec, str(data.source))}
        fit = fit_recordings(model, data, train, run_dir=out, resume=resume, identity=identity)
        nominal = build(nominal_config(cfg))
        models, compare = nominal_entries(nominal, spec.sim, spec.compare)
        scores, rolls, windows = heldout_rollouts({"phast": fit.model, **models}, heldout, spec.rollout_window_s,
                                                  compare=compare)
        levels = FitLevels(_noise(data.train), window_rmse(nominal, data, train))
        metrics = _metrics(spec, data, fit, scores, levels)
        _write(fit, metrics, spec, train, out)
        if plots:
            from .rig_plots import plot_friction, plot_heldout

            plot_heldout(windows, rolls, heldout.dt, out / "heldout_rollout.png")
            metrics["friction_check"] = plot_friction(fit.model, nominal.system, data.train, out / "friction.png")
            from ..train.checkpoint import atomic_write_json

            atomic_write_json(out / METRICS_FILE, metrics)
    return metrics


#: a run whose training windows' RMSE is above this multiple of the recordings' noise, and above the nominal model's
#: on the same windows, has not converged
NOT_CONVERGED = 10.0


@dataclass(frozen=True)
class FitLevels:
    """What a run's training-window RMSE is judged against: the recordings' noise and the nominal model's RMSE on the
    same windows (:func:`phast_model.train.rig_fit.window_rmse`)."""

    noise: float
    nominal: float


def verdict(train_rmse: float, epochs: int, levels: FitLevels, over_nominal: float) -> dict[str, bool | str | float]:
    """Whether the run learned the rig, in one sentence a user reads first: it did not converge (its training windows'
    RMSE is above :data:`NOT_CONVERGED` x the recordings' noise and above the nominal model's on the same windows),
    or it predicts the held-out recordings worse than the nominal model (``over_nominal`` > 1), or it is usable."""
    converged = bool(np.isfinite(train_rmse)
                     and (train_rmse <= NOT_CONVERGED * levels.noise or train_rmse < levels.nominal))
    better = bool(np.isfinite(over_nominal) and over_nominal < 1.0)
    fit = (f"training RMSE {train_rmse:.3g} after {epochs} epochs (the nominal model {levels.nominal:.3g} on the same "
           f"windows; the recordings' noise about {levels.noise:.2g})")
    held = f"held-out rollout RMSE {over_nominal:.3g}x the nominal model's"
    if not converged:
        message = f"did not converge: {fit}; {held}"
    elif not better:
        message = f"worse than the nominal model: {held}; {fit}"
    else:
        message = f"converged: {fit}; {held}"
    return {"converged": converged, "better_than_nominal": better, "message": message, "train_rmse": train_rmse,
            "nominal_train_rmse": levels.nominal, "noise": levels.noise}


def _noise(rec: Recordings) -> float:
    """The recordings' measurement noise (RMS over coordinates), from their 4th differences."""
    return float(np.sqrt(np.mean(estimate_noise(rec.q, rec.t) ** 2)))


def _metrics(spec: RecordingsSpec, data: RigData, fit: RigFit, scores: dict[str, Any],
             levels: FitLevels) -> dict[str, Any]:
    """metrics.json: the held-out scores (``heldout.phast.rollout_rmse``, ``heldout.nominal.rollout_rmse``), the
    learned friction and the training record."""
    nom = scores["nominal"]["rollout_rmse"]
    ratios = {f"{name}_over_nominal": scores[name]["rollout_rmse"] / nom if nom > 0 else float("nan")
              for name in ("phast", *(spec.compare or {}))}
    friction = fit.model.friction
    return {
        "sim": spec.sim, "regime": spec.regime, "recordings": str(data.source),
        "holdout_trajectories": list(data.holdout),
        "dt": data.train.dt, "train_trajectories": int(data.train.n_traj), "train_samples": int(data.train.T),
        "heldout": {**scores, **ratios},
        "nominal_simulated_by": nominal_source(spec.sim),
        "friction": None if friction is None else {k: v.detach().tolist() for k, v in friction.coefficients().items()},
        "train_wall_time_s": fit.wall_time_s, "best_val_rmse": fit.best_val, "best_epoch": fit.best_epoch,
        "epochs_run": len(fit.history), "stopped_early": fit.stopped_early, "nan_skipped": fit.nan_skipped,
        "nan_rollbacks": fit.nan_rollbacks, "init": fit.init,
        "verdict": verdict(fit.best_val, len(fit.history), levels, ratios["phast_over_nominal"]),
    }


def spec_record(spec: RecordingsSpec, source: str) -> dict[str, Any]:
    """The recordings spec as config.json records it (and as the checkpoint's identity checks it on resume)."""
    return {**{f.name: getattr(spec, f.name) for f in fields(spec) if f.name != "compare"},
            "recordings": source, "holdout": list(spec.holdout or ()), "compare": sorted(spec.compare or {})}


def _write(fit: RigFit, metrics: dict[str, Any], spec: RecordingsSpec, train: RigTrainConfig, out: Path) -> None:
    from ..train.checkpoint import atomic_write_json, save_run

    save_run(fit.model, out, {"train": asdict(train), "recordings": spec_record(spec, metrics["recordings"])})
    atomic_write_json(out / METRICS_FILE, metrics)
    atomic_write_json(out / HISTORY_FILE, fit.history)


def heldout_summary(metrics: dict[str, Any]) -> dict[str, float]:
    """The headline numbers of a recordings run (what the CLI prints)."""
    h = metrics["heldout"]
    out = {"heldout_phast_rmse": h["phast"]["rollout_rmse"], "heldout_nominal_rmse": h["nominal"]["rollout_rmse"],
           "phast_over_nominal": h["phast_over_nominal"], "train_wall_time_s": metrics["train_wall_time_s"],
           "verdict": metrics["verdict"]["message"]}
    compared = [k[: -len("_over_nominal")] for k in h if k.endswith("_over_nominal") and k != "phast_over_nominal"]
    if compared:
        out["compared"] = {name: {"heldout_rmse": h[name]["rollout_rmse"], "over_nominal": h[f"{name}_over_nominal"]}
                           for name in compared}
    return out


__all__ = ["RecordingsSpec", "train_recordings_run", "prepare", "heldout_part", "heldout_summary", "sim_name",
           "spec_record"]


def headline(metrics: dict[str, Any], regime: str, reference: dict[str, float], out: Path) -> dict[str, Any]:
    """What the real-rig examples print and store: the held-out scores, the learned friction, the friction check."""
    check = {k: {kk: v[kk] for kk in ("bands_inside_ci95", "bands", "fraction_inside")}
             for k, v in metrics.get("friction_check", {}).items()}
    return {**heldout_summary(metrics), "regime": regime, "friction": metrics["friction"], "friction_check": check,
            "reference": reference, "run_dir": str(out)}


def example_cli(argv: list[str] | None, description: str, default_data: Path,
                run: Callable[..., Mapping[str, object]], name: str) -> int:
    """The command line of a real-rig example: ``--data --out --regime --epochs --seed --json --quiet``; ``run(data,
    out, regime, epochs, progress, seed)`` returns the headline dict."""
    import argparse
    import json
    import sys

    from phast_gym.fileio import atomic_write_json

    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--data", type=Path, default=default_data)
    ap.add_argument("--out", type=Path, required=True, help="run directory")
    ap.add_argument("--regime", default="partial", choices=("known", "partial", "unknown"))
    ap.add_argument("--epochs", type=int, default=RigTrainConfig().epochs)
    ap.add_argument("--seed", type=int, default=RigTrainConfig().seed,
                    help="the training seed (initialization, validation split, the windows drawn each epoch)")
    ap.add_argument("--json", type=Path, help="write the headline numbers here")
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    try:
        res = run(args.data, args.out, args.regime, args.epochs, progress=not args.quiet, seed=args.seed)
    except ValueError as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(res, indent=1))
    if args.json:
        atomic_write_json(args.json, res)
    return 0
