"""Loading and validating measured recordings (the recordings format of docs/mismatch.md).

A recording set is q (N, T, n) sampled at dt or at recorded times t ((T,) or
(N, T), strictly increasing, not necessarily uniform: real loggers jitter and
the tool simulates between the recorded times), an optional port input
u (N, T-1 or T, m) held over each interval, the indices of angular coordinates
and an angle offset (q_env = q_recorded + angle_offset).  Every problem gets a
ValueError naming it.

Logs of different lengths (a *log set*: ``q_0, q_1, ...`` keys, lists of arrays, a CSV whose trajectories differ in
length or hold bad rows, a folder of CSV logs) are read as they come and cut into equal-length pieces
(:mod:`.logs`: bad rows dropped and counted in ``meta["logs"]``, each piece's log in ``origin``); the angles' unit,
the model's joint order and ranges are checked by :mod:`.coordinates`.
"""

from __future__ import annotations

import math
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from phast_gym.systems import wrap

from .coordinates import LimitReached, angle_unit, check_names, check_radians, check_ranges, to_radians
from .logs import MAX_PIECE_SAMPLES, Table, cut_pieces, is_log_set, log_set_from_keys, logs_of, read_rows

#: fewest samples per trajectory the analysis accepts (windows + holdout need room)
MIN_SAMPLES = 40


#: steps within this fraction of dt count as uniform sampling
UNIFORM_RTOL = 1e-3


