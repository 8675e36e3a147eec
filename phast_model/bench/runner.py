"""The one run function shared by every executor, and the sweep driver.

``run_one(config, out_dir)`` trains and scores one (env, model, seed) with
:func:`phast_model.train.runs.train_and_score`, the function behind ``phast-train`` too (same
optimizer, schedule, epochs and best-validation selection for PHAST and baselines, the
metrics of :func:`phast_model.train.metrics.forecast_metrics`); the result JSON is written atomically under
``out_dir/runs/`` and named by the configuration hash, so a finished run is
never redone and an interrupted sweep resumes where it stopped.

The worker returns the record too, and the sweep driver writes it where it is missing on the driver's disk
(:func:`persist_record`): on a cluster whose nodes do not share a disk no result is lost.  ``out_dir`` is
made absolute before it is shipped to workers (:func:`absolute_out_dir`), whose working directory differs.
"""

from __future__ import annotations

import dataclasses
import json
import platform
import socket
import time
import traceback
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from phast_gym.fileio import atomic_write_text, dir_lock
from phast_gym.fileio import jsonable as _jsonable

from ..train.provenance import code_commit
from .spec import RunRecord, RunSpec, run_key

if TYPE_CHECKING:
    from phast_gym.datasets import Dataset

    from ..train.config import TrainConfig
    from ..world.interfaces import ForecastModel


def run_slug(spec: RunSpec) -> str:
    """Relative path stem of a run: ``<env>/<model>/seed<k>-<hash>``."""
    env = spec.env_id.replace("PHAST/", "").replace("/", "_")
    fs = "-fullstate" if spec.full_state else ""
    return f"{env}{fs}/{spec.model}/seed{spec.seed}-{run_key(spec)}"


def result_path(out_dir: str | Path, spec: RunSpec) -> Path:
    return Path(out_dir) / "runs" / f"{run_slug(spec)}.json"


def absolute_out_dir(out_dir: str | Path) -> Path:
    """``out_dir`` as an absolute path (``~`` expanded): the form shipped to workers, whose working directory may
    differ from the driver's (a Ray worker starts in the directory its node was started from)."""
    return Path(out_dir).expanduser().absolute()


#: record fields that describe one delivery of a run, not the run: never stored in its result file
TRANSIENT_FIELDS = ("status", "persisted_by")


def write_record(out_dir: str | Path, rec: RunRecord) -> Path:
    """Write a finished run's record (its transient fields dropped) to its result file, atomically; the same bytes
    whether a worker or the driver writes it."""
    spec = RunSpec.from_config(rec["config"])
    if rec.get("key") != run_key(spec) or not isinstance(rec.get("metrics"), dict):
        raise ValueError(f"not a finished run record of {spec.env_id} {spec.model} seed {spec.seed} "
                         "(key or metrics missing)")
    stored = {k: v for k, v in rec.items() if k not in TRANSIENT_FIELDS}
    return atomic_write_text(result_path(out_dir, spec), json.dumps(stored, indent=1, sort_keys=True))


def persist_record(out_dir: str | Path, rec: RunRecord) -> RunRecord:
    """Driver side: write a returned record (ran or cached on its worker) whose result file this machine lacks.

    On one machine, or nodes sharing a disk, the worker already wrote it and nothing happens; on a node with its
    own disk the record only reached the driver through the return value, and is written here.  Returns the
    record, marked ``persisted_by: "driver"`` when written here."""
    if rec.get("status") not in ("ran", "cached"):
        return rec
    if load_result(out_dir, RunSpec.from_config(rec["config"])) is not None:
        return rec
    write_record(out_dir, rec)
    return {**rec, "persisted_by": "driver"}


def failed_record(config: dict[str, Any], error: str, tb: str = "") -> RunRecord:
    """The record of a run that produced no result (it raised, or its worker was lost)."""
    return {"status": "failed", "env": config.get("env_id"), "model": config.get("model"), "seed": config.get("seed"),
            "config": config, "error": error, "traceback": tb}


def lost_record(config: dict[str, Any], exc: BaseException) -> RunRecord:
    """The failed record of a run whose worker was lost (``on_lost`` of the executors); rerunning the sweep retries
    it."""
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return failed_record(config, f"worker lost: {type(exc).__name__}: {first}".rstrip(": "),
                         "".join(traceback.format_exception_only(exc)))


#: the trained weights of a benchmark run (a bare state dict) in its :func:`work_dir`, read by the figures
BENCH_MODEL_FILE = "bench_model.pt"


def work_dir(out_dir: str | Path, spec: RunSpec) -> Path:
    """Checkpoint directory of a run (``fit(..., resume=True)`` resumes from it)."""
    return Path(out_dir) / "work" / run_slug(spec)


def load_result(out_dir: str | Path, spec: RunSpec) -> RunRecord | None:
    """The stored result of ``spec`` if it exists, is complete and matches its hash; else None."""
    path = result_path(out_dir, spec)
    if not path.exists():
        return None
    try:
        rec = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    if rec.get("key") != run_key(spec) or not isinstance(rec.get("metrics"), dict):
        return None
    return rec


