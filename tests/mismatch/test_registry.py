"""The term registry: a friction law registered from outside the package is a candidate everywhere (one class), a law
with a velocity parameter brings its own velocity rules, and the PySINDy peer's library is built from it."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from phast_gym.registry import make_env_system
from phast_gym.systems.base import ArrayNamespace
from phast_model.bench.reality import make_reality
from phast_model.identify.recordings import Recordings
from phast_model.mismatch import Options, Term, analyze
from phast_model.mismatch.friction import STRIBECK_FRACTIONS, fit_law, select_law, weak_form
from phast_model.mismatch.vocabulary.registry import (
    VOCABULARY,
    DissipationKind,
    ScaleContext,
    VelocityKind,
    law_terms,
    register,
    sign,
    unregister,
)

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


# --------------------------------------------------------------------------- a law with a velocity parameter
class ExpDecayFriction(VelocityKind):
    """Friction decaying exponentially with the speed: its own v_s grids (none of them Stribeck's) and refinement."""

    name, short, formula = "exp_decay_friction", "expdecay", "-c*sign(qdot{i})*exp(-abs(qdot{i})/v_s)"
    velocity_fractions = (0.45, 0.6, 0.8)
    shooting_fractions = (0.25, 0.5)

    def basis(self, q: Any, v: Any, eps: float, velocity: float, xp: ArrayNamespace) -> Any:
        return sign(v, eps, xp) * xp.exp(-xp.abs(v) / velocity)


@pytest.fixture
def exp_law():
    kind = register(ExpDecayFriction())
    try:
        yield kind
    finally:
        unregister(kind.name)


def test_a_velocity_law_owns_its_velocity_rules(exp_law):
    """The grids, the minimum and the refinement are the kind's: nothing is inherited from Stribeck by name."""
    stribeck = VOCABULARY["stribeck_friction"]
    assert exp_law.has_velocity and exp_law.cost == 2 and exp_law.refines_velocity and exp_law.excess_near_rest
    assert exp_law.velocity_grid(2.0) == [0.9, 1.2, 1.6]
    assert stribeck.velocity_grid(2.0) == [2.0 * f for f in STRIBECK_FRACTIONS]
    assert exp_law.min_velocity(0.01) == pytest.approx(0.04)
    assert not VOCABULARY["coulomb_friction"].refines_velocity and VOCABULARY["coulomb_friction"].velocity_grid(2.0) == []
    assert Term("exp_decay_friction", 0, 0.1, 0.3).expression() == "-0.1*sign(qdot0)*exp(-abs(qdot0)/0.3)"
    with pytest.raises(ValueError, match="velocity"):
        Term("exp_decay_friction", 0, 0.1)
    rng = np.random.default_rng(0)
    ctx = ScaleContext(rng.normal(size=200), rng.normal(size=200), 1.0, 1.0, 0.01, 0.01, None, True)
    v_rms = float(np.sqrt(np.mean(ctx.v**2)))
    assert [s.velocity for s in exp_law.scales(ctx)] == [0.25 * v_rms, 0.5 * v_rms]  # its shooting grid


def test_a_velocity_law_is_profiled_on_its_own_grid(exp_law):
    """The weak-form fit profiles v_s over the new kind's grid, not Stribeck's."""
    d = make_reality("PHAST/DampedOscillator-v0", [Term("exp_decay_friction", 0, 0.05, 0.6)], n_traj=6, T=400, noise_std=1e-4,
                     seed=1)
    rec = Recordings(d["q"], d["dt"], None, tuple(d["angle_dims"]))
    sys0 = make_env_system("PHAST/DampedOscillator-v0")
    wf = weak_form(sys0, rec)
    law = fit_law(sys0, rec, [("exp_decay_friction", 0, None)], weak=wf)
    v_rms = float(np.sqrt(np.mean(wf.vs[..., 0] ** 2)))
    assert law.terms[0].velocity in exp_law.velocity_grid(v_rms)
    assert law.terms[0].velocity not in VOCABULARY["stribeck_friction"].velocity_grid(v_rms)
    assert law.name.startswith("expdecay[0](v_s=")


def test_a_velocity_law_is_refined_like_stribeck(exp_law, capsys):
    """The shooting selection refines a chosen term's v_s when its kind says so (as it does Stribeck's): the velocity
    leaves the shooting grid and lands near the truth."""
    truth = 0.5
    d = make_reality("PHAST/DampedOscillator-v0", [Term("exp_decay_friction", 0, 0.05, truth)], n_traj=16, T=400,
                     noise_std=0.005, seed=1)
    rep = analyze("PHAST/DampedOscillator-v0", d, options=Options(terms=("exp_decay_friction",), max_terms=1, progress=True))
    assert [(m["term"], m["coordinate"]) for m in rep.missing_physics] == [("exp_decay_friction", 0)], rep.summary
    assert "velocity refined: exp_decay_friction[0]" in capsys.readouterr().out
    velocity = rep.missing_physics[0]["stribeck_velocity"]
    assert truth / 1.3 < velocity < truth * 1.3


def test_the_pysindy_peer_library_is_the_registry(sqrt_law, exp_law):
    """The peer's columns come from the kinds: registered laws are columns (sign(qdot) sharp, also for a basis written
    with tanh(v / eps)), and the built-in columns are the ones the peer typed before (same values, same order)."""
    from phast_model.cli.mismatch_bench import sindy_library

    rng = np.random.default_rng(3)
    q, v, u = rng.normal(size=500), rng.normal(size=500), rng.normal(size=500)
    v[7] = 0.0
    lib = sindy_library(q, v, u)
    v_s = 0.2 * float(np.sqrt(np.mean(v**2))) + 1e-12
    typed = {"viscous_damping": -v, "coulomb_friction": -np.sign(v), "quadratic_drag": -np.abs(v) * v,
             "position_dependent_damping": -np.abs(np.sin(q)) * v, "linear_stiffness": -q, "cubic_stiffness": -q**3,
             "constant_force": np.ones_like(q), "sqrt_friction": -np.sign(v) * np.sqrt(np.abs(v)),
             "stribeck_friction": -np.sign(v) * np.exp(-((v / v_s) ** 2)),
             "exp_decay_friction": -np.sign(v) * np.exp(-np.abs(v) / v_s), "actuator_gain": u}
    assert list(lib) == list(typed)
    assert all(np.array_equal(lib[k], typed[k]) for k in typed)
    assert "actuator_gain" not in sindy_library(q, v, None)