@dataclass
class Recordings:
    """Validated recordings in the env's convention (angles unwrapped along time).

    ``dt`` is the (median) sampling step, used for time scales and filters; ``t``
    (N, T) the recorded sample times when given (absolute, not necessarily
    uniform: the simulation runs between them, see :attr:`steps` and :attr:`sim_dt`).
    """

    q: np.ndarray  # (N, T, n) float64, angle dims unwrapped, offset applied
    dt: float
    u: np.ndarray | None = None  # (N, T-1, n) generalized port force G u, or None
    angle_dims: tuple[int, ...] = ()
    source: str = "<arrays>"
    meta: dict[str, Any] = field(default_factory=dict)
    t: np.ndarray | None = None  # (N, T) recorded sample times in seconds, or None (uniform at dt)
    # (N, 3) log, first row, last row of each piece of a log set; None: each its own log
    origin: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.t is not None:
            t = np.asarray(self.t, dtype=np.float64)
            if t.ndim == 1:
                t = np.broadcast_to(t, self.q.shape[:2])
            if t.shape != self.q.shape[:2]:
                raise ValueError(f"{self.source}: 't' must have shape (T,) or (N, T) = {self.q.shape[:2]}, got "
                                 f"{np.shape(self.t)}")
            self.t = t
        if self.origin is not None:
            self.origin = np.asarray(self.origin, dtype=int).reshape(-1, 3)
            if self.origin.shape[0] != self.q.shape[0]:
                raise ValueError(f"{self.source}: 'origin' must have one row per trajectory ({self.q.shape[0]}), got "
                                 f"{self.origin.shape}")

    @property
    def n_traj(self) -> int:
        return self.q.shape[0]

    @property
    def T(self) -> int:
        return self.q.shape[1]

    @property
    def n(self) -> int:
        return self.q.shape[2]

    @property
    def steps(self) -> np.ndarray:
        """(N, T-1) length of every sampling interval in seconds (dt everywhere when t is None)."""
        if self.t is None:
            return np.full((self.n_traj, self.T - 1), float(self.dt))
        return np.diff(self.t, axis=1)

    @property
    def uniform(self) -> bool:
        """Whether every interval is dt (within UNIFORM_RTOL): then the scalar dt is the time base."""
        if self.t is None or self.T < 2:
            return True
        return bool(np.max(np.abs(np.diff(self.t, axis=1) - self.dt)) <= UNIFORM_RTOL * self.dt)

    @property
    def sim_dt(self) -> float | np.ndarray:
        """What to pass as ``dt`` to the simulation of whole trajectories: the scalar dt when the sampling is
        uniform (uniform recordings take the fixed-step path of the simulator), else the (N, T-1) recorded steps."""
        return float(self.dt) if self.uniform else self.steps

    def times(self) -> np.ndarray:
        """(N, T) sample times (from 0 at dt when no times were recorded)."""
        if self.t is None:
            return np.broadcast_to(np.arange(self.T) * float(self.dt), self.q.shape[:2])
        return self.t

    @property
    def log_of(self) -> np.ndarray | None:
        """(N,) the log each trajectory is a piece of (a log set), or None (every trajectory is its own log)."""
        return None if self.origin is None else self.origin[:, 0]

    def _with(self, q: np.ndarray, dt: float, u: np.ndarray | None, t: np.ndarray | None) -> Recordings:
        """The same trajectories (same origin) with new samples."""
        return Recordings(q, dt, u, self.angle_dims, self.source, self.meta, t, self.origin)

    def subset(self, idx: slice | Sequence[int] | np.ndarray) -> Recordings:
        """Trajectories ``idx`` (an index array or slice)."""
        origin = None if self.origin is None else self.origin[idx]
        return Recordings(self.q[idx], self.dt, None if self.u is None else self.u[idx], self.angle_dims, self.source,
                          self.meta,
                          None if self.t is None else self.t[idx], origin)

    def time_slice(self, start: int, stop: int) -> Recordings:
        """Samples ``start:stop`` of every trajectory (u follows the intervals; t keeps absolute times)."""
        u = None if self.u is None else self.u[:, start:stop - 1]
        return self._with(self.q[:, start:stop], self.dt, u, None if self.t is None else self.t[:, start:stop])

    def decimate(self, k: int) -> Recordings:
        """Every ``k``-th sample (dt becomes k dt, or the median of the new steps when t is not uniform).

        Not with a port input: u is held per recorded interval and averaging it over k intervals would
        change the physics; keep the recorded rate and compare every k-th sample instead
        (``Windows.cut(rec, length, stride=k)``).
        """
        k = int(k)
        if k < 1:
            raise ValueError(f"decimate: k must be a positive integer, got {k}")
        if k == 1:
            return self
        if self.u is not None:
            raise ValueError("decimation with a port input u is not supported (u is held per recorded interval); "
                             "compare every k-th sample instead: Windows.cut(rec, length, stride=k)")
        if self.T < 2 * k:
            raise ValueError(f"decimate: T={self.T} samples is too short to keep every {k}-th")
        t = None if self.t is None else self.t[:, ::k]
        if t is None or self.uniform:
            dt = self.dt * k
        else:
            dt = float(np.median(np.diff(t, axis=1)))
        return self._with(self.q[:, ::k], dt, None, t)

    def windows(self, W: int) -> Recordings:
        """Consecutive non-overlapping windows of ``W`` samples of every trajectory as trajectories
        (trajectory-major: trajectory 0's windows first; the remainder of each trajectory is dropped;
        u and t carried, t keeps absolute times).  Unchanged when a trajectory holds fewer than two windows."""
        W = int(W)
        if W < 2:
            raise ValueError(f"windows: W must be at least 2 samples, got {W}")
        k = self.T // W
        if k <= 1:
            return self
        N = self.n_traj
        q = self.q[:, : k * W].reshape(N * k, W, self.n)
        u = None
        if self.u is not None:
            u = np.stack([self.u[:, j * W: j * W + W - 1] for j in range(k)], 1).reshape(N * k, W - 1, -1)
        t = None if self.t is None else self.t[:, : k * W].reshape(N * k, W)
        origin = None if self.origin is None else np.repeat(self.origin, k, axis=0)
        return Recordings(q, self.dt, u, self.angle_dims, self.source, self.meta, t, origin)

    def resampled(self) -> Recordings:
        """The recordings interpolated onto a uniform grid of step dt from each trajectory's first time
        (q by cubic spline, u zero-order hold; as many samples as fit in the shortest trajectory).

        For filters that assume uniform sampling (Savitzky-Golay derivatives, local force residuals) only:
        fits simulate between the recorded times instead.  Returns ``self`` when the sampling is uniform.
        """
        if self.uniform:
            return self
        from scipy.interpolate import CubicSpline

        t = self.t
        assert t is not None  # (non-uniform sampling carries its times)
        span = float(np.min(t[:, -1] - t[:, 0]))
        T2 = int(math.floor(span / self.dt + 1e-9)) + 1
        grid = t[:, :1] + np.arange(T2)[None, :] * self.dt  # (N, T2)
        grid = np.minimum(grid, t[:, -1:])
        q = np.stack([CubicSpline(t[i], self.q[i], axis=0)(grid[i]) for i in range(self.n_traj)])
        u = None
        if self.u is not None:
            j = np.stack([np.clip(np.searchsorted(t[i], grid[i, :-1], side="right") - 1, 0,
                                  self.T - 2) for i in range(self.n_traj)])
            u = np.take_along_axis(self.u, j[..., None], axis=1)
        return self._with(q, self.dt, u, grid)


