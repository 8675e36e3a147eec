"""Train one run and score it: the library function behind ``phast-train``, the benchmark harness and the examples.

* :func:`train_and_score` is the shared core: :func:`phast_model.train.fit.fit` (checkpoints in the run's
  directory, resumable), a refusal of non-finite weights, then the test metrics of
  :func:`phast_model.train.metrics.forecast_metrics`.  ``phast-train`` and every benchmark run
  (:func:`phast_model.bench.runner.run_one`, PHAST and baselines alike) train through it.
* :func:`train_run` is a whole PHAST run directory (what ``phast-train`` writes): checks, the dataset,
  :func:`train_and_score`, then ``model.pt`` + ``config.json`` (:func:`phast_model.train.checkpoint.save_run`,
  read back by :func:`phast_model.api.load_run`), ``metrics.json``, ``history.json`` and the plots of
  :func:`phast_model.train.plots.make_plots`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

from phast_gym.datasets import PortExcitation, check_noise_std

if TYPE_CHECKING:
    from phast_gym.datasets import Dataset

    from ..world.interfaces import ForecastModel, TimedTrajectories
    from ..world.model import PHAST
    from .fit import FitResult, TrainConfig

#: the run files :func:`train_run` writes besides the checkpoint
METRICS_FILE, HISTORY_FILE = "metrics.json", "history.json"


def train_and_score(model: ForecastModel, splits: Mapping[str, TimedTrajectories], cfg: TrainConfig,
                    run_dir: str | Path, identity: Mapping[str, object], resume: bool = False,
                    test: TimedTrajectories | None = None, horizons: tuple[int, ...] = (10, 50, 100),
                    burn_in: int = 10, energy: bool = True) -> tuple[FitResult, dict[str, float]]:
    """Train ``model`` on ``splits["train"]`` with best-validation selection on ``splits["val"]``, then score it.

    ``run_dir`` holds the resumable ``checkpoint.pt`` (``resume=True`` continues from it; ``identity`` is recorded
    in it and checked on resume).  Non-finite trained weights raise RuntimeError.  ``test`` (default
    ``splits["test"]``) is scored at ``horizons`` after ``burn_in`` true samples, with the energy diagnostics of the
    data's physics unless ``energy=False``.  Returns ``(FitResult, metrics)``."""
    import torch

    from .fit import fit
    from .metrics import forecast_metrics

    res = fit(model, splits["train"], splits["val"], cfg, run_dir=run_dir, resume=resume, identity=identity)
    if not all(bool(torch.isfinite(p).all()) for p in res.model.parameters()):
        raise RuntimeError("training produced non-finite parameters; nothing saved")
    metrics = forecast_metrics(res.model, splits["test"] if test is None else test, horizons=horizons, burn_in=burn_in,
                               energy=energy)
    return res, metrics


def check_split_sizes(n_train: int, n_val: int, n_test: int, T: int) -> None:
    """ValueError naming the flag when a split is empty or T is too short (before any work is done)."""
    for name, v in (("n_train", n_train), ("n_val", n_val), ("n_test", n_test)):
        if isinstance(v, bool) or int(v) != v or v < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be a positive integer (the {name[2:]} split cannot be "
                             f"empty), got {v!r}")
    if int(T) != T or T < 2:
        raise ValueError(f"--T must be an integer >= 2, got {T!r}")


