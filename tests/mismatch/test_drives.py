"""A motor-driven model file whose CAD leaves out its drives (rotor inertia, gear friction) still describes the
recordings: the weak form's drive share (phast_model.mismatch.friction.systematic.drive_share)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

pytest.importorskip("mujoco")

from phast_model.bench import mjcf_cases as mc  # noqa: E402
from phast_model.identify.recordings import validate  # noqa: E402
from phast_model.identify.simulators import load_simulator  # noqa: E402
from phast_model.mismatch.analysis import Described  # noqa: E402
from phast_model.mismatch.fitting.problem import prepare  # noqa: E402
from phast_model.mismatch.friction.systematic import drive_share  # noqa: E402
from phast_model.mismatch.options import Options, Progress  # noqa: E402


def _problem(q: np.ndarray, rec: dict, path: str):
    sim = load_simulator(path)
    sys0 = sim.build()
    data = validate({"q": q, "u": rec["u"], "dt": rec["dt"]}, sys0.n, sys0.angle_dims, actuated_dofs=sys0.actuated_dofs)
    return prepare(sim, sys0, data, Options(), Progress(False))


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    case = mc.cases()["arm3_drives"]
    real = mc.write_real(case, mc.hidden_effects(case, 0), tmp_path_factory.mktemp("real"))
    return mc.record(case, real, 6, 300, 0), str(mc.nominal_path(case))


def test_the_drives_account_for_the_force_the_cad_model_leaves(drives):
    rec, path = drives
    assert drive_share(_problem(rec["q"], rec, path)) > 0.9


def test_white_noise_with_the_same_commands_is_not_a_drive(drives):
    rec, path = drives
    q = np.random.default_rng(0).normal(0.0, 0.5, rec["q"].shape)
    assert drive_share(_problem(q, rec, path)) < 0.0


def test_described_up_to_its_drives():
    assert Described(0.9).ok and Described(0.9).to_dict() == {"explained_share": 0.9}
    assert Described(0.1, 0.95).ok and Described(0.1, 0.95).to_dict() == {"explained_share": 0.1, "drive_share": 0.95}
    assert not Described(0.1, 0.2).ok and not Described(0.1).ok
    assert Described(0.1, 0.95).drives_first and not Described(0.9).drives_first
    assert Described(0.9, None, 1.1).drives_first and not Described(0.9, None, 6.0).drives_first
    # drives that remove 90% of the file's misfit (143 -> 15.3): drives first, the body values after them
    near = Described(0.6, None, 15.3, 143.0)
    assert near.ok and near.drives_first and near.drives_near and not near.drives_follow
    assert not Described(0.6, None, 81.8, 94.1).drives_near  # a CAD model's body values: the drives remove 13%
    assert not Described(0.6, None, 9.4e3, 1.1e5).drives_near  # far from following (a real arm's model error)
    assert Described(0.9, None, 1.1).to_dict() == {"explained_share": 0.9, "drives_alone_chi2_per_dof": 1.1}


def _trial(rec: dict, path: str):
    from phast_model.mismatch.calibrate import nominal_sample
    from phast_model.mismatch.friction.systematic import drives_trial
    from phast_model.mismatch.written import in_mujoco

    problem = _problem(rec["q"], rec, path)
    shooter, fit = nominal_sample(problem, in_mujoco(problem.nominal_family.build(np.zeros(0))))
    return drives_trial(problem, shooter, fit.X)


def test_the_drives_alone_follow_a_cad_model_without_its_drives(drives):
    """Weak form, then a shooting refit in MuJoCo: rotor inertia on every joint (the yaw's too), the shoulder's and
    elbow's frictionloss and the yaw's damping as MuJoCo means them, and nothing the data do not back."""
    rec, path = drives
    trial = _trial(rec, path)
    assert trial is not None and trial.fit.chi2_red < 1.5
    found = {it.label: float(v) for it, v in zip(trial.items, trial.values)}
    truth = {"armature[0]": 0.004, "armature[1]": 0.012, "armature[2]": 0.006, "coulomb_friction[1]": 0.08,
             "coulomb_friction[2]": 0.04, "viscous_damping[0]": 0.03}
    assert set(found) == set(truth), found
    for k, v in truth.items():
        assert found[k] == pytest.approx(v, rel=0.1), k
    for it, ci in zip(trial.items, trial.ci95):  # every kept term's interval excludes zero
        assert ci[0] > 0, it.label


@pytest.mark.slow
def test_body_values_off_are_not_drives(tmp_path):
    """The same arm with every body value 3-8% off and no drive: the drives alone do not follow it."""
    from phast_model.mismatch.analysis import DRIVES_CHI2

    case = mc.cases()["arm3_cad"]
    real = mc.write_real(case, mc.hidden_effects(case, 0), tmp_path)
    trial = _trial(mc.record(case, real, 6, 300, 0), str(mc.nominal_path(case)))
    assert trial is None or trial.fit.chi2_red > DRIVES_CHI2


def test_the_weak_form_parameter_check_says_where_it_is(drives):
    """The backward elimination reports its columns and rounds (every 20 s; here every one) and decides as without a
    listener."""
    from phast_model.identify.shooting import Heartbeat
    from phast_model.mismatch.friction.weakid import WeakModel, check_parameters

    rec, path = drives
    problem = _problem(rec["q"], rec, path)
    params = ["upper_arm.mass", "upper_arm.inertia_y", "forearm.mass", "forearm.inertia_x"]
    model = WeakModel(problem.sim, {}, params, [], [0, 1, 2], problem.eps, 0.0, problem.smoothing_window)
    law = [(nm, i) for i in range(3) for nm in ("viscous_damping", "coulomb_friction")]
    train = problem.train.resampled()
    quiet = check_parameters(model, train, law)
    said: list[str] = []
    loud = check_parameters(model, train, law, Heartbeat(said.append, every=0.0))
    assert loud.kept == quiet.kept and loud.table == quiet.table
    rounds = [m for m in said if "weak-form parameter check" in m and "parameters left" in m]
    columns = [m for m in said if "weak form: column" in m and "s left" in m]
    assert len(rounds) == len(params) - len(quiet.kept) and len(columns) == len(params) - 1
    assert len(said) == len(rounds) + len(columns)


def test_an_input_held_over_each_interval_is_not_read_half_a_sample_early():
    """Under a stiff PD controller a half-sample shift of u is a damping of Kp dt / 2: the weak form takes the mean of
    the two intervals that meet at a sample, so that a frictionless pendulum shows no friction."""
    from phast_gym.integrate import step
    from phast_gym.registry import make_env_system
    from phast_gym.systems.base import NUMPY
    from phast_model.identify.recordings import Recordings
    from phast_model.mismatch.friction import fit_law

    system = make_env_system("PHAST/Pendulum-v0")
    rng = np.random.default_rng(0)
    dt, T, kp, kd = 0.01, 600, 40.0, 2.0
    ref = 0.4 * np.sin(np.outer(rng.uniform(1.0, 3.0, 6), np.arange(T) * dt))
    q, p = [rng.uniform(-0.5, 0.5, 6)], [np.zeros(6)]
    qs, us = [q[0]], []
    for k in range(T - 1):  # the controller's torque held over each interval
        v = system.velocity(q, p, NUMPY)[0]
        us.append(-kp * (q[0] - ref[:, k]) - kd * v)
        q, p = step(system, q, p, [us[-1]], NUMPY, dt=dt, substeps=10)
        qs.append(q[0])
    rec = Recordings(np.stack(qs, 1)[..., None], dt, np.stack(us, 1)[..., None], (0,))
    law = fit_law(system, rec, ["viscous_damping"])
    assert abs(law.terms[0].coefficient) < 0.05 * kp * dt / 2


def test_a_refit_that_leaves_model_error_hands_on_only_positive_terms():
    """A refit with chi^2/dof far above the noise (a real arm's model error) is not at the noise, and the terms it
    hands to a later refit are the physical ones (a rotor inertia or friction fitted below zero is left out)."""
    from phast_model.identify.shooting import ShootFit
    from phast_model.mismatch.friction.engine_refit import EngineRefit, Item

    fit = ShootFit(np.zeros((2, 2)), np.array([1.0, -0.5]), np.full((2, 10), 3.0), np.zeros((2, 10, 2)),
                   np.zeros((2, 10, 2)), 180.0, 20, 1)
    items = [Item("inertia", "armature", 0, start=0.1, scale=0.1),
             Item("law", "coulomb_friction", 1, start=0.2, scale=0.2)]
    refit = EngineRefit(items, fit, np.array([0.1, -0.1]), np.zeros((2, 2)), 1.96, 200.0, [])
    assert not refit.at_noise  # 180 / (20 - 4 - 2) = 12.9
    assert [(t.name, t.coordinate, t.coefficient) for t in refit.terms()] == [("armature", 0, 0.1)]
    assert [it.value(g) for it, g in zip(items, fit.g)] == pytest.approx([0.1, -0.1])
    assert items[0].g0 == pytest.approx(1.0) and items[1].label == "coulomb_friction[1]"


def test_after_the_drives_only_body_values_that_cannot_stand_in_for_them_are_fitted(drives):
    """turret.inertia_z adds to M_00 exactly what a rotor inertia on the yaw joint adds, and the turret's mass moves
    nothing: neither is fitted after the drives; the links' masses (gravity) are."""
    from phast_model.mismatch.friction.weakid import WeakModel, beyond_drives, identify

    rec, path = drives
    problem = _problem(rec["q"], rec, path)
    law = [(nm, i) for i in range(3) for nm in ("viscous_damping", "coulomb_friction")]
    train = problem.train.resampled()
    params = ["turret.inertia_z", "upper_arm.mass", "forearm.mass"]
    model = WeakModel(problem.sim, {}, params, [], [0, 1, 2], problem.eps, 0.0, problem.smoothing_window)
    assert "armature:0" in identify(model, train, law).no_signal  # fitted freely, the body value takes its place
    assert beyond_drives(model, train, law) == ["upper_arm.mass", "forearm.mass"]


def test_body_values_are_told_from_joint_and_gear_values():
    from phast_gym.systems.mjcf import is_body_value

    assert all(is_body_value(k) for k in ("link.mass", "upper_arm_link.ipos_z", "a.b.inertia_x"))
    assert not any(is_body_value(k) for k in ("elbow.armature", "j1.damping", "m1.gear", "gravity", "mass"))


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), folds=st.integers(2, 6), p=st.integers(1, 5))
def test_left_out_fits_from_fold_grams_equal_the_direct_ones(seed: int, folds: int, p: int) -> None:
    """The parameter check's leave-one-fold-out residuals from per-fold normal equations are those of refitting the
    design without each fold."""
    from phast_model.mismatch.friction.weakid import _FoldGrams

    rng = np.random.default_rng(seed)
    X = rng.normal(size=(40 * folds, p)) * rng.uniform(0.01, 100.0, size=p)
    y = X @ rng.normal(size=p) + rng.normal(size=40 * folds)
    labels = np.repeat(np.arange(folds), 40)
    cols = list(range(p))
    direct = []
    for f in range(folds):
        te = labels == f
        c = np.linalg.lstsq(X[~te], y[~te], rcond=None)[0]
        direct.append(np.sqrt(np.mean((y[te] - X[te] @ c) ** 2)))
    np.testing.assert_allclose(_FoldGrams.of(X, y, labels).left_out_rms(cols), direct, rtol=1e-7)


