"""Parameters before terms (docs/mismatch_claims.md): parameter errors are not turned into invented physics, known
constants stay fixed, short real data get a report, and exit codes tell bad input from an internal failure."""

from __future__ import annotations

import math

import numpy as np
import pytest

from phast_model.bench.reality import make_reality
from phast_model.cli.mismatch import main
from phast_model.mismatch import Term, analyze
from phast_model.mismatch.calibrate import identifiability
from tests import ROOT

#: a two-motor arm in joint coordinates with compound links (the DFKI C.0 design's CAD values)
ARM = {"coordinates": "relative", "mass1": 0.6417, "mass2": 0.5639, "length1": 0.2, "length2": 0.3,
       "com1": 0.2, "com2": 0.3213, "inertia1": 0.02671, "inertia2": 0.05388, "gravity": 9.81}
REAL = ROOT.parent / "shared" / "data" / "real" / "multiarm_single_pendulum.npz"


def _arm(true: dict, terms: list[Term], seed: int, n_traj: int = 16, T: int = 400) -> dict:
    return make_reality("PHAST/DoublePendulum-v0", terms, {**ARM, **true}, n_traj=n_traj, T=T, noise_std=0.002, seed=seed,
                        u_std=0.5)


def test_identifiability_finds_the_combination_and_its_equivalents():
    """Columns a = p0, b = 2 p0 (one combination), c independent: rank 2, b written in terms of the pivots."""
    rng = np.random.default_rng(0)
    a, c = rng.normal(size=50), rng.normal(size=50)
    ident = identifiability(["a", "b", "c"], np.stack([a, 2 * a, c], 1))
    assert ident.rank == 2
    (other,) = ident.equivalents
    pivot = "a" if other == "b" else "b"
    assert set(ident.basis) == {pivot, "c"}
    assert ident.equivalents[other][pivot] == pytest.approx(0.5 if other == "a" else 2.0, rel=1e-6)
    assert abs(ident.equivalents[other]["c"]) < 1e-8


def test_parameter_only_arm_gives_no_term():
    """inertia2 10% high is a parameter change, reported as such, and no term is named."""
    rep = analyze("PHAST/DoublePendulum-v0", _arm({"inertia2": ARM["inertia2"] * 1.1}, [], seed=3), sim_kwargs=ARM,
                  rollout_window=1.0)
    assert rep.missing_physics == []
    changed = {k: v for k, v in rep.sim["calibrated"].items() if v.get("ci95")}
    assert "inertia2" in changed and changed["inertia2"]["relative_change"] == pytest.approx(0.1, abs=0.02)
    assert "gravity" not in changed
    assert rep.details["identifiability"]["rank"] >= 4


def test_cad_errors_and_one_coulomb_give_that_friction_and_parameter_changes_only():
    """All six link parameters 3-8% off and a Coulomb friction at joint 2: the friction and parameter changes, nothing else."""
    rng = np.random.default_rng(5)
    true = {k: ARM[k] * (1 + rng.choice([-1, 1]) * rng.uniform(0.03, 0.08))
            for k in ("mass1", "mass2", "com1", "com2", "inertia1", "inertia2")}
    rep = analyze("PHAST/DoublePendulum-v0", _arm(true, [Term("coulomb_friction", 1, 0.08)], seed=5), sim_kwargs=ARM,
                  rollout_window=1.0)
    found = {(m["term"], m["coordinate"]) for m in rep.missing_physics}
    assert ("coulomb_friction", 1) in found
    assert found <= {("coulomb_friction", 1), ("stribeck_friction", 1)}  # (a sharper Coulomb edge than the tool's)
    coulomb = next(m for m in rep.missing_physics if m["term"] == "coulomb_friction")
    assert coulomb["coefficient"] == pytest.approx(0.08, rel=0.3)


