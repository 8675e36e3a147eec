"""The term registry: one small class per term kind of the docs/mismatch.md vocabulary (PySINDy feature-library style).

A kind owns everything the tool knows about a term: its port-Hamiltonian component, its basis ``f(q, v, xp)`` (a
dissipative term's force is ``-c f``), its expression, short name and default coefficient, its sign constraint, its
cost in the law selection's parsimony rule, the scale of its shooting candidates, the rules of a velocity parameter
(:class:`VelocityKind`: the grid the weak form profiles, the shooting grid, the smallest value, the refinement of a
chosen term) and its column in a sparse-regression library (the PySINDy peer of ``phast-mismatch-bench``).  The
augmented model (:class:`.terms.AugmentedSystem`), the candidates, the selection, the friction laws, the report and
the peer iterate over :data:`VOCABULARY` and ask the kind, so a new friction law is one class registered from
anywhere::

    class CubicDrag(DissipationKind):
        name, short, formula = "cubic_drag", "cubic", "-c*qdot{i}**3"

        def basis(self, q, v, eps, velocity, xp):
            return v**3

    register(CubicDrag())

and a law with a velocity parameter subclasses :class:`VelocityKind` (docs/extending.md)::

    class ExpDecayFriction(VelocityKind):
        name, short, formula = "exp_decay_friction", "expdecay", "-c*sign(qdot{i})*exp(-abs(qdot{i})/v_s)"

        def basis(self, q, v, eps, velocity, xp):
            return sign(v, eps, xp) * xp.exp(-xp.abs(v) / velocity)

    register(ExpDecayFriction())

Components:

* dissipation (``viscous_damping``, ``coulomb_friction``, ``quadratic_drag``, ``position_dependent_damping`` and
  ``stribeck_friction`` ``-c * sign(qdot_i) * exp(-(qdot_i / v_s)**2)``, the extra static friction a bearing shows
  near velocity reversals, with its Stribeck velocity ``v_s`` carried by the term): a force ``-c * f(qdot_i)`` with
  ``f`` odd and ``c >= 0``, so ``qdot_i * force <= 0``: the augmented model stays passive (paper Eq. 4);
* potential (``linear_stiffness``, ``cubic_stiffness``, ``constant_force``): an extra potential V_extra(q_i) added
  to H, force ``-dV_extra/dq_i``;
* port (``actuator_gain``, ``actuator_deadzone``): the delivered port force;
* inertia (``armature``): the reflected rotor inertia ``c`` of the motor behind joint i, added to ``M_ii``; its
  kinetic energy is part of H, so the model stays passive, and ``c >= 0`` keeps ``M + A`` positive definite;
* sensor (``sensor_offset``, ``sensor_gain`` ``q_meas = c q`` and ``sensor_eccentricity``
  ``q_meas = q + c (1 - cos q)``, the even part of an off-centre encoder): the measurement map;
* delays (``input_delay``, a port term: the port delivers ``u_i(t - c)``; ``sensor_delay``, a sensor term: the sensor
  reports ``q_i(t - c)``), ``c`` in seconds, ``0 <= c <= MAX_DELAY_SAMPLES`` samples, fractions of a sample by linear
  interpolation (:mod:`phast_model.identify.delays`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import ClassVar, NamedTuple, TypeVar

import numpy as np

from phast_gym.systems.base import NUMPY, ArrayNamespace, Coord

from ...identify.delays import MAX_DELAY_SAMPLES

#: the ports of the augmented model a term kind can act through
COMPONENTS = ("dissipation", "potential", "port", "inertia", "sensor")


@dataclass
class Maps:
    """The per-coordinate maps that inertia and sensor terms set on an augmented model (identity: no effect)."""

    armature: list[float]
    sensor_offset: list[float]
    sensor_gain: list[float]
    sensor_eccentricity: list[float] = field(default_factory=list)
    input_delay: list[float] = field(default_factory=list)  # [s] per port (the port delivers u_i(t - d_i))
    sensor_delay: list[float] = field(default_factory=list)  # [s] per coordinate (the sensor reports q_i(t - d_i))

    @classmethod
    def identity(cls, n: int) -> Maps:
        return cls([0.0] * n, [0.0] * n, [1.0] * n, [0.0] * n, [0.0] * n, [0.0] * n)


@dataclass(frozen=True)
class ScaleContext:
    """What a kind needs to scale its shooting candidate on one coordinate: z = 1 is about the coordinate's force
    scale."""

    q: np.ndarray  # smoothed q_i of the training recordings
    v: np.ndarray  # smoothed qdot_i
    force_rms: float  # rms conservative (+ port) force on the coordinate
    mass_rms: float  # rms of M_ii (1 when no inertia kind is screened)
    sensor_scale: float  # 10 x the noise + 1e-3 x the spread of q_i
    eps: float  # the coordinate's tanh smoothing of sign(qdot)
    u: np.ndarray | None  # the port input on the coordinate (None when none acts on it)
    is_angle: bool
    dt: float = 0.0  # the recordings' (median) sampling step [s] (delays are scaled by it; 0: unknown)
    n: int = 1  # coordinates of the system


class Scale(NamedTuple):
    """A shooting candidate of a kind: coefficient = default + scale * z; its finite-difference step; its v_s."""

    scale: float
    fd_step: float
    velocity: float | None = None


#: finite-difference step in z of a candidate's shooting column
FD_STEP = 1e-3


def sign(v: Coord, eps: float, xp: ArrayNamespace) -> Coord:
    """sign(qdot) as a basis writes it: smoothed as tanh(qdot / eps), the sharp sign at ``eps = 0`` (a regression
    library's column, :meth:`TermKind.regression_column`)."""
    return xp.tanh(v / eps) if eps > 0 else xp.sign(v)


class TermKind:
    """One named term kind.  Subclasses set the class attributes and the hooks of their component."""

    name: ClassVar[str]
    component: ClassVar[str]
    formula: ClassVar[str]  # the force / map with the coefficient c, ``{i}`` the coordinate
    short: ClassVar[str] = ""  # the name in a friction law's name (dissipation)
    default: ClassVar[float] = 0.0  # the coefficient at which the term has no effect
    positive: ClassVar[bool] = False  # c must be >= 0 (the docs' sign constraint)
    cost: ClassVar[int] = 1  # parameters the term costs in the law selection's parsimony rule
    has_velocity: ClassVar[bool] = False  # carries a velocity parameter (the Stribeck v_s): see VelocityKind
    #: an excess friction near rest: beside a Coulomb term on its coordinate it may only stand in for a sharper Coulomb
    #: edge than the fits' tanh smoothing (the selection then weighs it against that edge)
    excess_near_rest: ClassVar[bool] = False
    #: factors by which the velocity of a chosen term is refined, in turn (each tried down and up); none: not refined
    refine_steps: ClassVar[tuple[float, ...]] = ()
    magnitude: ClassVar[bool] = False  # the fitted coefficient is |c| (a threshold, an inertia)
    stiff_edge: ClassVar[bool] = False  # a sharp sign(qdot): simulate the "reality" with short substeps
    #: a delay [s] (a port or sensor term that shifts a signal in time): set by :meth:`set_map`, applied around the
    #: simulation (:mod:`phast_model.identify.delays`), never in the vector field
    delay: ClassVar[bool] = False
    #: the MuJoCo attribute (joint or actuator) that expresses the term exactly, or None
    mjcf: ClassVar[str | None] = None
    #: a generalized force that does not depend on the state (-gradient(0, c)): MuJoCo applies it as qfrc_applied
    applied_force: ClassVar[bool] = False
    #: what a MuJoCo user adds for a term no attribute expresses
    mjcf_advice: ClassVar[str] = ("no MuJoCo attribute expresses it: apply the force as qfrc_applied (or mjcb_passive) "
                                  "each step")

    @property
    def fit_positive(self) -> bool:
        """The selection keeps only c > 0 (passivity); an actuator gain's sign is free around 1."""
        return self.positive

    @property
    def in_mujoco(self) -> bool:
        """MuJoCo simulates a model file with this term: as an attribute (:attr:`mjcf`), a map of the recorded control
        before the rollout (a port term), of the rolled-out q after it (a sensor term or delay), or a constant
        ``qfrc_applied`` (:attr:`applied_force`); not a state-dependent force no attribute expresses."""
        return self.mjcf is not None or self.component in ("port", "sensor") or self.applied_force

    def check(self, coefficient: float, velocity: float) -> None:
        """Raise ValueError for a coefficient / velocity the term cannot have."""

    def expression(self, c: float, i: int, velocity: float) -> str:
        """Human-readable force / map with the coefficient filled in (-c* with the sign folded in)."""
        return self.formula.format(i=i).replace("-c*", f"{-c:+.4g}*")

    def scales(self, ctx: ScaleContext) -> list[Scale]:
        """Shooting candidates of this kind on one coordinate (none: it cannot act there)."""
        return []

    # ---- a velocity parameter (only kinds with ``has_velocity``; see VelocityKind) ----
    @property
    def refines_velocity(self) -> bool:
        """The selection refines the velocity of a chosen term of this kind (:attr:`refine_steps`)."""
        return self.has_velocity and bool(self.refine_steps)

    def velocity_grid(self, v_rms: float) -> list[float]:
        """The velocities a weak-form law fit profiles on a coordinate of rms speed ``v_rms`` (none without one)."""
        return []

    def min_velocity(self, eps: float) -> float:
        """The smallest velocity a shooting candidate or a refinement may take, given the tanh smoothing ``eps``."""
        return 0.0

    # ---- a sparse-regression library (the PySINDy peer) ----
    def regression_column(self, q: np.ndarray, v: np.ndarray, u: np.ndarray | None, v_rms: float) -> np.ndarray | None:
        """The term's generalized force on coordinate i at coefficient ``default + 1`` less that at ``default``, for a
        library linear in the coefficients (sign(qdot) sharp; ``u`` the port input on the coordinate, None when none
        acts on it; ``v_rms`` its rms speed); None when the force is not linear in the coefficient (or not a force)."""
        return None

    # ---- the component hooks (only the component's own are called) ----
    def basis(self, q: Coord, v: Coord, eps: float, velocity: float, xp: ArrayNamespace) -> Coord:
        """Dissipation: f(q_i, qdot_i), odd in qdot (force -c f); ``eps`` smooths sign(qdot) as tanh(qdot / eps)."""
        raise ValueError(f"{self.name!r} is not a dissipative term")

    def potential(self, q: Coord, c: float) -> Coord:
        """Potential: V_extra(q_i)."""
        raise ValueError(f"{self.name!r} is not a potential term")

    def gradient(self, q: Coord, c: float) -> Coord:
        """Potential: dV_extra/dq_i."""
        raise ValueError(f"{self.name!r} is not a potential term")

    def port(self, u: Coord, c: float, deadzone_width: float, xp: ArrayNamespace) -> Coord:
        """Port: the delivered port force."""
        raise ValueError(f"{self.name!r} is not a port term")

    def set_map(self, maps: Maps, i: int, c: float) -> None:
        """Inertia / sensor: change the model's per-coordinate map."""
        raise ValueError(f"{self.name!r} sets no map")

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r})"


