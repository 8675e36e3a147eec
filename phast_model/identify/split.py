"""Which recordings are held out: by index (``--holdout-trajectories``) or by fraction (of trajectories, or of time for one)."""

from __future__ import annotations

import numbers
from collections.abc import Sequence

import numpy as np

from .recordings import Recordings

__all__ = ["check_holdout_indices", "check_holdout_range", "split"]


def check_holdout_indices(indices: Sequence[int] | None) -> list[int] | None:
    """Type and duplicate checks of ``holdout_trajectories`` (before anything is loaded); the range is checked by
    :func:`split`."""
    if indices is None:
        return None
    if isinstance(indices, (str, bytes)) or not isinstance(indices, Sequence | np.ndarray):
        raise ValueError(f"holdout_trajectories must be a sequence of trajectory indices, got {indices!r}")
    bad = [k for k in indices if isinstance(k, bool) or not isinstance(k, numbers.Integral)]
    if bad:
        raise ValueError(f"holdout_trajectories must be integers (0-based trajectory indices), got {bad}")
    out = [int(k) for k in indices]
    if not out:
        raise ValueError("holdout_trajectories is empty; give at least one trajectory index (or use holdout_fraction)")
    dup = sorted({k for k in out if out.count(k) > 1})
    if dup:
        raise ValueError(f"holdout_trajectories has duplicates: {dup}")
    neg = [k for k in out if k < 0]
    if neg:
        raise ValueError(f"holdout_trajectories out of range: {neg} (0-based indices, must be >= 0)")
    return out


def check_holdout_range(indices: list[int], n_traj: int) -> None:
    """Every index names a recorded trajectory and at least one trajectory is left for fitting."""
    over = [k for k in indices if k >= n_traj]
    if over:
        raise ValueError(f"holdout_trajectories out of range: {over} (the recordings have {n_traj} trajectories, indices 0..{n_traj - 1})")
    if len(set(indices)) >= n_traj:
        raise ValueError(f"holdout_trajectories {sorted(indices)} holds out all {n_traj} trajectories; none is left for fitting")


def split(rec: Recordings, frac: float, indices: list[int] | None = None) -> tuple[Recordings, Recordings, str]:
    """(training, held-out, description): the given trajectories, else the last ``frac`` of the trajectories (of time for one)."""
    N, T = rec.n_traj, rec.T
    if indices is not None:
        check_holdout_range(indices, N)
        hold = sorted(indices)
        train = [k for k in range(N) if k not in hold]
        return rec.subset(train), rec.subset(hold), f"held-out recordings (trajectories {hold})"
    if not 0.0 < frac < 1.0:
        raise ValueError(f"holdout_fraction must be in (0, 1), got {frac}")
    if N >= 2:
        k = min(max(1, int(round(N * frac))), N - 1)
        return rec.subset(slice(0, N - k)), rec.subset(slice(N - k, N)), f"held-out recordings (trajectories {list(range(N - k, N))})"
    cut = int(round(T * (1 - frac)))
    if cut < 20 or T - cut < 20:
        raise ValueError(f"recording too short to hold out {frac:.0%} in time (T={T})")
    return rec.time_slice(0, cut), rec.time_slice(cut, T), f"held-out last {frac:.0%} of the recording in time (samples {cut}..{T - 1})"


