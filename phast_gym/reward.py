"""The standard reward of the suite: regulation of q to a target, with small velocity and effort costs.

``-(|wrap(q - q*)|^2 + 0.1 |qdot|^2 + 0.001 |u|^2)`` per step, Gymnasium's Pendulum-v1 cost on every coordinate
(angles wrapped).  One function, :func:`regulation_reward`, of the three squared norms: the real env
(:class:`phast_gym.PortHamiltonianEnv`), the learned world model's env and the SAC benchmark's rewards (which add
their own shaping terms to it) all call it.  Numpy only; the packages above this one import it, it names none of them.
"""

from __future__ import annotations

#: the weight of |qdot|^2 in the standard reward
VELOCITY_WEIGHT = 0.1
#: the weight of |u|^2 in the standard reward
ACTION_WEIGHT = 0.001


def regulation_reward(error_sq: float, speed_sq: float, effort_sq: float) -> float:
    """The standard per-step reward ``-(error_sq + VELOCITY_WEIGHT speed_sq + ACTION_WEIGHT effort_sq)`` from the
    squared norms of the wrapped error to the target, of the velocity and of the port input (the caller sums the
    squares)."""
    return -(error_sq + VELOCITY_WEIGHT * speed_sq + ACTION_WEIGHT * effort_sq)