# --------------------------------------------------------------------------- dissipation
class DissipationKind(TermKind):
    """A passive friction force -c f(q_i, qdot_i), f odd in qdot, c >= 0.  A subclass sets ``name``, ``short``,
    ``formula`` and :meth:`basis`; its shooting candidate is scaled by the rms of its basis unless it says otherwise."""

    component = "dissipation"
    positive = True

    def basis_rms(self, q: np.ndarray, v: np.ndarray, eps: float) -> float:
        return float(np.sqrt(np.mean(np.asarray(self.basis(q, v, eps, 0.0, NUMPY)) ** 2)))

    def scales(self, ctx: ScaleContext) -> list[Scale]:
        b = float(self.basis_rms(ctx.q, ctx.v, ctx.eps))
        return [Scale(float(ctx.force_rms / b), FD_STEP)] if b > 1e-12 else []

    def regression_column(self, q: np.ndarray, v: np.ndarray, u: np.ndarray | None, v_rms: float) -> np.ndarray | None:
        """-f(q_i, qdot_i) with sign(qdot) sharp."""
        return self._sharp_column(q, v, 0.0)

    def _sharp_column(self, q: np.ndarray, v: np.ndarray, velocity: float) -> np.ndarray:
        """-f at eps = 0 (a basis written with tanh(v / eps) instead of :func:`sign` gives sign(v) too: its 0/0 at
        v = 0 is set to 0)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            col = -np.asarray(self.basis(q, v, 0.0, velocity, NUMPY), dtype=float)
        return np.where(np.isnan(col), 0.0, col)


class VelocityKind(DissipationKind):
    """A passive friction law with a velocity parameter v_s (the term's ``velocity``, qdot units; it counts as a second
    parameter).  The kind owns that parameter's rules: the grid the weak form profiles (:meth:`velocity_grid`), the
    shooting candidates' grid (:attr:`shooting_fractions`), the smallest value (:meth:`min_velocity`), the refinement
    of a chosen term (:attr:`refine_steps`) and the value of its regression column.  A subclass sets ``name``,
    ``short``, ``formula`` (with ``v_s``) and :meth:`basis`, and may change any of these."""

    cost = 2
    has_velocity = True
    excess_near_rest = True
    #: velocities the weak-form law fits profile, as fractions of the coordinate's rms speed (log grid).  Friction with
    #: a v_s is an excess near rest; a term whose v_s reaches the typical speed is a curve-fitting device, not that
    #: effect (docs/mismatch.md, design notes)
    velocity_fractions: ClassVar[tuple[float, ...]] = tuple(float(x) for x in np.geomspace(0.03, 0.3, 7))
    #: velocities of the shooting candidates, as fractions of the coordinate's rms speed (a chosen one is refined)
    shooting_fractions: ClassVar[tuple[float, ...]] = tuple(0.05 * 2.0**k for k in range(4))  # 0.05, 0.1, 0.2, 0.4
    #: smallest v_s, in units of the tanh smoothing of sign(qdot): below it the term only reshapes the smoothed Coulomb
    #: edge (a sharper real edge than the model's), which is not physics the data can name
    min_over_eps: ClassVar[float] = 4.0
    #: a chosen term's v_s is refined around its grid value in half, quarter and eighth octaves (profile of the refit)
    refine_steps: ClassVar[tuple[float, ...]] = (2**0.5, 2**0.25, 2**0.125)
    #: v_s of the regression column, as a fraction of the rms speed (a regression cannot profile it; the middle of
    #: the shooting grid)
    regression_fraction: ClassVar[float] = 0.2

    def check(self, coefficient: float, velocity: float) -> None:
        if not velocity > 0:
            raise ValueError(f"{self.name} needs a velocity v_s > 0, got {velocity!r}")

    def expression(self, c: float, i: int, velocity: float) -> str:
        return super().expression(c, i, velocity).replace("v_s", f"{velocity:.4g}")

    def velocity_grid(self, v_rms: float) -> list[float]:
        return [f * v_rms for f in self.velocity_fractions]

    def min_velocity(self, eps: float) -> float:
        return self.min_over_eps * eps

    def scales(self, ctx: ScaleContext) -> list[Scale]:
        """One candidate per velocity of the shooting grid (at least :meth:`min_velocity`)."""
        out = []
        v_rms = float(np.sqrt(np.mean(ctx.v**2)))
        for f in self.shooting_fractions:
            w = float(f * v_rms)
            if w < self.min_velocity(ctx.eps):
                continue
            b = float(np.sqrt(np.mean(np.asarray(self.basis(ctx.q, ctx.v, ctx.eps, w, NUMPY)) ** 2)))
            if b > 1e-12:
                out.append(Scale(float(ctx.force_rms / b), FD_STEP, w))
        return out

    def regression_column(self, q: np.ndarray, v: np.ndarray, u: np.ndarray | None, v_rms: float) -> np.ndarray | None:
        """-f(q_i, qdot_i) at v_s = :attr:`regression_fraction` x the rms speed, sign(qdot) sharp."""
        return self._sharp_column(q, v, self.regression_fraction * v_rms + 1e-12)


class Viscous(DissipationKind):
    name, short, formula = "viscous_damping", "viscous", "-c*qdot{i}"
    mjcf = "damping"

    def basis(self, q: Coord, v: Coord, eps: float, velocity: float, xp: ArrayNamespace) -> Coord:
        return v

    def basis_rms(self, q: np.ndarray, v: np.ndarray, eps: float) -> float:
        return np.sqrt(np.mean(v**2))


class Coulomb(DissipationKind):
    name, short, formula = "coulomb_friction", "coulomb", "-c*sign(qdot{i})"
    mjcf = "frictionloss"
    stiff_edge = True

    def basis(self, q: Coord, v: Coord, eps: float, velocity: float, xp: ArrayNamespace) -> Coord:
        return sign(v, eps, xp)

    def basis_rms(self, q: np.ndarray, v: np.ndarray, eps: float) -> float:
        return 1.0


class QuadraticDrag(DissipationKind):
    name, short, formula = "quadratic_drag", "quadratic", "-c*abs(qdot{i})*qdot{i}"

    def basis(self, q: Coord, v: Coord, eps: float, velocity: float, xp: ArrayNamespace) -> Coord:
        return xp.abs(v) * v

    def basis_rms(self, q: np.ndarray, v: np.ndarray, eps: float) -> float:
        return np.sqrt(np.mean(v**4))


class PositionDependentDamping(DissipationKind):
    name, short, formula = "position_dependent_damping", "position_dependent", "-c*abs(sin(q{i}))*qdot{i}"

    def basis(self, q: Coord, v: Coord, eps: float, velocity: float, xp: ArrayNamespace) -> Coord:
        return xp.abs(xp.sin(q)) * v

    def basis_rms(self, q: np.ndarray, v: np.ndarray, eps: float) -> float:
        return np.sqrt(np.mean((np.abs(np.sin(q)) * v) ** 2))


class Stribeck(VelocityKind):
    """Stribeck friction, v_s = the term's ``velocity`` (qdot units); its v_s counts as a second parameter."""

    name, short, formula = "stribeck_friction", "stribeck", "-c*sign(qdot{i})*exp(-(qdot{i}/v_s)**2)"

    def check(self, coefficient: float, velocity: float) -> None:
        if not velocity > 0:
            raise ValueError(f"{self.name} needs a Stribeck velocity > 0, got {velocity!r}")

    def basis(self, q: Coord, v: Coord, eps: float, velocity: float, xp: ArrayNamespace) -> Coord:
        return sign(v, eps, xp) * xp.exp(-((v / velocity) ** 2))