def _read_csv(path: Path) -> dict[str, Any]:
    """CSV with columns traj,t,q0..q{n-1}[,u0..] -> the npz-style dict: equal-length trajectories stacked, else a log
    set
    (trajectories of different lengths, or truncated / non-finite rows: :mod:`.logs` drops and counts them)."""
    table = read_rows(path)
    header = table.header or []
    for key in ("traj", "t", "q0"):
        if key not in header:
            raise ValueError(f"{path}: CSV is missing column {key!r} (need traj,t,q0..q{{n-1}}[,u0..]); got {header}")
    if not len(table.values):
        raise ValueError(f"{path}: CSV has a header ({','.join(header)}) but no data rows")
    data = table.values
    col, qcols, ucols = _columns(header)
    traj, when = _filled(data[:, col["traj"]]), _filled(data[:, col["t"]])
    trajs = np.unique(traj)
    groups = []
    for tr in trajs:
        rows_tr = np.flatnonzero(traj == tr)
        groups.append(rows_tr[np.argsort(when[rows_tr], kind="stable")])
    if table.truncated.any() or not np.all(np.isfinite(data)) or len({len(g) for g in groups}) != 1:
        return _csv_log_set(path, table, groups, [f"{path.name} traj {tr:g}" for tr in trajs])
    # each trajectory keeps its own time stamps (jittered loggers: they need not agree, nor be uniform)
    out: dict[str, Any] = {"q": np.stack([data[g][:, [col[h] for h in qcols]] for g in groups]),
                           "t": np.stack([data[g, col["t"]] for g in groups])}
    if ucols:
        out["u"] = np.stack([data[g][:, [col[h] for h in ucols]] for g in groups])
    return out


def _columns(header: list[str]) -> tuple[dict[str, int], list[str], list[str]]:
    """(column index by name, the q columns, the u columns in numeric order)."""
    col = {h: i for i, h in enumerate(header)}
    qcols = sorted((h for h in header if h.startswith("q") and h[1:].isdigit()), key=lambda h: int(h[1:]))
    ucols = sorted((h for h in header if h.startswith("u") and h[1:].isdigit()), key=lambda h: int(h[1:]))
    return col, qcols, ucols


def _filled(values: np.ndarray) -> np.ndarray:
    """A column with each missing value taken from the row before (a truncated row keeps its log and its place)."""
    values = np.array(values, dtype=np.float64)
    ok = np.isfinite(values)
    if not ok.any():
        return np.zeros_like(values)
    last = np.maximum.accumulate(np.where(ok, np.arange(len(values)), -1))
    return values[np.where(last < 0, np.flatnonzero(ok)[0], last)]


def _csv_log_set(path: Path, table: Table, groups: list[np.ndarray], names: list[str]) -> dict[str, Any]:
    """The rows ``groups`` of ``table`` as a log set (each group a log)."""
    col, qcols, ucols = _columns(table.header or [])
    data = table.values
    usable = [int(np.sum(np.all(np.isfinite(data[g]), axis=1))) for g in groups]
    if max(usable) < 2:
        raise ValueError(f"{path}: no trajectory has two complete rows "
                         f"({table.first_truncated or 'rows with NaN / inf'})")
    out: dict[str, Any] = {"q": [data[g][:, [col[h] for h in qcols]] for g in groups],
                           "t": [data[g, col["t"]] for g in groups],
                           "log_names": names, "rows_truncated": [int(np.sum(table.truncated[g])) for g in groups],
                           "truncated_lines": [table.first_truncated] * len(groups)}
    if ucols:
        out["u"] = [data[g][:, [col[h] for h in ucols]] for g in groups]
    return out