def test_a_refitted_term_at_zero_or_below_leaves_the_answer():
    """MuJoCo simulates a negative friction or inertia at zero: such a term is absent from the model the refit
    describes, so it leaves the answer (and its label joins the dropped), the other values as they were."""
    from phast_model.identify.shooting import ShootFit
    from phast_model.mismatch.friction.engine_refit import Item, _absent_at_zero

    rng = np.random.default_rng(0)
    JX, Jg = rng.normal(size=(4, 6, 2)), rng.normal(size=(4, 6, 3))
    Jg[..., 0] = 0.0  # clamped at zero: no effect
    fit = ShootFit(np.zeros((4, 2)), np.array([-0.5, 0.2, 0.0]), np.zeros((4, 6)), JX, Jg, 0.0, 24, 3)
    items = [Item("law", "viscous_damping", 3), Item("inertia", "armature", 1, scale=0.01),
             Item("param", "link2.mass", start=1.0, nominal=1.0)]
    fit2, kept, dropped = _absent_at_zero(fit, items, ["link2.ipos_y"])
    assert [it.label for it in kept] == ["armature[1]", "link2.mass"]
    assert dropped == ["link2.ipos_y", "viscous_damping[3]"]
    np.testing.assert_allclose(fit2.g, [0.2, 0.0], atol=1e-12)