# --------------------------------------------------------------------------- potential
class PotentialKind(TermKind):
    """An extra potential V_extra(q_i) added to H (force -dV_extra/dq_i); scaled by the rms of that force at c = 1."""

    component = "potential"

    def basis_rms(self, q: np.ndarray) -> float:
        raise NotImplementedError

    def scales(self, ctx: ScaleContext) -> list[Scale]:
        b = float(self.basis_rms(ctx.q))
        return [Scale(float(ctx.force_rms / b), FD_STEP)] if b > 1e-12 else []

    def regression_column(self, q: np.ndarray, v: np.ndarray, u: np.ndarray | None, v_rms: float) -> np.ndarray | None:
        """-dV_extra/dq_i at c = 1."""
        return -np.asarray(self.gradient(q, 1.0))


class LinearStiffness(PotentialKind):
    name, formula = "linear_stiffness", "-c*q{i}"
    mjcf = "stiffness"

    def potential(self, q: Coord, c: float) -> Coord:
        return 0.5 * c * q * q

    def gradient(self, q: Coord, c: float) -> Coord:
        return c * q

    def basis_rms(self, q: np.ndarray) -> float:
        return np.sqrt(np.mean(q**2))


class CubicStiffness(PotentialKind):
    name, formula = "cubic_stiffness", "-c*q{i}**3"

    def potential(self, q: Coord, c: float) -> Coord:
        return 0.25 * c * q**4

    def gradient(self, q: Coord, c: float) -> Coord:
        return c * q**3

    def basis_rms(self, q: np.ndarray) -> float:
        return np.sqrt(np.mean(q**6))