#: HEAD when this module was imported (the code a long-lived worker actually runs; provenance only, not hashed)
_CODE_COMMIT = code_commit()


# --------------------------------------------------------------------------- data + models
def load_splits(spec: RunSpec) -> dict[str, Dataset]:
    """The run's train/val/test datasets (cached on disk by phast_gym); full-state runs see (q, p)."""
    from phast_gym.datasets import make_splits

    splits = make_splits(spec.env_id, spec.n_train, spec.n_val, spec.n_test, T=spec.T, seed=spec.data_seed)
    if spec.full_state:
        splits = {k: full_state_view(v) for k, v in splits.items()}
    return splits


def full_state_view(ds: Dataset) -> Dataset:
    """The dataset with ``q`` replaced by the full state ``(q, p)`` (paper Appendix H.1 ablation)."""
    q = np.concatenate([ds.q, ds.p], axis=-1)
    return dataclasses.replace(ds, q=q, q_true=np.concatenate([ds.q_true, ds.p], axis=-1))


def build_run_model(spec: RunSpec, train: Dataset) -> ForecastModel:
    """PHAST (via :func:`phast_model.world.regimes.build_model`) or a baseline (via :func:`make_baseline`)."""
    if spec.model.startswith("phast-"):
        from phast_model.world.regimes import build_model

        # the run's seed is the model's seed (its initial weights), as in ``phast-train --seed``
        phast = build_model(spec.env_id, spec.model.split("-", 1)[1], **{"seed": spec.seed, **spec.model_kw})
        if spec.full_state:  # p observed: the core on (q, p), no observer (paper Table 25)
            from phast_model.world.fullstate import FullStatePHAST

            return FullStatePHAST(phast)
        return phast
    from phast_model.baselines import make_baseline
    from phast_model.world.interfaces import NormalizedModel

    n, m = train.q.shape[-1], train.u.shape[-1]
    kw = dict(spec.model_kw)
    if spec.model == "dhnn":
        if not spec.full_state:
            raise ValueError("dhnn is the full-state ablation: run it with full_state=True (--full-state)")
        kw.setdefault("dt", float(train.dt))
    model = make_baseline(spec.model, n, m, tuple(train.angle_dims), **kw)
    if isinstance(model, NormalizedModel):
        model.fit_normalizer(train.q, train.u)
    return model


def make_train_config(spec: RunSpec) -> TrainConfig:
    """``TrainConfig(epochs, seed, progress=False, **spec.train)``, with a PHAST regime's trainer settings
    (:func:`phast_model.world.regimes.recipe`) where it leaves them None; unknown fields are a clear error."""
    from phast_model.train.fit import TrainConfig

    names = {f.name for f in dataclasses.fields(TrainConfig)}
    bad = sorted(set(spec.train) - names)
    if bad:
        raise ValueError(f"unknown TrainConfig field(s) {bad}; known: {sorted(names)}")
    cfg = TrainConfig(**{"epochs": spec.epochs, "seed": spec.seed, **spec.train, "progress": False})
    if spec.model.startswith("phast-"):  # the regime's trainer settings where spec.train leaves them None
        from phast_model.world.regimes import recipe

        cfg = recipe(spec.env_id, spec.model.split("-", 1)[1], cfg, **{"seed": spec.seed, **spec.model_kw}).train
    return cfg


# --------------------------------------------------------------------------- the run function
#: seconds a Ray task waits for a run directory another process holds (see :func:`run_sweep`)
RAY_LOCK_WAIT_S = 60.0


def run_one(config: dict[str, Any], out_dir: str, threads: int = 1, lock_wait_s: float = 0.0) -> RunRecord:
    """Train + evaluate one run (or return its stored result).  Same function for every executor.

    One writer per run: while another process holds the run's directory this waits up to ``lock_wait_s`` seconds
    (returning the result if the holder finishes it), then raises :class:`phast_gym.fileio.DirLocked`."""
    import torch

    spec = RunSpec.from_config(config)
    cached = load_result(out_dir, spec)
    if cached is not None:
        return {**cached, "status": "cached"}
    torch.set_num_threads(max(1, int(threads)))
    wdir = work_dir(out_dir, spec)
    with dir_lock(wdir, wait_s=lock_wait_s):
        cached = load_result(out_dir, spec)  # finished while we waited for the lock
        if cached is not None:
            return {**cached, "status": "cached"}
        return _train_and_score(spec, out_dir, wdir)


