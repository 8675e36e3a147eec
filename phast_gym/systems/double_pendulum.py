"""Double pendulum (absolute angles from the downward vertical).

H = p^T M(q)^-1 p / 2 + V(q),
M = [[(m1+m2) l1^2, m2 l1 l2 cos(t1-t2)], [m2 l1 l2 cos(t1-t2), m2 l2^2]],
V = -(m1+m2) g l1 cos t1 - m2 g l2 cos t2.
D = diag(b + d0 + dd |sin t_i|): b on the absolute rates (paper Eq. 77),
windy d0 + dd |sin t_i| for the figures' windy variant.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
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

    # Each formula below is written once; the public methods and the fused ``rhs`` share them.
    def _dV(self, s1: Any, s2: Any) -> tuple:
        """dV/dq from s_i = sin(theta_i)."""
        m1, m2, l1, l2, g = self.mass1, self.mass2, self.length1, self.length2, self.gravity
        return ((m1 + m2) * g * l1 * s1, m2 * g * l2 * s2)

    def grad_potential(self, q: Components, xp: Any = NUMPY) -> tuple:
        return self._dV(xp.sin(q[0]), xp.sin(q[1]))

    def mass_matrix(self, q: Components, xp: Any = NUMPY) -> tuple:
        m1, m2, l1, l2 = self.mass1, self.mass2, self.length1, self.length2
        m12 = m2 * l1 * l2 * xp.cos(q[0] - q[1])
        return ((const_like(q[0], (m1 + m2) * l1 * l1), m12), (m12, const_like(q[0], m2 * l2 * l2)))

    def _velocity(self, c12: Any, p: Components) -> tuple:
        """M(q)^-1 p from c12 = cos(theta1 - theta2)."""
        m1, m2, l1, l2 = self.mass1, self.mass2, self.length1, self.length2
        m11, m22 = (m1 + m2) * l1 * l1, m2 * l2 * l2
        m12 = m2 * l1 * l2 * c12
        det = m11 * m22 - m12 * m12
        return ((m22 * p[0] - m12 * p[1]) / det, (m11 * p[1] - m12 * p[0]) / det)

    def velocity(self, q: Components, p: Components, xp: Any = NUMPY) -> tuple:
        return self._velocity(xp.cos(q[0] - q[1]), p)

    def _dH_dq(self, g: tuple, s12: Any, v: Sequence) -> tuple:
        """dH/dq|_p = dV/dq - v^T (dM/dq) v / 2 with dM12/dt1 = -dM12/dt2 = -m2 l1 l2 sin(t1 - t2);
        g = dV/dq, s12 = sin(theta1 - theta2)."""
        cross = self.mass2 * self.length1 * self.length2 * s12 * v[0] * v[1]
        return (g[0] + cross, g[1] - cross)

    def dH_dq(self, q: Components, p: Components, xp: Any = NUMPY) -> tuple:
        return self._dH_dq(self.grad_potential(q, xp), xp.sin(q[0] - q[1]), self.velocity(q, p, xp))

    def _wind(self, s: Any, xp: Any) -> Any:
        """b + d0 + dd |sin theta_i| from s = sin(theta_i) (dd > 0)."""
        return self.b + self.d0 + self.dd * xp.abs(s)

    def damping(self, q: Components, xp: Any = NUMPY) -> tuple:
        if self.dd == 0.0:
            return tuple(const_like(qi, c) for qi, c in zip(q, self.constant_damping()))
        return tuple(self._wind(xp.sin(qi), xp) for qi in q)

    def constant_damping(self) -> tuple[float, ...] | None:
        return (self.b + self.d0,) * 2 if self.dd == 0.0 else None

    def has_damping(self) -> bool:
        return self.b + self.d0 + self.dd > 0.0

    def rhs(self, q: Components, p: Components, u: Components | None, xp: Any = NUMPY) -> tuple[tuple, tuple]:
        """:meth:`System.rhs` (Eq. 1-3) with each sin/cos evaluated once per call."""
        d12 = q[0] - q[1]
        s1, s2 = xp.sin(q[0]), xp.sin(q[1])
        v = self._velocity(xp.cos(d12), p)
        a = self._dH_dq(self._dV(s1, s2), xp.sin(d12), v)
        if not self._damped:
            if u is None:
                return v, (-a[0], -a[1])
            return v, (u[0] - a[0], u[1] - a[1])
        d = self._const_d if self._const_d is not None else (self._wind(s1, xp), self._wind(s2, xp))
        if u is None:
            return v, (-a[0] - d[0] * v[0], -a[1] - d[1] * v[1])
        return v, (u[0] - a[0] - d[0] * v[0], u[1] - a[1] - d[1] * v[1])

    def switching(self, q: Components, p: Components, xp: Any = NUMPY) -> Any | None:
        return xp.sin(q[0]) * xp.sin(q[1]) if self.dd != 0.0 else None

    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        q = rng.uniform(-math.pi, math.pi, size=(size, 2))
        w = rng.uniform(-2.0, 2.0, size=(size, 2))
        (m11, m12), (_, m22) = self.mass_matrix((q[:, 0], q[:, 1]), NUMPY)
        p = np.stack([m11 * w[:, 0] + m12 * w[:, 1], m12 * w[:, 0] + m22 * w[:, 1]], axis=1)
        return np.concatenate([q, p], axis=1)
