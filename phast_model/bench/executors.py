"""Executors behind one interface: run the same function over many run configs.

* :class:`LocalExecutor` (default): a process pool over the machine's cores
  (``spawn`` context, one torch thread per worker); ``workers=1`` runs inline.  Workers
  die with the process that started them (a killed sweep leaves none behind).
* :class:`RayExecutor` (``--backend ray``, extra ``ray``): one Ray task per run
  (``num_cpus=threads``) on a running cluster (``address``, e.g. ``auto`` or ``HOST:PORT``) or, with no
  address, on a private local instance started for this sweep and stopped after it.  Ray is imported
  lazily, so the harness works without it.

Both yield results as runs finish (``map_unordered``).  A run whose worker is lost (killed, out of memory,
its node gone) is handed to ``on_lost(config, exc)``, which turns it into a record (a failed run), so one
lost worker never ends the sweep; without ``on_lost`` the error is raised.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from types import ModuleType
from typing import Any

from .spec import RunRecord

#: ``on_lost(config, exc)``: the record of a run whose worker was lost
OnLost = Callable[[dict[str, Any], BaseException], RunRecord]


class Executor:
    """Interface: ``map_unordered(fn, configs, out_dir, on_lost)`` yields ``fn(config, out_dir, threads)`` as they
    finish."""

    name = "base"

    def map_unordered(self, fn: Callable[..., RunRecord], configs: list[dict[str, Any]], out_dir: str,
                      on_lost: OnLost | None = None) -> Iterator[RunRecord]:  # pragma: no cover
        raise NotImplementedError

    def shutdown(self) -> None:
        """Release workers (idempotent)."""


def _exit_with_parent(parent_pid: int, poll_s: float = 0.5) -> None:
    """Make this worker die with the sweep that started it: on Linux the kernel sends SIGKILL when the parent
    dies (``PR_SET_PDEATHSIG``); everywhere, a daemon thread exits the process once it is orphaned (its parent
    pid changes).  A killed ``phast-bench`` so leaves no worker training and writing checkpoints."""
    import signal
    import sys
    import threading
    import time

    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, int(signal.SIGKILL), 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
        except (OSError, AttributeError):  # pragma: no cover - no libc prctl: the watchdog still runs
            pass
    if os.getppid() != parent_pid:  # the parent died before the signal was armed
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(poll_s)
        os._exit(1)

    threading.Thread(target=watch, name="phast-bench-parent-watch", daemon=True).start()


def _init_worker(threads: int, parent_pid: int | None = None) -> None:
    if parent_pid is not None:
        _exit_with_parent(parent_pid)
    os.environ.setdefault("OMP_NUM_THREADS", str(threads))
    import torch

    torch.set_num_threads(threads)


class LocalExecutor(Executor):
    """Process pool over local cores (``workers`` defaults to ``os.cpu_count()``)."""

    name = "local"

    def __init__(self, workers: int | None = None, threads: int = 1) -> None:
        for name, v in (("workers", workers), ("threads", threads)):
            if v is not None and (isinstance(v, bool) or int(v) != v or v < 1):
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        self.workers = int(workers or os.cpu_count() or 1)
        self.threads = int(threads)
        self._pool: ProcessPoolExecutor | None = None

    def map_unordered(self, fn: Callable[..., RunRecord], configs: list[dict[str, Any]], out_dir: str,
                      on_lost: OnLost | None = None) -> Iterator[RunRecord]:
        if self.workers == 1 or len(configs) <= 1:
            for cfg in configs:  # inline: no process start-up, easiest to debug
                yield fn(cfg, out_dir, self.threads)
            return
        self._pool = ProcessPoolExecutor(max_workers=min(self.workers, len(configs)), mp_context=get_context("spawn"),
                                         initializer=_init_worker, initargs=(self.threads, os.getpid()))
        futures = {self._pool.submit(fn, cfg, out_dir, self.threads): cfg for cfg in configs}
        pending = set(futures)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                try:
                    yield f.result()
                except BrokenProcessPool as exc:  # a worker died (killed, out of memory): this run is lost
                    if on_lost is None:
                        raise
                    yield on_lost(futures[f], exc)

    def shutdown(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


def _import_ray() -> ModuleType:
    try:
        import ray
    except ImportError:
        raise ImportError("the Ray backend needs the 'ray' extra: pip install 'phast[ray]' "
                          "(or pip install 'ray[default]')") from None
    return ray


def ray_lost_errors(ray: ModuleType) -> tuple[type[BaseException], ...]:
    """The errors ``ray.get`` raises for a task that did not return (``ray.exceptions.RayError``: worker crashed or
    killed, node died, result lost, out of memory, cancelled).  The run function itself never raises: it returns
    failures as records."""
    err = getattr(getattr(ray, "exceptions", None), "RayError", None)
    return (err,) if isinstance(err, type) and issubclass(err, BaseException) else (Exception,)


class RayExecutor(Executor):
    """One Ray task per run.

    ``address`` None starts a **private** local instance (``ray.init(address="local")``, ``workers`` CPUs) that
    is stopped after the sweep, even when a cluster is running on this machine (Ray's own default would attach
    to it silently); ``"auto"`` or ``HOST:PORT`` attaches to a running cluster, which keeps running.  A task whose
    worker dies is retried ``max_retries`` times by Ray, then handed to ``on_lost``.
    """

    name = "ray"

    def __init__(self, address: str | None = None, workers: int | None = None, threads: int = 1,
                 max_retries: int = 1) -> None:
        self.ray = _import_ray()
        self.threads = max(1, int(threads))
        self.max_retries = int(max_retries)
        self.address = address or "local"
        self._started = False
        self._pending: list[Any] = []
        if not self.ray.is_initialized():
            kw: dict[str, object] = {"address": self.address, "include_dashboard": False, "log_to_driver": True}
            if self.address == "local" and workers:
                kw["num_cpus"] = int(workers)
            self.ray.init(**kw)
            self._started = True
        self.workers = workers

    def map_unordered(self, fn: Callable[..., RunRecord], configs: list[dict[str, Any]], out_dir: str,
                      on_lost: OnLost | None = None) -> Iterator[RunRecord]:
        ray = self.ray
        lost = ray_lost_errors(ray)
        remote = ray.remote(num_cpus=self.threads, max_retries=self.max_retries)(fn)
        by_ref = {remote.remote(cfg, out_dir, self.threads): cfg for cfg in configs}
        self._pending = list(by_ref)
        try:
            while self._pending:
                done, self._pending = ray.wait(self._pending, num_returns=1)
                for ref in done:
                    try:
                        rec = ray.get(ref)
                    except lost as exc:
                        if on_lost is None:
                            raise
                        rec = on_lost(by_ref[ref], exc)
                    yield rec
        finally:
            self._cancel_pending()  # interrupted (Ctrl-C, an error): no task keeps training for a sweep that is gone

    def _cancel_pending(self) -> None:
        for ref in self._pending:
            try:
                self.ray.cancel(ref, force=True)
            except Exception:  # noqa: BLE001 - already finished or its node is gone: nothing to cancel
                pass
        self._pending = []

    def shutdown(self) -> None:
        self._cancel_pending()
        if self._started:
            self.ray.shutdown()  # stops a private instance; on a cluster, only disconnects this driver
            self._started = False


def make_executor(backend: str = "local", workers: int | None = None, address: str | None = None,
                  threads: int = 1) -> Executor:
    """``"local"`` or ``"ray"``; anything else is a ValueError."""
    if backend == "local":
        return LocalExecutor(workers, threads)
    if backend == "ray":
        return RayExecutor(address, workers, threads)
    raise ValueError(f"unknown backend {backend!r}; use 'local' or 'ray'")
