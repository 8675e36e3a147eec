"""Tests of the simulation-vs-reality mismatch tool (small synthetic cases, fast)."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from phast_gym.registry import make_env_system
from phast_model.bench.reality import make_reality
from phast_model.identify.shooting import estimate_noise
from phast_model.mismatch import AugmentedSystem, Term, analyze, validate


@pytest.fixture(scope="module")
def coulomb_data() -> dict:
    return make_reality("PHAST/Pendulum-v0", [Term("coulomb_friction", 0, 0.1)], n_traj=12, T=300, noise_std=0.01, seed=3)


@pytest.fixture(scope="module")
def coulomb_report(coulomb_data):
    return analyze("PHAST/Pendulum-v0", coulomb_data)


def test_clean_recordings_give_no_missing_physics():
    rec = make_reality("PHAST/DampedPendulum-v0", [], n_traj=12, T=300, noise_std=0.01, seed=5)
    rep = analyze("PHAST/DampedPendulum-v0", rec)
    assert rep.missing_physics == []
    assert "No missing physics" in rep.summary
    assert rep.located == []
    # the calibrated parameters stay at the truth
    assert abs(rep.sim["calibrated"]["gamma"]["fitted"] - 0.5) / 0.5 < 0.05


def test_parameter_error_is_calibrated_not_missing_physics():
    rec = make_reality("PHAST/DampedPendulum-v0", [], true_kwargs={"gamma": 0.42}, n_traj=12, T=300, noise_std=0.01, seed=6)
    rep = analyze("PHAST/DampedPendulum-v0", rec)
    assert rep.missing_physics == []
    cal = rep.sim["calibrated"]["gamma"]
    assert abs(cal["fitted"] - 0.42) / 0.42 < 0.05
    assert cal["ci95"][0] < cal["fitted"] < cal["ci95"][1]


def test_concealed_coulomb_friction_is_found(coulomb_report):
    rep = coulomb_report
    assert [(m["term"], m["coordinate"]) for m in rep.missing_physics] == [("coulomb_friction", 0)]
    m = rep.missing_physics[0]
    assert m["component"] == "dissipation"
    assert abs(m["coefficient"] - 0.1) / 0.1 < 0.15
    assert m["ci95"][0] < m["coefficient"] < m["ci95"][1] and m["ci95"][0] > 0
    # the augmented model predicts held-out recordings better than the calibrated one
    assert rep.fit["augmented"]["rollout_rmse"] < 0.7 * rep.fit["calibrated"]["rollout_rmse"]
    assert rep.located and rep.located[0]["component"] == "dissipation" and rep.located[0]["removes_energy"]
    # noise level reported
    assert abs(rep.data["noise_std"] - 0.01) < 0.002


def test_answer_is_stable_across_smoothing_choices(coulomb_data, coulomb_report):
    """Smoothing only seeds the shooting fit: term set and coefficient do not move with the filter or window."""
    ref = coulomb_report.missing_physics[0]["coefficient"]
    for sg, L in ((5, 20), (21, 40), (41, 60)):
        rep = analyze("PHAST/Pendulum-v0", coulomb_data, smoothing_window=sg, shoot_window=L)
        assert [(m["term"], m["coordinate"]) for m in rep.missing_physics] == [("coulomb_friction", 0)], (sg, L)
        assert abs(rep.missing_physics[0]["coefficient"] - ref) / ref < 0.1, (sg, L)


def test_constant_force_on_linear_oscillator_names_sensor_offset_alternative():
    rec = make_reality("PHAST/DampedOscillator-v0", [Term("constant_force", 0, 0.15)], n_traj=10, T=250, noise_std=0.01, seed=2)
    rep = analyze("PHAST/DampedOscillator-v0", rec, terms=("constant_force", "sensor_offset", "viscous_damping"))
    assert len(rep.missing_physics) == 1
    m = rep.missing_physics[0]
    assert m["coordinate"] == 0 and m["term"] in ("constant_force", "sensor_offset")
    other = "sensor_offset" if m["term"] == "constant_force" else "constant_force"
    assert any(a.get("term") == other for a in m["alternatives"])
    assert "cannot tell" in rep.summary


def test_report_schema_and_files(coulomb_report, tmp_path):
    d = coulomb_report.to_dict()
    assert set(d) >= {"sim", "data", "located", "missing_physics", "fit", "summary"}
    assert set(d["sim"]) >= {"env_id", "kwargs", "calibrated"}
    assert set(d["data"]) >= {"n_traj", "T", "dt", "noise_std"}
    for loc in d["located"]:
        assert set(loc) >= {"coordinate", "component", "where", "share"}
    for m in d["missing_physics"]:
        assert set(m) >= {"term", "coordinate", "component", "coefficient", "ci95", "expression", "explains"}
    for name in ("nominal", "calibrated", "augmented"):
        assert set(d["fit"][name]) == {"one_step_mse", "rollout_rmse"}
        assert all(math.isfinite(v) for v in d["fit"][name].values())
    assert d["fit"]["evaluated_on"]
    out = coulomb_report.write(tmp_path / "rep")
    loaded = json.loads((out / "report.json").read_text())
    assert loaded["missing_physics"][0]["term"] == "coulomb_friction"
    for f in ("report.md", "residual_map.png", "heldout_fit.png", "decay.png"):
        assert (out / f).stat().st_size > 0
    # rewriting replaces the directory atomically, nothing left behind
    coulomb_report.write(out, plots=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep"]


def test_augmented_system_stays_passive():
    base = make_env_system("PHAST/Pendulum-v0")
    aug = AugmentedSystem(base, [Term("coulomb_friction", 0, 0.2), Term("quadratic_drag", 0, 0.1),
                                 Term("position_dependent_damping", 0, 0.3), Term("linear_stiffness", 0, 0.5),
                                 Term("stribeck_friction", 0, 0.1, velocity=0.3)])
    rng = np.random.default_rng(0)
    q, p = rng.normal(size=(1, 500)), rng.normal(size=(1, 500)) * 3
    diss, _ = aug.power_balance((q[0],), (p[0],), None)
    assert np.all(diss >= 0)
    # dH/dt along the vector field equals minus the dissipated power (conservative part in H)
    qd, pd = aug.rhs((q[0],), (p[0],), None)
    dq = aug.dH_dq((q[0],), (p[0],))
    dH = dq[0] * qd[0] + aug.velocity((q[0],), (p[0],))[0] * pd[0]
    np.testing.assert_allclose(dH, -diss, rtol=1e-10, atol=1e-10)


def test_noise_estimate():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 20, 2000)
    q = np.sin(t)[None, :, None] + rng.normal(0, 0.003, size=(3, 2000, 1))
    assert abs(estimate_noise(q)[0] - 0.003) < 0.0005


# --------------------------------------------------------------------------- bad input
def _ok() -> dict:
    return make_reality("PHAST/Pendulum-v0", [], n_traj=3, T=100, noise_std=0.01, seed=1)


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.pop("q"), "missing key 'q'"),
    (lambda d: d.pop("dt"), "time base"),
    (lambda d: d.__setitem__("q", np.where(np.arange(100)[None, :, None] == 50, np.nan, d["q"])), "NaN"),
    (lambda d: d.__setitem__("q", d["q"][:, :10]), "too short"),
    (lambda d: d.__setitem__("q", np.concatenate([d["q"], d["q"]], -1)), "n=2"),
    (lambda d: d.__setitem__("q", d["q"][..., 0][..., None, None]), "shape"),
    (lambda d: (d.pop("dt"), d.__setitem__("t", np.r_[np.arange(99) * 0.05, 4.9])), "not strictly increasing"),
    (lambda d: d.__setitem__("u", np.zeros((3, 50, 1))), "'u' must have shape"),
])
def test_bad_recordings_raise_clear_errors(mutate, match):
    d = _ok()
    mutate(d)
    with pytest.raises(ValueError, match=match):
        analyze("PHAST/Pendulum-v0", d)


def test_unknown_env_and_bad_kwargs():
    with pytest.raises(ValueError, match="unknown simulator"):
        analyze("PHAST/NoSuchThing-v0", _ok())
    with pytest.raises(ValueError, match="sim-kwargs"):
        analyze("PHAST/Pendulum-v0", _ok(), sim_kwargs={"lenght": 1.0})
    with pytest.raises(ValueError, match="not a port-Hamiltonian"):
        analyze("PHAST/PredatorPrey-v0", _ok())


def test_cli_bad_input_leaves_nothing(tmp_path, capsys):
    from phast_model.cli.mismatch import main

    d = _ok()
    d["q"][0, 3, 0] = np.nan
    np.savez(tmp_path / "bad.npz", **d)
    rc = main(["--sim", "PHAST/Pendulum-v0", "--recordings", str(tmp_path / "bad.npz"), "--out", str(tmp_path / "out"), "--quiet"])
    assert rc == 2
    assert "NaN" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npz"]
    rc = main(["--sim", "PHAST/Pendulum-v0", "--recordings", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "out")])
    assert rc == 2


def test_csv_recordings_roundtrip(tmp_path):
    d = _ok()
    q = d["q"]
    rows = ["traj,t,q0"] + [f"{k},{i * d['dt']:.6f},{q[k, i, 0]:.10f}" for k in range(q.shape[0]) for i in range(q.shape[1])]
    (tmp_path / "r.csv").write_text("\n".join(rows) + "\n")
    from phast_model.mismatch import load_raw

    raw, _ = load_raw(tmp_path / "r.csv")
    rec = validate(raw, 1, (0,))
    assert rec.q.shape == q.shape and abs(rec.dt - d["dt"]) < 1e-9
    np.testing.assert_allclose(np.sin(rec.q), np.sin(q), atol=1e-8)


def test_angle_offset_convention():
    d = _ok()
    shifted = dict(d, q=d["q"] - math.pi, angle_offset=math.pi)  # recorded with 0 upright, pi hanging
    a = validate(d, 1, (0,))
    b = validate(shifted, 1, (0,))
    np.testing.assert_allclose(np.sin(a.q), np.sin(b.q), atol=1e-12)


def test_unexplained_residual_is_located_when_no_term_fits():
    """A bias torque with only friction terms allowed: nothing passes, the residual is located as a potential force."""
    rec = make_reality("PHAST/DampedPendulum-v0", [Term("constant_force", 0, 0.4)], n_traj=10, T=250, noise_std=0.01, seed=8)
    rep = analyze("PHAST/DampedPendulum-v0", rec, terms=("viscous_damping", "coulomb_friction"))
    assert rep.missing_physics == []
    assert "Unexplained residual" in rep.summary
    assert rep.located and rep.located[0]["coordinate"] == 0 and rep.located[0]["component"] == "potential"
    times = math.sqrt(rep.details["chi2_per_dof"]["augmented"])  # the misfit left, in units of the noise
    assert times > 1.2 and f"Incomplete: the final model's residual on the training recordings is {times:.3g} times" in rep.summary


def test_stribeck_term_needs_its_velocity():
    with pytest.raises(ValueError, match="Stribeck velocity"):
        Term("stribeck_friction", 0, 0.1)
    assert "exp(-(qdot0/0.3)**2)" in Term("stribeck_friction", 0, 0.1, velocity=0.3).expression()


def test_stribeck_friction_found_by_shooting():
    """Noise-dominated regime (shooting selection): Coulomb plus Stribeck friction, v_s refined from the grid."""
    raw = make_reality("PHAST/DampedOscillator-v0", [Term("coulomb_friction", 0, 0.02), Term("stribeck_friction", 0, 0.04, 0.5)],
                       n_traj=24, T=400, noise_std=0.01, seed=1)
    rep = analyze("PHAST/DampedOscillator-v0", raw)
    found = {m["term"]: m for m in rep.missing_physics}
    assert set(found) == {"coulomb_friction", "stribeck_friction"}
    assert abs(found["coulomb_friction"]["coefficient"] - 0.02) / 0.02 < 0.3
    assert abs(found["stribeck_friction"]["coefficient"] - 0.04) / 0.04 < 0.3
    assert 0.5 / 1.3 < found["stribeck_friction"]["stribeck_velocity"] < 0.5 * 1.3
    assert "exp(-(qdot0/" in found["stribeck_friction"]["expression"]


def test_energy_check_measures_missing_dissipation():
    """measured / predicted energy loss is 1 for the true model and 1/0.8 when its friction is 80% of the truth."""
    from phast_model.mismatch.energy import energy_check

    truth = [Term("coulomb_friction", 0, 0.03), Term("quadratic_drag", 0, 0.005)]
    rec = validate(make_reality("PHAST/Pendulum-v0", truth, n_traj=6, T=600, noise_std=1e-3, seed=4, x0_scale=0.7), 1, (0,))
    base = make_env_system("PHAST/Pendulum-v0")
    exact = energy_check(AugmentedSystem(base, truth, 0.01), rec, 7)
    low = energy_check(AugmentedSystem(base, [Term(t.name, 0, 0.8 * t.coefficient) for t in truth], 0.01), rec, 7)
    assert abs(exact["measured_over_predicted"] - 1.0) < 0.01 and exact["ci95"][0] < 1.0 < exact["ci95"][1] + 0.005
    assert abs(low["measured_over_predicted"] - 1.25) < 0.015 and low["ci95"][0] > 1.2
    assert energy_check(base, rec, 7) is None  # the undamped model dissipates nothing: no ratio


def test_systematic_regime_finds_the_friction_law(tmp_path):
    """Forcing the model-error regime on encoder-grade recordings (the weak form needs resolved derivatives; at noise
    0.01 and dt 0.05 every law predicts the left-out curves equally badly and the shooting regime is the right one):
    the law is the concealed Coulomb friction (within 15%), the total friction force is passive, and the report has
    the friction section and the friction-curve plot."""
    data = make_reality("PHAST/Pendulum-v0", [Term("coulomb_friction", 0, 0.1)], n_traj=8, T=400, noise_std=1e-4, seed=3)
    rep = analyze("PHAST/Pendulum-v0", data, systematic_chi2=0.0)
    fr = rep.details["friction"]
    assert fr["used"]
    assert set(fr) >= {"used", "law", "passivity", "selection", "curve", "law_vs_curve", "armature"}
    assert [(t["term"], t["coordinate"]) for t in fr["law"]["terms"]] == [("coulomb_friction", 0)]
    assert abs(fr["law"]["terms"][0]["coefficient"] - 0.1) / 0.1 < 0.15
    assert fr["passivity"]["passive"]
    assert [m["term"] for m in rep.missing_physics] == ["coulomb_friction"]
    m = rep.missing_physics[0]
    assert abs(m["coefficient"] - 0.1) / 0.1 < 0.15 and m["ci95"][0] > 0
    assert rep.fit["augmented"]["rollout_rmse"] < 0.5 * rep.fit["calibrated"]["rollout_rmse"]
    out = rep.write(tmp_path / "rep")
    assert "## Friction from the training recordings" in (out / "report.md").read_text()
    assert (out / "friction_curve.png").stat().st_size > 0


def test_systematic_regime_report_sections(coulomb_data, tmp_path):
    """Whatever law is chosen, the forced regime reports its evidence (details.friction) and writes the curve plot."""
    rep = analyze("PHAST/Pendulum-v0", coulomb_data, systematic_chi2=0.0)
    fr = rep.details["friction"]
    assert fr["used"] and set(fr) >= {"law", "passivity", "selection", "curve", "law_vs_curve", "armature"}
    assert fr["passivity"]["passive"]
    assert fr["curve"]["bands"] and all(b["ci95"][0] <= b["force"] <= b["ci95"][1] for b in fr["curve"]["bands"])
    assert len(fr["selection"]) == 1 and fr["selection"][0]["candidates"]
    out = rep.write(tmp_path / "rep")
    assert "## Friction from the training recordings" in (out / "report.md").read_text()
    assert (out / "friction_curve.png").stat().st_size > 0


@pytest.mark.slow
@pytest.mark.parametrize("with_eccentricity", [False, True])
def test_encoder_grade_noise_friction_and_drag(with_eccentricity):
    """Encoder-grade noise (2e-5): Coulomb + quadratic drag (+ eccentricity) are found by the shooting selection, and
    forcing the model-error regime (weak-form law chosen by left-out friction curves) finds the same friction law."""
    terms = [Term("coulomb_friction", 0, 0.02), Term("quadratic_drag", 0, 0.002)]
    if with_eccentricity:
        terms.append(Term("sensor_eccentricity", 0, 0.01))
    d = make_reality("PHAST/DampedPendulum-v0", terms, n_traj=40, T=400, noise_std=2e-5, seed=0)
    want = {t.name for t in terms}
    for forced in (False, True):
        rep = analyze("PHAST/DampedPendulum-v0", d, **({"systematic_chi2": 0.0} if forced else {}))
        assert {m["term"] for m in rep.missing_physics} == want
        fr = rep.details["friction"]
        assert fr["used"] == forced
        if forced:
            assert sorted(t["term"] for t in fr["law"]["terms"]) == ["coulomb_friction", "quadratic_drag"]
            assert fr["passivity"]["passive"]
        for m in rep.missing_physics:
            true = next(t.coefficient for t in terms if t.name == m["term"])
            assert abs(m["coefficient"] - true) / true < 0.15


def test_rollout_window_cuts_heldout_into_consecutive_windows(coulomb_data):
    rep = analyze("PHAST/Pendulum-v0", coulomb_data, rollout_window=4.0)  # dt 0.05: 81-sample windows, 3 per 300-sample trajectory
    assert rep.fit["rollout_window_samples"] == 81
    assert rep.fit["rollout_n_windows"] == 4 * 3
    assert "consecutive windows" in rep.fit["rollout"]
    assert rep.fit["augmented"]["rollout_rmse"] < rep.fit["calibrated"]["rollout_rmse"]
    with pytest.raises(ValueError, match="rollout_window"):
        analyze("PHAST/Pendulum-v0", coulomb_data, rollout_window=0.1)


# --------------------------------------------------------------------------- held-out trajectories
@pytest.mark.parametrize("holdout, match", [
    ([3], "out of range"),
    ([-1], "out of range"),
    ([1, 1], "duplicates"),
    ([0, 1, 2], "all 3 trajectories"),
    ([1.5], "integers"),
    (["1"], "integers"),
    ([True], "integers"),
    ([], "empty"),
    ("12", "sequence"),
])
def test_holdout_trajectories_are_validated_before_any_work(holdout, match, monkeypatch):
    import phast_model.mismatch.analysis as analysis

    monkeypatch.setattr(analysis, "prepare", lambda *a, **k: pytest.fail("fitting started before validation"))
    with pytest.raises(ValueError, match=match):
        analyze("PHAST/Pendulum-v0", _ok(), holdout_trajectories=holdout)


def test_split_by_given_trajectories():
    from phast_model.identify.split import split

    rec = validate(make_reality("PHAST/Pendulum-v0", [], n_traj=4, T=60, noise_std=0.01, seed=1), 1, (0,))
    train, hold, on = split(rec, 0.9, [2, 0])
    np.testing.assert_array_equal(train.q, rec.q[[1, 3]])
    np.testing.assert_array_equal(hold.q, rec.q[[0, 2]])
    assert on == "held-out recordings (trajectories [0, 2])"


def test_holdout_trajectories_equal_to_the_fraction_split_give_the_same_report(coulomb_data, coulomb_report):
    rep = analyze("PHAST/Pendulum-v0", coulomb_data, holdout_trajectories=[8, 9, 10, 11])  # what holdout_fraction 0.3 holds out of 12
    assert rep.fit == coulomb_report.fit
    assert rep.missing_physics == coulomb_report.missing_physics


def test_cli_holdout_trajectories_and_out_fail_fast(tmp_path, capsys, monkeypatch):
    import phast_model.mismatch as mm
    from phast_model.cli.mismatch import main

    monkeypatch.setattr(mm, "analyze", lambda *a, **k: pytest.fail("analysis started"))
    np.savez(tmp_path / "rec.npz", **_ok())
    base = ["--sim", "PHAST/Pendulum-v0", "--recordings", str(tmp_path / "rec.npz"), "--quiet"]
    assert main(base + ["--out", str(tmp_path / "out"), "--holdout-trajectories", "1,x"]) == 2
    assert "'x' is not an integer" in capsys.readouterr().err
    assert main(base + ["--out", str(tmp_path / "rec.npz")]) == 2  # an existing file: refused before the analysis
    assert "not a directory" in capsys.readouterr().err
    assert main(base + ["--out", str(tmp_path)]) == 2  # a directory holding the user's recording
    assert "not a phast-mismatch report" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.npz"]


# --------------------------------------------------------------------------- writing reports
def test_write_refuses_what_it_did_not_write(coulomb_report, tmp_path):
    user = tmp_path / "mine"
    user.mkdir()
    (user / "recordings.npz").write_bytes(b"precious")
    with pytest.raises(ValueError, match="not a phast-mismatch report"):
        coulomb_report.write(user, plots=False)
    assert (user / "recordings.npz").read_bytes() == b"precious" and sorted(p.name for p in user.iterdir()) == ["recordings.npz"]
    f = tmp_path / "file.txt"
    f.write_text("keep")
    with pytest.raises(ValueError, match="not a directory"):
        coulomb_report.write(f, plots=False)
    assert f.read_text() == "keep"
    fake = tmp_path / "fake"  # a report.json without the marker
    fake.mkdir()
    (fake / "report.json").write_text('{"summary": "x"}')
    with pytest.raises(ValueError, match="not a phast-mismatch report"):
        coulomb_report.write(fake, plots=False)
    with pytest.raises(ValueError, match="not a directory"):  # the parent is a file
        coulomb_report.write(f / "sub", plots=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fake", "file.txt", "mine"]


def test_write_replaces_only_a_previous_report(coulomb_report, tmp_path):
    out = coulomb_report.write(tmp_path / "rep", plots=False)
    assert json.loads((out / "report.json").read_text())["tool"] == "phast-mismatch"
    assert sorted(p.name for p in out.iterdir()) == ["report.html", "report.json", "report.md"]
    coulomb_report.write(out, plots=False)  # a previous report: replaced
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rep"]
    (out / "notes.txt").write_text("mine")  # a user file inside: no longer only a report
    with pytest.raises(ValueError, match="not a phast-mismatch report"):
        coulomb_report.write(out, plots=False)
    assert (out / "notes.txt").read_text() == "mine"
    empty = tmp_path / "empty"
    empty.mkdir()
    assert (coulomb_report.write(empty, plots=False) / "report.md").exists()


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root writes anywhere")
def test_check_writable_read_only_parent(tmp_path):
    from phast_model.mismatch.report import check_writable

    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(ValueError, match="not writable"):
            check_writable(ro / "out")
    finally:
        ro.chmod(0o700)


def test_report_html_is_self_contained(coulomb_report, tmp_path):
    out = coulomb_report.write(tmp_path / "rep")
    page = (out / "report.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and page.count("<table>") >= 3
    assert page.count('src="data:image/png;base64,') == 3
    assert "http://" not in page and "https://" not in page and "|---|" not in page
    assert "<td>coulomb_friction</td>" in page


def test_markdown_to_html_subset():
    from phast_model.mismatch.report import markdown_to_html

    page = markdown_to_html("# T\n\nline one\nline `a<b`\n\n| x | y |\n|---|---|\n| 1 | - |\n")
    assert page == ("<h1>T</h1>\n<p>line one line <code>a&lt;b</code></p>\n<table>\n<thead><tr><th>x</th><th>y</th></tr></thead>\n"
                    "<tbody>\n<tr><td>1</td><td>-</td></tr>\n</tbody>\n</table>")


# --------------------------------------------------------------------------- candidates
def test_armature_candidate():
    """The inertia term (c added to M_ii) gets a candidate scaled to 5% of the rms of M_ii."""
    from phast_model.identify.simulators import load_simulator
    from phast_model.mismatch.fitting.problem import prepare
    from phast_model.mismatch.options import Options, Progress
    from phast_model.mismatch.selection.screening import candidates

    sim = load_simulator("PHAST/Pendulum-v0")
    sys0 = sim.build()
    rec = validate(make_reality("PHAST/Pendulum-v0", [], n_traj=3, T=100, noise_std=0.01, seed=1), 1, (0,))
    problem = prepare(sim, sys0, rec, Options(terms=("armature", "viscous_damping")), Progress())
    system = problem.nominal_family.build(np.zeros(0))
    (arm,) = [c for c in candidates(problem, system) if c.term == "armature"]
    M = float(np.asarray(sys0.mass_matrix((rec.q[..., 0],))[0][0]).mean())
    assert arm.coordinate == 0 and arm.must_be_positive and abs(arm.scale - 0.05 * M) < 1e-12 * M


@pytest.mark.parametrize("bad, msg", [(["--threshold", "-1"], "--threshold"), (["--threshold", "nan"], "--threshold"),
                                      (["--max-terms", "-3"], "--max-terms"), (["--shoot-window", "0"], "--shoot-window"),
                                      (["--smoothing-window", "1"], "--smoothing-window"),
                                      (["--rollout-window", "-2"], "--rollout-window")])
def test_cli_rejects_out_of_range_options_before_analysis(tmp_path, capsys, monkeypatch, bad, msg):
    import phast_model.mismatch as mm
    from phast_model.cli.mismatch import main

    monkeypatch.setattr(mm, "analyze", lambda *a, **k: pytest.fail("analysis started"))
    np.savez(tmp_path / "rec.npz", **_ok())
    assert main(["--sim", "PHAST/Pendulum-v0", "--recordings", str(tmp_path / "rec.npz"), "--out", str(tmp_path / "out"),
                 "--quiet", *bad]) == 2
    assert msg in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.npz"]


@pytest.mark.parametrize("name, content, match", [
    ("empty.npz", b"", "is empty"),
    ("noarrays.npz", None, "no arrays"),
    ("header.csv", "traj,t,q0\n", "header .* but no data rows"),
    ("short.csv", "traj,t,q0\n0,0,1\n0,0.1\n", "line 3 has 2 values, the header has 3 columns"),
    ("long.csv", "traj,t,q0\n0,0,1,5\n0,0.1,2\n", "line 2 has 4 values"),
    ("text.csv", "traj,t,q0\n0,0,1\n0,0.1,x\n", "line 3 has a non-numeric value 'x'"),
])
def test_unusable_recording_files_name_the_problem(tmp_path, name, content, match):
    from phast_model.mismatch import load_raw

    path = tmp_path / name
    if content is None:
        np.savez(path)
    elif isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    with pytest.raises(ValueError, match=match):
        load_raw(path)


# --------------------------------------------------------------------------- nothing invented
@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_pure_noise_is_not_described_and_nothing_is_named(seed):
    """White-noise 'recordings' against the pendulum: no term, no calibration, and the summary says the simulator does
    not describe them (it used to report cubic_stiffness in 3 of 4 seeds)."""
    q = np.random.default_rng(seed).normal(0.0, 0.5, (8, 200, 1))
    rep = analyze("PHAST/Pendulum-v0", {"q": q, "dt": 0.05})
    assert rep.missing_physics == [] and rep.located == []
    assert rep.details["explained_share"] < 0.5
    assert all(v.get("ci95") is None for v in rep.sim["calibrated"].values())
    assert "does not describe these recordings" in rep.summary


def test_real_system_is_described(coulomb_report):
    assert coulomb_report.details["explained_share"] > 0.9


def test_terms_that_do_not_improve_held_out_prediction_are_not_reported():
    from phast_model.mismatch.analysis import Described, _confirmed, _verdicts
    from phast_model.mismatch.evaluate import FitTable, ModelScore, RolloutSetup
    from phast_model.mismatch.rows import TermRow

    row = TermRow("cubic_stiffness", 0, "stiffness", 0.1, (0.05, 0.15), "-0.1*q0**3")
    setup = RolloutSetup(100, 4, 5.0, 10, "")
    fit = FitTable({"calibrated": ModelScore(0.1, 1.818), "augmented": ModelScore(0.1, 1.855)}, "held-out", setup)
    missing, unconfirmed = _confirmed([row], fit)
    assert missing == [] and unconfirmed == [row]
    assert "not reported as missing physics" in " ".join(_verdicts(Described(1.0), unconfirmed, fit))
    fit.models["augmented"] = ModelScore(0.1, 1.0)
    assert _confirmed([row], fit) == ([row], [])


def test_report_rows_write_the_report_json_keys_in_order():
    """The typed rows give report.json's objects as they have always been written (keys, order, nulls)."""
    from phast_model.mismatch.rows import Alternative, ParamRow, TermRow

    assert list(ParamRow(1.0, 1.1, (1.05, 1.15), 0.1, "same as b").to_dict()) == [
        "nominal", "fitted", "ci95", "relative_change", "equivalent_changes"]
    assert ParamRow.held(2, "known").to_dict() == {"nominal": 2, "fitted": 2, "ci95": None, "note": "known"}
    alt = Alternative(parameter="gamma", value=0.4, similarity=0.99, note="same effect")
    shooting = TermRow("stribeck_friction", 0, "dissipation", 0.04, (0.03, 0.05), "e", 0.5, (alt,), 0.5)
    assert list(shooting.to_dict()) == ["term", "coordinate", "component", "coefficient", "ci95", "stribeck_velocity",
                                        "expression", "explains", "alternatives"]
    assert shooting.to_dict()["alternatives"] == [{"parameter": "gamma", "value": 0.4, "similarity": 0.99, "note": "same effect"}]
    weak = TermRow("stribeck_friction", 0, "dissipation", 0.04, (0.03, 0.05), "e", None, (Alternative(law="x", note="n"),), 0.5,
                   evidence="weak form")
    assert list(weak.to_dict()) == ["term", "coordinate", "component", "coefficient", "ci95", "expression", "stribeck_velocity",
                                    "explains", "alternatives", "evidence"]
    assert weak.to_dict()["explains"] is None and weak.to_dict()["alternatives"] == [{"law": "x", "note": "n"}]


