"""Loading and validating measured recordings (the recordings format of docs/mismatch.md).

A recording set is q (N, T, n) sampled at dt or at recorded times t ((T,) or
(N, T), strictly increasing, not necessarily uniform: real loggers jitter and
the tool simulates between the recorded times), an optional port input
u (N, T-1 or T, m) held over each interval, the indices of angular coordinates
and an angle offset (q_env = q_recorded + angle_offset).  Every problem gets a
ValueError naming it.
"""

from __future__ import annotations

import csv
import math
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.systems import wrap

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

    def __post_init__(self) -> None:
        if self.t is not None:
            t = np.asarray(self.t, dtype=np.float64)
            if t.ndim == 1:
                t = np.broadcast_to(t, self.q.shape[:2])
            if t.shape != self.q.shape[:2]:
                raise ValueError(f"{self.source}: 't' must have shape (T,) or (N, T) = {self.q.shape[:2]}, got {np.shape(self.t)}")
            self.t = t

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

    def _with(self, q: np.ndarray, dt: float, u: np.ndarray | None, t: np.ndarray | None) -> Recordings:
        return Recordings(q, dt, u, self.angle_dims, self.source, self.meta, t)

    def subset(self, idx: Any) -> Recordings:
        """Trajectories ``idx`` (an index array or slice)."""
        return self._with(self.q[idx], self.dt, None if self.u is None else self.u[idx], None if self.t is None else self.t[idx])

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
        return self._with(q, self.dt, u, t)

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
            j = np.stack([np.clip(np.searchsorted(t[i], grid[i, :-1], side="right") - 1, 0, self.T - 2) for i in range(self.n_traj)])
            u = np.take_along_axis(self.u, j[..., None], axis=1)
        return self._with(q, self.dt, u, grid)


def _read_csv(path: Path) -> dict[str, Any]:
    """CSV with columns traj,t,q0..q{n-1}[,u0..] -> the npz-style dict."""
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise ValueError(f"{path}: empty CSV file") from None
        rows = [(reader.line_num, r) for r in reader if r]
    for key in ("traj", "t", "q0"):
        if key not in header:
            raise ValueError(f"{path}: CSV is missing column {key!r} (need traj,t,q0..q{{n-1}}[,u0..]); got {header}")
    if not rows:
        raise ValueError(f"{path}: CSV has a header ({','.join(header)}) but no data rows")
    for line, r in rows:  # ragged rows: name the first one, before any number is parsed
        if len(r) != len(header):
            raise ValueError(f"{path}: line {line} has {len(r)} values, the header has {len(header)} columns ({','.join(header)})")
    values = []
    for line, r in rows:
        try:
            values.append([float(x) for x in r])
        except ValueError:
            bad = next(x for x in r if not _is_float(x))
            raise ValueError(f"{path}: line {line} has a non-numeric value {bad!r}") from None
    data = np.array(values, dtype=np.float64)
    col = {h: i for i, h in enumerate(header)}
    qcols = sorted((h for h in header if h.startswith("q") and h[1:].isdigit()), key=lambda h: int(h[1:]))
    ucols = sorted((h for h in header if h.startswith("u") and h[1:].isdigit()), key=lambda h: int(h[1:]))
    trajs = np.unique(data[:, col["traj"]])
    qs, us, ts = [], [], []
    for tr in trajs:
        rows_tr = data[data[:, col["traj"]] == tr]
        rows_tr = rows_tr[np.argsort(rows_tr[:, col["t"]], kind="stable")]
        ts.append(rows_tr[:, col["t"]])
        qs.append(rows_tr[:, [col[h] for h in qcols]])
        if ucols:
            us.append(rows_tr[:, [col[h] for h in ucols]])
    lengths = {len(t) for t in ts}
    if len(lengths) != 1:
        raise ValueError(f"{path}: trajectories have different lengths {sorted(lengths)}; all must have the same T")
    # each trajectory keeps its own time stamps (jittered loggers: they need not agree, nor be uniform)
    out: dict[str, Any] = {"q": np.stack(qs), "t": np.stack(ts)}
    if ucols:
        out["u"] = np.stack(us)
    return out


def _is_float(x: str) -> bool:
    try:
        float(x)
    except ValueError:
        return False
    return True


def load_raw(source: str | Path | Mapping[str, Any]) -> tuple[dict[str, Any], str]:
    """Read an .npz / .csv path or take a mapping; returns (dict, description)."""
    if isinstance(source, Mapping):
        return dict(source), "<arrays>"
    path = Path(source)
    if not path.exists():
        raise ValueError(f"recordings file {path} does not exist")
    if path.suffix.lower() == ".csv":
        return _read_csv(path), str(path)
    if path.is_file() and path.stat().st_size == 0:
        raise ValueError(f"recordings file {path} is empty (0 bytes)")
    try:
        z = np.load(path, allow_pickle=False)
        if isinstance(z, np.ndarray):
            raise ValueError(f"recordings file {path} holds a single .npy array, not an .npz archive with key 'q'")
        with z:
            if not z.files:
                raise ValueError(f"recordings file {path} is an .npz archive with no arrays (need at least 'q')")
            return {k: z[k] for k in z.files}, str(path)
    except ValueError as exc:
        if str(exc).startswith(f"recordings file {path}"):
            raise
        raise ValueError(f"recordings file {path} is not a readable .npz or .csv ({exc})") from None
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"recordings file {path} is not a readable .npz or .csv ({exc})") from None


def validate(raw: Mapping[str, Any], n: int, env_angle_dims: tuple[int, ...], source: str = "<arrays>",
             min_samples: int = MIN_SAMPLES, actuated_dofs: tuple[int, ...] | None = None) -> Recordings:
    """Check shapes, finiteness and the time base (strictly increasing t); convert to the env's convention."""
    q = _check_q(raw, n, source, min_samples)
    T = q.shape[1]
    t = _check_t(np.asarray(raw["t"], dtype=np.float64), q.shape[0], T, source) if raw.get("t") is not None else None
    dt = _time_step(raw, t, source)
    angle_dims = tuple(int(i) for i in np.atleast_1d(raw["angle_dims"])) if "angle_dims" in raw else tuple(env_angle_dims)
    if any(not 0 <= i < n for i in angle_dims):
        raise ValueError(f"{source}: angle_dims {angle_dims} out of range for n={n}")
    q = _continuous_angles(q, raw.get("angle_offset"), angle_dims, source)
    u = _port_input(raw, q.shape, actuated_dofs, source) if raw.get("u") is not None else None
    return Recordings(q=q, dt=dt, u=u, angle_dims=angle_dims, source=source, t=t)


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
        raise ValueError(f"{source}: 'q' contains NaN/inf (first at trajectory {bad[0]}, sample {bad[1]}, coordinate {bad[2]})")
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
        raise ValueError(f"{source}: recordings are missing the time base: give 'dt' (scalar) or 't' ((T,) or (N, T) seconds)")
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"{source}: dt must be a positive finite number, got {dt}")
    return dt


def _continuous_angles(q: np.ndarray, offset: Any, angle_dims: tuple[int, ...], source: str) -> np.ndarray:
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
        raise ValueError(f"{source}: 'u' must have shape (N, T, m) or (N, T-1, m) matching q {tuple(q_shape)}, got {u_raw.shape}")
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
        raise ValueError(f"{source}: t is not strictly increasing at trajectory {i}, index {j} (t={t[i, j]!r}, next={t[i, j + 1]!r})")
    return np.array(t)
