"""Double pendulum (absolute angles from the downward vertical).

H = p^T M(q)^-1 p / 2 + V(q),
M = [[(m1+m2) l1^2, m2 l1 l2 cos(t1-t2)], [m2 l1 l2 cos(t1-t2), m2 l2^2]],
V = -(m1+m2) g l1 cos t1 - m2 g l2 cos t2.
D = diag(b + d0 + dd |sin t_i|): b on the absolute rates (paper Eq. 77),
windy d0 + dd |sin t_i| for the figures' windy variant.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .base import NUMPY, Components, Param, System, const_like


class DoublePendulum(System):
    """Double pendulum with a torque port on each absolute angle."""

    name = "double_pendulum"
    n = 2
    angle_dims = (0, 1)
    dt = 0.01
    substeps = 3
    default_max_action = 50.0
    separable = False
    coordinate_names = ("theta1", "theta2")
    PARAMS = {
        "mass1": Param(1.0, "mass of bob 1 [kg]"),
        "mass2": Param(1.0, "mass of bob 2 [kg]"),
        "length1": Param(1.0, "length of rod 1 [m]"),
        "length2": Param(1.0, "length of rod 2 [m]"),
        "gravity": Param(9.81, "gravitational acceleration [m/s^2]"),
        "b": Param(0.0, "viscous damping on both absolute angle rates", "nonnegative"),
        "d0": Param(0.0, "base of the windy damping d0 + dd |sin theta_i|", "nonnegative"),
        "dd": Param(0.0, "amplitude of the windy damping", "nonnegative"),
    }

    def potential(self, q: Components, xp: Any = NUMPY) -> Any:
        m1, m2, l1, l2, g = self.mass1, self.mass2, self.length1, self.length2, self.gravity
        return -(m1 + m2) * g * l1 * xp.cos(q[0]) - m2 * g * l2 * xp.cos(q[1])

    def grad_potential(self, q: Components, xp: Any = NUMPY) -> tuple:
        m1, m2, l1, l2, g = self.mass1, self.mass2, self.length1, self.length2, self.gravity
        return ((m1 + m2) * g * l1 * xp.sin(q[0]), m2 * g * l2 * xp.sin(q[1]))

    def mass_matrix(self, q: Components, xp: Any = NUMPY) -> tuple:
        m1, m2, l1, l2 = self.mass1, self.mass2, self.length1, self.length2
        m12 = m2 * l1 * l2 * xp.cos(q[0] - q[1])
        return ((const_like(q[0], (m1 + m2) * l1 * l1), m12), (m12, const_like(q[0], m2 * l2 * l2)))

    def velocity(self, q: Components, p: Components, xp: Any = NUMPY) -> tuple:
        m1, m2, l1, l2 = self.mass1, self.mass2, self.length1, self.length2
        m11, m22 = (m1 + m2) * l1 * l1, m2 * l2 * l2
        m12 = m2 * l1 * l2 * xp.cos(q[0] - q[1])
        det = m11 * m22 - m12 * m12
        return ((m22 * p[0] - m12 * p[1]) / det, (m11 * p[1] - m12 * p[0]) / det)

    def dH_dq(self, q: Components, p: Components, xp: Any = NUMPY) -> tuple:
        # dH/dq|_p = dV/dq - v^T (dM/dq) v / 2 with dM12/dt1 = -dM12/dt2 = -m2 l1 l2 sin(t1 - t2)
        v = self.velocity(q, p, xp)
        g1, g2 = self.grad_potential(q, xp)
        cross = self.mass2 * self.length1 * self.length2 * xp.sin(q[0] - q[1]) * v[0] * v[1]
        return (g1 + cross, g2 - cross)

    def damping(self, q: Components, xp: Any = NUMPY) -> tuple:
        c = self.b + self.d0
        if self.dd == 0.0:
            return tuple(const_like(qi, c) for qi in q)
        return tuple(c + self.dd * xp.abs(xp.sin(qi)) for qi in q)

    def has_damping(self) -> bool:
        return self.b + self.d0 + self.dd > 0.0

    def switching(self, q: Components, p: Components, xp: Any = NUMPY) -> Any | None:
        return xp.sin(q[0]) * xp.sin(q[1]) if self.dd != 0.0 else None

    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        q = rng.uniform(-math.pi, math.pi, size=(size, 2))
        w = rng.uniform(-2.0, 2.0, size=(size, 2))
        (m11, m12), (_, m22) = self.mass_matrix((q[:, 0], q[:, 1]), NUMPY)
        p = np.stack([m11 * w[:, 0] + m12 * w[:, 1], m12 * w[:, 0] + m22 * w[:, 1]], axis=1)
        return np.concatenate([q, p], axis=1)