def test_heldout_initial_state_refitted_where_it_is_not_determined():
    """A pendulum falling from near its upright: the state fitted to the first 50 samples leaves an open-loop spread
    far above the noise, so it is fitted to more samples (up to half the recording); a small swing keeps 50."""
    from phast_model.identify.recordings import Recordings
    from phast_model.identify.shooting import simulate_qv, substeps_for
    from phast_model.mismatch.evaluate import _initial_states

    system = make_env_system("PHAST/Pendulum-v0")
    q0, v0 = np.array([[0.5], [math.pi - 0.05]]), np.zeros((2, 1))
    q = simulate_qv(system, q0, v0, 399, None, 0.01, substeps_for(system, 0.01))
    q = q + np.random.default_rng(0).normal(scale=0.002, size=q.shape)
    rec = Recordings(q=q, dt=0.01, angle_dims=(0,))
    X, Ks = _initial_states({"true": system}, rec, 50, np.array([0.002]), np.array([1.0, 1.0]), q, np.zeros_like(q))
    assert Ks[0] == 50 and Ks[1] in (100, 200)
    assert np.allclose(X["true"][:, 0], q0[:, 0], atol=0.01)


def test_a_system_listed_under_two_names_is_scored_once_with_the_same_numbers(coulomb_data, monkeypatch):
    from phast_model.identify.recordings import validate as validate_recordings
    from phast_model.mismatch import evaluate as ev

    system = make_env_system("PHAST/Pendulum-v0")
    rec = validate_recordings(coulomb_data, 1, (0,)).subset(np.arange(3))
    args = (np.full(1, 0.01), np.ones(2), 20, 7, np.ones(1))
    calls: list[list[str]] = []
    real = ev._evaluate
    monkeypatch.setattr(ev, "_evaluate", lambda models, *a: calls.append(list(models)) or real(models, *a))
    twice, rolls = ev.evaluate_models({"nominal": system, "calibrated": system}, rec, *args)
    apart, _ = ev.evaluate_models({"nominal": system, "calibrated": make_env_system("PHAST/Pendulum-v0")}, rec, *args)
    assert calls == [["nominal"], ["nominal", "calibrated"]]
    assert twice == apart and twice["calibrated"] == twice["nominal"]
    assert list(twice) == list(rolls) == ["nominal", "calibrated"]


def test_linear_reach_is_what_every_column_at_once_leaves():
    """The chi^2 the whole vocabulary leaves to first order: none for a residual in the columns' span, all of it for
    one orthogonal to them; a column with a non-finite entry is left out."""
    from phast_model.mismatch.selection.forward import linear_reach

    rng = np.random.default_rng(0)
    cols = rng.normal(size=(50, 3))
    r = cols @ np.array([1.0, -2.0, 0.5])
    assert linear_reach(r, cols) == pytest.approx(0.0, abs=1e-18)
    q, _ = np.linalg.qr(np.column_stack([cols, rng.normal(size=50)]))
    ortho = q[:, 3] * 7.0
    assert linear_reach(ortho, cols) == pytest.approx(49.0)
    bad = np.column_stack([cols, np.full(50, np.nan)])
    assert linear_reach(r + ortho, bad) == pytest.approx(49.0)