def _train_and_score(spec: RunSpec, out_dir: str, wdir: Path) -> RunRecord:
    import torch

    from phast_model.train.checkpoint import atomic_torch_save
    from phast_model.train.runs import train_and_score

    t0 = time.perf_counter()
    splits = load_splits(spec)
    torch.manual_seed(spec.seed)
    np.random.seed(spec.seed)
    model = build_run_model(spec, splits["train"])
    # the energy diagnostics read q as positions: not defined for full-state (q, p) inputs
    fit_res, metrics = train_and_score(model, splits, make_train_config(spec), wdir, spec.config(), resume=True,
                                       horizons=tuple(spec.horizons), burn_in=spec.burn_in, energy=not spec.full_state)
    fitted = fit_res.model
    # the weights the metrics came from, for figures (state_dict only: torch.load(weights_only=True))
    atomic_torch_save(fitted.state_dict(), wdir / BENCH_MODEL_FILE)
    rec: RunRecord = {
        "key": run_key(spec), "env": spec.env_id, "model": spec.model, "seed": spec.seed,
        "config": spec.config(), "metrics": _jsonable(metrics), "params": int(fitted.n_parameters()),
        "best_val": _jsonable(fit_res.best_val),
        "fit_wall_time_s": float(fit_res.wall_time_s), "wall_time_s": time.perf_counter() - t0,
        "history": _jsonable(list(fit_res.history)),
        "git_commit": _CODE_COMMIT, "host": socket.gethostname(), "python": platform.python_version(),
        "torch": str(torch.__version__),
        "threads": torch.get_num_threads(), "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    write_record(out_dir, rec)
    return {**rec, "status": "ran"}


def safe_run_one(config: dict[str, Any], out_dir: str, threads: int = 1, lock_wait_s: float = 0.0) -> RunRecord:
    """:func:`run_one` that reports a failure as a record instead of raising (one bad run keeps the sweep going)."""
    try:
        return run_one(config, out_dir, threads, lock_wait_s)
    except Exception as exc:  # noqa: BLE001 - reported to the caller with its traceback
        return failed_record(config, f"{type(exc).__name__}: {exc}", traceback.format_exc())


def safe_run_one_waiting(config: dict[str, Any], out_dir: str, threads: int = 1) -> RunRecord:
    """:func:`safe_run_one` waiting up to :data:`RAY_LOCK_WAIT_S` for a run directory another process holds (the Ray
    task function: a plain function, as ``ray.remote`` needs)."""
    return safe_run_one(config, out_dir, threads, lock_wait_s=RAY_LOCK_WAIT_S)


# --------------------------------------------------------------------------- sweeps
def grid(envs: Iterable[str], models: Iterable[str], seeds: Iterable[int], **common: Any) -> list[RunSpec]:
    """The cross product env x model x seed; DHNN runs are full-state, others q-only."""
    out = []
    for env in envs:
        for model in models:
            for seed in seeds:
                kw = dict(common)
                if model == "dhnn":
                    kw["full_state"] = True
                out.append(RunSpec(env_id=env, model=model, seed=int(seed), **kw))
    return out


def run_sweep(specs: list[RunSpec], out_dir: str | Path, backend: str = "local", workers: int | None = None,
              address: str | None = None, progress: bool = True, threads: int = 1) -> list[RunRecord]:
    """Run every spec not already finished in ``out_dir``; return all records (cached, ran or failed).

    Finished runs are read from disk in this process and never dispatched, so a
    repeated call with the same grid does no work.  Each returned record is written by this process where its
    worker's disk is not this one (:func:`persist_record`); a run whose worker is lost becomes a failed record.
    """
    from .executors import make_executor

    out_dir = absolute_out_dir(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    records: list[RunRecord] = []
    pending: list[RunSpec] = []
    specs = list({run_key(s): s for s in specs}.values())  # a run asked for twice runs once
    for spec in specs:
        rec = load_result(out_dir, spec)
        if rec is None:
            pending.append(spec)
        else:
            records.append({**rec, "status": "cached"})
    if pending:
        ex = make_executor(backend, workers=workers, address=address, threads=threads)
        try:
            configs = [s.config() for s in pending]
            # a killed Ray driver's tasks are stopped by Ray a few seconds later (local workers die with their
            # parent): a rerun started at once waits for their run directories instead of failing those runs
            fn = safe_run_one_waiting if ex.name == "ray" else safe_run_one
            it = ex.map_unordered(fn, configs, str(out_dir), on_lost=lost_record)
            if progress:
                from tqdm.auto import tqdm

                it = tqdm(it, total=len(configs), desc=f"phast-bench ({ex.name}, {len(records)} cached)", unit="run")
            for rec in it:
                try:
                    rec = persist_record(out_dir, rec)
                except (OSError, ValueError) as exc:  # keep the sweep (and this record, in memory) going
                    print(f"[phast-bench] could not store {rec.get('env')} {rec.get('model')} seed {rec.get('seed')}: "
                          f"{exc}", flush=True)
                if rec.get("status") == "failed":
                    print(f"[phast-bench] FAILED {rec['env']} {rec['model']} seed {rec['seed']}: {rec['error']}",
                          flush=True)
                records.append(rec)
        finally:
            ex.shutdown()
    return records