class ConstantForce(PotentialKind):
    name, formula = "constant_force", "c"
    applied_force = True

    def potential(self, q: Coord, c: float) -> Coord:
        return -c * q

    def gradient(self, q: Coord, c: float) -> Coord:
        return -c + 0.0 * q

    def basis_rms(self, q: np.ndarray) -> float:
        return 1.0

    def expression(self, c: float, i: int, velocity: float) -> str:
        return f"{c:+.4g}"


# --------------------------------------------------------------------------- inertia, port, sensor
def _fill(text: str, c: float) -> str:
    """A map's text with its coefficient filled in."""
    return text.replace("+ c", f"+ {c:.4g}").replace("< c", f"< {c:.4g}").replace("= c *", f"= {c:.4g} *")


class Armature(TermKind):
    name, component, formula = "armature", "inertia", "M{i}{i} += c (reflected rotor inertia)"
    mjcf = "armature"
    positive = True
    magnitude = True

    def check(self, coefficient: float, velocity: float) -> None:
        if not coefficient >= 0:  # (also rejects NaN)
            raise ValueError(f"{self.name} is a rotor inertia added to M_ii: its coefficient must be >= 0, got "
                             f"{coefficient!r}")

    def expression(self, c: float, i: int, velocity: float) -> str:
        return self.formula.format(i=i).replace("+= c", f"+= {c:.4g}")

    def set_map(self, maps: Maps, i: int, c: float) -> None:
        maps.armature[i] += c

    def scales(self, ctx: ScaleContext) -> list[Scale]:
        return [Scale(0.05 * float(ctx.mass_rms), FD_STEP)]  # z = 1 is 5% of the coordinate's inertia


