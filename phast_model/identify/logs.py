"""Logs as they come: several recordings of different lengths, with the rows a logger got wrong.

A *log set* is several logs (one run of the rig each) of their own lengths (docs/mismatch.md, "Logs of different
lengths").  The rest of the tool works on equal-length trajectories q (N, T, n), so a log set becomes equal-length
*pieces*: each log is cut into pieces of a common length T_p that share their boundary sample (stride T_p - 1), the
last one aligned to the log's end (it overlaps the one before), so no sample is dropped.  Each piece remembers its
log (``origin``), and the held-out split (:mod:`.split`) holds out whole logs.

Rows are dropped, never silently, and counted per reason and per log (``Recordings.meta["logs"]``):

* ``truncated``: a row with fewer values than the header (a logger cut off mid-row) or an empty field;
* ``not_finite``: a row with a NaN or inf value;
* ``isolated``: rows left in a run of fewer than ``min_samples`` rows between two *breaks*: a jump (a coordinate
  moves more than :data:`JUMP_FACTOR` times the set's fast speed in one step), time that does not advance, or a gap
  of more than :data:`MAX_GAP_STEPS` nominal steps.  A logger's garbage rows (uninitialised values at start-up) end up
  here.

A dropped row is a missing sample, never interpolated across.  When the log records its times ``t``, the samples on
either side of a short gap stay neighbours, joined by the longer recorded step (the simulator integrates across it
with the input held, as over any jittered step); without ``t``, and at a break, the log is split into segments that
are cut into pieces separately.
"""

from __future__ import annotations

import csv
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.systems import wrap

#: a recorded time step up to this many nominal steps joins the samples either side of dropped rows (t recorded)
MAX_GAP_STEPS = 5.0
#: a step moving a coordinate more than this many times the set's fast speed (x the step) is a jump
JUMP_FACTOR = 10.0
#: the set's fast speed: this percentile of |dq|/dt over all steps of all logs (the largest over coordinates)
FAST_PERCENTILE = 99.0
#: the longest pieces a log set is cut into (samples)
MAX_PIECE_SAMPLES = 1000
#: keys of a log set that hold one array per log (``q_0``, ``t_0``, ``u_0``, ...)
PER_LOG = ("q", "t", "u")
_PER_LOG_KEY = re.compile(r"^(q|t|u)_(\d+)$")
#: values the loader uses as large but finite stand-ins for overflowing steps
_HUGE = 1e300


# --------------------------------------------------------------------------- reading rows
@dataclass
class Table:
    """A CSV file's numeric rows: ``values`` (R, C) with NaN where a value is missing, which rows were truncated, and
    each row's line number in the file (for messages)."""

    header: list[str] | None
    values: np.ndarray
    truncated: np.ndarray
    lines: np.ndarray
    first_truncated: str = ""  # the message naming the first truncated row ("" when none)


def read_rows(path: str | Path, header: bool = True, columns: int | None = None) -> Table:
    """The numeric rows of a CSV file, truncated rows (a logger cut off mid-row, or an empty field) kept in place as
    NaN.

    ``header``: the first row names the columns; without one, rows have ``columns`` values (default: the most common
    count).  A row with more values than that, or a value that is not a number ('nan' and 'inf' are numbers), is a
    ValueError naming its line: that is not a logger's truncation.
    """
    path = Path(path)
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        rows = [(reader.line_num, [x.strip() for x in r]) for r in reader if r and any(x.strip() for x in r)]
    names: list[str] | None = None
    if header:
        if not rows:
            raise ValueError(f"{path}: empty CSV file")
        names = rows.pop(0)[1]
        width = len(names)
        what = f"the header has {width} columns ({','.join(names)})"
    else:
        if not rows:
            raise ValueError(f"{path}: empty CSV file")
        counts = np.bincount([len(r) for _, r in rows])
        width = int(columns or np.argmax(counts))
        what = f"the file's rows have {width} values"
    values = np.full((len(rows), width), np.nan)
    truncated = np.zeros(len(rows), dtype=bool)
    first = ""
    for i, (line, r) in enumerate(rows):
        if len(r) > width:
            raise ValueError(f"{path}: line {line} has {len(r)} values, {what}")
        numbers = [_number(x, path, line) if x else np.nan for x in r]
        if len(r) < width or "" in r:  # cut off mid-row: even the values written may be partial, none is used
            truncated[i] = True
            first = first or f"line {line} has {sum(1 for x in r if x)} values, {what}"
        else:
            values[i] = numbers
    return Table(names, values, truncated, np.array([line for line, _ in rows], dtype=int), first)


