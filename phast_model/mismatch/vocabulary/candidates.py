"""Candidate terms and the model family they are fitted in.

A fitted term's coefficient is ``default + scale * z`` (the kind's
``default`` is where the term has no effect), so every global of the shooting fit is O(1); a
calibrated parameter is ``nominal * exp(z)`` (log-relative).  :func:`candidates`
(:mod:`..selection.screening`) builds the list the selection screens.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ...identify.simulators import Simulator
from .registry import FD_STEP, VOCABULARY, TermKind
from .terms import AugmentedSystem, Term

__all__ = ["FD_STEP", "Candidate", "Family", "ParamCandidate", "ScaledTerm"]


@dataclass(frozen=True)
class ScaledTerm:
    """A vocabulary term on one coordinate with coefficient ``default + scale * z``."""

    term: str
    coordinate: int
    scale: float
    velocity: float | None = None  # Stribeck velocity v_s (stribeck_friction only)

    def coefficient(self, z: float) -> float:
        return VOCABULARY[self.term].default + self.scale * z

    def at(self, z: float) -> Term:
        """The :class:`Term` at scaled coefficient ``z`` (a deadzone threshold and an armature are |c|: an iterate may
        step past zero; a fitted negative armature is rejected by the sign rule)."""
        c = self.coefficient(float(z))
        if VOCABULARY[self.term].magnitude:
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
        return self.kind.fit_positive

    @property
    def kind(self) -> TermKind:
        return VOCABULARY[self.term]

    @property
    def component(self) -> str:
        return self.kind.component

    @property
    def vocabulary_rank(self) -> int:
        return list(VOCABULARY).index(self.term)

    def coefficient(self, z: float) -> float:
        return self.kind.default + self.scale * z

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
    """g -> system: calibrated parameters (log-relative) then terms (scaled coefficients), built by the simulator.
    ``engine``: what simulates a built system (a model file's MuJoCo: ``written.family_engine``; None: the tool's
    own integrator)."""

    sim: Simulator
    kwargs: dict[str, Any]  # overrides of the simulator's kwargs
    params: list[tuple[str, float]]  # (name, nominal value); value = nominal * exp(z)
    terms: list[ScaledTerm]
    eps: float | tuple[float, ...]  # Coulomb smoothing, one or one per coordinate
    deadzone_width: float = 0.0
    engine: Callable[[AugmentedSystem], AugmentedSystem] | None = None

    def kwargs_of(self, g: np.ndarray) -> dict[str, Any]:
        kw = dict(self.kwargs)
        for (name, nom), z in zip(self.params, g[: len(self.params)]):
            kw[name] = nom * math.exp(float(np.clip(z, -20, 20)))
        return kw

    def terms_of(self, g: np.ndarray) -> list[Term]:
        return [t.at(z) for t, z in zip(self.terms, g[len(self.params):])]

    def build(self, g: np.ndarray) -> AugmentedSystem:
        system = AugmentedSystem(self.sim.build(**self.kwargs_of(g)), self.terms_of(g), self.eps, self.deadzone_width)
        return system if self.engine is None else self.engine(system)

    def with_(self, params: list[tuple[str, float]] | None = None, terms: list[ScaledTerm] | None = None) -> Family:
        return replace(self, params=self.params if params is None else params,
                       terms=self.terms if terms is None else terms)

    def plus(self, cand: Candidate) -> Family:
        """This family with one more term."""
        return self.with_(terms=self.terms + [cand.family_term])
