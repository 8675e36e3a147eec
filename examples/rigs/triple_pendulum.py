"""A user's rig: a three-link pendulum (compound links) in joint coordinates, free swing, viscous joint friction.

Joint angles phi_i (link i relative to link i-1; phi_1 from hanging), absolute angles theta_i = phi_1 + ... + phi_i.
With link i's mass m_i, joint spacing l_i, joint-to-centre-of-mass distance r_i and inertia I_i about its own joint:

    V = -g sum_i b_i cos(theta_i),            b_i = m_i r_i + l_i sum_{k>i} m_k
    T = 1/2 sum_ij a_ij cos(theta_i - theta_j) w_i w_j,   w = d theta / dt,
        a_ii = I_i + l_i^2 sum_{k>i} m_k,     a_ij = l_i (m_j r_j + l_j sum_{k>j} m_k)  (i < j)

so M(phi) = T^T M_abs(theta) T with T the lower-triangular matrix of ones.  Load it with
``--sim examples/rigs/triple_pendulum.py:TriplePendulum``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from phast_gym.systems import NUMPY, Param, System, const_like
from phast_gym.systems.base import Components, solve_spd

N_LINKS = 3


class TriplePendulum(System):
    """Three compound links in joint coordinates; one viscous coefficient at every joint."""

    name = "triple_pendulum"
    n = N_LINKS
    angle_dims = (0, 1, 2)
    dt = 0.001  # the encoders' sampling interval [s]
    substeps = 1
    separable = False
    coordinate_names = ("phi1", "phi2", "phi3")
    PARAMS = {
        "mass1": Param(0.30, "link 1 mass [kg]"), "mass2": Param(0.20, "link 2 mass [kg]"),
        "mass3": Param(0.10, "link 3 mass [kg]"),
        "length1": Param(0.20, "joint 1 to joint 2 [m]"), "length2": Param(0.15, "joint 2 to joint 3 [m]"),
        "com1": Param(0.10, "joint 1 to link 1's centre of mass [m]"), "com2": Param(0.075, "joint 2 to link 2's [m]"),
        "com3": Param(0.06, "joint 3 to link 3's [m]"),
        "inertia1": Param(4.0e-3, "link 1's inertia about joint 1 [kg m^2]"),
        "inertia2": Param(1.5e-3, "link 2's inertia about joint 2 [kg m^2]"),
        "inertia3": Param(5.0e-4, "link 3's inertia about joint 3 [kg m^2]"),
        "friction": Param(1e-4, "viscous friction at every joint [N m s / rad]", "nonnegative"),
        "gravity": Param(9.81, "gravitational acceleration [m/s^2]", known=True),
    }

    def _finalize(self) -> None:
        m = [self.mass1, self.mass2, self.mass3]
        r = [self.com1, self.com2, self.com3]
        ell = [self.length1, self.length2, 0.0]
        inertia = [self.inertia1, self.inertia2, self.inertia3]
        beyond = [sum(m[k + 1:]) for k in range(N_LINKS)]
        self._b = [m[i] * r[i] + ell[i] * beyond[i] for i in range(N_LINKS)]
        a = np.zeros((N_LINKS, N_LINKS))
        for i in range(N_LINKS):
            a[i, i] = inertia[i] + ell[i] ** 2 * beyond[i]
            for j in range(i + 1, N_LINKS):
                a[i, j] = a[j, i] = ell[i] * (m[j] * r[j] + ell[j] * beyond[j])
        self._a = a

    def _theta(self, q: Components) -> list:
        """Absolute link angles from the joint angles."""
        out, acc = [], 0.0 * q[0]
        for qi in q:
            acc = acc + qi
            out.append(acc)
        return out

    def potential(self, q: Components, xp: Any = NUMPY) -> Any:
        th = self._theta(q)
        return -self.gravity * sum(b * xp.cos(t) for b, t in zip(self._b, th))

    def grad_potential(self, q: Components, xp: Any = NUMPY) -> tuple:
        th = self._theta(q)
        dth = [self.gravity * b * xp.sin(t) for b, t in zip(self._b, th)]  # dV / d theta_i
        return tuple(sum(dth[k:]) for k in range(N_LINKS))  # d theta_i / d phi_k = 1 for i >= k

    def _trig(self, q: Components, xp: Any) -> tuple[list, dict, dict]:
        """Absolute angles, and cos / sin of every difference theta_i - theta_j (i < j), each computed once."""
        th = self._theta(q)
        cos = {(i, j): xp.cos(th[i] - th[j]) for i in range(N_LINKS) for j in range(i + 1, N_LINKS)}
        sin = {(i, j): xp.sin(th[i] - th[j]) for i in range(N_LINKS) for j in range(i + 1, N_LINKS)}
        return th, cos, sin

    def _mass(self, q: Components, cos: dict) -> tuple:
        """M(phi) = T^T M_abs T: entry (k, l) sums M_abs over i >= k, j >= l (cumulative sums from the last link)."""
        n, a = N_LINKS, self._a
        m_abs = [[a[i, j] * cos[(min(i, j), max(i, j))] if i != j else const_like(q[0], a[i, i]) for j in range(n)]
                 for i in range(n)]
        S = [[0.0] * (n + 1) for _ in range(n + 1)]
        for k in range(n - 1, -1, -1):
            for l_ in range(n - 1, -1, -1):
                S[k][l_] = m_abs[k][l_] + S[k + 1][l_] + S[k][l_ + 1] - S[k + 1][l_ + 1]
        return tuple(tuple(S[k][l_] for l_ in range(n)) for k in range(n))

    def mass_matrix(self, q: Components, xp: Any = NUMPY) -> tuple:
        return self._mass(q, self._trig(q, xp)[1])

    def _kinetics(self, q: Components, p: Components, xp: Any) -> tuple[tuple, tuple]:
        """(v = M^-1 p, dH/dq) with one mass matrix and one solve: dH/dphi_k = dV/dphi_k
        + sum_{i<j} a_ij w_i w_j sin(theta_i - theta_j) (1[k <= i] - 1[k <= j]), w the absolute rates."""
        th, cos, sin = self._trig(q, xp)
        v = tuple(solve_spd(self._mass(q, cos), p))
        w = self._theta(v)
        dth = [self.gravity * b * xp.sin(t) for b, t in zip(self._b, th)]  # dV / d theta_i
        g = [sum(dth[k:]) for k in range(N_LINKS)]
        for (i, j), s_ij in sin.items():  # i < j: 1[k <= i] - 1[k <= j] = -1 for i < k <= j
            term = self._a[i, j] * w[i] * w[j] * s_ij
            for k in range(i + 1, j + 1):
                g[k] = g[k] - term
        return v, tuple(g)

    def velocity(self, q: Components, p: Components, xp: Any = NUMPY) -> tuple:
        return tuple(solve_spd(self.mass_matrix(q, xp), p))

    def dH_dq(self, q: Components, p: Components, xp: Any = NUMPY) -> tuple:
        return self._kinetics(q, p, xp)[1]

    def rhs(self, q: Components, p: Components, u: Components | None, xp: Any = NUMPY) -> tuple[tuple, tuple]:
        """Eq. 1-3 with one mass matrix and one solve per call (the simulation's hot path)."""
        v, dh = self._kinetics(q, p, xp)
        pdot = [-a - self.friction * vi for a, vi in zip(dh, v)]
        if u is not None:
            pdot = [f + ui for f, ui in zip(pdot, u)]
        return v, tuple(pdot)

    def damping(self, q: Components, xp: Any = NUMPY) -> tuple:
        return tuple(const_like(qi, self.friction) for qi in q)

    def constant_damping(self) -> tuple[float, ...] | None:
        return (self.friction,) * N_LINKS

    def has_damping(self) -> bool:
        return self.friction > 0.0

    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """Joint angles within +-60 deg, rates within +-3 rad/s (a free swing released by hand), p = M(q) qdot."""
        q = rng.uniform(-math.pi / 3, math.pi / 3, size=(size, N_LINKS))
        w = rng.uniform(-3.0, 3.0, size=(size, N_LINKS))
        M = self.mass_matrix(tuple(q[:, i] for i in range(N_LINKS)), NUMPY)
        p = np.stack([sum(np.asarray(M[i][j]) * w[:, j] for j in range(N_LINKS)) for i in range(N_LINKS)], axis=1)
        return np.concatenate([q, p], axis=1)
