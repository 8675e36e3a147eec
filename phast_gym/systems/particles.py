"""Planar particle clusters with a pair potential: Lennard-Jones and softened gravity.

q = (x1, y1, x2, y2, x3, y3), M = m I, D = gamma I.
The pair geometry is written once here; subclasses give phi(r^2) and its
derivative with respect to r^2.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from itertools import combinations
from typing import Any

import numpy as np

from .base import NUMPY, ArrayNamespace, Components, Coord, Param, System, const_like


class PairParticles(System):
    """Base class: N planar particles interacting through phi(|r_i - r_j|^2)."""

    n_particles = 3
    n = 6
    coordinate_names = ("x1", "y1", "x2", "y2", "x3", "y3")
    #: radius of the triangle the initial state is drawn around, and noise scales
    init_q_std: float = 0.0
    init_p_std: float = 0.0
    #: the parameters every subclass has (in its PARAMS)
    mass: float
    gamma: float

    def _pairs(self, q: Components) -> Iterator[tuple[int, int, Any, Any, Any]]:
        for i, j in combinations(range(self.n_particles), 2):
            dx = q[2 * i] - q[2 * j]
            dy = q[2 * i + 1] - q[2 * j + 1]
            yield i, j, dx, dy, dx * dx + dy * dy

    def pair_energy(self, r2: Coord, xp: ArrayNamespace) -> Coord:
        """phi as a function of the squared distance."""
        raise NotImplementedError

    def pair_denergy(self, r2: Coord, xp: ArrayNamespace) -> Coord:
        """d phi / d(r^2)."""
        raise NotImplementedError

    def potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> Any:
        return sum(self.pair_energy(r2, xp) for *_, r2 in self._pairs(q))

    def grad_potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        # accumulators start as the float 0.0 (0.0 + x == x): no constant arrays per RK4 stage
        g: list = [0.0] * self.n
        for i, j, dx, dy, r2 in self._pairs(q):
            f = 2.0 * self.pair_denergy(r2, xp)  # dphi/dr2 * d r2/dx = 2 dx dphi/dr2
            fx, fy = f * dx, f * dy
            g[2 * i] = g[2 * i] + fx
            g[2 * i + 1] = g[2 * i + 1] + fy
            g[2 * j] = g[2 * j] - fx
            g[2 * j + 1] = g[2 * j + 1] - fy
        return tuple(g)  # every particle is in a pair, so every entry has q's type

    def mass_matrix(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        z, m = const_like(q[0], 0.0), const_like(q[0], self.mass)
        return tuple(tuple(m if a == b else z for b in range(self.n)) for a in range(self.n))

    def velocity(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return tuple(pi / self.mass for pi in p)

    def damping(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return tuple(const_like(qi, c) for qi, c in zip(q, self.constant_damping()))

    def constant_damping(self) -> tuple[float, ...]:
        return (self.gamma,) * self.n

    def has_damping(self) -> bool:
        return self.gamma > 0.0

    def triangle(self) -> np.ndarray:
        """Vertices of the initial equilateral triangle, (3, 2), angles 90/210/330 deg."""
        ang = np.deg2rad([90.0, 210.0, 330.0])
        r = self.triangle_radius()
        return np.stack([r * np.cos(ang), r * np.sin(ang)], axis=1)

    def triangle_radius(self) -> float:
        raise NotImplementedError

    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        q = self.triangle().reshape(1, -1) + rng.normal(0.0, self.init_q_std, size=(size, self.n))
        p = rng.normal(0.0, self.init_p_std, size=(size, self.n))
        return np.concatenate([q, p], axis=1)


class LennardJones3(PairParticles):
    """Three Lennard-Jones particles, deterministic friction, optional Langevin heat bath."""

    name = "lennard_jones3"
    dt = 0.002
    substeps = 1
    default_max_action = 10.0
    init_q_std = 0.05
    init_p_std = 0.1
    PARAMS = {
        "mass": Param(1.0, "particle mass m"),
        "epsilon": Param(1.0, "well depth eps"),
        "sigma": Param(1.0, "length scale s"),
        "gamma": Param(0.1, "isotropic friction", "nonnegative"),
        "temperature": Param(0.0, "Langevin temperature T (noise sqrt(2 gamma T dt) per step)", "nonnegative"),
    }
    epsilon: float
    sigma: float
    temperature: float

    # (s / r)^6 as x * x * x with x = (s / r)^2: a float power is ~5x slower on arrays
    def pair_energy(self, r2: Coord, xp: ArrayNamespace) -> Coord:
        x = self.sigma * self.sigma / r2
        s6 = x * x * x
        return 4.0 * self.epsilon * (s6 * s6 - s6)

    def pair_denergy(self, r2: Coord, xp: ArrayNamespace) -> Coord:
        x = self.sigma * self.sigma / r2
        s6 = x * x * x
        return 4.0 * self.epsilon * (-6.0 * s6 * s6 + 3.0 * s6) / r2

    def triangle_radius(self) -> float:
        return 2.0 ** (1.0 / 6.0) * self.sigma / math.sqrt(3.0)

    @property
    def stochastic(self) -> bool:
        return self.temperature > 0.0

    def stochastic_kick(self, p: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        if self.temperature <= 0.0:
            return p
        return p + math.sqrt(2.0 * self.gamma * self.temperature * self.dt) * rng.standard_normal(np.shape(p))


class NBody3(PairParticles):
    """Three gravitating bodies with softened gravity and weak friction."""

    name = "nbody3"
    dt = 0.01
    substeps = 4
    default_max_action = 10.0
    init_q_std = 0.3
    init_p_std = 0.5
    PARAMS = {
        "mass": Param(1.0, "body mass m (all bodies)"),
        "grav_const": Param(1.0, "gravitational constant G"),
        "softening": Param(0.1, "softening length eps"),
        "gamma": Param(0.05, "isotropic friction", "nonnegative"),
        "radius": Param(2.0, "radius of the initial triangle"),
    }
    grav_const: float
    softening: float
    radius: float

    def pair_energy(self, r2: Coord, xp: ArrayNamespace) -> Coord:
        return -self.grav_const * self.mass * self.mass / xp.sqrt(r2 + self.softening**2)

    def pair_denergy(self, r2: Coord, xp: ArrayNamespace) -> Coord:
        s = r2 + self.softening**2
        return 0.5 * self.grav_const * self.mass * self.mass / (s * xp.sqrt(s))

    def triangle_radius(self) -> float:
        return self.radius
