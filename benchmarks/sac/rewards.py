"""The per-step rewards of the SAC agents on the torque-port pendulum (``benchmarks/control_sac.py``).

``zoo`` is the suite's standard reward (:func:`phast_gym.reward.regulation_reward`); ``quiet`` and ``precise`` add a
torque penalty near the target and angle wells (:class:`Well`), see :func:`pendulum_reward`.  At an unstable target
the quiet weight must stay below :func:`max_quiet_weight` (docs/control_results/sac/DIAGNOSIS.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

from phast_gym.reward import regulation_reward

REWARDS = ("zoo", "quiet", "precise")
#: the quiet reward's extra torque weight and the angle scale of the region where it applies
QUIET_WEIGHT, QUIET_SCALE = 0.5, 0.3
#: the precise reward's extra angle well: depth and width (the success rule's 0.05 rad tolerance)
PRECISE_WEIGHT, PRECISE_SCALE = 0.1, 0.05


class Well(NamedTuple):
    """An angle well of the ``precise`` reward: ``-depth (1 - exp(-(err / width)^2))`` per step."""

    depth: float
    width: float


#: the ``precise`` reward's default wells (``--wells``): one, as wide as the success tolerance
PRECISE_WELLS: tuple[Well, ...] = (Well(PRECISE_WEIGHT, PRECISE_SCALE),)


def parse_wells(text: str) -> tuple[Well, ...]:
    """``"DEPTH:WIDTH[,DEPTH:WIDTH...]"`` -> wells; depths >= 0 and widths > 0, or a ValueError naming the bad item."""
    wells = []
    for item in text.split(","):
        try:
            depth, width = (float(x) for x in item.split(":"))
        except ValueError:
            raise ValueError(f"well {item!r} is not DEPTH:WIDTH (e.g. 0.1:0.05)") from None
        if not (depth >= 0 and width > 0 and math.isfinite(depth) and math.isfinite(width)):
            raise ValueError(f"well {item!r} needs depth >= 0 and width > 0")
        wells.append(Well(depth, width))
    return tuple(wells)


def format_wells(wells: Sequence[Well]) -> str:
    return ",".join(f"{w.depth:g}:{w.width:g}" for w in wells)


def pendulum_reward(err: float, v: float, u: float, kind: str = "zoo", quiet_weight: float = QUIET_WEIGHT,
                    wells: Sequence[Well] = PRECISE_WELLS) -> float:
    """Per-step reward from the wrapped angle error ``err`` (rad), velocity ``v`` and torque ``u`` (N m).

    ``zoo``: the suite's standard reward (:func:`phast_gym.reward.regulation_reward`), the Gymnasium Pendulum shape
    ``-(err^2 + 0.1 v^2 + 0.001 u^2)``.
    ``quiet``: that minus ``quiet_weight u^2 exp(-(err / QUIET_SCALE)^2)``: a torque penalty that is 500x larger
    (``quiet_weight`` 0.5) near the target, so holding the target with a quiet actuator (the success rule's RMS
    torque) pays.  At an unstable target the weight must stay below :func:`max_quiet_weight` (see there).
    ``precise``: ``quiet`` minus ``PRECISE_WEIGHT (1 - exp(-(err / PRECISE_SCALE)^2))``: a narrow angle well as wide as
    the success tolerance, whose slope at a few 0.01 rad is ~30x that of ``err^2``, so a steady offset of the held angle
    costs (at the upright a 0.03 rad offset needs 0.3 N m of holding torque, over the 0.25 N m RMS limit).
    ``wells`` replaces that one well by others (``--wells``), e.g. a second, wider one whose pull reaches the offsets
    of 0.1-0.3 rad where the narrow well is flat and ``err^2`` is weak.
    """
    r = regulation_reward(err * err, v * v, u * u)
    if kind in ("quiet", "precise"):
        r -= quiet_weight * u * u * math.exp(-((err / QUIET_SCALE) ** 2))
    if kind == "precise":
        r -= sum(w.depth * (1.0 - math.exp(-((err / w.width) ** 2))) for w in wells)
    elif kind not in ("zoo", "quiet"):
        raise ValueError(f"reward must be one of {REWARDS}, got {kind!r}")
    return r


@dataclass(frozen=True)
class Reward:
    """One of the :data:`REWARDS` with its weights; ``reward(err, v, u)`` is :func:`pendulum_reward`."""

    kind: str = "zoo"
    quiet_weight: float = QUIET_WEIGHT
    wells: tuple[Well, ...] = PRECISE_WELLS

    def __post_init__(self) -> None:
        if self.kind not in REWARDS:
            raise ValueError(f"reward must be one of {REWARDS}, got {self.kind!r}")
        object.__setattr__(self, "wells", tuple(self.wells))

    def __call__(self, err: float, v: float, u: float) -> float:
        return pendulum_reward(err, v, u, self.kind, self.quiet_weight, self.wells)


def max_quiet_weight(mgl: float) -> float:
    """The largest ``quiet_weight`` for which holding a pendulum still at an angle error ``e`` from an *unstable* target
    costs more the larger ``e`` is.

    Holding still at ``e`` needs the gravity torque ``u = m g l sin e`` (zero only at the target), so the quiet
    reward's static cost is ``h(e) = e^2 + w (m g l sin e)^2 exp(-(e / s)^2)``.  For small ``e`` that is
    ``e^2 (1 + c exp(-x))`` with ``c = w (m g l)^2``, ``x = (e / s)^2``, whose derivative ``2 e (1 + c exp(-x) (1 - x))``
    stays positive for every ``x`` iff ``c < e^2 = 7.39`` (the minimum of ``exp(-x) (1 - x)`` is ``-exp(-2)``, at
    ``x = 2``), whatever the scale ``s``.  Above it ``h`` has a spurious minimum away from the target (with
    ``w = 0.5``, ``m g l = 9.81``: at ``e = 0.7`` rad, cost 0.62 per step behind a barrier of 1.64 at ``e = 0.3``).
    At a stable target (hanging) no holding torque is needed and the bound does not apply.
    """
    return math.exp(2.0) / mgl**2


def upright_quiet_weight(mgl: float) -> float:
    """The quiet weight used at the upright by default: ``0.05 (9.81 / m g l)^2`` (0.05 for our plant, 0.65 of
    :func:`max_quiet_weight`, 10x below :data:`QUIET_WEIGHT`).  The reward only reads ``m g l`` to set this weight."""
    return 0.05 * (9.81 / mgl) ** 2
