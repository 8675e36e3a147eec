"""The explainers behind phast-mismatch's answer are strategies behind one interface (phast_model.mismatch.explainers):
a custom one plugs in through ``analyze(..., explainers=...)``, and a later answer is adopted only when it predicts
the held-out recordings better than the calibrated model."""

from __future__ import annotations

from dataclasses import replace

import pytest

from phast_model.bench.reality import make_reality
from phast_model.mismatch import AugmentedSystem, Term, analyze
from phast_model.mismatch.analysis import EXPLAINERS
from phast_model.mismatch.explainers import Answer, Context, Declined, ShootingExplainer
from phast_model.mismatch.friction.systematic import WeakFormExplainer


@pytest.fixture(scope="module")
def data() -> dict:
    return make_reality("PHAST/Pendulum-v0", [Term("coulomb_friction", 0, 0.1)], n_traj=8, T=300, noise_std=0.01, seed=3)


@pytest.fixture(scope="module")
def default_report(data):
    return analyze("PHAST/Pendulum-v0", data)


def _without_wall_time(d: dict) -> dict:
    return {**d, "details": {k: v for k, v in d["details"].items() if k != "wall_time_s"}}


class Silent:
    """Never applies, says nothing."""

    def explain(self, ctx: Context) -> None:
        return None


class Overdamped:
    """The standing answer with a large viscous damping added: worse on the held-out recordings."""

    def explain(self, ctx: Context) -> Answer:
        assert ctx.current is not None
        base = ctx.current.system
        assert isinstance(base, AugmentedSystem)
        system = AugmentedSystem(base.base, [*base.terms, Term("viscous_damping", 0, 2.0)],
                                 base.coulomb_eps_per_coordinate, base.deadzone_width)
        return replace(ctx.current, label="overdamped answer", system=system, method="; an overdamped guess",
                       section="overdamped", evidence={"used": True})


class Truth:
    """The model the recordings were made with (the concealed Coulomb friction, nothing else)."""

    def explain(self, ctx: Context) -> Answer:
        assert ctx.current is not None
        base = ctx.current.system
        assert isinstance(base, AugmentedSystem)
        system = AugmentedSystem(base.base, [Term("coulomb_friction", 0, 0.1)], base.coulomb_eps_per_coordinate,
                                 base.deadzone_width)
        return replace(ctx.current, label="true model", system=system, missing=(), method="; the truth",
                       section="truth", evidence={"used": True})


def test_the_default_explainers_are_shooting_then_weak_form():
    assert [type(e) for e in EXPLAINERS] == [ShootingExplainer, WeakFormExplainer]


def test_an_explainer_that_never_applies_changes_nothing(data, default_report):
    rep = analyze("PHAST/Pendulum-v0", data, explainers=[*EXPLAINERS, Silent()])
    assert _without_wall_time(rep.to_dict()) == _without_wall_time(default_report.to_dict())


def test_a_worse_answer_is_not_adopted(data, default_report):
    rep = analyze("PHAST/Pendulum-v0", data, explainers=[*EXPLAINERS, Overdamped()])
    before, after = default_report.to_dict(), rep.to_dict()
    for key in ("sim", "missing_physics", "fit", "summary", "located"):
        assert after[key] == before[key], key
    note = rep.details["overdamped"]
    assert note["used"] and note["not_adopted"].startswith("the overdamped answer does not improve the held-out prediction")
    assert rep.details["method"] == before["details"]["method"]  # not adopted: its reason is in its own section
    assert rep.details["intervals"] == before["details"]["intervals"]
    assert rep.details["friction"] == before["details"]["friction"]


def test_a_better_answer_is_adopted(data, default_report):
    rep = analyze("PHAST/Pendulum-v0", data, explainers=[*EXPLAINERS, Truth()])
    assert "not_adopted" not in rep.details["truth"]
    assert rep.details["method"] == default_report.details["method"] + "; the truth"
    assert rep.fit["augmented"]["rollout_rmse"] < rep.fit["calibrated"]["rollout_rmse"]
    assert rep.fit["calibrated"] == default_report.fit["calibrated"]
    assert rep.plot_data["augmented_system"].terms == (Term("coulomb_friction", 0, 0.1),)


def test_a_declined_explainer_is_reported_and_one_answer_is_needed(data):
    class Declines:
        def explain(self, ctx: Context) -> Declined:
            return Declined({"mine": {"used": False, "reason": "not my regime"}})

    rep = analyze("PHAST/Pendulum-v0", data, explainers=[ShootingExplainer(), Declines()])
    assert rep.details["mine"] == {"used": False, "reason": "not my regime"}
    assert "friction" not in rep.details
    with pytest.raises(RuntimeError, match="no explainer answered"):
        analyze("PHAST/Pendulum-v0", data, explainers=[Declines()])


def test_weak_form_parameters_the_simulator_refuses_leave_the_shooting_answer(data, default_report, monkeypatch):
    """The weak form's least squares can leave the simulator's valid parameters (a two-link arm whose mass matrix is
    not positive definite, seen on a delayed-sensor arm in the model-error regime): the weak form then declines with
    the reason and the shooting answer stands, instead of an internal failure."""
    from phast_gym.systems.base import ParameterError
    from phast_model.mismatch.friction import systematic as weak

    def refused(ctx):
        raise ParameterError("DoublePendulum: a mass matrix that is not positive definite")

    monkeypatch.setattr(weak, "systematic", refused)
    rep = analyze("PHAST/Pendulum-v0", data, systematic_chi2=0.0)
    assert [(m["term"], m["coordinate"]) for m in rep.missing_physics] == [("coulomb_friction", 0)]
    assert rep.details["method"] == default_report.details["method"] and not rep.details["friction"]["used"]
    reason = rep.details["friction"]["reason"]
    assert "reached parameters the simulator refuses" in reason and "not positive definite" in reason
