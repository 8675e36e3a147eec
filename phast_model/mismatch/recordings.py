"""Loading and validating measured recordings (MISMATCH.md "Recordings").

A recording set is q (N, T, n) sampled uniformly at dt, an optional port input
u (N, T-1 or T, m), the indices of angular coordinates and an angle offset
(q_env = q_recorded + angle_offset).  Every problem gets a ValueError naming it.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.systems import wrap

#: fewest samples per trajectory the analysis accepts (windows + holdout need room)
MIN_SAMPLES = 40


@dataclass
class Recordings:
    """Validated recordings in the env's convention (angles unwrapped along time)."""

    q: np.ndarray  # (N, T, n) float64, angle dims unwrapped, offset applied
    dt: float
    u: np.ndarray | None = None  # (N, T-1, n) generalized port force G u, or None
    angle_dims: tuple[int, ...] = ()
    source: str = "<arrays>"
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def n_traj(self) -> int:
        return self.q.shape[0]

    @property
    def T(self) -> int:
        return self.q.shape[1]

    @property
    def n(self) -> int:
        return self.q.shape[2]

    def subset(self, idx: Any) -> Recordings:
        """Trajectories ``idx`` (an index array or slice)."""
        return Recordings(self.q[idx], self.dt, None if self.u is None else self.u[idx], self.angle_dims, self.source, self.meta)

    def time_slice(self, start: int, stop: int) -> Recordings:
        """Samples ``start:stop`` of every trajectory (u follows the intervals)."""
        u = None if self.u is None else self.u[:, start:stop - 1]
        return Recordings(self.q[:, start:stop], self.dt, u, self.angle_dims, self.source, self.meta)


def _read_csv(path: Path) -> dict[str, Any]:
    """CSV with columns traj,t,q0..q{n-1}[,u0..] -> the npz-style dict."""
    with open(path, newline="") as fh:
        reader = csv.reader(fh)
        try:
            header = [h.strip() for h in next(reader)]
        except StopIteration:
            raise ValueError(f"{path}: empty CSV file") from None
        rows = [r for r in reader if r]
    for key in ("traj", "t", "q0"):
        if key not in header:
            raise ValueError(f"{path}: CSV is missing column {key!r} (need traj,t,q0..q{{n-1}}[,u0..]); got {header}")
    try:
        data = np.array([[float(x) for x in r] for r in rows], dtype=np.float64)
    except ValueError as exc:
        raise ValueError(f"{path}: non-numeric CSV value ({exc})") from None
    if data.ndim != 2 or data.shape[1] != len(header):
        raise ValueError(f"{path}: CSV rows do not all have {len(header)} columns")
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
    out: dict[str, Any] = {"q": np.stack(qs), "t": ts[0]}
    for t in ts[1:]:
        if not np.allclose(t, ts[0]):
            raise ValueError(f"{path}: trajectories use different time stamps; give one uniform grid")
    if ucols:
        out["u"] = np.stack(us)
    return out


def load_raw(source: str | Path | Mapping[str, Any]) -> tuple[dict[str, Any], str]:
    """Read an .npz / .csv path or take a mapping; returns (dict, description)."""
    if isinstance(source, Mapping):
        return dict(source), "<arrays>"
    path = Path(source)
    if not path.exists():
        raise ValueError(f"recordings file {path} does not exist")
    if path.suffix.lower() == ".csv":
        return _read_csv(path), str(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}, str(path)
    except (OSError, ValueError) as exc:
        raise ValueError(f"recordings file {path} is not a readable .npz or .csv ({exc})") from None


def validate(raw: Mapping[str, Any], n: int, env_angle_dims: tuple[int, ...], source: str = "<arrays>",
             min_samples: int = MIN_SAMPLES, actuated_dofs: tuple[int, ...] | None = None) -> Recordings:
    """Check shapes, finiteness and uniform sampling; convert to the env's convention."""
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
    T = q.shape[1]
    # ---- time base
    if "dt" in raw and np.size(raw["dt"]) == 1:
        dt = float(np.asarray(raw["dt"]).reshape(()))
        if "t" in raw:
            _check_t(np.asarray(raw["t"], dtype=np.float64), T, source, dt)
    elif "t" in raw:
        dt = _check_t(np.asarray(raw["t"], dtype=np.float64), T, source, None)
    else:
        raise ValueError(f"{source}: recordings are missing the time base: give 'dt' (scalar) or 't' (T,)")
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"{source}: dt must be a positive finite number, got {dt}")
    # ---- angles
    angle_dims = tuple(int(i) for i in np.atleast_1d(raw["angle_dims"])) if "angle_dims" in raw else tuple(env_angle_dims)
    if any(not 0 <= i < n for i in angle_dims):
        raise ValueError(f"{source}: angle_dims {angle_dims} out of range for n={n}")
    q = q.copy()
    if "angle_offset" in raw:
        off = np.asarray(raw["angle_offset"], dtype=np.float64)
        if off.size not in (1, n) or not np.all(np.isfinite(off)):
            raise ValueError(f"{source}: angle_offset must be a finite scalar or n={n} values, got {off}")
        q = q + off.reshape(-1)[None, None, :] * np.ones(n)
    for i in angle_dims:
        # convention: wrap then unwrap along time (continuous angle near the env's range)
        w = wrap(q[..., i])
        q[..., i] = np.unwrap(w, axis=1)
    # ---- port input
    u = None
    if "u" in raw and raw["u"] is not None:
        u_raw = np.asarray(raw["u"], dtype=np.float64)
        if u_raw.ndim == 2:
            u_raw = u_raw[None]
        if u_raw.ndim != 3 or u_raw.shape[0] != q.shape[0] or u_raw.shape[1] not in (T, T - 1):
            raise ValueError(f"{source}: 'u' must have shape (N, T, m) or (N, T-1, m) matching q {q.shape}, got {u_raw.shape}")
        if not np.all(np.isfinite(u_raw)):
            raise ValueError(f"{source}: 'u' contains NaN/inf")
        u_raw = u_raw[:, : T - 1]
        m = u_raw.shape[2]
        dofs = tuple(int(i) for i in np.atleast_1d(raw["actuated_dofs"])) if "actuated_dofs" in raw else actuated_dofs
        if dofs is None:
            dofs = tuple(range(n)) if m == n else None
        if dofs is None or len(dofs) != m or any(not 0 <= i < n for i in dofs):
            raise ValueError(f"{source}: 'u' has m={m} inputs; give 'actuated_dofs' (m indices into n={n} coordinates)")
        u = np.zeros(u_raw.shape[:2] + (n,))
        u[..., list(dofs)] = u_raw
    return Recordings(q=q, dt=dt, u=u, angle_dims=angle_dims, source=source)


def _check_t(t: np.ndarray, T: int, source: str, dt: float | None) -> float:
    if t.ndim != 1 or t.shape[0] != T:
        raise ValueError(f"{source}: 't' must have shape (T,) = ({T},), got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError(f"{source}: 't' contains NaN/inf")
    d = np.diff(t)
    step = float(np.median(d))
    if step <= 0:
        raise ValueError(f"{source}: 't' is not increasing")
    if np.max(np.abs(d - step)) > 1e-3 * step + 1e-12:
        i = int(np.argmax(np.abs(d - step)))
        raise ValueError(f"{source}: 't' is not uniformly spaced (step {d[i]:.6g} at index {i} vs median {step:.6g}); resample first")
    if dt is not None and abs(step - dt) > 1e-3 * dt:
        raise ValueError(f"{source}: 'dt'={dt} disagrees with the spacing of 't' ({step})")
    return step
