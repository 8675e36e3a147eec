"""A user's rig: a pendulum on a torsion spring, with bearing friction, driven by a motor at the pivot.

H = p^2 / (2 I) + m g l (1 - cos theta) + k theta^2 / 2,  D = b,  u = motor torque [N m].
Load it with ``--sim examples/rigs/torsion_pendulum.py:TorsionPendulum``.
"""

import math
from typing import Any

import numpy as np

from phast_gym.systems import NUMPY, Param, System, const_like
from phast_gym.systems.base import Components


class TorsionPendulum(System):
    """Torsion pendulum: theta from hanging, motor torque port."""

    name = "torsion_pendulum"
    n = 1  # one coordinate: theta [rad] from hanging
    angle_dims = (0,)
    dt = 0.01  # the logger's sampling interval [s]
    coordinate_names = ("theta",)
    PARAMS = {
        "mass": Param(0.5, "bob mass [kg]"),
        "length": Param(0.3, "pivot to centre of mass [m]"),
        "inertia": Param(0.05, "moment of inertia about the pivot [kg m^2]"),
        "stiffness": Param(0.8, "torsion spring [N m / rad]", "nonnegative"),
        "friction": Param(0.01, "viscous bearing friction [N m s / rad]", "nonnegative"),
        "gravity": Param(9.81, "gravitational acceleration [m/s^2]", known=True),
    }

    def potential(self, q: Components, xp: Any = NUMPY) -> Any:
        """V(q) [J]."""
        return self.mass * self.gravity * self.length * (1.0 - xp.cos(q[0])) + 0.5 * self.stiffness * q[0] ** 2

    def grad_potential(self, q: Components, xp: Any = NUMPY) -> tuple:
        """dV/dq, one component per coordinate [N m]."""
        return (self.mass * self.gravity * self.length * xp.sin(q[0]) + self.stiffness * q[0],)

    def mass_matrix(self, q: Components, xp: Any = NUMPY) -> tuple:
        """M(q) as nested tuples [kg m^2]."""
        return ((const_like(q[0], self.inertia),),)

    def velocity(self, q: Components, p: Components, xp: Any = NUMPY) -> tuple:
        """qdot = M(q)^-1 p [rad/s]."""
        return (p[0] / self.inertia,)

    def damping(self, q: Components, xp: Any = NUMPY) -> tuple:
        """Diagonal of D(q): force -D qdot [N m s / rad]."""
        return (const_like(q[0], self.friction),)

    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """(size, 2n) states (q, p) for tests and synthetic data."""
        theta = rng.uniform(-math.pi / 2, math.pi / 2, size)
        p = self.inertia * rng.normal(0.0, 2.0, size)
        return np.stack([theta, p], axis=1)
