"""Candidate terms and the model family they are fitted in.

A fitted term's coefficient is ``default + scale * z`` (:func:`.terms.default_value`
is where the term has no effect), so every global of the shooting fit is O(1); a
calibrated parameter is ``nominal * exp(z)`` (log-relative).  :func:`candidates`
builds the list the selection screens: every vocabulary term on every coordinate
where it can act, scaled so that z = 1 is about the force scale of that coordinate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from phast_gym.systems.base import NUMPY, System

from .shooting import momentum
from .simulators import Simulator
from .terms import FORCE_TERMS, VOCABULARY, AugmentedSystem, Term, default_value, friction_basis

#: Stribeck velocities of the shooting candidates, as fractions of the coordinate's rms speed (a chosen one is refined)
STRIBECK_FRACTIONS = tuple(0.05 * 2.0**k for k in range(4))  # 0.05, 0.1, 0.2, 0.4
#: smallest Stribeck velocity, in units of the tanh smoothing of sign(qdot): below it a "Stribeck" term only reshapes
#: the smoothed Coulomb edge (a sharper real edge than the model's), which is not physics the data can name
MIN_STRIBECK_OVER_EPS = 4.0

if TYPE_CHECKING:
    from .problem import Problem

#: finite-difference step in z of a candidate's shooting column
FD_STEP = 1e-3


@dataclass(frozen=True)
class ScaledTerm:
    """A vocabulary term on one coordinate with coefficient ``default + scale * z``."""

    term: str
    coordinate: int
    scale: float
    velocity: float | None = None  # Stribeck velocity v_s (stribeck_friction only)

    def coefficient(self, z: float) -> float:
        return default_value(self.term) + self.scale * z

    def at(self, z: float) -> Term:
        """The :class:`Term` at scaled coefficient ``z`` (a deadzone threshold and an armature are |c|: an iterate may
        step past zero; a fitted negative armature is rejected by the sign rule)."""
        c = self.coefficient(float(z))
        if self.term in ("actuator_deadzone", "armature"):
            c = abs(c)
        return Term(self.term, self.coordinate, c, *([] if self.velocity is None else [self.velocity]))


@dataclass(frozen=True)
class Candidate:
    """A term the selection may add: its scaled form plus the finite-difference step of its column."""

    term: str
    coordinate: int
    scale: float
    fd_step: float
    velocity: float | None = None

    @property
    def key(self) -> tuple[str, int]:
        return (self.term, self.coordinate)

    @property
    def label(self) -> str:
        return f"{self.term}[{self.coordinate}]" + ("" if self.velocity is None else f"(v_s={self.velocity:.3g})")

    @property
    def family_term(self) -> ScaledTerm:
        return ScaledTerm(self.term, self.coordinate, self.scale, self.velocity)

    @property
    def must_be_positive(self) -> bool:
        """Passivity: a friction-like coefficient must be > 0 (the actuator gain's sign is free around 1)."""
        return VOCABULARY[self.term][2] and self.term != "actuator_gain"

    @property
    def vocabulary_rank(self) -> int:
        return list(VOCABULARY).index(self.term)

    def coefficient(self, z: float) -> float:
        return default_value(self.term) + self.scale * z

    def with_velocity(self, velocity: float) -> Candidate:
        return replace(self, velocity=velocity)

    @property
    def is_param(self) -> bool:
        return False

    def add_to(self, fam: Family, g: np.ndarray, z: float) -> tuple[Family, np.ndarray]:
        """``fam`` and its global vector ``g`` with this term appended at scaled coefficient ``z``."""
        return fam.plus(self), np.append(g, z)


@dataclass(frozen=True)
class ParamCandidate:
    """A change of one of the simulator's own parameters, as a candidate of the same selection as the terms:
    value = nominal * exp(z)."""

    name: str
    nominal: float
    fd_step: float

    @property
    def key(self) -> tuple[str, int]:
        return ("param:" + self.name, -1)

    @property
    def label(self) -> str:
        return f"param {self.name}"

    @property
    def is_param(self) -> bool:
        return True

    @property
    def must_be_positive(self) -> bool:
        return False

    @property
    def vocabulary_rank(self) -> int:
        return -1  # listed before every term: a parameter change wins at equal evidence

    @property
    def term(self) -> str:
        return "param:" + self.name

    def coefficient(self, z: float) -> float:
        return self.nominal * math.exp(float(z))

    def add_to(self, fam: Family, g: np.ndarray, z: float) -> tuple[Family, np.ndarray]:
        """``fam`` with this parameter appended to its parameters, and ``g`` with ``z`` inserted after theirs."""
        P = len(fam.params)
        return fam.with_(params=fam.params + [(self.name, self.nominal)]), np.insert(np.asarray(g, float), P, z)


@dataclass
class Family:
    """g -> system: calibrated parameters (log-relative) then terms (scaled coefficients), built by the simulator."""

    sim: Simulator
    kwargs: dict[str, Any]  # overrides of the simulator's kwargs
    params: list[tuple[str, float]]  # (name, nominal value); value = nominal * exp(z)
    terms: list[ScaledTerm]
    eps: float | tuple[float, ...]  # Coulomb smoothing, one or one per coordinate
    deadzone_width: float = 0.0

    def kwargs_of(self, g: np.ndarray) -> dict[str, Any]:
        kw = dict(self.kwargs)
        for (name, nom), z in zip(self.params, g[: len(self.params)]):
            kw[name] = nom * math.exp(float(np.clip(z, -20, 20)))
        return kw

    def terms_of(self, g: np.ndarray) -> list[Term]:
        return [t.at(z) for t, z in zip(self.terms, g[len(self.params):])]

    def build(self, g: np.ndarray) -> AugmentedSystem:
        return AugmentedSystem(self.sim.build(**self.kwargs_of(g)), self.terms_of(g), self.eps, self.deadzone_width)

    def with_(self, params: list[tuple[str, float]] | None = None, terms: list[ScaledTerm] | None = None) -> Family:
        return Family(self.sim, self.kwargs, self.params if params is None else params,
                      self.terms if terms is None else terms, self.eps, self.deadzone_width)

    def plus(self, cand: Candidate) -> Family:
        """This family with one more term."""
        return self.with_(terms=self.terms + [cand.family_term])


def _coordinate_scales(problem: Problem, system: System) -> tuple[np.ndarray, np.ndarray]:
    """rms of the conservative force (plus the port force) and of M_ii per coordinate, along the smoothed training states."""
    qs, vs, n, train = problem.qs, problem.vs, problem.n, problem.train
    qc = tuple(qs[..., i] for i in range(n))
    p = momentum(system, qs, vs)
    pc = tuple(p[..., i] for i in range(n))
    force_rms = np.array([float(np.sqrt(np.mean(np.asarray(f) ** 2))) for f in system.base.dH_dq(qc, pc, NUMPY)])
    if train.u is not None:
        force_rms = force_rms + np.sqrt(np.mean(train.u**2, axis=(0, 1)))
    force_rms = np.where(force_rms > 0, force_rms, 1.0)
    mass_rms = np.ones(n)
    if "armature" in VOCABULARY and "armature" in (problem.opts.terms or VOCABULARY):
        M = system.base.mass_matrix(qc, NUMPY)
        mass_rms = np.array([float(np.sqrt(np.mean(np.broadcast_to(np.asarray(M[i][i], float), qs.shape[:-1]) ** 2)))
                             for i in range(n)])
    return force_rms, mass_rms


def candidates(problem: Problem, system: System) -> list[Candidate]:
    """Every term of the vocabulary (``Options.terms``) on every coordinate where it can act, at the calibrated ``system``."""
    qs, vs, train = problem.qs, problem.vs, problem.train
    force_rms, mass_rms = _coordinate_scales(problem, system)
    sensor_scale = problem.sigma * 10 + 1e-3 * problem.q_std
    h = FD_STEP
    out: list[Candidate] = []
    for i in range(problem.n):
        qi, vi = qs[..., i], vs[..., i]
        vi_rms = float(np.sqrt(np.mean(vi**2)))
        basis_rms = {
            "viscous_damping": np.sqrt(np.mean(vi**2)), "coulomb_friction": 1.0,
            "quadratic_drag": np.sqrt(np.mean(vi**4)), "position_dependent_damping": np.sqrt(np.mean((np.abs(np.sin(qi)) * vi) ** 2)),
            "linear_stiffness": np.sqrt(np.mean(qi**2)), "cubic_stiffness": np.sqrt(np.mean(qi**6)), "constant_force": 1.0,
        }
        for name in problem.opts.terms or tuple(VOCABULARY):
            if name in FORCE_TERMS:
                b = float(basis_rms[name])
                if b > 1e-12:
                    out.append(Candidate(name, i, float(force_rms[i] / b), h))
            elif name == "stribeck_friction":  # one candidate per Stribeck velocity of a coarse grid
                for f in STRIBECK_FRACTIONS:
                    w = float(f * vi_rms)
                    if w < MIN_STRIBECK_OVER_EPS * problem.eps_coord[i]:
                        continue
                    b = float(np.sqrt(np.mean(np.asarray(friction_basis(name, qi, vi, problem.eps_coord[i], w, NUMPY)) ** 2)))
                    if b > 1e-12:
                        out.append(Candidate(name, i, float(force_rms[i] / b), h, w))
            elif name == "armature" and name in VOCABULARY:  # c added to M_ii (c >= 0): z = 1 is 5% of the coordinate's inertia
                out.append(Candidate(name, i, 0.05 * float(mass_rms[i]), h))
            elif name == "actuator_gain" and problem.has_u[i]:
                out.append(Candidate(name, i, 0.1, h))
            elif name == "actuator_deadzone" and problem.has_u[i]:
                out.append(Candidate(name, i, float(np.median(np.abs(train.u[..., i]))), 0.3))
            elif name == "sensor_offset":
                out.append(Candidate(name, i, float(sensor_scale[i]), h))
            elif name == "sensor_gain":
                out.append(Candidate(name, i, 0.01, h))
            elif name == "sensor_eccentricity" and i in train.angle_dims:
                out.append(Candidate(name, i, float(sensor_scale[i]), h))
    return out
