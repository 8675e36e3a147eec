"""Windy cart-pole: cart position x and pole angle theta (0 = hanging).

H = p^T M(q)^-1 p / 2 + m_p g l (1 - cos theta),
M(q) = [[m_c + m_p, m_p l cos theta], [m_p l cos theta, m_p l^2]].
D = diag(d_cart, d0 + dd |sin theta|)  (``damping="diag"``, the main text), or
d0 + dd |sin theta| on both coordinates (``damping="scalar"``, paper Eq. 65).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .base import NUMPY, ArrayNamespace, Components, Coord, Param, ParameterError, System, const_like


class CartPole(System):
    """Cart-pole with force on the cart and torque on the pole as ports."""

    name = "cartpole"
    n = 2
    angle_dims = (1,)
    dt = 0.02
    substeps = 4
    default_max_action = 50.0
    separable = False
    coordinate_names = ("x", "theta")
    PARAMS = {
        "cart_mass": Param(1.0, "cart mass m_c [kg]"),
        "pole_mass": Param(1.0, "pole (bob) mass m_p [kg]"),
        "length": Param(1.0, "pole length l [m]"),
        "gravity": Param(9.81, "gravitational acceleration g [m/s^2]", known=True),
        "d_cart": Param(0.3, "cart friction (diag variant)", "nonnegative"),
        "d0": Param(0.3, "base of the windy pole damping d0 + dd |sin theta|", "nonnegative"),
        "dd": Param(0.5, "amplitude of the windy pole damping", "nonnegative"),
    }
    cart_mass: float
    pole_mass: float
    length: float
    gravity: float
    d_cart: float
    d0: float
    dd: float

    def __init__(self, damping: str = "diag", **params: object) -> None:
        if damping not in ("diag", "scalar"):
            raise ParameterError(f"CartPole: damping must be 'diag' or 'scalar', got {damping!r}")
        self.damping_kind = damping
        super().__init__(**params)
        self.params["damping"] = damping

    def potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> Any:
        return self.pole_mass * self.gravity * self.length * (1.0 - xp.cos(q[1]))

    # Each formula below is written once; the public methods and the fused ``rhs`` share them.
    def _dV_theta(self, s: Coord) -> Coord:
        """dV/dtheta from s = sin(theta) (dV/dx = 0)."""
        return self.pole_mass * self.gravity * self.length * s

    def grad_potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return (const_like(q[0], 0.0), self._dV_theta(xp.sin(q[1])))

    def mass_matrix(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        m12 = self.pole_mass * self.length * xp.cos(q[1])
        return (
            (const_like(q[0], self.cart_mass + self.pole_mass), m12),
            (m12, const_like(q[0], self.pole_mass * self.length**2)),
        )

    def _velocity(self, c: Coord, p: Components) -> tuple:
        """M(q)^-1 p from c = cos(theta)."""
        mc, mp, l = self.cart_mass, self.pole_mass, self.length
        m11, m12, m22 = mc + mp, mp * l * c, mp * l * l
        det = m11 * m22 - m12 * m12
        return ((m22 * p[0] - m12 * p[1]) / det, (m11 * p[1] - m12 * p[0]) / det)

    def velocity(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return self._velocity(xp.cos(q[1]), p)

    def _dH_dtheta(self, s: Coord, v: Sequence) -> Coord:
        """dH/dtheta|_p = dV/dtheta - v^T (dM/dtheta) v / 2, dM12/dtheta = -m_p l sin theta (dH/dx = 0)."""
        mpl = self.pole_mass * self.length
        return mpl * s * (self.gravity + v[0] * v[1])

    def dH_dq(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return (const_like(q[0], 0.0), self._dH_dtheta(xp.sin(q[1]), self.velocity(q, p, xp)))

    def _pole_damping(self, s: Coord, xp: ArrayNamespace) -> Coord:
        """d0 + dd |sin theta| from s = sin(theta)."""
        return self.d0 + self.dd * xp.abs(s)

    def damping(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        pole = self._pole_damping(xp.sin(q[1]), xp)
        if self.damping_kind == "scalar":
            return (pole, pole)
        return (const_like(q[0], self.d_cart), pole)

    def rhs(self, q: Components, p: Components, u: Components | None,
            xp: ArrayNamespace = NUMPY) -> tuple[tuple, tuple]:
        """:meth:`System.rhs` (Eq. 1-3) with cos/sin(theta) evaluated once per call.

        dH/dx = 0, so pdot_x = u_x - d_x v_x (the same value as ``u_x - 0 - d_x v_x``)."""
        c, s = xp.cos(q[1]), xp.sin(q[1])
        v0, v1 = v = self._velocity(c, p)
        a1 = self._dH_dtheta(s, v)
        pole = self._pole_damping(s, xp)
        d0 = pole if self.damping_kind == "scalar" else self.d_cart
        if u is None:
            return (v0, v1), (-(d0 * v0), -a1 - pole * v1)
        return (v0, v1), (u[0] - d0 * v0, u[1] - a1 - pole * v1)

    def switching(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> Any | None:
        return xp.sin(q[1]) if self.dd != 0.0 else None

    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        q = rng.uniform([-1.0, -math.pi], [1.0, math.pi], size=(size, 2))
        p = rng.uniform(-2.0, 2.0, size=(size, 2))
        return np.concatenate([q, p], axis=1)
