"""phast-bench on Ray: absolute --out, driver-side persistence, lost workers -> failed records, private local instance,
Ctrl-C, and the run-by-run comparison of two output directories (benchmarks/compare_runs.py).  A fake ``ray`` module
stands in for Ray (the default suite never needs it); the tests marked ``ray`` use the real one and are skipped
without it."""

from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys
import types
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from phast_model.bench import LocalExecutor, RayExecutor, grid, load_result, result_path, run_sweep
from phast_model.bench import executors as executors_mod
from phast_model.bench.compare import compare_dirs, format_table
from phast_model.bench.runner import (
    absolute_out_dir,
    lost_record,
    persist_record,
    run_one,
    safe_run_one,
    safe_run_one_waiting,
    write_record,
)
from phast_model.cli.bench import main
from tests import ROOT
from tests.bench.test_bench import ENV, TINY  # the tiny protocol the sweep tests share

CLI_TINY = ["--envs", "WindyPendulum-v0", "--models", "gru", "--epochs", "1", "--n-train", "6", "--n-val", "3", "--n-test", "3",
            "--T", "30", "--horizons", "5,10", "--burn-in", "5", "--train", "batch_size=4", "--no-progress"]


# --------------------------------------------------------------------------- a fake ray module
class _FakeRayError(Exception):
    pass


class _FakeWorkerCrashed(_FakeRayError):
    pass


class _FakeRay(types.ModuleType):
    """Just enough of ``ray`` for :class:`RayExecutor`: tasks run inline at ``.remote()``; a config with
    ``"_lose": True`` or a seed in ``lose_seeds`` is a task whose worker died (``ray.get`` raises WorkerCrashedError)."""

    def __init__(self) -> None:
        super().__init__("ray")
        self.exceptions = types.SimpleNamespace(RayError=_FakeRayError, WorkerCrashedError=_FakeWorkerCrashed)
        self.init_kwargs: dict[str, Any] | None = None
        self.remote_kwargs: dict[str, Any] | None = None
        self.cancelled: list[int] = []
        self.shut_down = False
        self.lose_seeds: set[int] = set()
        self._results: dict[int, Any] = {}

    def is_initialized(self) -> bool:
        return self.init_kwargs is not None and not self.shut_down

    def init(self, **kw: Any) -> None:
        self.init_kwargs = kw

    def remote(self, **kw: Any) -> Callable[[Callable[..., dict]], Any]:
        self.remote_kwargs = kw
        fake = self

        def wrap(fn: Callable[..., dict]) -> Any:
            if not inspect.isfunction(fn):  # as Ray: a function or a class, not a partial or other callable
                raise TypeError("The @ray.remote decorator must be applied to either a function or a class.")

            def submit(cfg: dict, out_dir: str, threads: int) -> int:
                ref = len(fake._results)
                lost = cfg.get("_lose") or cfg.get("seed") in fake.lose_seeds
                fake._results[ref] = _FakeWorkerCrashed("The worker died unexpectedly") if lost else fn(cfg, out_dir, threads)
                return ref

            return types.SimpleNamespace(remote=submit)

        return wrap

    def wait(self, refs: list[int], num_returns: int = 1) -> tuple[list[int], list[int]]:
        return refs[:num_returns], refs[num_returns:]

    def get(self, ref: int) -> Any:
        res = self._results[ref]
        if isinstance(res, BaseException):
            raise res
        return res

    def cancel(self, ref: int, force: bool = False) -> None:
        self.cancelled.append(ref)

    def shutdown(self) -> None:
        self.shut_down = True


@pytest.fixture
def fake_ray(monkeypatch: pytest.MonkeyPatch) -> Iterator[_FakeRay]:
    ray = _FakeRay()
    monkeypatch.setitem(sys.modules, "ray", ray)
    yield ray


def _echo(cfg: dict, out_dir: str, threads: int) -> dict:
    return {"status": "ran", "cfg": cfg, "out_dir": out_dir, "threads": threads}


# --------------------------------------------------------------------------- tests without ray
def test_absolute_out_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert absolute_out_dir("res/x") == tmp_path / "res" / "x"
    assert absolute_out_dir(tmp_path / "y") == tmp_path / "y"
    assert absolute_out_dir("~/z") == Path.home() / "z"


