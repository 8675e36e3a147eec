"""Which recordings are held out: by index (``--holdout-trajectories``) or by fraction (of trajectories, or of time for
one).

For a log set (logs of different lengths cut into pieces, :mod:`.logs`) the unit is the log: indices name logs, a
fraction holds out the last logs, and every piece of a held-out log is held out, so nothing the fit saw is scored.
One log is held out in time: its last pieces, without the pieces that overlap them.
"""

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
        raise ValueError(f"holdout_trajectories out of range: {over} (the recordings have {n_traj} trajectories, "
                         f"indices 0..{n_traj - 1})")
    if len(set(indices)) >= n_traj:
        raise ValueError(f"holdout_trajectories {sorted(indices)} holds out all {n_traj} trajectories; none is left "
                         "for fitting")


def split(rec: Recordings, frac: float, indices: list[int] | None = None) -> tuple[Recordings, Recordings, str]:
    """(training, held-out, description): the given trajectories, else the last ``frac`` of the trajectories (of time
    for one);
    whole logs for a log set (:func:`split_logs`)."""
    if rec.origin is not None:
        return split_logs(rec, frac, indices)
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
        return (rec.subset(slice(0, N - k)), rec.subset(slice(N - k, N)),
                f"held-out recordings (trajectories {list(range(N - k, N))})")
    cut = int(round(T * (1 - frac)))
    if cut < 20 or T - cut < 20:
        raise ValueError(f"recording too short to hold out {frac:.0%} in time (T={T})")
    return (rec.time_slice(0, cut), rec.time_slice(cut, T),
            f"held-out last {frac:.0%} of the recording in time (samples {cut}..{T - 1})")




def split_logs(rec: Recordings, frac: float, indices: list[int] | None = None) -> tuple[Recordings, Recordings, str]:
    """:func:`split` of a log set's pieces: the logs ``indices`` (0-based, as given), else the last ``frac`` of the logs
    that kept samples; with one such log, its last pieces in time."""
    assert rec.origin is not None
    log = rec.origin[:, 0]
    facts = rec.meta.get("logs", {})
    n_logs = int(facts.get("n_logs", log.max() + 1))
    names = list(facts.get("names", [f"log {k}" for k in range(n_logs)]))
    used = sorted({int(k) for k in log})
    if indices is not None:
        over = [k for k in indices if k >= n_logs]
        if over:
            raise ValueError(f"holdout_trajectories out of range: {over} (the recordings are {n_logs} logs, indices "
                             f"0..{n_logs - 1})")
        empty = [k for k in indices if k not in used]
        if empty:
            raise ValueError(f"holdout_trajectories: logs {empty} ({', '.join(names[k] for k in empty)}) kept no "
                             "usable piece (report.json data.logs says what was dropped)")
        if set(used) <= set(indices):
            raise ValueError(f"holdout_trajectories {sorted(indices)} holds out every log; none is left for fitting")
        held = sorted(indices)
    elif not 0.0 < frac < 1.0:
        raise ValueError(f"holdout_fraction must be in (0, 1), got {frac}")
    elif len(used) >= 2:
        held = used[len(used) - min(max(1, int(round(len(used) * frac))), len(used) - 1):]
    else:
        return _split_one_log(rec, frac, names[used[0]])
    hold = np.isin(log, held)
    what = f"held-out recordings (logs {held}: {', '.join(names[k] for k in held)}; {int(hold.sum())} pieces)"
    return rec.subset(np.flatnonzero(~hold)), rec.subset(np.flatnonzero(hold)), what


def _split_one_log(rec: Recordings, frac: float, name: str) -> tuple[Recordings, Recordings, str]:
    """One log's pieces: the last ``frac`` of them held out, the pieces overlapping those beyond a boundary sample left
    out of training; one piece is split in time like one trajectory."""
    assert rec.origin is not None
    P = rec.n_traj
    if P == 1:
        return split(Recordings(rec.q, rec.dt, rec.u, rec.angle_dims, rec.source, rec.meta, rec.t), frac)
    order = np.argsort(rec.origin[:, 1], kind="stable")
    k = min(max(1, int(round(P * frac))), P - 1)
    held = order[P - k:]
    first = int(rec.origin[held, 1].min())
    train = np.array([i for i in order[: P - k] if rec.origin[i, 2] <= first], dtype=int)
    if not train.size:
        raise ValueError(f"the one log {name} is too short to hold out {frac:.0%} of it in time without overlap; give "
                         "more logs or holdout_trajectories")
    return (rec.subset(train), rec.subset(np.sort(held)),
            f"held-out last {k} of {P} pieces of the one log {name} in time")