def _read_csv_logs(paths: Sequence[Path], source: str) -> dict[str, Any]:
    """CSV files of columns ``[traj,]t,q0..[,u0..]``, each trajectory of each file a log: a log set."""
    if not paths:
        raise ValueError(f"{source}: no .csv log found")
    merged: dict[str, list[Any]] = {"q": [], "t": [], "u": [], "log_names": [], "rows_truncated": [],
                                    "truncated_lines": []}
    layout = None
    for path in paths:
        table = read_rows(path)
        header = table.header or []
        for key in ("t", "q0"):
            if key not in header:
                raise ValueError(f"{path}: CSV is missing column {key!r} (need [traj,]t,q0..q{{n-1}}[,u0..]); got "
                                 f"{header}")
        col, qcols, ucols = _columns(header)
        if layout is not None and layout != (len(qcols), len(ucols)):
            raise ValueError(f"{path}: {len(qcols)} q and {len(ucols)} u columns, the first log has {layout[0]} and "
                             f"{layout[1]}")
        layout = (len(qcols), len(ucols))
        traj = _filled(table.values[:, col["traj"]]) if "traj" in col else np.zeros(len(table.values))
        trajs, when = np.unique(traj), _filled(table.values[:, col["t"]])
        groups = [g[np.argsort(when[g], kind="stable")] for g in (np.flatnonzero(traj == tr) for tr in trajs)]
        names = [path.name if len(trajs) == 1 else f"{path.name} traj {tr:g}" for tr in trajs]
        part = _csv_log_set(path, table, groups, names) if len(table.values) else {}
        for key in merged:
            merged[key] += list(part.get(key, []))
    if not layout or not layout[1]:
        merged.pop("u")
    return merged


def load_raw(source: str | Path | Mapping[str, object] | Sequence[str | Path]) -> tuple[dict[str, Any], str]:
    """Read an .npz / .csv path, a folder of .csv logs or a list of .csv paths, or take a mapping; returns (dict,
    description).  A log set (logs of different lengths) comes back with ``q`` (and ``t``, ``u``) as lists."""
    if isinstance(source, Mapping):
        raw = dict(source)
        return (log_set_from_keys(raw, "<arrays>") if "q" not in raw and "q_0" in raw else raw), "<arrays>"
    if not isinstance(source, (str, Path)):
        paths = [Path(p) for p in source]
        missing = [str(p) for p in paths if not p.is_file()]
        if missing:
            raise ValueError(f"recordings files {missing} do not exist")
        return _read_csv_logs(paths, "recordings"), ",".join(str(p) for p in paths)
    path = Path(source)
    if not path.exists():
        raise ValueError(f"recordings file {path} does not exist")
    if path.is_dir():
        return _read_csv_logs(sorted(path.glob("*.csv")), str(path)), str(path)
    if path.suffix.lower() == ".csv":
        return _read_csv(path), str(path)
    return _read_npz(path), str(path)


def _read_npz(path: Path) -> dict[str, Any]:
    """An .npz archive's arrays (``q_0, q_1, ...`` keys: a log set)."""
    if path.is_file() and path.stat().st_size == 0:
        raise ValueError(f"recordings file {path} is empty (0 bytes)")
    try:
        z = np.load(path, allow_pickle=False)
        if isinstance(z, np.ndarray):
            raise ValueError(f"recordings file {path} holds a single .npy array, not an .npz archive with key 'q'")
        with z:
            if not z.files:
                raise ValueError(f"recordings file {path} is an .npz archive with no arrays (need at least 'q')")
            files = {k: z[k] for k in z.files}
    except ValueError as exc:
        if str(exc).startswith(f"recordings file {path}"):
            raise
        if "allow_pickle" in str(exc):
            raise ValueError(f"recordings file {path} holds object arrays (pickled, not loaded): save logs of "
                             "different lengths as q_0, q_1, ... (t_0, u_0, ...; docs/mismatch.md)") from None
        raise ValueError(f"recordings file {path} is not a readable .npz or .csv ({exc})") from None
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"recordings file {path} is not a readable .npz or .csv ({exc})") from None
    return log_set_from_keys(files, str(path)) if "q" not in files and "q_0" in files else files