class ActuatorGain(TermKind):
    name, component, formula = "actuator_gain", "port", "(c-1)*u{i}"
    mjcf = "gear"
    default = 1.0
    positive = True

    @property
    def fit_positive(self) -> bool:
        return False

    def expression(self, c: float, i: int, velocity: float) -> str:
        return f"({c:.4g}-1)*u{i}"

    def port(self, u: Coord, c: float, deadzone_width: float, xp: ArrayNamespace) -> Coord:
        return c * u

    def scales(self, ctx: ScaleContext) -> list[Scale]:
        return [Scale(0.1, FD_STEP)] if ctx.u is not None else []

    def regression_column(self, q: np.ndarray, v: np.ndarray, u: np.ndarray | None, v_rms: float) -> np.ndarray | None:
        """u_i: the extra port force per unit of c - 1."""
        return None if u is None else np.asarray(u)


class ActuatorDeadzone(TermKind):
    name, component, formula = "actuator_deadzone", "port", "port delivers 0 when abs(u{i}) < c"
    mjcf_advice = "no MuJoCo attribute expresses it: zero ctrl below the threshold before each mj_step"
    positive = True
    magnitude = True
    #: the threshold's start values tried before its refit (z; zero slope at c = 0)
    START_GRID = (0.1, 1.5, 15)

    def expression(self, c: float, i: int, velocity: float) -> str:
        return _fill(self.formula.format(i=i), c)

    def port(self, u: Coord, c: float, deadzone_width: float, xp: ArrayNamespace) -> Coord:
        if deadzone_width > 0:  # smooth edge (differentiable in the threshold c) for fitting
            return u * (0.5 + 0.5 * xp.tanh((xp.abs(u) - c) / deadzone_width))
        return xp.where(xp.abs(u) < c, 0.0 * u, u)

    def scales(self, ctx: ScaleContext) -> list[Scale]:
        return [Scale(float(np.median(np.abs(ctx.u))), 0.3)] if ctx.u is not None else []