def test_gravity_stays_fixed_unless_freed():
    """A pendulum whose port delivers 0.8 u: the port gain, with gravity at its known value; freed, gravity may move."""
    rec = make_reality("PHAST/Pendulum-v0", [Term("actuator_gain", 0, 0.8)], n_traj=12, T=300, noise_std=0.002, seed=4,
                       u_std=1.0)
    rep = analyze("PHAST/Pendulum-v0", rec)
    assert rep.sim["calibrated"]["gravity"]["fitted"] == 9.81
    assert "known constant" in rep.sim["calibrated"]["gravity"]["note"]
    assert [(m["term"], m["coordinate"]) for m in rep.missing_physics] == [("actuator_gain", 0)]
    assert rep.missing_physics[0]["coefficient"] == pytest.approx(0.8, rel=0.02)
    freed = analyze("PHAST/Pendulum-v0", rec, free=("gravity",))
    assert "gravity" in freed.details["identifiability"]["examined"]
    with pytest.raises(ValueError, match="not a numeric parameter"):
        analyze("PHAST/Pendulum-v0", rec, free=("gravitation",))


@pytest.mark.skipif(not REAL.exists(), reason="the real pendulum recordings are not beside the repository")
def test_short_real_windows_give_a_report(tmp_path):
    """Six 1-s windows of the real pendulum at 200 Hz (a case that once crashed in the law selection)."""
    with np.load(REAL) as z:
        q = np.stack([z["q"][5, i * 1000:(i + 1) * 1000:5] - math.pi for i in range(6)])
        fit = dict(zip([str(s) for s in z["published_fit_names"]], [float(v) for v in z["published_fit"]]))
    kw = {"mass": fit["m1_kg"], "length": fit["a1_m"], "gravity": fit["g"],
          "inertia": fit["m1_kg"] * fit["a1_m"] ** 2 + fit["I1_kgm2"], "gamma": fit["k1_viscous"]}
    np.savez(tmp_path / "rec.npz", q=q, dt=0.005, angle_dims=np.array([0]))
    import json

    rc = main(["--sim", "PHAST/DampedPendulum-v0", "--sim-kwargs", json.dumps(kw), "--recordings", str(tmp_path / "rec.npz"),
               "--out", str(tmp_path / "out"), "--quiet", "--no-plots"])
    assert rc == 0
    assert (tmp_path / "out" / "report.json").is_file()


def test_exit_codes_bad_input_2_internal_failure_1(tmp_path, monkeypatch, capsys):
    rec = make_reality("PHAST/DampedPendulum-v0", [], n_traj=6, T=200, noise_std=0.01, seed=1)
    np.savez(tmp_path / "rec.npz", **rec)
    args = ["--sim", "PHAST/DampedPendulum-v0", "--recordings", str(tmp_path / "rec.npz"), "--quiet", "--no-plots"]
    assert main(args + ["--out", str(tmp_path / "a"), "--free", "nope"]) == 2
    assert "not a numeric parameter" in capsys.readouterr().err

    import phast_model.mismatch.analysis as analysis

    def broken(*a, **k):
        raise ValueError("min() arg is an empty sequence")

    monkeypatch.setattr(analysis, "screen_parameters", broken)
    assert main(args + ["--out", str(tmp_path / "b")]) == 1
    err = capsys.readouterr().err
    assert "internal error" in err and "error.log" in err
    log = (tmp_path / "b" / "error.log").read_text()
    assert "Traceback" in log and "min() arg is an empty sequence" in log
    monkeypatch.undo()
    assert main(args + ["--out", str(tmp_path / "b")]) == 0  # a rerun replaces what the failed run left
    assert not (tmp_path / "b" / "error.log").exists()


@pytest.mark.parametrize("stage", ["prepare", "held_out"])
def test_a_failure_in_the_set_up_stages_is_the_tools_own(tmp_path, monkeypatch, capsys, stage):
    """A ValueError raised inside ``prepare`` or ``held_out`` (after the input checks) is an internal error: exit 1
    with error.log, never "bad input" (exit 2)."""
    rec = make_reality("PHAST/DampedPendulum-v0", [], n_traj=6, T=200, noise_std=0.01, seed=1)
    np.savez(tmp_path / "rec.npz", **rec)
    import phast_model.mismatch.analysis as analysis

    def broken(*a, **k):
        raise ValueError(f"injected failure in {stage}")

    monkeypatch.setattr(analysis, stage, broken)
    args = ["--sim", "PHAST/DampedPendulum-v0", "--recordings", str(tmp_path / "rec.npz"), "--quiet", "--no-plots",
            "--out", str(tmp_path / "out")]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "internal error" in err and f"injected failure in {stage}" in err
    assert f"injected failure in {stage}" in (tmp_path / "out" / "error.log").read_text()