def test_the_summary_names_the_values_the_recordings_decide_and_counts_the_priors():
    """A body value refitted within the file's prior that the recordings hardly inform is not a calibration to
    announce: the summary counts it and the table says how much of it is the data's."""
    from types import SimpleNamespace

    from phast_model.mismatch.report.document import summary_text
    from phast_model.mismatch.rows import ParamRow

    rows = {"link3.mass": ParamRow(0.8, 0.84, (0.82, 0.86), 0.05, data_share=0.9),
            "link1.ipos_y": ParamRow(0.005, 0.00501, (0.0032, 0.0078), 0.002, data_share=0.1),
            "gear": ParamRow(1.0, 0.85, (0.84, 0.86), -0.15)}
    fit = SimpleNamespace(rmse=lambda name: 0.01, evaluated_on="held-out recordings", energy_check=None)
    text = summary_text("arm.xml", rows, [], [], fit, 1.0, 1.0, np.full(2, 0.002))  # type: ignore[arg-type]
    assert "link3.mass 0.8 -> 0.84" in text and "gear 1 -> 0.85" in text and "link1.ipos_y" not in text
    assert "1 more value(s) refitted within the file's prior" in text
    held = ParamRow(0.9, 0.901, (0.89, 0.91), 0.001, data_share=0.95)  # decided by the data, and at the file's value
    assert not held.from_data and held.changed
    assert rows["link1.ipos_y"].to_dict()["data_share"] == 0.1 and "data_share" not in rows["gear"].to_dict()