def _number(x: str, path: Path, line: int) -> float:
    try:
        return float(x)
    except ValueError:
        raise ValueError(f"{path}: line {line} has a non-numeric value {x!r}") from None


# --------------------------------------------------------------------------- a log set
@dataclass
class Log:
    """One log as given: q (L, n), recorded times t (L,) or None, the input u (L, m) row-aligned (row k's u is held
    until the next row; a u of L-1 rows gets an unused zero row), NaN where a value is missing."""

    name: str
    q: np.ndarray
    t: np.ndarray | None
    u: np.ndarray | None
    truncated: int = 0  # rows of q / t / u that a logger truncated (NaN-filled)
    truncated_line: str = ""  # the first truncated row, for messages


def is_log_set(raw: Mapping[str, object]) -> bool:
    """Whether ``raw`` holds logs of their own lengths: ``q`` a list of arrays (or an object array), or ``q_0``, ...
    keys."""
    q = raw.get("q")
    if isinstance(q, (list, tuple)) or (isinstance(q, np.ndarray) and q.dtype == object):
        return True
    return "q" not in raw and "q_0" in raw


def log_set_from_keys(files: Mapping[str, Any], source: str) -> dict[str, Any]:
    """An .npz's ``q_0, q_1, ...`` (and ``t_k``, ``u_k``) keys as lists ``q``, ``t``, ``u``; the other keys as they
    are."""
    found: dict[str, dict[int, Any]] = {k: {} for k in PER_LOG}
    out: dict[str, Any] = {}
    for key, value in files.items():
        m = _PER_LOG_KEY.match(key)
        if m:
            found[m.group(1)][int(m.group(2))] = value
        else:
            out[key] = value
    K = len(found["q"])
    if sorted(found["q"]) != list(range(K)):
        raise ValueError(f"{source}: log keys must be q_0 .. q_{{K-1}} without gaps, got "
                         f"{sorted(f'q_{k}' for k in found['q'])}")
    for key in ("t", "u"):
        if found[key] and sorted(found[key]) != list(range(K)):
            raise ValueError(f"{source}: give {key}_k for every log q_0 .. q_{K - 1} or for none, got "
                             f"{sorted(found[key])}")
        if found[key]:
            out[key] = [found[key][k] for k in range(K)]
    out["q"] = [found["q"][k] for k in range(K)]
    return out


def logs_of(raw: Mapping[str, Any], n: int, source: str) -> list[Log]:
    """The logs of a log set, shapes checked (q (L, n), t (L,), u (L or L-1, m)); ValueError naming the log."""
    qs = list(raw["q"])
    K = len(qs)
    if K == 0:
        raise ValueError(f"{source}: the log set holds no log")
    names = [str(x) for x in raw["log_names"]] if raw.get("log_names") is not None else [f"log {k}" for k in range(K)]
    truncated = [int(x) for x in raw["rows_truncated"]] if raw.get("rows_truncated") is not None else [0] * K
    lines = list(raw.get("truncated_lines") or [""] * K)
    if len(names) != K or len(truncated) != K:
        raise ValueError(f"{source}: log_names / rows_truncated must have one entry per log ({K})")
    for key in ("t", "u"):
        if raw.get(key) is not None and len(raw[key]) != K:
            raise ValueError(f"{source}: '{key}' holds {len(raw[key])} logs but 'q' holds {K}")
    out = []
    for k in range(K):
        where = f"{source}: log {k} ({names[k]})"
        q = _float(qs[k], where, "q")
        q = q[:, None] if q.ndim == 1 and n == 1 else q
        if q.ndim != 2 or q.shape[1] != n:
            raise ValueError(f"{where}: 'q' must have shape (L, n={n}), got {q.shape}")
        t = None if raw.get("t") is None else _float(raw["t"][k], where, "t").reshape(-1)
        if t is not None and t.shape[0] != q.shape[0]:
            raise ValueError(f"{where}: 't' has {t.shape[0]} samples but 'q' has {q.shape[0]}")
        out.append(Log(names[k], q, t, None if raw.get("u") is None else _row_input(raw["u"][k], q.shape[0], where),
                       truncated[k], lines[k] if k < len(lines) else ""))
    if any(log.t is None for log in out) and any(log.t is not None for log in out):
        raise ValueError(f"{source}: give recorded times for every log or for none")
    return out