def validate(raw: Mapping[str, Any], n: int, env_angle_dims: tuple[int, ...], source: str = "<arrays>",
             min_samples: int = MIN_SAMPLES, actuated_dofs: tuple[int, ...] | None = None, model: object = None,
             piece_samples: int = MAX_PIECE_SAMPLES) -> Recordings:
    """Check shapes, finiteness and the time base (strictly increasing t); convert to the env's convention.

    A log set (:func:`.logs.is_log_set`) is cleaned and cut into pieces of at most ``piece_samples`` samples first
    (:func:`_validate_logs`).  ``model``, the simulator's system, adds the checks of :mod:`.coordinates` against its
    coordinate names and (a MuJoCo model file) joint ranges.
    """
    if is_log_set(raw):
        return _validate_logs(raw, n, env_angle_dims, source, min_samples, actuated_dofs, model, piece_samples)
    q = _check_q(raw, n, source, min_samples)
    T = q.shape[1]
    t = _check_t(np.asarray(raw["t"], dtype=np.float64), q.shape[0], T, source) if raw.get("t") is not None else None
    dt = _time_step(raw, t, source)
    angle_dims = _angle_dims(raw, env_angle_dims, n, source)
    q, offset = _radians(q, raw, angle_dims, np.diff(t, axis=1) if t is not None else np.full((1, 1), dt), source)
    limits = _against_model(q, offset, raw, model, source)
    q = _continuous_angles(q, offset, angle_dims, source)
    u = _port_input(raw, q.shape, actuated_dofs, source) if raw.get("u") is not None else None
    rec = Recordings(q=q, dt=dt, u=u, angle_dims=angle_dims, source=source, t=t)
    if limits:
        rec.meta["joint_limits_reached"] = limits
    return rec


#: keys of a log set that hold for every log
_SHARED = ("dt", "angle_dims", "angle_offset", "actuated_dofs", "coordinate_names")


def _validate_logs(raw: Mapping[str, Any], n: int, env_angle_dims: tuple[int, ...], source: str, min_samples: int,
                   actuated_dofs: tuple[int, ...] | None, model: object, piece_samples: int) -> Recordings:
    """A log set: units checked on the logs as given, bad rows dropped, the logs cut into equal-length pieces
    (:func:`.logs.cut_pieces`), the pieces validated like equal-length recordings; ``origin`` and ``meta["logs"]``
    say where each piece came from and what was dropped."""
    logs = logs_of(raw, n, source)
    angle_dims = _angle_dims(raw, env_angle_dims, n, source)
    given = raw.get("dt")
    dt = (np.asarray(given, dtype=np.float64).reshape(-1)[:1] if given is not None and np.size(given) == 1
          else np.full(1, np.nan))
    offset = raw.get("angle_offset")
    unit = angle_unit(raw.get("angle_unit"), source)
    if unit == "deg":
        logs = [replace(log, q=to_radians(log.q, None, angle_dims)[0]) for log in logs]
        offset = None if offset is None else to_radians(np.zeros(n), offset, angle_dims)[1]
    elif unit is None:
        check_radians([log.q for log in logs], [dt if log.t is None else np.diff(log.t) for log in logs], angle_dims,
                      source)
    pieces = cut_pieces(logs, angle_dims, min_samples, piece_samples)
    flat = {k: raw[k] for k in _SHARED if raw.get(k) is not None}
    flat.update(q=pieces.q, angle_unit="rad")
    if offset is not None:
        flat["angle_offset"] = offset
    if pieces.t is not None:
        flat["t"] = pieces.t
    if pieces.u is not None:
        flat["u"] = pieces.u
    rec = validate(flat, n, env_angle_dims, source, min_samples, actuated_dofs, model)
    rec.origin = pieces.origin
    rec.meta["logs"] = pieces.facts
    return rec