class SensorOffset(TermKind):
    name, component, formula = "sensor_offset", "sensor", "measured q{i} = true q{i} + c"
    mjcf_advice = "a sensor term, not dynamics: correct the logged q by the inverse map (the model file is unchanged)"

    def expression(self, c: float, i: int, velocity: float) -> str:
        return _fill(self.formula.format(i=i), c)

    def set_map(self, maps: Maps, i: int, c: float) -> None:
        maps.sensor_offset[i] += c

    def scales(self, ctx: ScaleContext) -> list[Scale]:
        return [Scale(float(ctx.sensor_scale), FD_STEP)]


class SensorGain(SensorOffset):
    name, formula = "sensor_gain", "measured q{i} = c * true q{i}"
    default = 1.0

    def set_map(self, maps: Maps, i: int, c: float) -> None:
        maps.sensor_gain[i] *= c

    def scales(self, ctx: ScaleContext) -> list[Scale]:
        return [Scale(0.01, FD_STEP)]


class SensorEccentricity(SensorOffset):
    name, formula = "sensor_eccentricity", "measured q{i} = true q{i} + c*(1 - cos(true q{i})) (angles only)"

    def set_map(self, maps: Maps, i: int, c: float) -> None:
        maps.sensor_eccentricity[i] += c

    def scales(self, ctx: ScaleContext) -> list[Scale]:
        return [Scale(float(ctx.sensor_scale), FD_STEP)] if ctx.is_angle else []