@dataclass(frozen=True)
class DataSpec:
    """The dataset of one run: split sizes, trajectory length, dataset seed, observation noise and an optional
    port excitation.  Defaults = the paper's protocol (1000 / 200 / 200 trajectories of T = 200, seed 42, free
    motion).  Checked on construction, so a bad value fails before anything is generated or written."""

    n_train: int = 1000
    n_val: int = 200
    n_test: int = 200
    T: int = 200
    seed: int = 42
    obs_noise_std: float = 0.0
    excitation: PortExcitation | None = None

    def __post_init__(self) -> None:
        check_split_sizes(self.n_train, self.n_val, self.n_test, self.T)
        object.__setattr__(self, "obs_noise_std", check_noise_std(self.obs_noise_std))

    @property
    def excited(self) -> bool:
        """Whether the port is driven (free-motion runs record no excitation, so their identity is unchanged)."""
        return self.excitation is not None and self.excitation.std > 0

    def identity(self) -> dict[str, Any]:
        """The JSON record of this dataset, kept in checkpoints and ``config.json``."""
        d: dict[str, Any] = {"n_train": self.n_train, "n_val": self.n_val, "n_test": self.n_test, "T": self.T,
                             "seed": self.seed, "obs_noise_std": self.obs_noise_std}
        if self.excitation is not None and self.excited:
            d["port_excitation"] = asdict(self.excitation)
        return d

    def splits(self, env: str) -> dict[str, Dataset]:
        """Generate (or load from the cache) the train / val / test splits of ``env``."""
        from phast_gym import make_splits

        kw: dict[str, Any] = {"obs_noise_std": self.obs_noise_std} if self.obs_noise_std > 0 else {}
        if self.excitation is not None and self.excited:
            kw["u"] = self.excitation.for_env(env, self.n_train + self.n_val + self.n_test, self.T)
        return make_splits(env, self.n_train, self.n_val, self.n_test, T=self.T, seed=self.seed, **kw)


def train_run(env: str, regime: str, out: str | Path, *, data: DataSpec | None = None, train: TrainConfig | None = None,
              overrides: dict[str, Any] | None = None, resume: bool = False, plots: bool = True) -> dict[str, Any]:
    """Train a PHAST model (``regime``: known / partial / unknown) on ``env`` and write the run directory ``out``.

    The Python entry point of ``phast-train``; returns the metrics dict it writes to ``metrics.json``.  ``data``
    (default: the paper's protocol) says which dataset, ``train`` (default: paper Table 13) how to train, with the
    regime's trainer settings (:func:`phast_model.world.regimes.recipe`) in the fields it leaves None; its ``seed``
    also seeds the model's initialisation.  ``overrides`` are PHASTConfig fields.  Every argument is checked
    before any work (no dataset generated, nothing written), and one process at a time may write ``out``."""
    from phast_gym import resolve_env_id
    from phast_gym.fileio import dir_lock, ensure_writable_dir

    from ..world.model import build_from_config
    from ..world.regimes import recipe
    from .fit import CHECKPOINT, check_resume

    env = resolve_env_id(env)
    data = DataSpec() if data is None else data
    # the regime's recipe: the model config, and the training config (its settings where ``train`` leaves them None)
    rec = recipe(env, regime, train, seed=(train.seed if train is not None else 0), **(overrides or {}))
    cfg = rec.train
    model = build_from_config(rec.model)
    identity = {"env_id": env, "regime": regime, "data": data.identity(), "overrides": overrides or {}}
    out = ensure_writable_dir(out, "--out")
    with dir_lock(out):  # one writer per run directory
        if resume:
            check_resume(out / CHECKPOINT, cfg, identity)
        splits = data.splits(env)
        res, metrics = train_and_score(model, splits, cfg, out, identity, resume=resume)
        return _write_run(res, metrics, splits["test"], cfg, identity, out, plots)


def _write_run(res: FitResult, metrics: dict[str, Any], test: Dataset, cfg: TrainConfig,
               identity: dict[str, Any], out: Path, plots: bool) -> dict[str, Any]:
    """Save model.pt + config.json, metrics.json / history.json and the plots of a scored run."""
    from .checkpoint import atomic_write_json, save_run
    from .metrics import benchmark_metric

    env, regime = identity["env_id"], identity["regime"]
    save_run(cast("PHAST", res.model), out,  # train_run trains a PHAST model
             {"train": cfg.__dict__, "data": identity["data"], "overrides": identity["overrides"]})
    metrics.update({"train_wall_time_s": res.wall_time_s, "best_val": res.best_val, "best_epoch": res.best_epoch,
                    "nan_events": res.nan_events, "benchmark_metric": benchmark_metric(env)})
    metrics["benchmark_value"] = metrics.get(metrics["benchmark_metric"], float("nan"))
    atomic_write_json(out / METRICS_FILE, {"env_id": env, "regime": regime, "seed": cfg.seed, "epochs": cfg.epochs,
                                           **metrics})
    atomic_write_json(out / HISTORY_FILE, res.history)
    if plots:
        from .plots import make_plots

        make_plots(res.model, test, out)
    return metrics
