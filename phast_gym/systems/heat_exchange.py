"""Heat exchange between two thermal masses, as a port-Hamiltonian analogue.

H = c1 T1^2 / 2 + c2 T2^2 / 2 + kc (T1 - T2)^2 / 2 + |p|^2 / (2 tau),
M = tau I, D = kloss I (docs/envs.md, a *choice* the paper implies).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .base import NUMPY, ArrayNamespace, Components, Param, System, const_like


class HeatExchange(System):
    """Two coupled thermal masses with a heat-input port on each."""

    name = "heat_exchange"
    n = 2
    dt = 0.02
    substeps = 1
    default_max_action = 10.0
    coordinate_names = ("T1", "T2")
    PARAMS = {
        "c1": Param(1.0, "heat capacity of mass 1"),
        "c2": Param(1.0, "heat capacity of mass 2"),
        "kc": Param(0.5, "coupling conductance", "nonnegative"),
        "tau": Param(1.0, "time constant (plays the role of M)"),
        "kloss": Param(0.1, "heat loss (plays the role of D)", "nonnegative"),
    }
    c1: float
    c2: float
    kc: float
    tau: float
    kloss: float

    def potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> Any:
        d = q[0] - q[1]
        return 0.5 * self.c1 * q[0] * q[0] + 0.5 * self.c2 * q[1] * q[1] + 0.5 * self.kc * d * d

    def grad_potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        d = q[0] - q[1]
        return (self.c1 * q[0] + self.kc * d, self.c2 * q[1] - self.kc * d)

    def mass_matrix(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        z, t = const_like(q[0], 0.0), const_like(q[0], self.tau)
        return ((t, z), (z, t))

    def velocity(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return tuple(pi / self.tau for pi in p)

    def damping(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return tuple(const_like(qi, c) for qi, c in zip(q, self.constant_damping()))

    def constant_damping(self) -> tuple[float, ...]:
        return (self.kloss,) * self.n

    def has_damping(self) -> bool:
        return self.kloss > 0.0

    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        q = 0.5 + 1.5 * rng.uniform(0.0, 1.0, size=(size, 2))
        p = rng.normal(0.0, 0.3, size=(size, 2))
        return np.concatenate([q, p], axis=1)