def test_a_too_short_rollout_window_is_the_users_input(tmp_path, capsys):
    rec = make_reality("PHAST/DampedPendulum-v0", [], n_traj=6, T=200, noise_std=0.01, seed=1)
    np.savez(tmp_path / "rec.npz", **rec)
    args = ["--sim", "PHAST/DampedPendulum-v0", "--recordings", str(tmp_path / "rec.npz"), "--quiet", "--no-plots",
            "--out", str(tmp_path / "out"), "--rollout-window", "0.05"]
    assert main(args) == 2
    assert "shorter than" in capsys.readouterr().err


def test_joint_change_that_is_one_parameter_is_reported_as_it():
    """A free RLC circuit whose capacitor is 8% low: the data fix R/L and 1/(LC); the pivots (resistance, inductance)
    moved together are exactly a capacitance change, which is what is reported."""
    rec = make_reality("PHAST/RLCCircuit-v0", [], {"capacitance": 0.92}, n_traj=16, T=200, noise_std=0.01, seed=6)
    rep = analyze("PHAST/RLCCircuit-v0", rec)
    changed = {k: v["fitted"] for k, v in rep.sim["calibrated"].items() if v.get("ci95")}
    assert list(changed) == ["capacitance"] and changed["capacitance"] == pytest.approx(0.92, rel=0.02)
    assert rep.missing_physics == []


def test_three_link_rig_example_is_exact_physics():
    """examples/rigs/triple_pendulum.py: dH/dq matches finite differences of H and a free swing keeps its energy."""
    from phast_gym.integrate import simulate
    from phast_model.identify.simulators import load_simulator

    rig = ROOT / "examples" / "rigs" / "triple_pendulum.py"
    s = load_simulator(f"{rig}:TriplePendulum", {"friction": 0.0}).build()
    x0 = s.sample_initial(np.random.default_rng(0), 4)
    q, p = tuple(x0[:, i] for i in range(3)), tuple(x0[:, 3 + i] for i in range(3))

    def energy(q, p):
        return 0.5 * sum(a * b for a, b in zip(p, s.velocity(q, p))) + s.potential(q)

    g, h = s.dH_dq(q, p), 1e-6
    for k in range(3):
        qk = tuple(qi + (h if i == k else 0.0) for i, qi in enumerate(q))
        np.testing.assert_allclose((energy(qk, p) - energy(q, p)) / h, g[k], atol=1e-5)
    x = simulate(s, x0, 1000)
    e0, e1 = energy(q, p), energy(tuple(x[:, -1, i] for i in range(3)), tuple(x[:, -1, 3 + i] for i in range(3)))
    np.testing.assert_allclose(e1, e0, rtol=1e-6, atol=1e-8)


def test_sharp_real_coulomb_edge_is_not_named_stribeck():
    """The bench's CAD-off arm at seed 324 (24 x 300): the recordings' Coulomb edge is sharper than the fits' tanh
    smoothing, and the excess near rest once came out as a Stribeck term; a sharper edge fits as well, so only the
    Coulomb friction is named, and the check is in the report."""
    from phast_model.cli.mismatch_bench import CASES, make_case_data

    case = next(c for c in CASES if c.name == "arm_cad_off_coulomb")
    rep = analyze(case.env_id, make_case_data(case, 24, 300, 324), sim_kwargs=case.sim_kwargs,
                  holdout_fraction=0.3, rollout_window=case.rollout_window)
    assert [(m["term"], m["coordinate"]) for m in rep.missing_physics] == [("coulomb_friction", 1)]
    (row,) = [r for r in rep.details["held_out_check"] if "chi2_rise_without_it" in r]
    assert not row["kept"] and "sharper Coulomb edge" in row["note"]
    assert rep.details["coulomb_sign_smoothing_per_coordinate"][1] < rep.details["coulomb_sign_smoothing_per_coordinate"][0] / 2


