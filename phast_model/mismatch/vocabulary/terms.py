"""Terms (a registered kind on one coordinate with its coefficient) and the augmented port-Hamiltonian model.

The vocabulary itself (which terms exist, their components, formulas and sign rules) is :mod:`.registry`.
All formulas are written in component form over an array namespace ``xp`` so the augmented model runs with numpy
(batched simulation) or torch, like the systems.  The nominal physics is never retyped: :class:`AugmentedSystem`
calls the base system for H, M, D and adds only the named terms, each through its kind's component hook.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from phast_gym.systems.base import NUMPY, ArrayNamespace, Components, Coord, System, solve_spd

from ...identify import delays
from .registry import VOCABULARY, Maps, TermKind, kind

if TYPE_CHECKING:
    import numpy as np

__all__ = ["VOCABULARY", "AugmentedSystem", "Term", "friction_basis"]


@dataclass(frozen=True)
class Term:
    """One named term on one coordinate with its coefficient (docs/mismatch.md units).

    ``velocity`` is the velocity parameter of a kind that carries one (the Stribeck v_s; unused by other terms)."""

    name: str
    coordinate: int
    coefficient: float
    velocity: float = 0.0

    def __post_init__(self) -> None:
        kind(self.name).check(self.coefficient, self.velocity)

    @property
    def kind(self) -> TermKind:
        return VOCABULARY[self.name]

    @property
    def component(self) -> str:
        return self.kind.component

    def expression(self) -> str:
        """Human-readable force / map with the coefficient filled in."""
        return self.kind.expression(self.coefficient, self.coordinate, self.velocity)


def friction_basis(name: str, q: Coord, v: Coord, eps: float, velocity: float = 0.0,
                   xp: ArrayNamespace = NUMPY) -> Coord:
    """f(q_i, qdot_i) of a dissipative term (the force is -c f, f odd in qdot), as its kind writes it.

    ``eps`` smooths sign(qdot) as tanh(qdot / eps); ``velocity`` is the Stribeck velocity v_s."""
    return kind(name).basis(q, v, eps, velocity, xp)


class AugmentedSystem(System):
    """A base system plus named terms, in the right port-Hamiltonian place.

    ``coulomb_eps`` (one value, or one per coordinate) smooths ``sign(qdot)`` as ``tanh(qdot / eps)`` (docs/mismatch.md
    allows smoothing near 0); it keeps explicit RK4 stable at the env's steps.
    ``deadzone_width > 0`` smooths the deadzone edge so its threshold can be fitted.
    """

    def __init__(self, base: System, terms: list[Term] | tuple[Term, ...] = (),
                 coulomb_eps: float | tuple[float, ...] = 1e-2,
                 deadzone_width: float = 0.0) -> None:
        # no System.__init__: parameters belong to the base system
        self.base = base
        self.terms = tuple(terms)
        # one smoothing per coordinate (a slow cart and a fast pole need different edges), or one for all
        eps = (tuple(float(e) for e in coulomb_eps) if isinstance(coulomb_eps, (tuple, list))
               else (float(coulomb_eps),) * base.n)
        if len(eps) != base.n:
            raise ValueError(f"coulomb_eps has {len(eps)} entries for {base.n} coordinates")
        self.coulomb_eps_per_coordinate = eps
        self.coulomb_eps = float(max(eps))
        self.deadzone_width = float(deadzone_width)
        self.params = dict(base.params)
        for attr in ("name", "n", "angle_dims", "dt", "substeps", "default_max_action", "separable",
                     "hamiltonian_system", "coordinate_names"):
            setattr(self, attr, getattr(base, attr))
        maps = Maps.identity(base.n)
        for t in self.terms:
            if not 0 <= t.coordinate < base.n:
                raise ValueError(f"term {t.name} on coordinate {t.coordinate}: {base.name} has coordinates "
                                 f"0..{base.n - 1}")
            if t.component in ("inertia", "sensor") or t.kind.delay:
                t.kind.set_map(maps, t.coordinate, t.coefficient)
        self.armature = maps.armature  # A = diag(armature): H = p^T (M(q) + A)^-1 p / 2 + V
        self.sensor_offset, self.sensor_gain, self.sensor_ecc = (maps.sensor_offset, maps.sensor_gain,
                                                                 maps.sensor_eccentricity)
        self.input_delay, self.sensor_delay = maps.input_delay, maps.sensor_delay  # [s] per port / coordinate
        self.has_armature = any(a != 0.0 for a in self.armature)
        # a base that carries its own rotor inertia (a MuJoCo model's joint armature) takes A into its M(q), so its
        # fused vector field stays in use (one kinematics pass per evaluation instead of three)
        fold = getattr(base, "with_armature", None)
        self.inertial_base: System | None = fold(self.armature) if self.has_armature and fold is not None else None

    @property
    def has_sensor_terms(self) -> bool:
        return any(t.component == "sensor" and not t.kind.delay for t in self.terms)

    def delayed_input(self, u: np.ndarray, dt: float | np.ndarray, u_before: np.ndarray | None = None) -> np.ndarray:
        """The port input delivered over each interval: the recorded u (B, K, n) delayed by :attr:`input_delay`
        (:func:`phast_model.identify.delays.delayed_input`; ``dt`` the step or the (B, K) steps, ``u_before`` (B, P, n)
        the
        recorded inputs before the first interval).  Used by the simulation around the vector field."""
        return delays.delayed_input(u, self.input_delay, dt, u_before)

    def delayed_output(self, q: np.ndarray, v0: np.ndarray, dt: float | np.ndarray) -> np.ndarray:
        """What delayed sensors report at the samples of a simulated q (B, K+1, n) started at (q[:, 0], v0):
        q_i(t_k - sensor_delay_i) (:func:`phast_model.identify.delays.delayed_output`)."""
        return delays.delayed_output(q, v0, self.sensor_delay, dt)

    def measure(self, q: np.ndarray) -> np.ndarray:
        """The measurement map: (..., n) true coordinates -> what the sensor reports."""
        if not self.has_sensor_terms:
            return q
        import numpy as np

        q = np.asarray(q, dtype=float)
        out = q * np.asarray(self.sensor_gain) + np.asarray(self.sensor_offset)
        ecc = np.asarray(self.sensor_ecc)
        if np.any(ecc != 0):
            out = out + ecc * (1.0 - np.cos(q))
        return out

    def unmeasure(self, y: np.ndarray) -> np.ndarray:
        """Approximate inverse of :meth:`measure` (two fixed-point steps; the effects are small)."""
        if not self.has_sensor_terms:
            return y
        import numpy as np

        y = np.asarray(y, dtype=float)
        q = (y - np.asarray(self.sensor_offset)) / np.asarray(self.sensor_gain)
        for _ in range(2):
            q = q - (self.measure(q) - y) / np.asarray(self.sensor_gain)
        return q

    def __repr__(self) -> str:
        return f"AugmentedSystem({self.base!r}, terms={list(self.terms)})"

    # ---- energy: base H plus the extra potential of conservative terms ----
    def _extra_potential(self, q: Components, xp: ArrayNamespace) -> Any:
        v = 0.0 * q[0]
        for t in self.terms:
            if t.component == "potential":
                v = v + t.kind.potential(q[t.coordinate], t.coefficient)
        return v

    def _extra_grad(self, q: Components, xp: ArrayNamespace) -> list:
        g = [0.0 * qi for qi in q]
        for t in self.terms:
            if t.component == "potential":
                g[t.coordinate] = g[t.coordinate] + t.kind.gradient(q[t.coordinate], t.coefficient)
        return g

    def potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> Any:
        return self.base.potential(q, xp) + self._extra_potential(q, xp)

    def grad_potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return tuple(a + b for a, b in zip(self.base.grad_potential(q, xp), self._extra_grad(q, xp)))

    def _dH_dq_at(self, q: Components, p: Components, v: Components | None, xp: ArrayNamespace) -> tuple:
        """dH/dq|_p given v = dH/dp.  With armature A (constant): dH/dq|_p = dV/dq - v^T (dM/dq) v / 2, which is the
        base's dH/dq at the base momentum p' = M(q) v (same v, same dM/dq), plus the extra potential's gradient."""
        if self.inertial_base is not None:
            return tuple(a + b for a, b in zip(self.inertial_base.dH_dq(q, p, xp), self._extra_grad(q, xp)))
        if self.has_armature:
            assert v is not None, "with an armature, dH/dq needs the velocity"
            p = self.base.momentum(q, v, xp)
        return tuple(a + b for a, b in zip(self.base.dH_dq(q, p, xp), self._extra_grad(q, xp)))

    def dH_dq(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        v = self.velocity(q, p, xp) if self.has_armature and self.inertial_base is None else None
        return self._dH_dq_at(q, p, v, xp)

    def mass_matrix(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        if self.inertial_base is not None:
            return self.inertial_base.mass_matrix(q, xp)
        M = self.base.mass_matrix(q, xp)
        if not self.has_armature:
            return M
        return tuple(tuple(mij + self.armature[i] if i == j else mij for j, mij in enumerate(row))
                     for i, row in enumerate(M))

    def velocity(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        if not self.has_armature:
            return self.base.velocity(q, p, xp)
        if self.inertial_base is not None:
            return self.inertial_base.velocity(q, p, xp)
        return solve_spd(self.mass_matrix(q, xp), p)

    def damping(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return self.base.damping(q, xp)

    def has_damping(self) -> bool:
        return self.base.has_damping()

    def switching(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> Any | None:
        return self.base.switching(q, p, xp)

    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """The base's states with the same rates qdot: p = (M(q) + A) qdot."""
        x = self.base.sample_initial(rng, size)
        if not self.has_armature:
            return x
        n = self.n
        q, p = tuple(x[:, i] for i in range(n)), tuple(x[:, n + i] for i in range(n))
        v = self.base.velocity(q, p, NUMPY)
        for i, a in enumerate(self.armature):
            x[:, n + i] = p[i] + a * v[i]
        return x

    # ---- port and dissipation -------------------------------------------------
    def port(self, u: Components | None, xp: ArrayNamespace) -> Components | None:
        """The port force actually delivered (actuator gain and deadzone)."""
        if u is None:
            return None
        u = list(u)
        for t in self.terms:
            if t.component == "port":
                u[t.coordinate] = t.kind.port(u[t.coordinate], t.coefficient, self.deadzone_width, xp)
        return u

    def extra_dissipation(self, q: Components, v: Components, xp: ArrayNamespace) -> list:
        """Passive friction forces -c f(v_i), f odd, c >= 0 (enters pdot like -D v)."""
        f = [0.0 * vi for vi in v]
        for t in self.terms:
            if t.component == "dissipation":
                i = t.coordinate
                eps = self.coulomb_eps_per_coordinate[i]
                f[i] = f[i] - t.coefficient * t.kind.basis(q[i], v[i], eps, t.velocity, xp)
        return f

    def rhs(self, q: Components, p: Components, u: Components | None,
            xp: ArrayNamespace = NUMPY) -> tuple[tuple, tuple]:
        uu = self.port(u, xp)
        # the base's fused field assumes its own M: generic Eq. 1-3
        if self.has_armature and self.inertial_base is None:
            qdot = self.velocity(q, p, xp)
            dh = self._dH_dq_at(q, p, qdot, xp)
            # -D v + u, in the order of Eq. 1-3
            if type(self.base).nonconservative_force is System.nonconservative_force:
                pdot = tuple(-a - di * vi for a, di, vi in zip(dh, self.base.damping(q, xp), qdot))
                if uu is not None:
                    pdot = tuple(ui + a for ui, a in zip(uu, pdot))
            else:  # the base's own friction laws and actuator model
                pdot = tuple(f - a for a, f in zip(dh, self.base.nonconservative_force(q, qdot, uu, xp)))
        else:
            qdot, pdot = (self.inertial_base or self.base).rhs(q, p, uu, xp)
            pdot = tuple(a - b for a, b in zip(pdot, self._extra_grad(q, xp)))
        f = self.extra_dissipation(q, qdot, xp)
        return tuple(qdot), tuple(a + c for a, c in zip(pdot, f))

    def power_balance(self, q: Components, p: Components, u: Components | None,
                      xp: ArrayNamespace = NUMPY) -> tuple[Any, Any]:
        """(v^T D v + the terms' friction power, v^T u delivered) with v = (M + A)^-1 p."""
        diss, supplied = super().power_balance(q, p, self.port(u, xp), xp)
        v = self.velocity(q, p, xp)
        extra = sum(-fi * vi for fi, vi in zip(self.extra_dissipation(q, v, xp), v))
        return diss + extra, supplied