def test_relative_out_is_shipped_absolute(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A worker whose cwd is elsewhere (a Ray node) gets the driver's absolute --out, not the relative one."""
    seen: list[str] = []

    class Remote(LocalExecutor):
        def map_unordered(self, fn, configs, out_dir, on_lost=None):  # type: ignore[override]
            seen.append(out_dir)
            yield from super().map_unordered(fn, configs, out_dir, on_lost)

    monkeypatch.setattr(executors_mod, "make_executor", lambda *a, **k: Remote(workers=1))
    monkeypatch.chdir(tmp_path)
    specs = grid([ENV], ["gru"], [0], **TINY)
    recs = run_sweep(specs, "rel/out", progress=False)
    assert [r["status"] for r in recs] == ["ran"]
    assert seen == [str(tmp_path / "rel" / "out")] and Path(seen[0]).is_absolute()
    assert load_result(tmp_path / "rel" / "out", specs[0]) is not None


def test_record_from_a_worker_with_its_own_disk_is_written_by_the_driver(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The worker writes its result on *its* disk only; the driver writes the returned record, byte for byte the same."""
    worker_disk, driver_disk = tmp_path / "worker", tmp_path / "driver"

    class OwnDisk(LocalExecutor):
        def map_unordered(self, fn, configs, out_dir, on_lost=None):  # type: ignore[override]
            yield from super().map_unordered(fn, configs, str(worker_disk), on_lost)

    monkeypatch.setattr(executors_mod, "make_executor", lambda *a, **k: OwnDisk(workers=1))
    specs = grid([ENV], ["gru"], [0, 1], **TINY)
    recs = run_sweep(specs, driver_disk, progress=False)
    assert sorted(r["status"] for r in recs) == ["ran", "ran"]
    assert all(r.get("persisted_by") == "driver" for r in recs)
    for spec in specs:
        assert result_path(driver_disk, spec).read_bytes() == result_path(worker_disk, spec).read_bytes()
        assert "status" not in json.loads(result_path(driver_disk, spec).read_text())
    # resume: every run is found on the driver's disk, nothing is dispatched
    monkeypatch.setattr(executors_mod, "make_executor", lambda *a, **k: pytest.fail("nothing should be dispatched"))
    assert [r["status"] for r in run_sweep(specs, driver_disk, progress=False)] == ["cached", "cached"]


def test_persist_record_rules(tmp_path: Path) -> None:
    spec = grid([ENV], ["gru"], [0], **TINY)[0]
    rec = run_one(spec.config(), str(tmp_path / "w"))
    assert rec["status"] == "ran" and type(rec["torch"]) is str  # not torch's TorchVersion
    assert persist_record(tmp_path / "d", rec)["persisted_by"] == "driver"
    assert "persisted_by" not in persist_record(tmp_path / "d", rec)  # already there: untouched
    failed = {"status": "failed", "config": spec.config()}
    assert persist_record(tmp_path / "e", failed) is failed and not (tmp_path / "e").exists()
    with pytest.raises(ValueError, match="not a finished run record"):
        write_record(tmp_path / "e", {**rec, "key": "0" * 16})


def test_run_waits_for_a_run_directory_held_elsewhere(tmp_path: Path) -> None:
    """A rerun that meets a run still held by a dying task waits for it (and returns its result) instead of failing."""
    import threading
    import time

    from phast_gym.fileio import DirLocked, dir_lock
    from phast_model.bench.runner import work_dir

    spec = grid([ENV], ["gru"], [0], **TINY)[0]
    rec = run_one(spec.config(), str(tmp_path / "elsewhere"))
    out = tmp_path / "out"
    with dir_lock(work_dir(out, spec)):
        with pytest.raises(DirLocked):
            run_one(spec.config(), str(out))
        assert safe_run_one(spec.config(), str(out))["error"].startswith("DirLocked")
    release = threading.Event()

    def holder() -> None:  # holds the run, then finishes it and lets go
        with dir_lock(work_dir(out, spec)):
            release.set()
            time.sleep(1.0)
            write_record(out, rec)

    t = threading.Thread(target=holder)
    t.start()
    release.wait()
    try:
        got = run_one(spec.config(), str(out), lock_wait_s=30)
    finally:
        t.join()
    assert got["status"] == "cached" and got["metrics"] == rec["metrics"]


def test_lost_record() -> None:
    cfg = {"env_id": ENV, "model": "gru", "seed": 3}
    rec = lost_record(cfg, _FakeWorkerCrashed("The worker died unexpectedly\nmore detail"))
    assert rec["status"] == "failed" and (rec["env"], rec["model"], rec["seed"]) == (ENV, "gru", 3)
    assert rec["error"] == "worker lost: _FakeWorkerCrashed: The worker died unexpectedly"


def test_fake_ray_lost_task_becomes_failed_record(fake_ray: _FakeRay) -> None:
    ex = RayExecutor(threads=2)
    configs = [{"seed": 0}, {"seed": 1, "_lose": True}, {"seed": 2}]
    recs = list(ex.map_unordered(_echo, configs, "/abs/out", on_lost=lambda c, e: {"status": "failed", "cfg": c, "e": e}))
    assert [r["status"] for r in recs] == ["ran", "failed", "ran"]
    assert isinstance(recs[1]["e"], _FakeWorkerCrashed) and recs[1]["cfg"]["seed"] == 1
    assert fake_ray.remote_kwargs == {"num_cpus": 2, "max_retries": 1}
    with pytest.raises(_FakeWorkerCrashed):  # no on_lost: the error is raised
        list(ex.map_unordered(_echo, configs, "/abs/out"))
    ex.shutdown()
    assert fake_ray.shut_down


def test_fake_ray_interrupted_sweep_cancels_pending_tasks(fake_ray: _FakeRay) -> None:
    ex = RayExecutor()
    it = ex.map_unordered(_echo, [{"seed": s} for s in range(4)], "/abs/out")
    next(it)
    it.close()  # the consumer stopped (Ctrl-C, an error): the tasks not yet collected are cancelled
    assert fake_ray.cancelled == [1, 2, 3]


def test_fake_ray_private_instance_unless_address(fake_ray: _FakeRay) -> None:
    RayExecutor(workers=3)
    assert fake_ray.init_kwargs["address"] == "local" and fake_ray.init_kwargs["num_cpus"] == 3  # never attaches silently
    for address in ("auto", "127.0.0.1:6379"):
        fake_ray.init_kwargs, fake_ray.shut_down = None, False
        RayExecutor(address=address, workers=3)
        assert fake_ray.init_kwargs["address"] == address and "num_cpus" not in fake_ray.init_kwargs


def test_fake_ray_sweep_with_a_lost_worker(fake_ray: _FakeRay, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """One lost run does not end the sweep: it is a failed record and a FAILED line, the other run is stored."""
    fake_ray.lose_seeds = {1}
    submitted: list[Any] = []
    real_remote = fake_ray.remote

    def remote(**kw: Any) -> Callable[[Callable[..., dict]], Any]:
        def wrap(fn: Callable[..., dict]) -> Any:
            submitted.append(fn)
            return real_remote(**kw)(fn)

        return wrap

    fake_ray.remote = remote  # type: ignore[method-assign]
    out = tmp_path / "out"
    assert main(CLI_TINY + ["--seeds", "0-1", "--backend", "ray", "--out", str(out)]) == 1
    printed = capsys.readouterr().out
    assert "FAILED PHAST/WindyPendulum-v0 gru seed 1: worker lost: _FakeWorkerCrashed" in printed
    assert json.loads(printed[printed.index("{"):])["failed"] == 1
    assert len(list((out / "runs").rglob("*.json"))) == 1
    # on Ray a run held by a task of a killed driver is waited for, not failed at once
    assert submitted == [safe_run_one_waiting]


def test_cli_address_needs_ray_backend(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(CLI_TINY + ["--address", "auto", "--out", str(tmp_path)]) == 2
    assert "add --backend ray" in capsys.readouterr().err


def test_cli_ctrl_c_keeps_finished_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """Ctrl-C after one finished run: exit 130 with a resume hint; the rerun skips the finished run."""

    class Interrupted(LocalExecutor):
        def map_unordered(self, fn, configs, out_dir, on_lost=None):  # type: ignore[override]
            yield fn(configs[0], out_dir, self.threads)
            raise KeyboardInterrupt

    monkeypatch.setattr(executors_mod, "make_executor", lambda *a, **k: Interrupted(workers=1))
    args = CLI_TINY + ["--seeds", "0-1", "--out", str(tmp_path)]
    assert main(args) == 130
    assert "interrupted; 1/2 runs are finished" in capsys.readouterr().err
    monkeypatch.setattr(executors_mod, "make_executor", lambda *a, **k: LocalExecutor(workers=1))
    assert main(args) == 0
    assert {k: v for k, v in json.loads(capsys.readouterr().out).items() if k in ("ran", "cached")} == {"ran": 1, "cached": 1}


def _die(cfg: dict, out_dir: str, threads: int) -> dict:
    os._exit(1)


def test_local_pool_lost_worker_becomes_failed_record(tmp_path: Path) -> None:
    ex = LocalExecutor(workers=2)
    try:
        recs = list(ex.map_unordered(_die, [{"env_id": ENV, "model": "gru", "seed": s} for s in range(2)], str(tmp_path),
                                     on_lost=lost_record))
    finally:
        ex.shutdown()
    assert [r["status"] for r in recs] == ["failed", "failed"]
    assert all(r["error"].startswith("worker lost: BrokenProcessPool") for r in recs)


def test_compare_runs(tmp_path: Path) -> None:
    spec = grid([ENV], ["gru"], [0], **TINY)[0]
    a, b = tmp_path / "a", tmp_path / "b"
    rec = run_one(spec.config(), str(a))
    write_record(b, {**rec, "host": "elsewhere", "wall_time_s": 123.0,
                     "history": [{**h, "time_s": 9.0} for h in rec["history"]]})  # provenance and times differ only
    rows = compare_dirs(a, b)
    assert [r.status for r in rows] == ["identical"] and "1/1 runs bit-identical" in format_table(rows)
    script = [sys.executable, str(ROOT / "benchmarks" / "compare_runs.py")]

    def compare_runs(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([*script, *args], capture_output=True, text=True)

    same = compare_runs(str(a), str(b))
    assert same.returncode == 0 and "1/1 runs bit-identical" in same.stdout
    changed = {**rec, "metrics": {**rec["metrics"], "mse": rec["metrics"]["mse"] + 1e-15}}
    write_record(b, changed)
    rows = compare_dirs(a, b)
    assert rows[0].status == "differs" and rows[0].first_diff == "metrics.mse" and 0 < rows[0].max_abs_diff < 1e-14
    assert compare_runs(str(a), str(b)).returncode == 1
    other = grid([ENV], ["gru"], [1], **TINY)[0]
    write_record(b, run_one(other.config(), str(tmp_path / "c")))
    assert {r.status for r in compare_dirs(a, b)} == {"differs", "only in B"}
    bad = compare_runs(str(a), str(tmp_path / "nope"))
    assert bad.returncode == 2 and "no runs/ directory" in bad.stderr
    assert compare_runs("--help").returncode == 0


# --------------------------------------------------------------------------- real ray (marker 'ray', skipped without it)
@pytest.mark.ray
def test_real_ray_lost_worker_and_private_instance(tmp_path: Path) -> None:
    ray = pytest.importorskip("ray")
    ex = RayExecutor(workers=2, max_retries=0)
    try:
        assert ray.is_initialized()

        def crash(cfg: dict, out_dir: str, threads: int) -> dict:  # nested: shipped by value to the worker
            if cfg["seed"] == 1:
                os._exit(1)
            return {"status": "ran", "seed": cfg["seed"], "out_dir": out_dir}

        configs = [{"env_id": ENV, "model": "gru", "seed": s} for s in range(2)]
        recs = sorted(ex.map_unordered(crash, configs, str(tmp_path), on_lost=lost_record), key=lambda r: r["seed"])
    finally:
        ex.shutdown()
    assert not ray.is_initialized()
    assert recs[0] == {"status": "ran", "seed": 0, "out_dir": str(tmp_path)}
    assert recs[1]["status"] == "failed" and recs[1]["error"].startswith("worker lost:"), recs[1]


@pytest.mark.ray
def test_real_ray_sweep_safe_run_one(tmp_path: Path) -> None:
    pytest.importorskip("ray")
    specs = grid([ENV], ["gru"], [0], **TINY)
    recs = run_sweep(specs, tmp_path, backend="ray", workers=1, progress=False)
    assert [r["status"] for r in recs] == ["ran"], [r.get("error") for r in recs]
    assert safe_run_one(specs[0].config(), str(tmp_path))["status"] == "cached"
