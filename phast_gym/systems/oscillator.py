"""Two-dimensional harmonic oscillator (plain and damped).

H = |p|^2 / (2 m) + m omega^2 |q|^2 / 2 (m = 1 gives docs/envs.md's
0.5|p|^2 + 0.5 w^2 |q|^2), D = gamma I.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .base import NUMPY, ArrayNamespace, Components, Param, System, const_like


class Oscillator(System):
    """Isotropic linear oscillator with a force port on each coordinate."""

    name = "oscillator"
    n = 2
    dt = 0.02
    substeps = 1
    default_max_action = 10.0
    coordinate_names = ("q1", "q2")
    PARAMS = {
        "omega": Param(1.0, "natural angular frequency [rad/s]"),
        "mass": Param(1.0, "mass m"),
        "gamma": Param(0.0, "viscous damping on both coordinates", "nonnegative"),
    }
    omega: float
    mass: float
    gamma: float

    def potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> Any:
        k = self.mass * self.omega**2
        return 0.5 * k * sum(qi * qi for qi in q)

    def grad_potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        k = self.mass * self.omega**2
        return tuple(k * qi for qi in q)

    def mass_matrix(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        z = const_like(q[0], 0.0)
        m = const_like(q[0], self.mass)
        return ((m, z), (z, m))

    def velocity(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return tuple(pi / self.mass for pi in p)

    def damping(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return tuple(const_like(qi, c) for qi, c in zip(q, self.constant_damping()))

    def constant_damping(self) -> tuple[float, ...]:
        return (self.gamma,) * self.n

    def has_damping(self) -> bool:
        return self.gamma > 0.0

    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        q = rng.normal(0.0, 1.0, size=(size, 2))
        p = rng.normal(0.0, 1.0, size=(size, 2))
        return np.concatenate([q, p], axis=1)
