"""Writing a report folder safely: nothing half-written is left, nothing the tool did not write is deleted.

:func:`write_atomically` fills a temporary sibling directory and swaps it in.  ``out`` must be new, empty, or a
previous phast-mismatch report (recognised by the ``"tool": "phast-mismatch"`` marker of its report.json and by
holding nothing but report files, :data:`REPORT_FILES`), which is then replaced atomically.  :func:`check_writable`
fails fast, before any analysis, when that is not so.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

#: report.json's marker of a directory this tool wrote
TOOL = "phast-mismatch"
PLOTS = ("residual_map.png", "heldout_fit.png", "decay.png")
#: written when the report carries a friction curve
CURVE_PLOT = "friction_curve.png"
#: the user's MuJoCo model with the calibrated parameters and the found terms it can express (MJCF / URDF simulators)
CALIBRATED_MODEL = "calibrated.xml"
#: every file a report directory holds (nothing else may be there for it to be replaced)
REPORT_FILES = ("report.json", "report.md", "report.html") + PLOTS + (CURVE_PLOT, "error.log", CALIBRATED_MODEL)
PLOTS_PREFIX = "Plots: "


def is_report_dir(path: Path) -> bool:
    """A directory this tool wrote: report.json with ``"tool": "phast-mismatch"`` and only report files."""
    entries = list(path.iterdir())
    if not all(p.name in REPORT_FILES and p.is_file() and not p.is_symlink() for p in entries):
        return False
    if [p.name for p in entries] == ["error.log"]:  # what a failed run left: its traceback only
        return True
    if not (path / "report.json").is_file():
        return False
    try:
        d = json.loads((path / "report.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(d, dict) and d.get("tool") == TOOL


def _check_replaceable(out: Path) -> None:
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise ValueError(f"refusing to overwrite {out}: it exists and is not a directory (give a new or report "
                         "directory as --out)")
    if out.is_dir() and any(out.iterdir()) and not is_report_dir(out):
        raise ValueError(f"refusing to overwrite {out}: it is a non-empty directory that is not a phast-mismatch "
                         f"report (a report directory holds only {', '.join(REPORT_FILES)}); give a new or empty "
                         "directory")


def check_writable(out_dir: str | Path) -> Path:
    """Fail fast (before any analysis) when the report could not be written to ``out_dir``: it is a file, a non-empty
    directory other than a previous report, or its nearest existing ancestor is not a writable directory."""
    out = Path(out_dir)
    _check_replaceable(out)
    parent = out.absolute().parent
    while not parent.exists() and not parent.is_symlink() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"cannot write the report to {out}: {parent} is not a directory")
    try:  # os.access is not enough (root, read-only mounts): create and remove a probe directory
        os.rmdir(tempfile.mkdtemp(prefix=f".{out.name}.probe-", dir=parent))
    except OSError as exc:
        raise ValueError(f"cannot write the report to {out}: {parent} is not writable "
                         f"({exc.strerror or exc})") from None
    return out



def _swap(tmp: Path, out: Path) -> None:
    """Move ``tmp`` to ``out``; a previous report there is moved aside first and then only its own files are removed."""
    _check_replaceable(out)
    if not out.exists():
        os.replace(tmp, out)
        return
    old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
    os.rmdir(old)
    os.replace(out, old)
    try:
        os.replace(tmp, out)
    except BaseException:
        os.replace(old, out)
        raise
    for name in REPORT_FILES:
        (old / name).unlink(missing_ok=True)
    try:
        old.rmdir()
    except OSError:  # something else appeared in it meanwhile: leave it
        pass



def write_atomically(out_dir: str | Path, fill: Callable[[Path], None]) -> Path:
    """Call ``fill(tmp)`` on a temporary sibling directory of ``out_dir``, then swap it in: no half-written report is
    ever left, and nothing the tool did not write is deleted (see :func:`check_writable`)."""
    out = check_writable(out_dir)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp creates 0700; a report directory is an ordinary one
    try:
        fill(tmp)
        _swap(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
