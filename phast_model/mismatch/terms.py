"""The named term vocabulary of docs/mismatch.md and the augmented port-Hamiltonian model.

Each term adds a force to ``pdot_i`` (or changes the port / the sensor) and sits
in one component of the port-Hamiltonian structure:

* dissipation (``viscous_damping``, ``coulomb_friction``, ``quadratic_drag``,
  ``position_dependent_damping``, and one addition documented the same way:
  ``stribeck_friction`` ``-c * sign(qdot_i) * exp(-(qdot_i / v_s)**2)``, the extra
  static friction a bearing shows near velocity reversals, with its Stribeck velocity
  ``v_s`` carried by the term): a force ``-c * f(qdot_i)`` with ``f`` odd and
  ``c >= 0``, so ``qdot_i * force <= 0``: the augmented model stays passive
  (paper Eq. 4, dH/dt = -v^T D v + v^T u);
* potential (``linear_stiffness``, ``cubic_stiffness``, ``constant_force``):
  an extra potential V_extra(q_i) added to H, force ``-dV_extra/dq_i``;
* port (``actuator_gain``, ``actuator_deadzone``): the delivered port force;
* inertia (``armature``): the reflected rotor inertia ``c`` of the motor behind joint i,
  added to ``M_ii``; its kinetic energy is part of H, so the model stays passive, and
  ``c >= 0`` keeps ``M + A`` positive definite;
* sensor (``sensor_offset``, and two additions documented the same way:
  ``sensor_gain`` ``q_meas = c q`` and ``sensor_eccentricity``
  ``q_meas = q + c (1 - cos q)``, the even part of an off-centre encoder): the
  measurement map.

All formulas are written in component form over an array namespace ``xp`` so the
augmented model runs with numpy (batched simulation) or torch, like the systems.
The nominal physics is never retyped: :class:`AugmentedSystem` calls the base
system for H, M, D and adds only the named terms.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from phast_gym.systems.base import NUMPY, Components, System, solve_spd

#: term name -> (component, basis force text with c, whether c must be >= 0)
VOCABULARY: dict[str, tuple[str, str, bool]] = {
    "viscous_damping": ("dissipation", "-c*qdot{i}", True),
    "coulomb_friction": ("dissipation", "-c*sign(qdot{i})", True),
    "quadratic_drag": ("dissipation", "-c*abs(qdot{i})*qdot{i}", True),
    "position_dependent_damping": ("dissipation", "-c*abs(sin(q{i}))*qdot{i}", True),
    # addition (dissipation): Stribeck friction, v_s = the term's ``velocity`` (qdot units)
    "stribeck_friction": ("dissipation", "-c*sign(qdot{i})*exp(-(qdot{i}/v_s)**2)", True),
    "linear_stiffness": ("potential", "-c*q{i}", False),
    "cubic_stiffness": ("potential", "-c*q{i}**3", False),
    "constant_force": ("potential", "c", False),
    "armature": ("inertia", "M{i}{i} += c (reflected rotor inertia)", True),
    "actuator_gain": ("port", "(c-1)*u{i}", True),
    "actuator_deadzone": ("port", "port delivers 0 when abs(u{i}) < c", True),
    "sensor_offset": ("sensor", "measured q{i} = true q{i} + c", False),
    # additions to the docs/mismatch.md vocabulary, documented the same way (sensor component):
    "sensor_gain": ("sensor", "measured q{i} = c * true q{i}", False),
    "sensor_eccentricity": ("sensor", "measured q{i} = true q{i} + c*(1 - cos(true q{i})) (angles only)", False),
}
SENSOR_TERMS = ("sensor_offset", "sensor_gain", "sensor_eccentricity")
FORCE_TERMS = ("viscous_damping", "coulomb_friction", "quadratic_drag", "position_dependent_damping",
               "linear_stiffness", "cubic_stiffness", "constant_force")  # stribeck_friction: energy balance only (needs v_s)


@dataclass(frozen=True)
class Term:
    """One named term on one coordinate with its coefficient (docs/mismatch.md units).

    ``velocity`` is the Stribeck velocity v_s of ``stribeck_friction`` (unused by other terms)."""

    name: str
    coordinate: int
    coefficient: float
    velocity: float = 0.0

    def __post_init__(self) -> None:
        if self.name not in VOCABULARY:
            raise ValueError(f"unknown term {self.name!r}; the vocabulary is {sorted(VOCABULARY)}")
        if self.name == "stribeck_friction" and not self.velocity > 0:
            raise ValueError(f"stribeck_friction needs a Stribeck velocity > 0, got {self.velocity!r}")
        if self.name == "armature" and not self.coefficient >= 0:  # (also rejects NaN)
            raise ValueError(f"armature is a rotor inertia added to M_ii: its coefficient must be >= 0, got {self.coefficient!r}")

    @property
    def component(self) -> str:
        return VOCABULARY[self.name][0]

    def expression(self) -> str:
        """Human-readable force / map with the coefficient filled in."""
        c, i = self.coefficient, self.coordinate
        text = VOCABULARY[self.name][1].format(i=i)
        if self.name == "actuator_gain":
            return f"({c:.4g}-1)*u{i}"
        if self.name == "constant_force":
            return f"{c:+.4g}"
        if self.name == "armature":
            return text.replace("+= c", f"+= {c:.4g}")
        neg = f"{-c:+.4g}*"  # -c* with the sign folded in (a negative friction coefficient reads +|c|*)
        if self.name == "stribeck_friction":
            return text.replace("-c*", neg).replace("v_s", f"{self.velocity:.4g}")
        if self.name in ("actuator_deadzone", "sensor_offset", "sensor_gain", "sensor_eccentricity"):
            return text.replace("+ c", f"+ {c:.4g}").replace("< c", f"< {c:.4g}").replace("= c *", f"= {c:.4g} *")
        return text.replace("-c*", neg)


def friction_basis(name: str, q: Any, v: Any, eps: float, velocity: float = 0.0, xp: Any = NUMPY) -> Any:
    """f(q_i, qdot_i) of a dissipative term (the force is -c f, f odd in qdot): the one place the friction laws are written.

    ``eps`` smooths sign(qdot) as tanh(qdot / eps); ``velocity`` is the Stribeck velocity v_s."""
    if name == "viscous_damping":
        return v
    if name == "coulomb_friction":
        return xp.tanh(v / eps)
    if name == "quadratic_drag":
        return xp.abs(v) * v
    if name == "position_dependent_damping":
        return xp.abs(xp.sin(q)) * v
    if name == "stribeck_friction":
        return xp.tanh(v / eps) * xp.exp(-((v / velocity) ** 2))
    raise ValueError(f"{name!r} is not a dissipative term")


def default_value(name: str) -> float:
    """The coefficient at which a term has no effect."""
    return 1.0 if name in ("actuator_gain", "sensor_gain") else 0.0


class AugmentedSystem(System):
    """A base system plus named terms, in the right port-Hamiltonian place.

    ``coulomb_eps`` (one value, or one per coordinate) smooths ``sign(qdot)`` as ``tanh(qdot / eps)`` (docs/mismatch.md
    allows smoothing near 0); it keeps explicit RK4 stable at the env's steps.
    ``deadzone_width > 0`` smooths the deadzone edge so its threshold can be fitted.
    """

    def __init__(self, base: System, terms: list[Term] | tuple[Term, ...] = (), coulomb_eps: float | tuple[float, ...] = 1e-2,
                 deadzone_width: float = 0.0) -> None:
        # no System.__init__: parameters belong to the base system
        self.base = base
        self.terms = tuple(terms)
        # one smoothing per coordinate (a slow cart and a fast pole need different edges), or one for all
        eps = tuple(float(e) for e in coulomb_eps) if isinstance(coulomb_eps, (tuple, list)) else (float(coulomb_eps),) * base.n
        if len(eps) != base.n:
            raise ValueError(f"coulomb_eps has {len(eps)} entries for {base.n} coordinates")
        self.coulomb_eps_per_coordinate = eps
        self.coulomb_eps = float(max(eps))
        self.deadzone_width = float(deadzone_width)
        self.params = dict(base.params)
        for attr in ("name", "n", "angle_dims", "dt", "substeps", "default_max_action", "separable",
                     "hamiltonian_system", "coordinate_names"):
            setattr(self, attr, getattr(base, attr))
        self.sensor_offset = [0.0] * base.n
        self.sensor_gain = [1.0] * base.n
        self.sensor_ecc = [0.0] * base.n
        self.armature = [0.0] * base.n  # A = diag(armature): H = p^T (M(q) + A)^-1 p / 2 + V
        for t in self.terms:
            if not 0 <= t.coordinate < base.n:
                raise ValueError(f"term {t.name} on coordinate {t.coordinate}: {base.name} has coordinates 0..{base.n - 1}")
            if t.name == "armature":
                self.armature[t.coordinate] += t.coefficient
            elif t.name == "sensor_offset":
                self.sensor_offset[t.coordinate] += t.coefficient
            elif t.name == "sensor_gain":
                self.sensor_gain[t.coordinate] *= t.coefficient
            elif t.name == "sensor_eccentricity":
                self.sensor_ecc[t.coordinate] += t.coefficient
        self.has_armature = any(a != 0.0 for a in self.armature)

    @property
    def has_sensor_terms(self) -> bool:
        return any(t.name in SENSOR_TERMS for t in self.terms)

    def measure(self, q: Any) -> Any:
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

    def unmeasure(self, y: Any) -> Any:
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
    def _extra_potential(self, q: Components, xp: Any) -> Any:
        v = 0.0 * q[0]
        for t in self.terms:
            qi, c = q[t.coordinate], t.coefficient
            if t.name == "linear_stiffness":
                v = v + 0.5 * c * qi * qi
            elif t.name == "cubic_stiffness":
                v = v + 0.25 * c * qi**4
            elif t.name == "constant_force":
                v = v - c * qi
        return v

    def _extra_grad(self, q: Components, xp: Any) -> list:
        g = [0.0 * qi for qi in q]
        for t in self.terms:
            i, c = t.coordinate, t.coefficient
            if t.name == "linear_stiffness":
                g[i] = g[i] + c * q[i]
            elif t.name == "cubic_stiffness":
                g[i] = g[i] + c * q[i] ** 3
            elif t.name == "constant_force":
                g[i] = g[i] - c + 0.0 * q[i]
        return g

    def potential(self, q: Components, xp: Any = NUMPY) -> Any:
        return self.base.potential(q, xp) + self._extra_potential(q, xp)

    def grad_potential(self, q: Components, xp: Any = NUMPY) -> tuple:
        return tuple(a + b for a, b in zip(self.base.grad_potential(q, xp), self._extra_grad(q, xp)))

    def _dH_dq_at(self, q: Components, p: Components, v: Components, xp: Any) -> tuple:
        """dH/dq|_p given v = dH/dp.  With armature A (constant): dH/dq|_p = dV/dq - v^T (dM/dq) v / 2, which is the
        base's dH/dq at the base momentum p' = M(q) v (same v, same dM/dq), plus the extra potential's gradient."""
        if self.has_armature:
            p = self.base.momentum(q, v, xp)
        return tuple(a + b for a, b in zip(self.base.dH_dq(q, p, xp), self._extra_grad(q, xp)))

    def dH_dq(self, q: Components, p: Components, xp: Any = NUMPY) -> tuple:
        return self._dH_dq_at(q, p, self.velocity(q, p, xp) if self.has_armature else None, xp)

    def mass_matrix(self, q: Components, xp: Any = NUMPY) -> tuple:
        M = self.base.mass_matrix(q, xp)
        if not self.has_armature:
            return M
        return tuple(tuple(mij + self.armature[i] if i == j else mij for j, mij in enumerate(row)) for i, row in enumerate(M))

    def velocity(self, q: Components, p: Components, xp: Any = NUMPY) -> tuple:
        if not self.has_armature:
            return self.base.velocity(q, p, xp)
        return solve_spd(self.mass_matrix(q, xp), p)

    def damping(self, q: Components, xp: Any = NUMPY) -> tuple:
        return self.base.damping(q, xp)

    def has_damping(self) -> bool:
        return self.base.has_damping()

    def switching(self, q: Components, p: Components, xp: Any = NUMPY) -> Any | None:
        return self.base.switching(q, p, xp)

    def sample_initial(self, rng: Any, size: int) -> Any:
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
    def port(self, u: Components | None, xp: Any) -> Components | None:
        """The port force actually delivered (actuator gain and deadzone)."""
        if u is None:
            return None
        u = list(u)
        for t in self.terms:
            i, c = t.coordinate, t.coefficient
            if t.name == "actuator_gain":
                u[i] = c * u[i]
            elif t.name == "actuator_deadzone":
                if self.deadzone_width > 0:  # smooth edge (differentiable in the threshold c) for fitting
                    u[i] = u[i] * (0.5 + 0.5 * xp.tanh((xp.abs(u[i]) - c) / self.deadzone_width))
                else:
                    u[i] = xp.where(xp.abs(u[i]) < c, 0.0 * u[i], u[i])
        return u

    def extra_dissipation(self, q: Components, v: Components, xp: Any) -> list:
        """Passive friction forces -c f(v_i), f odd, c >= 0 (enters pdot like -D v)."""
        f = [0.0 * vi for vi in v]
        for t in self.terms:
            if t.component == "dissipation":
                i = t.coordinate
                eps = self.coulomb_eps_per_coordinate[i]
                f[i] = f[i] - t.coefficient * friction_basis(t.name, q[i], v[i], eps, t.velocity, xp)
        return f

    def rhs(self, q: Components, p: Components, u: Components | None, xp: Any = NUMPY) -> tuple[tuple, tuple]:
        uu = self.port(u, xp)
        if self.has_armature:  # the base's (fused) vector field assumes its own M: the generic Eq. 1-3 instead
            qdot = self.velocity(q, p, xp)
            dh = self._dH_dq_at(q, p, qdot, xp)
            pdot = tuple(-a - di * vi for a, di, vi in zip(dh, self.base.damping(q, xp), qdot))
            if uu is not None:
                pdot = tuple(ui + a for ui, a in zip(uu, pdot))
        else:
            qdot, pdot = self.base.rhs(q, p, uu, xp)
            pdot = tuple(a - b for a, b in zip(pdot, self._extra_grad(q, xp)))
        f = self.extra_dissipation(q, qdot, xp)
        return tuple(qdot), tuple(a + c for a, c in zip(pdot, f))

    def power_balance(self, q: Components, p: Components, u: Components | None, xp: Any = NUMPY) -> tuple[Any, Any]:
        """(v^T D v + the terms' friction power, v^T u delivered) with v = (M + A)^-1 p."""
        diss, supplied = super().power_balance(q, p, self.port(u, xp), xp)
        v = self.velocity(q, p, xp)
        extra = sum(-fi * vi for fi, vi in zip(self.extra_dissipation(q, v, xp), v))
        return diss + extra, supplied
