"""Atomic file writes and JSON sanitizing, shared by every writer in the project.

A reader never sees a half-written file: data goes to a temp file in the same
directory, which is then moved into place with ``os.replace``.  Files get the
usual permissions (``mkstemp`` alone would leave them 0600).  A temp file is named
``.<name>.<host>-<pid>.<random>.tmp``; one left behind by a killed writer (its process
gone, or older than a day) is removed by the next write of the same file.

:func:`dir_lock` is an exclusive per-directory lock (``flock``), released when its
holder exits or dies; :func:`ensure_writable_dir` checks an output directory before
any work is done.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import socket
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

#: a temp file older than this is abandoned whoever wrote it (a writer on another host, a recycled pid)
STALE_TMP_S = 24 * 3600.0
_HOST = re.sub(r"[^A-Za-z0-9_]", "_", socket.gethostname())[:32] or "host"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True
    return True


def remove_stale_temps(path: str | Path, max_age_s: float = STALE_TMP_S) -> list[Path]:
    """Remove the temp files of earlier writes of ``path`` whose writer is gone (a process of this host that no
    longer runs, or any writer older than ``max_age_s``); returns what was removed.  Live writers' temps are kept."""
    path = Path(path)
    removed: list[Path] = []
    pat = re.compile(rf"^\.{re.escape(path.name)}\.(?P<host>[A-Za-z0-9_]+)-(?P<pid>\d+)\.[^.]*\.tmp$")
    # pre-pid names (and torch's tmp*.tmp)
    legacy = re.compile(rf"^(\.{re.escape(path.name)}\.[^.]*\.tmp|tmp[^.]*\.tmp)$")
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return removed
    now = time.time()
    for e in entries:
        m = pat.match(e.name)
        if m is None and not legacy.match(e.name):
            continue
        try:
            age = now - e.stat(follow_symlinks=False).st_mtime
        except OSError:
            continue
        dead = m is not None and m["host"] == _HOST and int(m["pid"]) != os.getpid() and not _pid_alive(int(m["pid"]))
        if dead or age > max_age_s:
            with contextlib.suppress(OSError):
                os.unlink(e.path)
                removed.append(Path(e.path))
    return removed


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (temp file + os.replace); returns the path.
    Temp files abandoned by earlier, killed writes of ``path`` are removed first (:func:`remove_stale_temps`)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{_HOST}-{os.getpid()}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically."""
    return atomic_write_bytes(path, text.encode("utf-8"))


def jsonable(x: object) -> Any:
    """Recursively turn numpy / torch scalars and arrays into JSON types; non-finite floats -> None."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if hasattr(x, "item") and getattr(x, "ndim", 1) == 0:
        return jsonable(x.item())
    if hasattr(x, "tolist"):
        return jsonable(x.tolist())
    return x


def atomic_write_json(path: str | Path, obj: object, indent: int | None = 2, sort_keys: bool = False) -> Path:
    """Write ``obj`` as JSON (sanitized by :func:`jsonable`) to ``path`` atomically."""
    text = json.dumps(jsonable(obj), indent=indent, sort_keys=sort_keys, default=str, allow_nan=False) + "\n"
    return atomic_write_text(path, text)


def ensure_writable_dir(path: str | Path, what: str = "output directory") -> Path:
    """Create ``path`` (and parents) if needed and check a file can be written in it, before any work is done;
    ValueError naming the problem otherwise."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{what} {path} exists and is not a directory")
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=path, prefix=".probe-", suffix=".tmp")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise ValueError(f"cannot write to {what} {path}: {exc.strerror or exc}") from None
    return path


class DirLocked(ValueError):
    """Raised by :func:`dir_lock` when another live process holds the directory."""


@contextlib.contextmanager
def dir_lock(directory: str | Path, name: str = ".lock", wait_s: float = 0.0) -> Iterator[Path]:
    """Exclusive lock on ``directory`` (``flock`` on ``directory/name``) for the duration of the block.

    Raises :class:`DirLocked` naming the holder's pid when another process holds it (after retrying for up to
    ``wait_s`` seconds; 0: at once).  The kernel releases the
    lock when its holder exits or is killed, so a crashed run never leaves the directory locked.  Where
    ``fcntl`` is unavailable (Windows) the block runs unlocked."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield directory
        return
    path = directory / name
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    deadline = time.monotonic() + max(0.0, float(wait_s))
    try:
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() < deadline:
                    time.sleep(0.5)
                    continue
                holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
                raise DirLocked(f"{directory} is in use by another process (pid {holder}); wait for it to finish "
                                f"or stop it") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield directory
    finally:
        os.close(fd)  # releases the flock