# --------------------------------------------------------------------------- delays
class DelayKind(TermKind):
    """A delay ``c`` [s] >= 0 on one port or coordinate; candidates scaled so that z = 1 is one sample (a fitted value
    is |c|, like a threshold: an iterate may step past zero).  No force and no regression column: the PySINDy peer's
    library has no delay (a delay is not linear in its coefficient)."""

    positive = True
    magnitude = True
    delay = True
    #: the longest delay, in samples of the recording (longer ones are clipped: docs/mismatch.md)
    max_samples: ClassVar[int] = MAX_DELAY_SAMPLES

    def check(self, coefficient: float, velocity: float) -> None:
        if not coefficient >= 0 or not np.isfinite(coefficient):  # (also rejects NaN)
            raise ValueError(f"{self.name} is a delay in seconds: it must be >= 0, got {coefficient!r}")

    def expression(self, c: float, i: int, velocity: float) -> str:
        return self.formula.format(i=i).replace("t - c", f"t - {c:.4g} s")

    def applies(self, ctx: ScaleContext) -> bool:
        return ctx.dt > 0

    def scales(self, ctx: ScaleContext) -> list[Scale]:
        return [Scale(float(ctx.dt), FD_STEP)] if self.applies(ctx) else []


class InputDelay(DelayKind):
    """Actuator latency: the port delivers ``u_i(t - c)`` (the recorded u, held per interval, interpolated linearly
    between samples for a fraction of a sample; at most :data:`MAX_DELAY_SAMPLES` samples)."""

    name, component, formula = "input_delay", "port", "port delivers u{i}(t - c)"
    mjcf_advice = ("MuJoCo has no actuator delay attribute: delay ctrl by c in your controller (a buffer of past "
                   "commands, interpolated for a fraction of a timestep) before each mj_step")

    def port(self, u: Coord, c: float, deadzone_width: float, xp: ArrayNamespace) -> Coord:
        return u  # the delay acts on the input sequence (AugmentedSystem.delayed_input), not on one value

    def applies(self, ctx: ScaleContext) -> bool:
        return ctx.dt > 0 and ctx.u is not None

    def set_map(self, maps: Maps, i: int, c: float) -> None:
        maps.input_delay[i] += c


