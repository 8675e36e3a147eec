"""The term registry: a friction law registered from outside the package is a candidate everywhere (one class)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from phast_gym.registry import make_env_system
from phast_gym.systems.base import ArrayNamespace
from phast_model.mismatch import Options, Term, analyze, make_reality
from phast_model.mismatch.friction import select_law
from phast_model.mismatch.registry import VOCABULARY, DissipationKind, law_terms, register, unregister
from phast_model.rigs.recordings import Recordings

ENV = "PHAST/Pendulum-v0"


class SqrtFriction(DissipationKind):
    """A friction force growing with the square root of the speed (sign(qdot) smoothed like Coulomb's)."""

    name, short, formula = "sqrt_friction", "sqrt", "-c*sign(qdot{i})*sqrt(abs(qdot{i}))"

    def basis(self, q: Any, v: Any, eps: float, velocity: float, xp: ArrayNamespace) -> Any:
        return xp.tanh(v / eps) * xp.sqrt(xp.abs(v))


@pytest.fixture
def sqrt_law():
    kind = register(SqrtFriction())
    try:
        yield kind
    finally:
        unregister(kind.name)


def test_registration_adds_and_removes_a_kind(sqrt_law):
    assert VOCABULARY["sqrt_friction"] is sqrt_law and "sqrt_friction" in law_terms()
    assert Term("sqrt_friction", 0, 0.1).expression() == "-0.1*sign(qdot0)*sqrt(abs(qdot0))"
    with pytest.raises(ValueError, match="already registered"):
        register(SqrtFriction())


def test_registry_is_restored_after_the_test():
    assert "sqrt_friction" not in VOCABULARY
    with pytest.raises(ValueError, match="unknown term"):
        Term("sqrt_friction", 0, 0.1)


def test_a_law_registered_outside_the_package_is_found_by_the_tool(sqrt_law):
    """Synthetic pendulum recordings that hold the new law: the shooting selection names it, with its coefficient."""
    data = make_reality(ENV, [Term("sqrt_friction", 0, 0.03)], n_traj=16, T=300, noise_std=0.01, seed=2)
    rep = analyze(ENV, data, options=Options(max_terms=2))
    found = [(m["term"], m["coordinate"]) for m in rep.missing_physics]
    assert found == [("sqrt_friction", 0)], rep.summary
    assert abs(rep.missing_physics[0]["coefficient"] - 0.03) < 0.3 * 0.03
    assert rep.missing_physics[0]["expression"].startswith("-0.0")


def test_a_law_registered_outside_the_package_is_chosen_by_law_selection(sqrt_law):
    """The weak-form law selection builds its candidate laws from the registry: the new law is chosen."""
    d = make_reality(ENV, [Term("sqrt_friction", 0, 0.03)], n_traj=6, T=400, noise_std=1e-4, seed=1)
    rec = Recordings(d["q"], d["dt"], None, tuple(d["angle_dims"]))
    sel = select_law(make_env_system(ENV), rec, coordinate=0, max_terms=1)
    assert sel.chosen_name == "sqrt[0]", [(s.law, s.mean) for s in sel.scores]
    assert np.isclose(sel.chosen.terms[0].coefficient, 0.03, rtol=0.1)