def _angle_dims(raw: Mapping[str, Any], env_angle_dims: tuple[int, ...], n: int, source: str) -> tuple[int, ...]:
    angle_dims = tuple(int(i)
                       for i in np.atleast_1d(raw["angle_dims"])) if "angle_dims" in raw else tuple(env_angle_dims)
    if any(not 0 <= i < n for i in angle_dims):
        raise ValueError(f"{source}: angle_dims {angle_dims} out of range for n={n}")
    return angle_dims


def _radians(q: np.ndarray, raw: Mapping[str, Any], angle_dims: tuple[int, ...], steps: np.ndarray,
             source: str) -> tuple[np.ndarray, npt.ArrayLike | None]:
    """(q, angle_offset) in radians: converted when ``angle_unit`` is 'deg', checked not to look like degrees when it
    is not declared (``steps``: the sample intervals, (N, T-1) or a broadcastable dt)."""
    unit = angle_unit(raw.get("angle_unit"), source)
    offset = raw.get("angle_offset")
    if unit == "deg":
        return to_radians(q, offset, angle_dims)
    if unit is None:
        check_radians([q], [steps], angle_dims, source)
    return q, offset


def _against_model(q: np.ndarray, offset: npt.ArrayLike | None, raw: Mapping[str, Any], model: object,
                   source: str) -> list[LimitReached]:
    """The recordings' coordinate names and values (offset applied, as recorded) checked against ``model``; the joints
    that reach a limit."""
    if model is None:
        return []
    check_names(raw.get("coordinate_names"), model, source)
    shifted = q if offset is None else q + np.asarray(offset, dtype=np.float64).reshape(-1) * np.ones(q.shape[-1])
    return check_ranges([shifted], model, source)


def _check_q(raw: Mapping[str, Any], n: int, source: str, min_samples: int) -> np.ndarray:
    """The measured coordinates as a finite (N, T, n) float array."""
    if "q" not in raw:
        raise ValueError(f"{source}: recordings are missing key 'q' (measured coordinates, (N, T, n) or (T, n)); "
                         f"keys present: {sorted(raw)}")
    try:
        q = np.asarray(raw["q"], dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{source}: 'q' is not numeric") from None
    if q.ndim == 2:
        q = q[None]
    if q.ndim == 1 and n == 1:
        q = q[None, :, None]
    if q.ndim != 3:
        raise ValueError(f"{source}: 'q' must have shape (N, T, n) or (T, n), got {q.shape}")
    if q.shape[2] != n:
        raise ValueError(f"{source}: 'q' has n={q.shape[2]} coordinates but the simulator has n={n}")
    if q.shape[1] < min_samples:
        raise ValueError(f"{source}: recordings are too short: T={q.shape[1]} samples, need at least {min_samples}")
    if q.shape[0] < 1:
        raise ValueError(f"{source}: 'q' holds no trajectory")
    if not np.all(np.isfinite(q)):
        bad = np.argwhere(~np.isfinite(q))[0]
        raise ValueError(f"{source}: 'q' contains NaN/inf (first at trajectory {bad[0]}, sample {bad[1]}, coordinate "
                         f"{bad[2]}); save the trajectories as logs (q_0, q_1, ...) to have such rows dropped and "
                         "counted")
    return q


def _time_step(raw: Mapping[str, Any], t: np.ndarray | None, source: str) -> float:
    """The nominal sample interval: 'dt', checked against the median step of 't' when both are given."""
    dt_raw = raw.get("dt")
    if dt_raw is not None and np.size(dt_raw) == 1:
        try:
            dt = float(np.asarray(dt_raw, dtype=np.float64).reshape(()))
        except (TypeError, ValueError):
            raise ValueError(f"{source}: 'dt' is not a number") from None
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"{source}: dt must be a positive finite number, got {dt}")
        if t is not None:
            step = float(np.median(np.diff(t, axis=1)))
            uniform = np.max(np.abs(np.diff(t, axis=1) - step)) <= UNIFORM_RTOL * step
            # uniform t must match dt closely; jittered t only roughly (its median step is the nominal rate)
            tol = UNIFORM_RTOL if uniform else 0.05
            if abs(step - dt) > tol * dt:
                raise ValueError(f"{source}: 'dt'={dt} disagrees with the median step of 't' ({step:.6g} s)")
    elif dt_raw is not None:
        raise ValueError(f"{source}: 'dt' must be a scalar, got shape {np.shape(dt_raw)}; give per-sample times as 't'")
    elif t is not None:
        dt = float(np.median(np.diff(t, axis=1)))
    else:
        raise ValueError(f"{source}: recordings are missing the time base: give 'dt' (scalar) or 't' ((T,) or (N, T) "
                         "seconds)")
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"{source}: dt must be a positive finite number, got {dt}")
    return dt