class SensorDelay(DelayKind):
    """Sensor latency on one coordinate: the sensor reports ``q_i(t - c)`` (the simulated q interpolated linearly
    between samples).  Screened only on systems of two or more coordinates: on one coordinate a sensor delay is exactly
    an input delay (with u) or nothing at all (without u: a time shift of a free motion is another initial state), and
    a delay of every coordinate alike is an input delay of every port."""

    name, component, formula = "sensor_delay", "sensor", "measured q{i}(t) = true q{i}(t - c)"
    mjcf_advice = ("a sensor term, not dynamics: MuJoCo has no sensor delay for joint positions; compare the model's "
                   "q(t - c) with the log (or shift the log by c) in your sensor pipeline (the model file is "
                   "unchanged)")

    def applies(self, ctx: ScaleContext) -> bool:
        return ctx.dt > 0 and ctx.n >= 2

    def set_map(self, maps: Maps, i: int, c: float) -> None:
        maps.sensor_delay[i] += c


# --------------------------------------------------------------------------- the registry
#: term name -> kind, in vocabulary order (the order breaks ties between terms of equal evidence)
VOCABULARY: dict[str, TermKind] = {}


K = TypeVar("K", bound="TermKind")


def register(kind: K) -> K:
    """Add ``kind`` to the vocabulary (after the built-in terms); returns it."""
    if not isinstance(kind, TermKind):
        raise TypeError(f"register() takes a TermKind instance, got {kind!r}")
    if kind.component not in COMPONENTS:
        raise ValueError(f"{kind.name}: component {kind.component!r} is not one of {COMPONENTS}")
    if kind.name in VOCABULARY:
        raise ValueError(f"a term named {kind.name!r} is already registered")
    VOCABULARY[kind.name] = kind
    return kind


def unregister(name: str) -> TermKind:
    """Remove a registered term kind (e.g. one a test added); returns it."""
    return VOCABULARY.pop(name)


def kind(name: str) -> TermKind:
    try:
        return VOCABULARY[name]
    except KeyError:
        raise ValueError(f"unknown term {name!r}; the vocabulary is {sorted(VOCABULARY)}") from None


def law_terms(vocabulary: Sequence[str] | None = None) -> tuple[str, ...]:
    """The dissipative terms a friction law is built from (of ``vocabulary``, default all), in vocabulary order."""
    return tuple(k.name for k in VOCABULARY.values()
                 if k.component == "dissipation" and (vocabulary is None or k.name in vocabulary))


def mujoco_vocabulary() -> tuple[str, ...]:
    """The default vocabulary on a MuJoCo model file: every term MuJoCo simulates (:attr:`TermKind.in_mujoco`), not
    the state-dependent forces no attribute expresses (quadratic drag, Stribeck, position-dependent damping, a cubic
    stiffness).  The fits then run on MuJoCo itself and the friction found is the friction MuJoCo simulates
    (``damping``, ``frictionloss``): the answer is the model written back.  A user who names such a term
    (``--terms``) gets it, and every fit on the tool's own integrator."""
    return tuple(k.name for k in VOCABULARY.values() if k.in_mujoco)


#: the built-in kinds other modules refer to by object (their names live here only)
VISCOUS, COULOMB, STRIBECK, ARMATURE, ACTUATOR_GAIN = Viscous(), Coulomb(), Stribeck(), Armature(), ActuatorGain()
_BUILT_IN: tuple[TermKind, ...] = (VISCOUS, COULOMB, QuadraticDrag(), PositionDependentDamping(), STRIBECK,
                                   LinearStiffness(),
                                   CubicStiffness(), ConstantForce(), ARMATURE, ACTUATOR_GAIN, ActuatorDeadzone(),
                                   SensorOffset(),
                                   SensorGain(), SensorEccentricity(), InputDelay(), SensorDelay())
for _kind in _BUILT_IN:
    register(_kind)
