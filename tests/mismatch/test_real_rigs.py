"""The mismatch tool on rig-like recordings: a driven two-motor arm with joint friction and armature, jittered
logger times, a user's rig loaded from a file, and bad input through the CLI (synthetic; slow cases marked)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from phast_gym.registry import make_env_system
from phast_model.cli.mismatch import main as cli_main
from phast_model.identify.shooting import simulate_qv
from phast_model.identify.simulators import load_simulator
from phast_model.mismatch import analyze
from phast_model.mismatch.vocabulary.terms import AugmentedSystem, Term
from tests import ROOT


def _jittered_steps(rng: np.random.Generator, n: int, T: int, dt: float) -> np.ndarray:
    """(n, T-1) sampling steps in 0.6-1.8 dt, rescaled so that their median is dt (the logger's nominal rate)."""
    steps = dt * rng.uniform(0.6, 1.8, size=(n, T - 1))
    return steps * (dt / np.median(steps))


def _record(true: AugmentedSystem, q0: np.ndarray, v0: np.ndarray, steps: np.ndarray, u: np.ndarray | None,
            h: float) -> np.ndarray:
    """q at the sample times of ``steps`` (RK4 substeps no longer than ``h``: the nearly sharp Coulomb law needs them)."""
    sub = np.full(steps.shape[1], int(np.ceil(steps.max() / h)))
    return simulate_qv(true, q0, v0, steps.shape[1], u, steps, sub)


# --------------------------------------------------------------------------- 1. a driven two-motor arm
#: a real two-motor arm: relative joint angles, compound links
ARM = {"coordinates": "relative", "mass1": 0.6, "mass2": 0.55, "length1": 0.2, "length2": 0.3,
       "com1": 0.2, "com2": 0.32, "inertia1": 0.027, "inertia2": 0.054}
ARM_COULOMB = (0.1, 0.1)  # N m at each joint
ARM_ARMATURE = (0.004, 0.004)  # kg m^2 at each joint
#: the vocabulary of a motor-driven joint: friction laws and the rotor's reflected inertia
JOINT_TERMS = ("viscous_damping", "coulomb_friction", "quadratic_drag", "armature")


def arm_recordings(n_traj: int, T: int, dt: float, seed: int = 0, jitter: bool = False, noise_std: float = 2e-4) -> dict:
    """Recordings of the arm with concealed joint Coulomb friction and armature, driven on both joints by a smooth
    multi-sine torque (4 tones per joint in 0.3-2.5 Hz, clipped to 1 N m, held over each sample interval)."""
    rng = np.random.default_rng(seed)
    base = make_env_system("PHAST/DoublePendulum-v0", **ARM)
    terms = [Term("coulomb_friction", i, ARM_COULOMB[i]) for i in range(2)] + [Term("armature", i, ARM_ARMATURE[i]) for i in range(2)]
    true = AugmentedSystem(base, terms, coulomb_eps=2e-3)
    steps = _jittered_steps(rng, n_traj, T, dt) if jitter else np.full((n_traj, T - 1), dt)
    t = np.concatenate([np.zeros((n_traj, 1)), np.cumsum(steps, 1)], 1)
    f = rng.uniform(0.3, 2.5, size=(n_traj, 4, 2))
    ph = rng.uniform(0, 2 * np.pi, size=(n_traj, 4, 2))
    a = rng.uniform(0.15, 0.3, size=(n_traj, 4, 2))
    u = np.sum(a[:, :, None, :] * np.sin(2 * np.pi * f[:, :, None, :] * t[:, None, :-1, None] + ph[:, :, None, :]), axis=1)
    u = np.clip(u, -1.0, 1.0)
    q0 = rng.uniform(-0.5, 0.5, size=(n_traj, 2))
    v0 = rng.normal(0.0, 0.5, size=(n_traj, 2))
    q = _record(true, q0, v0, steps, u, 2.5e-4)
    q = q + rng.normal(0.0, noise_std, q.shape)
    out = {"q": q, "u": u}
    if jitter:
        out["t"] = t + 5.0  # absolute logger times
    else:
        out["dt"] = dt
    return out


def _check_arm(rep, tol: float = 0.3) -> None:
    """Coulomb friction and armature within ``tol`` of the truth at both joints; the held-out rollout improves."""
    found = {(m["term"], m["coordinate"]): m for m in rep.missing_physics}
    for i in range(2):
        for name, truth in (("coulomb_friction", ARM_COULOMB[i]), ("armature", ARM_ARMATURE[i])):
            assert (name, i) in found, (name, i, sorted(found), rep.details["friction"].get("armature"))
            c = found[(name, i)]["coefficient"]
            assert abs(c - truth) / truth < tol, (name, i, c, truth)
    assert rep.fit["augmented"]["rollout_rmse"] < 0.5 * rep.fit["calibrated"]["rollout_rmse"], rep.fit
    assert rep.fit["augmented"]["rollout_rmse"] < 0.5 * rep.fit["nominal"]["rollout_rmse"], rep.fit
    fr = rep.details["friction"]
    assert not fr["used"] or fr["passivity"]["passive"]


@pytest.mark.parametrize("jitter", [False, True], ids=["uniform", "jittered"])
def test_two_motor_arm_weak_form_identification(jitter):
    """Fast check of the systematic regime's core on the arm: the weak form started at the nominal kwargs, with the
    masses and gravity free, recovers Coulomb friction and armature within 30% at both joints."""
    from phast_model.identify.recordings import validate
    from phast_model.mismatch.friction.weakid import WeakModel, identify

    rec = validate(arm_recordings(4, 500, 0.004, seed=2, jitter=jitter), 2, (0, 1)).resampled()
    model = WeakModel(load_simulator("PHAST/DoublePendulum-v0", ARM), {}, ["mass1", "mass2", "gravity"], [], [0, 1], 0.01, 0.0, 27)
    fit = identify(model, rec, [(nm, i) for i in range(2) for nm in ("viscous_damping", "coulomb_friction")])
    law = {(t.term, t.coordinate): t for t in fit.law.terms}
    for i in range(2):
        c = law[("coulomb_friction", i)]
        assert abs(c.coefficient - ARM_COULOMB[i]) / ARM_COULOMB[i] < 0.3 and c.excludes_zero, (i, c)
        assert not law[("viscous_damping", i)].ci95[0] > 0.01  # no viscous friction was hidden
        a = fit.armature[i]
        assert a.coordinate == i and abs(a.coefficient - ARM_ARMATURE[i]) / ARM_ARMATURE[i] < 0.3 and a.excludes_zero, (i, a)
    for k, true in (("mass1", 0.6), ("mass2", 0.55), ("gravity", 9.81)):
        assert abs(fit.kwargs[k] - true) / true < 0.1, (k, fit.kwargs[k])


@pytest.mark.slow
@pytest.mark.parametrize("jitter", [False, True], ids=["uniform", "jittered"])
def test_two_motor_arm_friction_and_armature_joint_vocabulary(jitter):
    """Arm (5 x 2 s at 5 ms) through analyze, the vocabulary of a motor joint: Coulomb and armature within 30% at both
    joints, held-out rollout at least halved (~1 min each)."""
    d = arm_recordings(5, 400, 0.005, seed=1, jitter=jitter)
    rep = analyze("PHAST/DoublePendulum-v0", d, sim_kwargs=ARM, terms=JOINT_TERMS)
    _check_arm(rep)


@pytest.mark.slow
@pytest.mark.parametrize("jitter", [False, True], ids=["uniform", "jittered"])
def test_two_motor_arm_friction_and_armature_full_vocabulary(jitter):
    """A realistic rig case: 6 x 3 s at 4 ms, the whole vocabulary, only the nominal (frictionless, no armature) kwargs.
    The shooting path alone ends at chi^2/dof 4 with sensor gains of 0.94 and masses bent 15% standing in for the
    rotor inertia; the weak-form regime (chi^2/dof > 3) recovers Coulomb and armature at both joints (~2.5 min each)."""
    d = arm_recordings(6, 750, 0.004, seed=0, jitter=jitter)
    rep = analyze("PHAST/DoublePendulum-v0", d, sim_kwargs=ARM)
    _check_arm(rep)


# --------------------------------------------------------------------------- 2. jittered sample times through analyze
def _pendulum_jittered(n_traj: int = 12, T: int = 300, seed: int = 3, coulomb: float = 0.1, noise_std: float = 0.01) -> dict:
    rng = np.random.default_rng(seed)
    base = make_env_system("PHAST/Pendulum-v0")
    true = AugmentedSystem(base, [Term("coulomb_friction", 0, coulomb)], coulomb_eps=1e-3)
    steps = _jittered_steps(rng, n_traj, T, base.dt)
    x0 = base.sample_initial(rng, n_traj)
    v0 = np.asarray(base.velocity((x0[:, 0],), (x0[:, 1],))[0])[:, None]
    q = _record(true, x0[:, :1], v0, steps, None, 2e-3)
    t = 3.0 + np.concatenate([np.zeros((n_traj, 1)), np.cumsum(steps, 1)], 1)
    return {"q": q + rng.normal(0.0, noise_std, q.shape), "t": t, "dt": base.dt}


@pytest.fixture(scope="module")
def pendulum_jittered() -> dict:
    return _pendulum_jittered()


@pytest.fixture(scope="module")
def jittered_report(pendulum_jittered):
    return analyze("PHAST/Pendulum-v0", pendulum_jittered)


def test_jittered_times_find_coulomb_friction(jittered_report):
    rep = jittered_report
    assert [(m["term"], m["coordinate"]) for m in rep.missing_physics] == [("coulomb_friction", 0)]
    m = rep.missing_physics[0]
    assert abs(m["coefficient"] - 0.1) / 0.1 < 0.15 and m["ci95"][0] < 0.1 < m["ci95"][1] + 0.01
    assert rep.details["chi2_per_dof"]["augmented"] < 1.5  # fits to the noise at the recorded times
    assert rep.fit["augmented"]["rollout_rmse"] < 0.5 * rep.fit["calibrated"]["rollout_rmse"]


def test_jittered_times_replaced_by_a_uniform_grid_is_worse(pendulum_jittered, jittered_report):
    """Control: the same q with its times thrown away (pretending uniform sampling at the median step)."""
    good = jittered_report
    bad = analyze("PHAST/Pendulum-v0", {"q": pendulum_jittered["q"], "dt": pendulum_jittered["dt"]})
    assert bad.details["chi2_per_dof"]["augmented"] > 5 * good.details["chi2_per_dof"]["augmented"]
    right = [m for m in bad.missing_physics if m["term"] == "coulomb_friction" and abs(m["coefficient"] - 0.1) / 0.1 < 0.15]
    assert not right or bad.fit["augmented"]["rollout_rmse"] > 2 * good.fit["augmented"]["rollout_rmse"]


# --------------------------------------------------------------------------- 3. a user's rig from a file
USER_RIG = '''
import math

import numpy as np

from phast_gym.systems import NUMPY, Param, System, const_like


class MyRig(System):
    """A pendulum on a torsion spring with viscous bearing friction (the user's nominal model)."""

    name = "my_rig"
    n = 1
    angle_dims = (0,)
    dt = 0.01
    coordinate_names = ("theta",)
    PARAMS = {
        "mass": Param(0.5, "bob mass [kg]"),
        "length": Param(0.3, "pivot to centre of mass [m]"),
        "inertia": Param(0.05, "moment of inertia about the pivot [kg m^2]"),
        "stiffness": Param(0.8, "torsion spring [N m / rad]", "nonnegative"),
        "friction": Param(0.01, "viscous bearing friction [N m s / rad]", "nonnegative"),
        "gravity": Param(9.81, "gravitational acceleration [m/s^2]"),
    }

    def _finalize(self):
        if self.stiffness > 100.0:
            raise ValueError(f"stiffness={self.stiffness} is beyond the spring's rating")

    def potential(self, q, xp=NUMPY):
        return self.mass * self.gravity * self.length * (1.0 - xp.cos(q[0])) + 0.5 * self.stiffness * q[0] ** 2

    def grad_potential(self, q, xp=NUMPY):
        return (self.mass * self.gravity * self.length * xp.sin(q[0]) + self.stiffness * q[0],)

    def mass_matrix(self, q, xp=NUMPY):
        return ((const_like(q[0], self.inertia),),)

    def velocity(self, q, p, xp=NUMPY):
        return (p[0] / self.inertia,)

    def damping(self, q, xp=NUMPY):
        return (const_like(q[0], self.friction),)

    def sample_initial(self, rng, size):
        theta = rng.uniform(-math.pi / 2, math.pi / 2, size)
        p = self.inertia * rng.normal(0.0, 2.0, size)
        return np.stack([theta, p], axis=1)


class NotARig:
    """Not a System."""
'''


@pytest.fixture(scope="module")
def user_rig(tmp_path_factory) -> tuple[Path, Path]:
    """The rig file and recordings (.npz) of that rig with a hidden Coulomb friction of 0.03 N m."""
    d = tmp_path_factory.mktemp("user_rig")
    rig = d / "rig.py"
    rig.write_text(USER_RIG)
    system = load_simulator(f"{rig}:MyRig").build()
    rng = np.random.default_rng(4)
    true = AugmentedSystem(system, [Term("coulomb_friction", 0, 0.03)], coulomb_eps=1e-3)
    n_traj, T = 10, 300
    x0 = system.sample_initial(rng, n_traj)
    q0, v0 = x0[:, :1], x0[:, 1:] / system.inertia
    q = _record(true, q0, v0, np.full((n_traj, T - 1), system.dt), None, 5e-4)
    np.savez(d / "rec.npz", q=q + rng.normal(0.0, 0.003, q.shape), dt=system.dt)
    return rig, d / "rec.npz"


def test_user_rig_file_through_analyze(user_rig):
    rig, rec = user_rig
    rep = analyze(f"{rig}:MyRig", str(rec))
    assert rep.sim["env_id"] == f"{rig}:MyRig"
    assert [(m["term"], m["coordinate"]) for m in rep.missing_physics] == [("coulomb_friction", 0)]
    assert abs(rep.missing_physics[0]["coefficient"] - 0.03) / 0.03 < 0.15
    assert rep.fit["augmented"]["rollout_rmse"] < 0.5 * rep.fit["calibrated"]["rollout_rmse"]


def test_user_rig_file_through_the_cli(user_rig, tmp_path):
    rig, rec = user_rig
    out = tmp_path / "report"
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""), OMP_NUM_THREADS="1")
    res = subprocess.run([sys.executable, "-m", "phast_model.cli.mismatch", "--sim", f"{rig}:MyRig", "--recordings", str(rec),
                          "--out", str(out), "--quiet", "--no-plots"], capture_output=True, text=True, env=env, cwd=tmp_path,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    assert "coulomb_friction on coordinate 0" in res.stdout
    import json

    report = json.loads((out / "report.json").read_text())
    assert [m["term"] for m in report["missing_physics"]] == ["coulomb_friction"]
    assert "coulomb_friction" in (out / "report.md").read_text()


# --------------------------------------------------------------------------- 4. bad input through the CLI
def _pendulum_npz(path: Path, **change) -> Path:
    rng = np.random.default_rng(0)
    T = 100
    t = np.arange(T) * 0.05
    q = np.sin(2.0 * t)[None, :, None] * np.array([1.0, 0.8, 0.6])[:, None, None] + rng.normal(0, 0.01, (3, T, 1))
    d = {"q": q, "t": np.broadcast_to(t, (3, T)).copy()}
    d.update(change)
    np.savez(path, **{k: v for k, v in d.items() if v is not None})
    return path


def _bad_t_nonincreasing(t: np.ndarray) -> np.ndarray:
    t = t.copy()
    t[1, 40] = t[1, 39]
    return t


def _bad_t_nan(t: np.ndarray) -> np.ndarray:
    t = t.copy()
    t[2, 10] = np.nan
    return t


BAD_CLI = [
    ("nonincreasing_t", "PHAST/Pendulum-v0", None, lambda d: {"t": _bad_t_nonincreasing(d["t"])}, None,
     r"t is not strictly increasing at trajectory 1, index 39"),
    ("nan_t", "PHAST/Pendulum-v0", None, lambda d: {"t": _bad_t_nan(d["t"])}, None,
     r"'t' contains NaN/inf \(first at trajectory 2, index 10\)"),
    ("not_a_system", "{rig}:NotARig", None, None, None, "is not a phast_gym.systems.System subclass"),
    ("unknown_kwarg", "{rig}:MyRig", '{"stifness": 1.0}', None, None, r"bad --sim-kwargs: .*unknown parameter\(s\) \['stifness'\]"),
    ("constructor_raises", "{rig}:MyRig", '{"stiffness": 500.0}', None, None, r"bad --sim-kwargs: .*beyond the spring's rating"),
    ("kwargs_not_json", "{rig}:MyRig", "{stiffness: 1}", None, None, "--sim-kwargs is not valid JSON"),
    ("n_mismatch", "PHAST/DoublePendulum-v0", None, None, None, "'q' has n=1 coordinates but the simulator has n=2"),
    ("holdout_out_of_range", "PHAST/Pendulum-v0", None, None, "0,3", r"holdout"),
    ("holdout_negative", "PHAST/Pendulum-v0", None, None, "-1", r"holdout"),
]


@pytest.mark.parametrize(("case", "sim", "kwargs", "change", "holdout", "match"), BAD_CLI, ids=[c[0] for c in BAD_CLI])
def test_cli_bad_input_exit_2_and_no_report(tmp_path, capsys, case, sim, kwargs, change, holdout, match):
    import re

    rig = tmp_path / "rig.py"
    rig.write_text(USER_RIG)
    rec = _pendulum_npz(tmp_path / "rec.npz")
    if change is not None:
        with np.load(rec) as z:
            d = {k: z[k] for k in z.files}
        _pendulum_npz(rec, **change(d))
    before = sorted(p.name for p in tmp_path.iterdir())
    argv = ["--sim", sim.format(rig=rig), "--recordings", str(rec), "--out", str(tmp_path / "report"), "--quiet"]
    if kwargs is not None:
        argv += ["--sim-kwargs", kwargs]
    if holdout is not None:
        argv += ["--holdout-trajectories", holdout]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("phast-mismatch: error: ") and re.search(match, err), err
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no report directory (nor probe / temp) left behind


def test_cli_bad_input_as_a_process(tmp_path):
    """The same through ``python -m`` (what the console script runs): exit status 2 and one error line."""
    rec = _pendulum_npz(tmp_path / "rec.npz")
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    res = subprocess.run([sys.executable, "-m", "phast_model.cli.mismatch", "--sim", "PHAST/DoublePendulum-v0", "--recordings",
                          str(rec), "--out", str(tmp_path / "report")], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 2
    assert res.stderr.strip().splitlines()[-1] == textwrap.dedent(
        f"phast-mismatch: error: {rec}: 'q' has n=1 coordinates but the simulator has n=2")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec.npz"]
