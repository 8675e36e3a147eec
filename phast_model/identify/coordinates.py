"""Are the recorded coordinates the model's?  Angles in radians, the model's joint order, inside its joint ranges.

Bad input of this kind does not fail loudly on its own: a log in degrees or with two joints swapped is just a very
different robot, and the fit would answer a question nobody asked.  Each check here raises a ValueError naming the
problem before anything runs (the CLIs exit 2, nothing is written).

* **Degrees.**  An angle coordinate that spans more than two turns *and* moves faster than :data:`DEGREE_SPEED` rad/s
  (robust percentiles over all samples) reads as degrees; ``angle_unit = 'deg'`` converts (q and angle_offset),
  ``'rad'`` takes the values as recorded (a wheel that really spins that fast).
* **Joint order.**  With ``coordinate_names`` in the recordings, they must be the model's coordinate names in the
  model's order (a permutation is named as such).
* **Joint ranges** (a MuJoCo model file's limited joints).  A recorded value beyond a limit by more than
  :data:`RANGE_SLACK` of the range is impossible for the model: wrong joint order, units or zero.  A value within
  :data:`LIMIT_MARGIN` of a limit is possible but the limit's constraint force is not part of the fitted model: it is
  noted (``Recordings.meta["joint_limits_reached"]``; the mismatch report says so), not refused, since the rest of the
  log is good data.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TypedDict

import numpy as np
import numpy.typing as npt

#: an angle coordinate spanning more than this (rad) ...
DEGREE_SPAN = 4 * math.pi
#: ... and moving faster than this (rad/s, 90th percentile of its steps) is taken for degrees
DEGREE_SPEED = 30.0
#: units ``angle_unit`` may declare
ANGLE_UNITS = ("rad", "deg")
#: a value beyond a joint limit by more than this share of the joint's range is refused
RANGE_SLACK = 0.02
#: a value within this share of the joint's range of a limit reaches the limit (as phast_model.mismatch.mjcf_answer)
LIMIT_MARGIN = 0.02


class LimitReached(TypedDict):
    """A joint the recordings reach a limit of (:func:`check_ranges`)."""

    joint: str
    range: list[float]
    share_of_samples: float


def angle_unit(raw_unit: npt.ArrayLike | None, source: str) -> str | None:
    """The declared ``angle_unit`` ('rad', 'deg') or None (undeclared: checked)."""
    if raw_unit is None:
        return None
    unit = str(np.asarray(raw_unit).reshape(-1)[0]) if np.size(raw_unit) else ""
    if unit not in ANGLE_UNITS:
        raise ValueError(f"{source}: angle_unit must be one of {ANGLE_UNITS}, got {unit!r}")
    return unit


def check_radians(qs: Sequence[np.ndarray], steps: Sequence[np.ndarray], angle_dims: Sequence[int],
                  source: str) -> None:
    """ValueError when an angle coordinate looks like degrees: ``qs`` arrays (..., L, n) of recorded values, ``steps``
    the matching (..., L-1) sample intervals in seconds (pooled over all trajectories)."""
    for j in angle_dims:
        vals = np.concatenate([q[..., j].reshape(-1) for q in qs])
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            speeds = np.concatenate([(np.abs(np.diff(q[..., j], axis=-1)) / s).reshape(-1) for q, s in zip(qs, steps)])
        vals, speeds = vals[np.isfinite(vals)], speeds[np.isfinite(speeds)]
        if vals.size < 2 or speeds.size < 1:
            continue
        lo, hi = np.percentile(vals, [0.5, 99.5])
        fast = float(np.percentile(speeds, 90))
        if hi - lo > DEGREE_SPAN and fast > DEGREE_SPEED:
            raise ValueError(f"{source}: angle coordinate {j} looks like degrees, not radians: it spans "
                             f"{lo:.4g}..{hi:.4g} "
                             f"and moves at {fast:.3g} per second (90th percentile). Record angles in radians, or "
                             "declare angle_unit = 'deg' (converted) or 'rad' (taken as recorded)")


def to_radians(q: np.ndarray, offset: npt.ArrayLike | None,
               angle_dims: Sequence[int]) -> tuple[np.ndarray, npt.ArrayLike | None]:
    """q (..., n) and angle_offset with the angle coordinates converted from degrees."""
    q = np.array(q, dtype=np.float64)
    q[..., list(angle_dims)] = np.deg2rad(q[..., list(angle_dims)])
    if offset is not None:
        off = np.asarray(offset, dtype=np.float64) * np.ones(q.shape[-1])
        off[list(angle_dims)] = np.deg2rad(off[list(angle_dims)])
        offset = off
    return q, offset


def check_names(given: npt.ArrayLike | None, model: object, source: str) -> None:
    """ValueError when the recordings' ``coordinate_names`` are not the model's, in its order."""
    names = tuple(getattr(model, "coordinate_names", ()) or ())
    if given is None or not names:
        return
    got = [str(x) for x in np.atleast_1d(np.asarray(given))]
    if got == list(names):
        return
    if sorted(got) == sorted(names):
        raise ValueError(f"{source}: the log's joint order {got} does not match the model's {list(names)}: put the "
                         "columns of q (and u) in the model's order")
    unknown, missing = sorted(set(got) - set(names)), sorted(set(names) - set(got))
    raise ValueError(f"{source}: the log's coordinates {got} are not the model's {list(names)} "
                     f"(not in the model: {unknown}; not in the log: {missing})")


def joint_ranges(model: object) -> np.ndarray | None:
    """(n, 2) joint ranges of a MuJoCo model file's system ((-inf, inf) where unlimited), or None."""
    tree = getattr(model, "TREE", None)
    ranges = getattr(tree, "joint_range", None)
    return None if ranges is None else np.asarray(ranges, dtype=float)


def check_ranges(qs: Sequence[np.ndarray], model: object, source: str) -> list[LimitReached]:
    """ValueError when a recorded joint value (``qs``: (..., L, n) arrays, offset applied, before any wrapping) is
    outside the model's range; the joints that reach a limit (noted, not refused)."""
    ranges = joint_ranges(model)
    if ranges is None:
        return []
    names = tuple(getattr(model, "coordinate_names", ())) or tuple(f"q{j}" for j in range(len(ranges)))
    out: list[LimitReached] = []
    for j, (lo, hi) in enumerate(ranges):
        if not (np.isfinite(lo) and np.isfinite(hi)) or j >= qs[0].shape[-1]:
            continue
        vals = np.concatenate([q[..., j].reshape(-1) for q in qs])
        vals = vals[np.isfinite(vals)]
        if not vals.size:
            continue
        span = hi - lo
        vmin, vmax = float(vals.min()), float(vals.max())
        if vmin < lo - RANGE_SLACK * span or vmax > hi + RANGE_SLACK * span:
            raise ValueError(f"{source}: joint {j} ({names[j]}) is recorded at {vmin:.4g}..{vmax:.4g}, outside its "
                             f"range {lo:.4g}..{hi:.4g} in the model: check the joint order (the model's is "
                             f"{list(names)}), the units (radians, metres) and the zero (angle_offset)")
        at = (vals <= lo + LIMIT_MARGIN * span) | (vals >= hi - LIMIT_MARGIN * span)
        if at.any():
            out.append({"joint": names[j], "range": [float(lo), float(hi)], "share_of_samples": float(at.mean())})
    return out
