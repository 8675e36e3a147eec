"""A motor-driven model file whose CAD leaves out its drives (rotor inertia, gear friction) still describes the
recordings: the weak form's drive share (phast_model.mismatch.friction.systematic.drive_share)."""

from __future__ import annotations

import numpy as np
import pytest

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


def test_the_weak_form_parameter_check_says_where_it_is(drives):
    """The backward elimination reports its rounds (every 30 s; here every round) and decides as without a listener."""
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
    assert said and len(said) == len(params) - len(quiet.kept)
    assert all("weak-form parameter check" in m and "parameters left" in m for m in said)