def test_bench_noise_scale_scales_the_noise_and_rejects_nonsense(tmp_path, capsys):
    """--noise-scale multiplies every case's q-noise (robustness sweeps); a non-positive scale is a usage error."""
    from phast_model.cli import mismatch_bench as bench

    assert bench.main(["--cases", "rlc_capacitance", "--noise-scale", "0"]) == 2
    assert "--noise-scale" in capsys.readouterr().err
    out = tmp_path / "b.json"
    assert bench.main(["--cases", "rlc_capacitance", "--noise-scale", "2", "--T", "120", "--n-traj", "8", "--no-sindy",
                       "--out", str(out)]) == 0
    import json
    import re

    res = json.loads(out.read_text())
    assert res["noise_scale"] == 2.0
    case = next(c for c in bench.CASES if c.name == "rlc_capacitance")
    estimated = float(re.search(r"estimated measurement noise ([0-9.e-]+)", res["rows"][0]["tool"]["summary"]).group(1))
    assert estimated == pytest.approx(2 * case.noise, rel=0.3)


def test_slow_damping_missed_by_short_windows_is_found_by_the_second_look():
    """A pendulum's viscous 0.01 under 0.02 rad of noise: no term in half-period shooting windows (chi^2 gain 18.5 <
    25), found by the second look at 4x longer windows, and it predicts the held-out recordings."""
    from dataclasses import replace

    from phast_model.cli.mismatch_bench import CASES, make_case_data

    k, case = next((k, c) for k, c in enumerate(CASES) if c.name == "pendulum_viscous")
    case = replace(case, noise=2 * case.noise)
    rep = analyze(case.env_id, make_case_data(case, 30, 350, 500 + k), holdout_fraction=0.3)
    assert [(m["term"], m["coordinate"]) for m in rep.missing_physics] == [("viscous_damping", 0)]
    assert rep.missing_physics[0]["coefficient"] == pytest.approx(0.01, rel=0.1)
    look = rep.details["second_look"]
    assert look["adopted"] and rep.details["shoot_window_samples"] == look["shoot_window_samples"]
    assert rep.fit["augmented"]["rollout_rmse"] < 0.1 * rep.fit["calibrated"]["rollout_rmse"]


def test_two_laws_of_equal_evidence_on_one_joint_are_settled_on_longer_windows():
    """Viscous 0.003 + quadratic drag 0.001 on a pendulum (the bench's case at seed 4): in half-period windows a
    Coulomb term fits a few chi^2 units better than the viscous one beside the drag (a wrong pair, drag 40% high);
    on windows twice as long the true pair wins, and it predicts the held-out recordings about 3x better."""
    from phast_model.cli.mismatch_bench import CASES, make_case_data

    case = next(c for c in CASES if c.name == "pendulum_viscous_and_drag")
    rep = analyze(case.env_id, make_case_data(case, 40, 400, 4), holdout_fraction=0.3)
    found = {m["term"]: m["coefficient"] for m in rep.missing_physics}
    assert set(found) == {"viscous_damping", "quadratic_drag"}
    assert found["viscous_damping"] == pytest.approx(0.003, rel=0.3)
    assert found["quadratic_drag"] == pytest.approx(0.001, rel=0.3)
    (look,) = [r for r in rep.details["held_out_check"] if r["item"].startswith("dissipation law")]
    assert not look["kept"] and "adopted: quadratic_drag[0] + viscous_damping[0]" in look["note"]
    chi2 = look["chi2_on_longer_windows"]
    assert chi2["quadratic_drag[0] + viscous_damping[0]"] < chi2["quadratic_drag[0] + coulomb_friction[0]"] - 2.0
    assert rep.fit["augmented"]["rollout_rmse"] < 0.05 * rep.fit["calibrated"]["rollout_rmse"]


def test_a_term_whose_interval_includes_zero_is_not_missing_physics():
    """The data back a term only when its own 95% interval excludes zero; the other is set aside with a sentence."""
    from types import SimpleNamespace

    from phast_model.mismatch import analysis
    from phast_model.mismatch.rows import TermRow

    backed = TermRow("actuator_gain", 1, "port", 0.85, (0.84, 0.86), "u1 *= c")
    unbacked = TermRow("armature", 1, "inertia", 1.7e-6, (-3.3e-5, 2.9e-5), "M11 += c")
    fitres = SimpleNamespace(rmse=lambda name: {"calibrated": 0.1, "augmented": 0.01}[name])
    assert analysis._confirmed([backed, unbacked], fitres) == ([backed], [unbacked])
    text = " ".join(analysis._verdicts(analysis.Described(1.0), [unbacked], fitres))
    assert "armature[1]" in text and "includes zero" in text and "do not improve" not in text
    worse = SimpleNamespace(rmse=lambda name: {"calibrated": 0.1, "augmented": 0.2}[name])
    assert analysis._confirmed([backed, unbacked], worse) == ([], [backed, unbacked])
    text = " ".join(analysis._verdicts(analysis.Described(1.0), [backed, unbacked], worse))
    assert "includes zero" in text and "(actuator_gain[1]) do not improve" in text