def _float(x: object, where: str, key: str) -> np.ndarray:
    try:
        return np.array(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: '{key}' is not numeric") from None


def _row_input(u: object, L: int, where: str) -> np.ndarray:
    u = _float(u, where, "u")
    u = u[:, None] if u.ndim == 1 else u
    if u.ndim != 2 or u.shape[0] not in (L, L - 1):
        raise ValueError(f"{where}: 'u' must have shape (L, m) or (L-1, m) with L={L} samples, got {u.shape}")
    return u if u.shape[0] == L else np.concatenate([u, np.zeros((1, u.shape[1]))])


# --------------------------------------------------------------------------- bad rows
@dataclass(frozen=True)
class StepScale:
    """The set's nominal time step and fast speed (what a jump and a gap are measured against)."""

    dt: float  # median recorded step (1 when no times are recorded: steps are then counted in samples)
    speed: float  # |dq|/dt that a step of the set rarely exceeds (FAST_PERCENTILE, the largest over coordinates)

    def jumps(self, dq: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """(S,) whether each step (S, n) moves a coordinate more than JUMP_FACTOR x the fast speed x its duration
        (a step recorded shorter than dt counts as dt: a logger's time stamps jitter more than its samples)."""
        limit = JUMP_FACTOR * self.speed * np.maximum(dt, self.dt)
        with np.errstate(invalid="ignore"):
            return ~np.all(np.abs(dq) <= limit[:, None], axis=1)


def finite_rows(log: Log) -> np.ndarray:
    """(L,) rows whose q, t and u are all finite."""
    ok = np.all(np.isfinite(log.q), axis=1)
    if log.t is not None:
        ok &= np.isfinite(log.t)
    if log.u is not None:
        ok &= np.all(np.isfinite(log.u), axis=1)
    return ok


def _steps(log: Log, idx: np.ndarray, dt: float, angle_dims: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """(dq (S, n) with angles wrapped, dt (S,)) between consecutive kept rows ``idx`` (dt in samples without t)."""
    a, b = idx[:-1], idx[1:]
    with np.errstate(invalid="ignore", over="ignore"):
        dq = np.nan_to_num(log.q[b] - log.q[a], nan=_HUGE, posinf=_HUGE, neginf=-_HUGE)
        if len(angle_dims):
            dq[:, list(angle_dims)] = wrap(dq[:, list(angle_dims)])
        steps = (log.t[b] - log.t[a]) if log.t is not None else (b - a) * dt
    return dq, steps


def step_scale(logs: Sequence[Log], keep: Sequence[np.ndarray], angle_dims: Sequence[int]) -> StepScale:
    """The nominal step and fast speed of the rows ``keep`` of every log (consecutive kept rows only)."""
    timed = [log.t is not None for log in logs]
    dts, dqs = [], []
    for log, k in zip(logs, keep):
        idx = np.flatnonzero(k)
        if idx.size < 2:
            continue
        dq, steps = _steps(log, idx, 1.0, angle_dims)
        adjacent = np.diff(idx) == 1
        dqs.append(np.abs(dq[adjacent]))
        dts.append(steps[adjacent])
    all_dt = np.concatenate(dts) if dts else np.ones(0)
    positive = all_dt[all_dt > 0]
    dt = float(np.median(positive)) if any(timed) and positive.size else 1.0
    if not dqs:
        return StepScale(dt, np.inf)
    dq = np.concatenate(dqs)
    ok = (all_dt > 0) & (all_dt <= MAX_GAP_STEPS * dt)
    speed = dq[ok] / np.maximum(all_dt[ok], dt)[:, None]
    if not speed.size:
        return StepScale(dt, np.inf)
    fast = float(np.max(np.percentile(np.minimum(speed, _HUGE), FAST_PERCENTILE, axis=0)))
    return StepScale(dt, fast if fast > 0 else np.inf)


def _runs(log: Log, keep: np.ndarray, scale: StepScale, angle_dims: Sequence[int]) -> list[np.ndarray]:
    """The kept rows split at every break (a jump, time not advancing, a gap; without t, any dropped row)."""
    idx = np.flatnonzero(keep)
    if idx.size < 2:
        return [idx] if idx.size else []
    dq, steps = _steps(log, idx, scale.dt, angle_dims)
    if log.t is not None:
        brk = ~((steps > 0) & (steps <= MAX_GAP_STEPS * scale.dt))
    else:
        brk = np.diff(idx) > 1
    brk |= scale.jumps(dq, steps)
    return np.split(idx, np.flatnonzero(brk) + 1)


@dataclass
class Cleaned:
    """What is kept of each log: its segments (row indices, each at least min_samples long) and the rows dropped."""

    segments: list[list[np.ndarray]]
    dropped: list[dict[str, int]]
    bridged: list[int]  # kept steps across dropped rows (t recorded)
    scale: StepScale


def clean(logs: Sequence[Log], angle_dims: Sequence[int], min_samples: int) -> Cleaned:
    """Drop non-finite rows, then rows isolated between breaks in runs shorter than ``min_samples``; the set's fast
    speed
    is estimated again without the rows dropped so far until nothing more is dropped (a logger's garbage can be a few
    percent of a short log: the first estimate may be too generous to see all of it)."""
    finite = [finite_rows(log) for log in logs]
    keep = [f.copy() for f in finite]
    scale = step_scale(logs, keep, angle_dims)
    for _ in range(50):
        changed = False
        for log, k in zip(logs, keep):
            for run in _runs(log, k, scale, angle_dims):
                if len(run) < min_samples:
                    k[run] = False
                    changed = True
        new = step_scale(logs, keep, angle_dims)
        if not changed and new == scale:
            break
        scale = new
    segments = [[r for r in _runs(log, k, scale, angle_dims) if len(r) >= min_samples] for log, k in zip(logs, keep)]
    dropped = [{"truncated": log.truncated, "not_finite": int(np.sum(~f)) - log.truncated,
                "isolated": int(np.sum(f & ~k))}
               for log, f, k in zip(logs, finite, keep)]
    bridged = [sum(int(np.sum(np.diff(s) > 1)) for s in segs) for segs in segments]
    return Cleaned(segments, dropped, bridged, scale)


# --------------------------------------------------------------------------- pieces
def piece_starts(length: int, size: int) -> list[int]:
    """Starts of the pieces of ``size`` samples that cover ``length`` samples: neighbours share their boundary sample
    (stride size - 1) and the last piece ends at the last sample (overlapping the one before when the stride does not
    fit); none when the log is shorter than a piece."""
    if length < size or size < 2:
        return []
    starts = list(range(0, length - size + 1, size - 1))
    if starts[-1] != length - size:
        starts.append(length - size)
    return starts


def repeated_samples(length: int, size: int) -> int:
    """Samples counted twice in the pieces of a log (beyond the shared boundary samples): the last piece's overlap."""
    starts = piece_starts(length, size)
    return len(starts) * (size - 1) + 1 - length if starts else 0


def piece_size(lengths: Sequence[int], min_samples: int, longest: int = MAX_PIECE_SAMPLES) -> int:
    """The common piece length: at most the shortest segment (so every sample is kept) and ``longest``; among lengths
    from half that up, the one that repeats the fewest samples in the overlapping last pieces (then the longest)."""
    hi = max(min(min(lengths), longest), min_samples)
    lo = min(max(min_samples, hi // 2), hi)
    return min(range(lo, hi + 1), key=lambda s: (sum(repeated_samples(L, s) for L in lengths), -s))


@dataclass
class Pieces:
    """A log set as equal-length pieces: q (P, T_p, n), t (P, T_p) or None, u (P, T_p - 1, m) or None, and each
    piece's origin (P, 3): its log, and the first and last row of that log it covers (rows as given)."""

    q: np.ndarray
    t: np.ndarray | None
    u: np.ndarray | None
    origin: np.ndarray
    facts: dict[str, Any] = field(default_factory=dict)


def cut_pieces(logs: Sequence[Log], angle_dims: Sequence[int], min_samples: int,
               longest: int = MAX_PIECE_SAMPLES) -> Pieces:
    """Clean every log (:func:`clean`) and cut its segments into pieces of one length (:func:`piece_size`)."""
    cleaned = clean(logs, angle_dims, min_samples)
    segs = [(k, s) for k, segments in enumerate(cleaned.segments) for s in segments]
    if not segs:
        lengths = ", ".join(f"{log.name}: {log.q.shape[0]}" for log in logs)
        extra = f"; {logs[0].truncated_line}" if logs[0].truncated_line else ""
        raise ValueError(f"no log holds {min_samples} consecutive usable samples (rows per log {lengths}; rows dropped "
                         f"{_dropped_total(cleaned.dropped)}{extra})")
    size = piece_size([len(s) for _, s in segs], min_samples, longest)
    rows = [(k, r[a:a + size]) for k, r in segs for a in piece_starts(len(r), size)]
    t = [logs[k].t for k, _ in rows]
    u = [logs[k].u for k, _ in rows]
    return Pieces(q=np.stack([logs[k].q[r] for k, r in rows]),
                  t=None if t[0] is None else np.stack([x[r] for x, (_, r) in zip(t, rows) if x is not None]),
                  u=None if u[0] is None else np.stack([x[r[:-1]] for x, (_, r) in zip(u, rows) if x is not None]),
                  origin=np.array([(k, int(r[0]), int(r[-1])) for k, r in rows], dtype=int),
                  facts=_facts(logs, cleaned, segs, size, len(rows)))


def _dropped_total(dropped: Sequence[Mapping[str, int]]) -> dict[str, int]:
    return {key: int(sum(d[key] for d in dropped)) for key in ("truncated", "not_finite", "isolated")}


def _facts(logs: Sequence[Log], cleaned: Cleaned, segs: list[tuple[int, np.ndarray]], size: int,
           n_pieces: int) -> dict[str, Any]:
    """``Recordings.meta["logs"]``: what was read, kept, dropped and cut (report.json ``data.logs``)."""
    rows = [int(log.q.shape[0]) for log in logs]
    total = _dropped_total(cleaned.dropped)
    repeated = int(sum(repeated_samples(len(s), size) for _, s in segs))
    n_dropped = sum(total.values())
    text = (f"{len(logs)} logs of {min(rows)}..{max(rows)} rows cut into {n_pieces} pieces of {size} samples "
            f"(neighbours share their boundary sample; {repeated} samples repeated where a segment's last piece "
            "overlaps)")
    if n_dropped:
        rows_text = f"{n_dropped} row{'s' if n_dropped > 1 else ''}"
        text += (f"; {rows_text} dropped: {total['truncated']} truncated, {total['not_finite']} not finite, "
                 f"{total['isolated']} isolated between breaks (jumps, time not advancing, gaps over {MAX_GAP_STEPS:g} "
                 "steps)")
    splits = sum(max(0, len(s) - 1) for s in cleaned.segments)
    if splits or sum(cleaned.bridged):
        text += (f"; {splits} splits of a log at a break, {sum(cleaned.bridged)} gaps of dropped rows bridged by the "
                 "recorded times")
    return {"n_logs": len(logs), "names": [log.name for log in logs], "rows": rows,
            "rows_used": [int(sum(len(s) for s in segments)) for segments in cleaned.segments],
            "segments": [len(s) for s in cleaned.segments], "n_pieces": n_pieces, "piece_samples": size,
            "samples_repeated": repeated, "rows_dropped": total, "rows_dropped_per_log": cleaned.dropped,
            "gaps_bridged": int(sum(cleaned.bridged)),
            "fast_speed": cleaned.scale.speed if np.isfinite(cleaned.scale.speed) else None, "note": text}


def report_facts(meta: Mapping[str, Any]) -> dict[str, Any]:
    """report.json ``data`` entries of a log set (``{"logs": ...}``); nothing for equal-length recordings."""
    return {"logs": dict(meta["logs"])} if "logs" in meta else {}