def _continuous_angles(q: np.ndarray, offset: npt.ArrayLike | None, angle_dims: tuple[int, ...],
                       source: str) -> np.ndarray:
    """The env's convention: add the angle offset, wrap, then unwrap along time (a continuous angle)."""
    n = q.shape[-1]
    q = q.copy()
    if offset is not None:
        off = np.asarray(offset, dtype=np.float64)
        if off.size not in (1, n) or not np.all(np.isfinite(off)):
            raise ValueError(f"{source}: angle_offset must be a finite scalar or n={n} values, got {off}")
        q = q + off.reshape(-1)[None, None, :] * np.ones(n)
    for i in angle_dims:
        q[..., i] = np.unwrap(wrap(q[..., i]), axis=1)
    return q


def _port_input(raw: Mapping[str, Any], q_shape: tuple[int, ...], actuated_dofs: tuple[int, ...] | None,
                source: str) -> np.ndarray:
    """The measured port input as (N, T-1, n) generalized forces (zero on unactuated coordinates)."""
    N, T, n = q_shape
    u_raw = np.asarray(raw["u"], dtype=np.float64)
    if u_raw.ndim == 2:
        u_raw = u_raw[None]
    if u_raw.ndim != 3 or u_raw.shape[0] != N or u_raw.shape[1] not in (T, T - 1):
        raise ValueError(f"{source}: 'u' must have shape (N, T, m) or (N, T-1, m) matching q {tuple(q_shape)}, got "
                         f"{u_raw.shape}")
    if not np.all(np.isfinite(u_raw)):
        raise ValueError(f"{source}: 'u' contains NaN/inf")
    u_raw = u_raw[:, : T - 1]
    m = u_raw.shape[2]
    if "actuated_dofs" not in raw and actuated_dofs is not None and len(actuated_dofs) != m:
        raise ValueError(f"{source}: 'u' has m={m} columns but the simulator has {len(actuated_dofs)} actuators "
                         f"(one column per actuator, in model order)")
    dofs = tuple(int(i) for i in np.atleast_1d(raw["actuated_dofs"])) if "actuated_dofs" in raw else actuated_dofs
    if dofs is None:
        dofs = tuple(range(n)) if m == n else None
    if dofs is None or len(dofs) != m or any(not 0 <= i < n for i in dofs):
        raise ValueError(f"{source}: 'u' has m={m} inputs; give 'actuated_dofs' (m indices into n={n} coordinates)")
    u = np.zeros(u_raw.shape[:2] + (n,))
    u[..., list(dofs)] = u_raw
    return u


def _check_t(t: np.ndarray, N: int, T: int, source: str) -> np.ndarray:
    """Recorded sample times (T,) or (N, T) -> (N, T), finite and strictly increasing (jitter and gaps are fine)."""
    if t.ndim == 1 and t.shape[0] == T:
        t = np.broadcast_to(t, (N, T))
    if t.ndim == 2 and t.shape == (1, T) and N > 1:
        t = np.broadcast_to(t, (N, T))
    if t.shape != (N, T):
        raise ValueError(f"{source}: 't' must have shape (T,) = ({T},) or (N, T) = ({N}, {T}), got {t.shape}")
    if not np.all(np.isfinite(t)):
        bad = np.argwhere(~np.isfinite(t))[0]
        raise ValueError(f"{source}: 't' contains NaN/inf (first at trajectory {bad[0]}, index {bad[1]})")
    d = np.diff(t, axis=1)
    if np.any(d <= 0):
        i, j = np.argwhere(d <= 0)[0]
        raise ValueError(f"{source}: t is not strictly increasing at trajectory {i}, index {j} (t={t[i, j]!r}, "
                         f"next={t[i, j + 1]!r})")
    return np.array(t)
