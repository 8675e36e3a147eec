"""Tests of the weak-form friction curve, law fits, passivity of the total force and law selection (synthetic, fast)."""

from __future__ import annotations

import numpy as np
import pytest

from phast_gym.registry import make_env_system
from phast_model.bench.reality import make_reality
from phast_model.identify.recordings import Recordings
from phast_model.mismatch import Term
from phast_model.mismatch.friction import (
    FrictionLaw,
    LawTerm,
    check_against_curve,
    fit_law,
    friction_curve,
    is_passive,
    plot_friction_curve,
    select_law,
)

ENV = "PHAST/Pendulum-v0"
TRUE = {"coulomb_friction": 0.03, "viscous_damping": 0.02}


@pytest.fixture(scope="module")
def rec() -> Recordings:
    """Encoder-grade recordings of a pendulum with hidden Coulomb 0.03 + viscous 0.02 (the nominal model has none)."""
    d = make_reality(ENV, [Term(k, 0, v) for k, v in TRUE.items()], n_traj=8, T=400, noise_std=1e-4, seed=1)
    return Recordings(d["q"], d["dt"], None, tuple(d["angle_dims"]))


@pytest.fixture(scope="module")
def system():
    return make_env_system(ENV)


def test_friction_curve_contains_the_known_law(rec, system, tmp_path):
    curve = friction_curve(system, rec, bands=6)
    assert len(curve.coordinate(0)) == 6 and curve.max_speed[0] > 1.0
    assert all(b.model_force == 0.0 for b in curve.bands)  # the nominal model has no dissipation of its own
    true = FrictionLaw([LawTerm(k, 0, v, (v, v)) for k, v in TRUE.items()], curve.filter["coulomb_eps"], 1)
    rows = check_against_curve(true, curve)
    assert all(r["inside"] for r in rows)
    # intervals are informative: every band excludes zero friction
    assert all(b.ci95[0] > 0 for b in curve.bands)
    d = curve.to_dict()
    assert d["bands"][0]["ci95"][0] <= d["bands"][0]["force"] <= d["bands"][0]["ci95"][1]
    assert plot_friction_curve(curve, [true], str(tmp_path / "curve.png"))
    assert (tmp_path / "curve.png").stat().st_size > 0


def test_weak_form_fit_recovers_coefficients(rec, system):
    law = fit_law(system, rec, [("coulomb_friction", 0), ("viscous_damping", 0)])
    for t in law.terms:
        assert abs(t.coefficient - TRUE[t.term]) / TRUE[t.term] < 0.10
        assert t.ci95[0] < t.coefficient < t.ci95[1] and t.excludes_zero


def test_total_force_passivity(system):
    own = [(np.array([0.0, 1.0]), np.array([0.05, 0.05]))]  # the model's own viscous damping 0.05
    # negative viscous coefficient, yet Coulomb 0.03 + (0.05 - 0.06) v > 0 up to v = 3: passive over observed speeds, flagged
    law = FrictionLaw([LawTerm("coulomb_friction", 0, 0.03, (0.02, 0.04)), LawTerm("viscous_damping", 0, -0.06, (-0.07, -0.05))],
                      0.01, 1, own_samples=own)
    p = is_passive(law, 2.5)
    assert p.passive and p.per_coordinate[0]["negative_terms"] == ["viscous[0]"]
    # the same law is not passive once the speeds reach beyond 3
    p = is_passive(law, 5.0)
    assert not p.passive and p.per_coordinate[0]["worst_speed"] > 3.0
    # a negative Coulomb coefficient pushes at low speed: never passive
    bad = FrictionLaw([LawTerm("coulomb_friction", 0, -0.01, (-0.02, 0.0))], 0.01, 1, own_samples=own)
    assert not is_passive(bad, 1.0).passive


def test_selection_picks_the_true_law(rec, system):
    sel = select_law(system, rec, candidates=[[], ["viscous_damping"], ["coulomb_friction"], ["coulomb_friction", "viscous_damping"],
                                              ["coulomb_friction", "viscous_damping", "quadratic_drag"],
                                              ["coulomb_friction", "quadratic_drag"]])
    assert sorted(t.term for t in sel.chosen.terms) == sorted(TRUE)
    assert sel.to_dict()["chosen"]["every_ci_excludes_zero"]


