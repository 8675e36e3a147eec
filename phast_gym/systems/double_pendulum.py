"""Double pendulum: two rigid links (point masses on massless rods by default).

Link i has mass m_i, length l_i, its centre of mass at c_i from its joint axis (default l_i)
and moment of inertia I_i about its joint axis (default m_i c_i^2, the point mass).

``coordinates="absolute"`` (default; the benchmark envs): t_i = angle of link i from hanging,
    M = [[I1 + m2 l1^2, m2 l1 c2 cos(t1-t2)], [m2 l1 c2 cos(t1-t2), I2]],
    V = -(m1 c1 + m2 l1) g cos t1 - m2 c2 g cos t2,  u_i = torque on absolute angle t_i.
``coordinates="relative"`` (acrobot / pendubot; real two-motor rigs): q1 = t1, q2 = t2 - t1,
    M11 = I1 + I2 + m2 l1^2 + 2 m2 l1 c2 cos q2, M12 = I2 + m2 l1 c2 cos q2, M22 = I2,
    V = -(m1 c1 + m2 l1) g cos q1 - m2 c2 g cos(q1 + q2),  u_i = torque of the motor at joint i.
D = diag(b + d0 + dd |sin q_i|) on the rates of the chosen coordinates: b viscous (paper Eq. 77),
windy d0 + dd |sin q_i| for the figures' windy variant.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .base import NUMPY, ArrayNamespace, Components, Coord, Param, ParameterError, System, const_like

COORDINATES = ("absolute", "relative")


class DoublePendulum(System):
    """Double pendulum (compound links) with a torque port on each coordinate."""

    name = "double_pendulum"
    n = 2
    angle_dims = (0, 1)
    dt = 0.01
    substeps = 3
    default_max_action = 50.0
    separable = False
    coordinate_names = ("theta1", "theta2")
    PARAMS = {
        "mass1": Param(1.0, "mass of link 1 [kg]"),
        "mass2": Param(1.0, "mass of link 2 [kg]"),
        "length1": Param(1.0, "length of link 1, joint 1 to joint 2 [m]"),
        "length2": Param(1.0, "length of link 2 [m] (sets the default com2)"),
        "gravity": Param(9.81, "gravitational acceleration [m/s^2]", known=True),
        "b": Param(0.0, "viscous damping on both coordinate rates", "nonnegative"),
        "d0": Param(0.0, "base of the windy damping d0 + dd |sin q_i|", "nonnegative"),
        "dd": Param(0.0, "amplitude of the windy damping", "nonnegative"),
        "com1": Param(None, "joint-1 axis to link 1's centre of mass [m] (default length1)", "nonnegative",
                      extension=True),
        "com2": Param(None, "joint-2 axis to link 2's centre of mass [m] (default length2)", "nonnegative",
                      extension=True),
        "inertia1": Param(None, "link 1's moment of inertia about joint 1 [kg m^2] (default mass1 com1^2)",
                          extension=True),
        "inertia2": Param(None, "link 2's moment of inertia about joint 2 [kg m^2] (default mass2 com2^2)",
                          extension=True),
        "coordinates": Param("absolute", "'absolute': both angles from hanging; 'relative': q2 = link 2 relative to "
                             "link 1, u_i = torque of the motor at joint i", choices=COORDINATES, extension=True),
    }
    mass1: float
    mass2: float
    length1: float
    length2: float
    gravity: float
    b: float
    d0: float
    dd: float
    com1: float | None  # None: the defaults below (c1, c2, i1, i2 hold the values used)
    com2: float | None
    inertia1: float | None
    inertia2: float | None
    coordinates: str

    def _finalize(self) -> None:
        """The constants of M, V and their derivatives (each written once, used by every method)."""
        m1, m2, l1, l2, g = self.mass1, self.mass2, self.length1, self.length2, self.gravity
        c1 = l1 if self.com1 is None else self.com1
        c2 = l2 if self.com2 is None else self.com2
        i1 = m1 * c1 * c1 if self.inertia1 is None else self.inertia1
        i2 = m2 * c2 * c2 if self.inertia2 is None else self.inertia2
        self.c1, self.c2, self.i1, self.i2 = c1, c2, i1, i2
        self.relative = self.coordinates == "relative"
        if self.relative:
            self.coordinate_names = ("theta1", "theta2_rel")  # joint angles: link 2 relative to link 1
        if self.com1 is None and self.inertia1 is None:  # point mass: the benchmark's formulas, operation for operation
            self._m11, self._g1 = (m1 + m2) * l1 * l1, (m1 + m2) * g * l1
        else:
            self._m11, self._g1 = i1 + m2 * l1 * l1, (m1 * c1 + m2 * l1) * g
        self._g2 = m2 * g * c2  # V = -g1 cos(t1) - g2 cos(t2), t_i absolute
        self._k = m2 * l1 * c2  # coupling: M12 = [I2 +] k cos(phi), phi = t1 - t2 or q2
        self._m22 = i2
        if self.relative:  # M11 = m11 + 2 k cos q2 with m11 = I1 + I2 + m2 l1^2
            self._m11 = self._m11 + i2
        # det M = (I1 + m2 l1^2) I2 - (m2 l1 c2 cos phi)^2 in both conventions: M must be positive definite at every q
        # (always so for rigid links, I_i >= m_i c_i^2 by the parallel-axis theorem)
        if not (i2 > 0 and (i1 + m2 * l1 * l1) * i2 > self._k * self._k):
            raise ParameterError(f"DoublePendulum: inertia1={i1:g}, inertia2={i2:g} with com2={c2:g} give a mass "
                                 "matrix that is not positive definite; need inertia2 > 0 and "
                                 "(inertia1 + mass2 length1^2) inertia2 > (mass2 length1 com2)^2 "
                                 "(a rigid link has inertia_i >= mass_i com_i^2)")

    # Each formula below is written once; the public methods and the fused ``rhs`` share them.
    def _phi(self, q: Components) -> Any:
        """The angle the coupling depends on: t1 - t2 (absolute) or q2 (relative)."""
        return q[1] if self.relative else q[0] - q[1]

    def _link2(self, q: Components) -> Any:
        """Link 2's angle from hanging."""
        return q[0] + q[1] if self.relative else q[1]

    def potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> Any:
        return -self._g1 * xp.cos(q[0]) - self._g2 * xp.cos(self._link2(q))

    def _dV(self, s1: Coord, s2: Coord) -> tuple:
        """dV/dq from s1 = sin(link 1's angle), s2 = sin(link 2's angle)."""
        g2 = self._g2 * s2
        return (self._g1 * s1 + g2, g2) if self.relative else (self._g1 * s1, g2)

    def grad_potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return self._dV(xp.sin(q[0]), xp.sin(self._link2(q)))

    def _mass(self, c: Coord) -> tuple:
        """(M11, M12, M22) from c = cos(phi); entries that do not depend on q are floats."""
        m12 = self._k * c
        if self.relative:
            return self._m11 + 2.0 * m12, self._m22 + m12, self._m22
        return self._m11, m12, self._m22

    def mass_matrix(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        m11, m12, m22 = self._mass(xp.cos(self._phi(q)))
        if not self.relative:
            m11 = const_like(q[0], m11)
        return ((m11, m12), (m12, const_like(q[0], m22)))

    def _velocity(self, c: Coord, p: Components) -> tuple:
        """M(q)^-1 p from c = cos(phi)."""
        m11, m12, m22 = self._mass(c)
        det = m11 * m22 - m12 * m12
        return ((m22 * p[0] - m12 * p[1]) / det, (m11 * p[1] - m12 * p[0]) / det)

    def velocity(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return self._velocity(xp.cos(self._phi(q)), p)

    def _dH_dq(self, g: tuple, s: Coord, v: Sequence) -> tuple:
        """dH/dq|_p = dV/dq - v^T (dM/dq) v / 2 from g = dV/dq, s = sin(phi):
        absolute dM12/dt1 = -dM12/dt2 = -k sin(t1 - t2); relative dM11/dq2 = 2 dM12/dq2 = -2 k sin q2."""
        if self.relative:
            return (g[0], g[1] + self._k * s * v[0] * (v[0] + v[1]))
        cross = self._k * s * v[0] * v[1]
        return (g[0] + cross, g[1] - cross)

    def dH_dq(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return self._dH_dq(self.grad_potential(q, xp), xp.sin(self._phi(q)), self.velocity(q, p, xp))

    def _wind(self, s: Coord, xp: ArrayNamespace) -> Coord:
        """b + d0 + dd |sin q_i| from s = sin(q_i) (dd > 0)."""
        return self.b + self.d0 + self.dd * xp.abs(s)

    def damping(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        d = self.constant_damping()
        if d is not None:
            return tuple(const_like(qi, c) for qi, c in zip(q, d))
        return tuple(self._wind(xp.sin(qi), xp) for qi in q)

    def constant_damping(self) -> tuple[float, ...] | None:
        return (self.b + self.d0,) * 2 if self.dd == 0.0 else None

    def has_damping(self) -> bool:
        return self.b + self.d0 + self.dd > 0.0

    def rhs(self, q: Components, p: Components, u: Components | None,
            xp: ArrayNamespace = NUMPY) -> tuple[tuple, tuple]:
        """:meth:`System.rhs` (Eq. 1-3) with each sin/cos evaluated once per call."""
        phi = self._phi(q)
        s1, sphi = xp.sin(q[0]), xp.sin(phi)
        # sin of link 2's absolute angle; sin(q2) = sin(phi) for the relative wind law
        s2 = xp.sin(self._link2(q)) if self.relative else xp.sin(q[1])
        v = self._velocity(xp.cos(phi), p)
        a = self._dH_dq(self._dV(s1, s2), sphi, v)
        if not self._damped:
            if u is None:
                return v, (-a[0], -a[1])
            return v, (u[0] - a[0], u[1] - a[1])
        if self._const_d is not None:
            d = self._const_d
        else:
            d = (self._wind(s1, xp), self._wind(sphi if self.relative else s2, xp))
        if u is None:
            return v, (-a[0] - d[0] * v[0], -a[1] - d[1] * v[1])
        return v, (u[0] - a[0] - d[0] * v[0], u[1] - a[1] - d[1] * v[1])

    def switching(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> Any | None:
        return xp.sin(q[0]) * xp.sin(q[1]) if self.dd != 0.0 else None

    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """Coordinates uniform in [-pi, pi), their rates uniform in [-2, 2] (both conventions), p = M(q) qdot."""
        q = rng.uniform(-math.pi, math.pi, size=(size, 2))
        w = rng.uniform(-2.0, 2.0, size=(size, 2))
        (m11, m12), (_, m22) = self.mass_matrix((q[:, 0], q[:, 1]), NUMPY)
        p = np.stack([m11 * w[:, 0] + m12 * w[:, 1], m12 * w[:, 0] + m22 * w[:, 1]], axis=1)
        return np.concatenate([q, p], axis=1)
