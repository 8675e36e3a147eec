"""PARTIAL on a model file starts from its drives (phast_model.train.motion_start.fit_drives): the file's bodies kept,
each joint's rotor inertia and friction by non-negative least squares on the recorded force balance.  Checked on a
MuJoCo arm whose 'reality' hides rotor inertia and friction (the phast-mismatch MJCF case ``arm3_drives``)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch

from phast_model.bench.mjcf_cases import cases, hidden_effects, nominal_path, record, write_real
from phast_model.train.motion_start import MotionStartConfig, fit_drives, motion_samples
from phast_model.train.rig_fit import build, load_rig_data, nominal_config, rig_config


@pytest.fixture(scope="module")
def arm3(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, dict[tuple[str, str], float], str]:
    """The nominal arm3.xml as the rig, recordings of its hidden-drives reality (8 runs of 3 s, noise 1e-4 rad)."""
    torch.set_num_threads(1)
    case = cases()["arm3_drives"]
    hidden = hidden_effects(case, 0)
    real = write_real(case, hidden, tmp_path_factory.mktemp("arm3"))
    rec = record(case, real, n_traj=8, T=300, seed=0, noise=1e-4)
    data = load_rig_data({"q": rec["q"], "u": rec["u"], "dt": rec["dt"]}, str(nominal_path(case)), {}, [7])
    truth = {(h.target, h.attr): h.value for h in hidden}
    return data, truth, str(nominal_path(case))


def test_partial_on_a_model_file_starts_from_its_drives(arm3: tuple) -> None:
    data, _, sim = arm3
    assert rig_config(sim, {}, "partial", data).init_from == "drives"


def test_the_drives_start_recovers_rotor_inertia_and_friction(arm3: tuple) -> None:
    data, truth, sim = arm3
    model = build(rig_config(sim, {}, "partial", data))
    residual = fit_drives(model, motion_samples(data.train, 0.1), MotionStartConfig())
    assert 0 < residual < 0.5  # what is left: the noise of a differentiated signal
    names = list(model.system.TREE.joint_names)
    arm = model.mass.bodies.armature().detach().numpy()
    fric = {law: c.detach().numpy() for law, c in model.friction.coefficients().items()}
    # the yaw's rotor inertia is one number with the turret's inertia about z: not checked
    for joint in ("shoulder", "elbow"):
        assert arm[names.index(joint)] == pytest.approx(truth[(joint, "armature")], rel=0.25)
        assert fric["coulomb"][names.index(joint)] == pytest.approx(truth[(joint, "frictionloss")], rel=0.25)
    assert fric["viscous"][names.index("yaw")] == pytest.approx(truth[("yaw", "damping")], rel=0.25)


def test_the_nominal_model_steps_no_longer_than_the_rig_does(arm3: tuple) -> None:
    """The nominal model is integrated at (at most) the file's own step, not at the recordings' coarser one."""
    data, _, sim = arm3
    cfg = rig_config(sim, {}, "partial", data)
    system = build(cfg).system
    nominal = nominal_config(cfg)
    assert nominal.substeps >= 1
    assert data.dt / nominal.substeps <= system.dt / max(system.substeps, 1) + 1e-12


def test_the_drives_start_needs_a_model_file_and_a_port() -> None:
    sim = "PHAST/DampedPendulum-v0"
    q = np.zeros((2, 50, 1)) + np.linspace(0, 1, 50)[None, :, None]
    data = load_rig_data({"q": q, "u": np.ones((2, 49, 1)), "dt": 0.01}, sim)
    model = build(rig_config(sim, {}, "partial", data))
    with pytest.raises(ValueError, match="rigid-body mass"):
        fit_drives(model, motion_samples(data.train, 0.1), MotionStartConfig())