def test_clean_damped_pendulum_gives_no_extra_friction():
    d = make_reality("PHAST/DampedPendulum-v0", [], n_traj=8, T=400, noise_std=1e-4, seed=2)
    r = Recordings(d["q"], d["dt"], None, tuple(d["angle_dims"]))
    system = make_env_system("PHAST/DampedPendulum-v0")
    curve = friction_curve(system, r, bands=5)
    none = FrictionLaw([], curve.filter["coulomb_eps"], 1)
    assert all(row["inside"] for row in check_against_curve(none, curve))  # the model's own damping explains the curve
    sel = select_law(system, r, candidates=[[], ["coulomb_friction"], ["viscous_damping"], ["coulomb_friction", "viscous_damping"]])
    assert sel.chosen.terms == []


def test_selection_accepts_a_passive_negative_coefficient_and_rejects_a_non_passive_law():
    """The model's own damping (gamma 0.5) is too large for the rig (0.3, plus Coulomb 0.05): the law that corrects it
    has a negative viscous coefficient, yet the *total* force stays passive, so it is chosen and flagged; the Coulomb-only
    law, whose fit goes negative (pushing at low speed), is not passive and is never chosen."""
    d = make_reality("PHAST/DampedPendulum-v0", [Term("coulomb_friction", 0, 0.05)], true_kwargs={"gamma": 0.3}, n_traj=8, T=400,
                     noise_std=1e-4, seed=1)
    r = Recordings(d["q"], d["dt"], None, tuple(d["angle_dims"]))
    system = make_env_system("PHAST/DampedPendulum-v0")
    sel = select_law(system, r, candidates=[[], ["coulomb_friction"], ["viscous_damping"], ["coulomb_friction", "viscous_damping"]])
    law = {t.term: t for t in sel.chosen.terms}
    assert set(law) == {"coulomb_friction", "viscous_damping"}
    assert abs(law["coulomb_friction"].coefficient - 0.05) / 0.05 < 0.05
    assert abs(law["viscous_damping"].coefficient + 0.2) / 0.2 < 0.05 and law["viscous_damping"].ci95[1] < 0
    p = is_passive(sel.chosen, 3.0)
    assert p.passive and p.per_coordinate[0]["negative_terms"] == ["viscous[0]"]
    scores = {s.law: s for s in sel.scores}
    assert not scores["coulomb[0]"].passive and scores["coulomb[0]"].fitted.terms[0].coefficient < 0
    assert all(s.passive for s in sel.scores if s.law == sel.chosen_name)


def test_a_fold_no_law_can_score_does_not_void_the_selection():
    """A left-out recording on which no law can be scored (the joint rests there: no speed band has samples) is no
    evidence either way: the other folds still choose (a real arm whose base joint rests in one run of 17 was left
    without friction)."""
    from phast_model.mismatch.friction.lawselect import CandidateScore, Eligibility, EligibilityRules, _choose, fold_stats

    def candidate(law: str, n_params: int, scores: list[float]) -> CandidateScore:
        stats = fold_stats(scores, [0.0] * len(scores))
        assert np.isfinite(stats.mean) and np.isfinite(stats.se)
        return CandidateScore(law, n_params, stats, Eligibility(True, True))

    rng = np.random.default_rng(0)
    nothing = candidate("model only", 0, [*(1.0 + 0.05 * rng.normal(size=12)), np.nan])
    law = candidate("viscous + coulomb", 2, [*(0.1 + 0.05 * rng.normal(size=12)), np.nan])
    pick, rule = _choose([law, nothing], EligibilityRules())
    assert pick is law and "not enough data" not in rule


def test_the_law_selection_says_where_it_is(rec, system):
    """A long law selection (minutes on a 6-joint arm) writes progress lines: the coordinate, the candidates scored and
    the time left."""
    from phast_model.identify.shooting import Heartbeat
    from phast_model.mismatch.friction import select_friction

    lines: list[str] = []
    select_friction(system, rec, Heartbeat(lines.append, every=0.0), terms=("viscous_damping", "coulomb_friction"))
    assert lines and "coordinate 1 of 1" in lines[-1] and "4 of 4 candidate laws" in lines[-1] and "s left" in lines[-1]


def test_a_folds_weak_form_is_a_slice_of_the_whole(rec, system):
    """Leave-one-recording-out folds slice the weak form of every recording instead of recomputing it N times: the
    filters run along each recording, so a slice is what the recordings alone give."""
    from phast_model.identify.weakform import weak_form

    whole = weak_form(system, rec)
    keep = np.array([0, 2, 5])
    alone = weak_form(system, rec.subset(keep), whole.window, whole.eps)
    part = whole.subset(keep)
    for name in ("qs", "vs", "total", "own", "carried", "q_raw", "v_raw"):
        np.testing.assert_allclose(getattr(part, name), getattr(alone, name), rtol=1e-12, atol=1e-12, err_msg=name)
