"""Series RLC circuit: q = capacitor charge, p = flux linkage phi = L i.

H = q^2 / (2 C) + phi^2 / (2 L), D = R (so phidot = -q/C - R phi/L + u),
u = source voltage.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .base import NUMPY, ArrayNamespace, Components, Param, System, const_like


class RLCCircuit(System):
    """Series RLC circuit with a voltage source as the port."""

    name = "rlc"
    n = 1
    dt = 0.02
    substeps = 1
    default_max_action = 10.0
    coordinate_names = ("charge",)
    PARAMS = {
        "resistance": Param(0.5, "resistance R [Ohm]", "nonnegative"),
        "inductance": Param(1.0, "inductance L [H]"),
        "capacitance": Param(1.0, "capacitance C [F]"),
    }
    resistance: float
    inductance: float
    capacitance: float

    def potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> Any:
        return q[0] * q[0] / (2.0 * self.capacitance)

    def grad_potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return (q[0] / self.capacitance,)

    def mass_matrix(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return ((const_like(q[0], self.inductance),),)

    def velocity(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return (p[0] / self.inductance,)

    def damping(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return (const_like(q[0], self.constant_damping()[0]),)

    def constant_damping(self) -> tuple[float, ...]:
        return (self.resistance,)

    def has_damping(self) -> bool:
        return self.resistance > 0.0

    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        q = rng.uniform(-2.0, 2.0, size=(size, 1))
        p = rng.uniform(-2.0, 2.0, size=(size, 1))
        return np.concatenate([q, p], axis=1)
