"""Single pendulum family: plain, damped (gamma) and windy (d0 + dd |sin theta|).

H = p^2 / (2 I) + m g l (1 - cos theta), theta from the downward vertical.
D(theta) = gamma + d0 + dd |sin theta|  (docs/envs.md; paper Appendix B).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .base import NUMPY, ArrayNamespace, Components, Coord, Param, System, const_like


class Pendulum(System):
    """Pendulum with torque port at the pivot."""

    name = "pendulum"
    n = 1
    angle_dims = (0,)
    dt = 0.05
    substeps = 4
    default_max_action = 50.0
    coordinate_names = ("theta",)
    PARAMS = {
        "mass": Param(1.0, "bob mass m [kg]"),
        "length": Param(1.0, "rod length l [m]"),
        "gravity": Param(9.81, "gravitational acceleration g [m/s^2]", known=True),
        "inertia": Param(None, "moment of inertia I about the pivot [kg m^2] (default m l^2)"),
        "gamma": Param(0.0, "constant viscous damping [N m s]", "nonnegative"),
        "d0": Param(0.0, "base of the windy damping d0 + dd |sin theta|", "nonnegative"),
        "dd": Param(0.0, "amplitude of the windy damping d0 + dd |sin theta|", "nonnegative"),
        "init_p_std": Param(3.0, "std of the initial momentum p0 ~ N(0, s^2)", "nonnegative"),
    }
    mass: float
    length: float
    gravity: float
    inertia: float  # None (the default m l^2) only until _finalize
    gamma: float
    d0: float
    dd: float
    init_p_std: float

    def _finalize(self) -> None:
        if self.inertia is None:
            self.inertia = self.mass * self.length**2
            self.params["inertia"] = None
        self.mgl = self.mass * self.gravity * self.length

    # Each formula below is written once; the public methods and the fused ``rhs`` share them.
    def potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> Any:
        return self.mgl * (1.0 - xp.cos(q[0]))

    def _dV(self, s: Coord) -> Coord:
        """dV/dtheta from s = sin(theta)."""
        return self.mgl * s

    def grad_potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return (self._dV(xp.sin(q[0])),)

    def mass_matrix(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return ((const_like(q[0], self.inertia),),)

    def velocity(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return (p[0] / self.inertia,)

    def _wind(self, s: Coord, xp: ArrayNamespace) -> Coord:
        """D(theta) from s = sin(theta) when dd > 0 (the kinked wind law)."""
        return self.gamma + self.d0 + self.dd * xp.abs(s)

    def damping(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        d = self.constant_damping()
        if d is not None:
            return (const_like(q[0], d[0]),)
        return (self._wind(xp.sin(q[0]), xp),)

    def constant_damping(self) -> tuple[float, ...] | None:
        return (self.gamma + self.d0,) if self.dd == 0.0 else None

    def has_damping(self) -> bool:
        return self.gamma + self.d0 + self.dd > 0.0

    def rhs(self, q: Components, p: Components, u: Components | None,
            xp: ArrayNamespace = NUMPY) -> tuple[tuple, tuple]:
        """:meth:`System.rhs` (Eq. 1-3) with sin(theta) evaluated once for dV/dq and D(q)."""
        s = xp.sin(q[0])
        (v,) = self.velocity(q, p, xp)
        a = self._dV(s)
        if self._damped:
            d = self._const_d[0] if self._const_d is not None else self._wind(s, xp)
            return (v,), ((-a - d * v) if u is None else (u[0] - a - d * v),)
        return (v,), ((-a) if u is None else (u[0] - a),)

    def switching(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> Any | None:
        return xp.sin(q[0]) if self.dd != 0.0 else None

    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        theta = rng.uniform(-math.pi, math.pi, size=(size, 1))
        p = rng.normal(0.0, self.init_p_std, size=(size, 1))
        return np.concatenate([theta, p], axis=1)