@pytest.mark.parametrize("chi2", [0.95, 4.2e3])
def test_no_second_look_when_the_first_answer_fits_the_longer_windows_or_cannot_follow_them(monkeypatch, chi2):
    """The longer look starts from the first pass's answer: when it fits 4x longer windows within the noise, or cannot
    follow them at all (chi^2/dof in the thousands), the first answer stands and the report says why."""
    from dataclasses import replace

    from phast_model.cli.mismatch_bench import CASES, make_case_data
    from phast_model.mismatch import analysis

    monkeypatch.setattr(analysis, "_followed_on", lambda problem, calibrated: chi2)
    k, case = next((k, c) for k, c in enumerate(CASES) if c.name == "pendulum_viscous")
    case = replace(case, noise=2 * case.noise)
    rep = analyze(case.env_id, make_case_data(case, 30, 350, 500 + k), holdout_fraction=0.3, max_terms=0)
    assert rep.missing_physics == []
    assert rep.details["second_look"] == {"shoot_window_samples": 88, "calibrated_chi2_per_dof": chi2, "taken": False}


def test_the_same_large_gain_on_every_driven_joint_is_the_inputs_scale_not_missing_physics():
    """Currents given where the model expects torques: every motor 'needs' the same gain.  The report says the input's
    scale does not match (a drive gain or gear), and names no actuator_gain; one weak motor stays a motor."""
    from types import SimpleNamespace

    from phast_model.mismatch import analysis
    from phast_model.mismatch.rows import TermRow

    def gain(i: int, c: float) -> TermRow:
        return TermRow("actuator_gain", i, "port", c, (0.95 * c, 1.05 * c), f"u{i} *= c")

    assert analysis.input_scale([gain(0, 9.8), gain(1, 10.6)], [True, True]) == pytest.approx(math.sqrt(9.8 * 10.6))
    assert analysis.input_scale([gain(0, 0.85)], [True, True]) is None  # one weak motor
    assert analysis.input_scale([gain(0, 0.85), gain(1, 0.9)], [True, True]) is None  # near 1: motors
    assert analysis.input_scale([gain(0, 3.0), gain(1, 9.0)], [True, True]) is None  # not one factor
    assert analysis.input_scale([gain(0, 9.8)], [True, False]) is None  # one driven joint: cannot tell
    fitres = SimpleNamespace(rmse=lambda name: {"calibrated": 0.1, "augmented": 0.01}[name])
    text = " ".join(analysis._verdicts(analysis.Described(1.0), [gain(0, 9.8), gain(1, 10.6)], fitres, 10.2))
    assert "input's scale does not match" in text and "drive gain" in text and "do not improve" not in text


def test_currents_for_torques_end_to_end():
    """A two-motor arm whose recorded u is a tenth of the torque (a current, drive gain 10): the report names the
    input's scale, about 10x, and no actuator_gain as missing physics; with the gain applied the model predicts."""
    rec = make_reality("PHAST/DoublePendulum-v0", [Term("actuator_gain", 0, 10.0), Term("actuator_gain", 1, 10.0)], ARM,
                       n_traj=12, T=300, noise_std=0.002, seed=4, u_std=0.01)
    rep = analyze("PHAST/DoublePendulum-v0", rec, sim_kwargs=ARM, holdout_fraction=0.3)
    assert rep.missing_physics == []
    gains = {m["coordinate"]: m["coefficient"] for m in rep.details["unconfirmed_terms"] if m["term"] == "actuator_gain"}
    assert set(gains) == {0, 1} and all(g == pytest.approx(10.0, rel=0.02) for g in gains.values())
    assert "input's scale does not match" in rep.summary
    assert rep.fit["augmented"]["rollout_rmse"] < 0.2 * rep.fit["nominal"]["rollout_rmse"]
