"""A MuJoCo model file as the simulator: the rigid-body formulas against MuJoCo itself, the torch path, merged
batches, MuJoCo rollouts, the written-back model and the refusals (docs/mismatch.md, "Your robot as MJCF / URDF")."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from phast_gym.systems.mjcf import mjcf_system  # noqa: E402
from phast_gym.systems.mjcf_tree import ModelFileError, read_tree  # noqa: E402
from phast_model.identify.merging import merge_systems  # noqa: E402
from phast_model.identify.mjcf_write import Edit, calibrated_xml  # noqa: E402
from phast_model.identify.mujoco_sim import rollout_q  # noqa: E402
from phast_model.identify.shooting import simulate_qv  # noqa: E402
from phast_model.identify.simulators import load_simulator  # noqa: E402

#: a 4-joint tree with what MuJoCo models allow: rotated frames and inertia axes, joint anchors off the body origin,
#: a reference angle, a slide joint, a jointless body at the base, armature, damping, a motor and a position servo
ARM = """
<mujoco model="arm4">
  <option gravity="0 0 -9.81" timestep="0.001" integrator="RK4"><flag contact="disable"/></option>
  <worldbody>
    <body name="base" pos="0 0 1">
      <body name="link1" pos="0.1 0 0" quat="0.9 0.1 0.2 0.3">
        <joint name="shoulder" type="hinge" axis="0 1 0" pos="0 0 0.05" damping="0.1" armature="0.01"/>
        <inertial pos="0.02 0.01 -0.2" mass="1.2" diaginertia="0.03 0.02 0.01" quat="0.8 0.2 0.1 0.3"/>
        <body name="link2" pos="0.05 0.02 -0.4">
          <joint name="elbow" type="hinge" axis="1 0.3 0.2" ref="0.3"/>
          <inertial pos="0 0.03 -0.15" mass="0.7" diaginertia="0.02 0.017 0.004"/>
          <body name="slider" pos="0 0 -0.3">
            <joint name="slide" type="slide" axis="0.1 0 1"/>
            <inertial pos="0.01 0 0.02" mass="0.3" diaginertia="0.001 0.002 0.003"/>
            <body name="tip" pos="0 0.1 0">
              <joint name="wrist" type="hinge" axis="0 0 1"/>
              <inertial pos="0.05 0.02 0" mass="0.2" diaginertia="0.001 0.001 0.0005"/>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <actuator>
    <motor name="m_shoulder" joint="shoulder" gear="2"/>
    <position name="p_elbow" joint="elbow" kp="5" kv="0.3"/>
  </actuator>
</mujoco>
"""


@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    path = tmp_path_factory.mktemp("mjcf") / "arm4.xml"
    path.write_text(ARM)
    return path


def _comps(x: np.ndarray) -> tuple:
    return tuple(x[..., i] for i in range(x.shape[-1]))


def _mj_state(m, q, v, ctrl=None):
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = q, v
    if ctrl is not None:
        d.ctrl[:] = ctrl
    mujoco.mj_forward(m, d)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, M)
    return d, M


def test_mass_matrix_and_forces_are_mujocos(arm):
    """M(q) equals mj_fullM, and pdot = d(M v)/dt = M qacc + (dM/dt) v of MuJoCo's forward dynamics (gravity, Coriolis,
    armature, damping, a motor with gear 2 and a position servo)."""
    system = mjcf_system(arm)()
    m = mujoco.MjModel.from_xml_path(str(arm))
    rng = np.random.default_rng(0)
    for _ in range(4):
        q, v, ctrl = rng.uniform(-1, 1, 4), rng.uniform(-1, 1, 4), rng.uniform(-1, 1, 2)
        d, M = _mj_state(m, q, v, ctrl)
        ours = np.array([[np.ravel(c)[0] for c in row] for row in system.mass_matrix(_comps(q[None]))])
        np.testing.assert_allclose(ours, M, atol=1e-13)
        u = np.zeros(4)
        u[list(system.actuated_dofs)] = ctrl
        qdot, pdot = system.rhs(_comps(q[None]), _comps((M @ v)[None]), _comps(u[None]))
        np.testing.assert_allclose(np.ravel(qdot), v, atol=1e-12)
        h = 1e-6  # dM/dt v by central differences along the motion
        Mp, Mm = (_mj_state(m, q + s * h * v, v)[1] for s in (1, -1))
        expected = M @ d.qacc + (Mp - Mm) / (2 * h) @ v
        np.testing.assert_allclose(np.ravel(pdot), expected, rtol=1e-7, atol=1e-7)


def test_coriolis_derivative_matches_finite_differences(arm):
    """dH/dq at fixed p: the closed form of v^T (dM/dq) v / 2 against central differences of H."""
    system = mjcf_system(arm)()
    rng = np.random.default_rng(1)
    q, p = rng.uniform(-1, 1, (3, 4)), rng.uniform(-1, 1, (3, 4))
    got = np.stack(system.dH_dq(_comps(q), _comps(p)), -1)
    h = 1e-6
    for k in range(4):
        e = np.zeros(4)
        e[k] = h
        Hp, Hm = system.hamiltonian(_comps(q + e), _comps(p)), system.hamiltonian(_comps(q - e), _comps(p))
        np.testing.assert_allclose(got[:, k], (Hp - Hm) / (2 * h), rtol=1e-6, atol=1e-8)


def test_torch_matches_numpy_and_differentiates(arm):
    torch = pytest.importorskip("torch")
    system = mjcf_system(arm)()
    rng = np.random.default_rng(2)
    q, p = rng.uniform(-1, 1, (5, 4)), rng.uniform(-1, 1, (5, 4))
    qt = torch.tensor(q, dtype=torch.float64, requires_grad=True)
    pt = torch.tensor(p, dtype=torch.float64)
    dH = torch.stack(system.dH_dq(qt.unbind(-1), pt.unbind(-1)), -1)
    np.testing.assert_allclose(dH.detach().numpy(), np.stack(system.dH_dq(_comps(q), _comps(p)), -1), atol=1e-12)
    dH.sum().backward()
    assert qt.grad is not None and torch.isfinite(qt.grad).all()


def test_parameter_sets_simulate_as_one_batch(arm):
    cls = mjcf_system(arm)
    systems = [cls(**{"link1.mass": 1.2 + 0.1 * k, "shoulder.damping": 0.1 + 0.02 * k, "m_shoulder.gear": 2 - 0.1 * k})
               for k in range(3)]
    merged = merge_systems(systems, 4)
    assert merged is not None
    rng = np.random.default_rng(3)
    q0, v0, u = rng.uniform(-1, 1, (12, 4)), rng.uniform(-1, 1, (12, 4)), rng.uniform(-1, 1, (12, 10, 4))
    whole = simulate_qv(merged, q0, v0, 10, u, 0.01, 2)
    parts = [simulate_qv(s, q0[4 * k: 4 * k + 4], v0[4 * k: 4 * k + 4], 10, u[4 * k: 4 * k + 4], 0.01, 2) for k, s in enumerate(systems)]
    # the same formulas per sample; einsum may order a contraction's sum differently for another batch size
    np.testing.assert_allclose(whole, np.concatenate(parts), rtol=1e-13, atol=1e-15)


def test_mujoco_rollout_agrees_with_the_model(arm):
    """MuJoCo (RK4 at 1 ms) and the tool's RK4 at 5 ms on the same file: the same trajectories to integration error."""
    system = mjcf_system(arm)()
    rng = np.random.default_rng(4)
    q0, v0 = rng.uniform(-0.5, 0.5, (3, 4)), rng.uniform(-0.5, 0.5, (3, 4))
    ctrl = rng.uniform(-0.5, 0.5, (3, 50, 2))
    u = np.zeros((3, 50, 4))
    u[..., list(system.actuated_dofs)] = ctrl
    ours = simulate_qv(system, q0, v0, 50, u, 0.01, 2)
    theirs = rollout_q(str(arm), q0, v0, ctrl, 0.01, 50)
    assert np.max(np.abs(ours - theirs)) < 1e-4


def test_parameters_carry_the_files_names(arm):
    specs = mjcf_system(arm).PARAMS
    for name in ("link1.mass", "link2.ipos_y", "tip.inertia_z", "shoulder.armature", "elbow.frictionloss",
                 "m_shoulder.gear", "p_elbow.gear", "gravity"):
        assert name in specs, name
    assert specs["shoulder.damping"].default == pytest.approx(0.1)
    assert specs["gravity"].known


def test_written_model_compiles_and_holds_the_values(arm, tmp_path):
    tree = read_tree(arm)
    edits = [Edit("elbow", "frictionloss", 0.03), Edit("shoulder", "damping", 0.05), Edit("p_elbow", "gear", 0.9, "scale")]
    written = calibrated_xml(tree, {"link2.mass": 0.8, "link1.inertia_y": 0.025, "m_shoulder.gear": 2.2}, edits)
    assert written.notes == []
    out = tmp_path / "calibrated.xml"
    out.write_text(written.text)
    mujoco.MjModel.from_xml_path(str(out))
    back = read_tree(out)
    np.testing.assert_allclose(back.body_mass, [1.2, 0.8, 0.3, 0.2])
    assert back.body_inertia[0, 1] == pytest.approx(0.025)
    np.testing.assert_allclose(back.frictionloss, [0, 0.03, 0, 0])
    np.testing.assert_allclose(back.damping, [0.15, 0, 0, 0])
    assert [a.gear for a in back.actuators] == pytest.approx([2.2, 0.9])


BAD = {
    "free joint": '<mujoco><worldbody><body><freejoint/><geom size="0.1"/></body></worldbody></mujoco>',
    "ball joint": '<mujoco><worldbody><body><joint type="ball"/><geom size="0.1"/></body></worldbody></mujoco>',
    "does not compile": '<mujoco><worldbody><body><joint type="hinge"/><inertial pos="0 0 0" mass="1" diaginertia="1 0.1 0.1"/>'
                        '</body></worldbody></mujoco>',
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_unusable_models_are_refused_with_the_reason(case, tmp_path):
    path = tmp_path / "bad.xml"
    path.write_text(BAD[case])
    with pytest.raises(ModelFileError) as err:
        load_simulator(str(path))
    msg = str(err.value)
    assert ("not supported" in msg) if "joint" in case else ("does not compile" in msg and "inertia" in msg)


URDF = """<robot name="two_link">
  <link name="base"/>
  <link name="l1">
    <inertial><origin xyz="0 0 -0.2"/><mass value="1.0"/><inertia ixx="0.02" iyy="0.02" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><mesh filename="package://missing/l1.stl"/></geometry></visual>
    <collision><geometry><mesh filename="meshes/l1_missing.stl"/></geometry></collision>
  </link>
  <link name="l2">
    <inertial><origin xyz="0 0 -0.15"/><mass value="0.5"/><inertia ixx="0.01" iyy="0.01" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial>
  </link>
  <joint name="j1" type="continuous"><parent link="base"/><child link="l1"/><axis xyz="0 1 0"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0 0 -0.4"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" effort="10" velocity="10"/></joint>
</robot>"""


def test_urdf_with_missing_meshes_loads(tmp_path):
    path = tmp_path / "two_link.urdf"
    path.write_text(URDF)
    system = load_simulator(str(path)).build()
    assert system.n == 2 and system.coordinate_names == ("j1", "j2")
    assert "l2.mass" in system.params and system.params["l2.mass"] == pytest.approx(0.5)
    assert system.actuated_dofs == (0, 1) and "j2.gear" in system.params  # one torque motor per joint, named after it
    written = calibrated_xml(read_tree(path), {"l2.mass": 0.6}, [Edit("j2", "frictionloss", 0.01)])
    m = mujoco.MjModel.from_xml_string(written.text)
    assert m.nu == 2 and m.body_mass[-1] == pytest.approx(0.6) and m.dof_frictionloss[1] == pytest.approx(0.01)


def test_cli_refuses_bad_input_with_exit_2_and_writes_nothing(arm, tmp_path, capsys):
    from phast_model.cli.mismatch import main

    rng = np.random.default_rng(5)
    q = rng.normal(0, 0.1, (2, 60, 4))
    cases = {
        "u_columns": (str(arm), {"q": q, "u": np.zeros((2, 59, 3)), "dt": 0.01}, "'u' has m=3 columns but the simulator has 2 actuators"),
        "q_columns": (str(arm), {"q": q[..., :3], "dt": 0.01}, "'q' has n=3 coordinates but the simulator has n=4"),
        "free_joint": (BAD["free joint"], {"q": q, "dt": 0.01}, "free and ball joints are not supported"),
        "no_compile": (BAD["does not compile"], {"q": q, "dt": 0.01}, "does not compile"),
    }
    for name, (model, rec, message) in cases.items():
        sim = model
        if model.startswith("<"):
            sim = str(tmp_path / f"{name}.xml")
            (tmp_path / f"{name}.xml").write_text(model)
        np.savez(tmp_path / f"{name}.npz", **rec)
        out = tmp_path / f"out_{name}"
        assert main(["--sim", sim, "--recordings", str(tmp_path / f"{name}.npz"), "--out", str(out), "--quiet"]) == 2, name
        assert message in capsys.readouterr().err, name
        assert not out.exists(), name


def test_compare_models_are_checked_before_any_work(arm, tmp_path, capsys):
    """``--compare NAME=MODEL``: a model file, found, that MuJoCo compiles; anything else exits 2 naming the item."""
    from phast_model.cli.mismatch import main

    np.savez(tmp_path / "rec.npz", q=np.random.default_rng(6).normal(0, 0.1, (2, 60, 4)), dt=0.01)
    (tmp_path / "broken.xml").write_text(BAD["does not compile"])
    cases = {"no_name": (str(arm), "expected NAME=path/to/model.xml"),
             "the_name=nowhere.xml": (None, "file 'nowhere.xml' not found"),
             "broken": (f"broken={tmp_path / 'broken.xml'}", "does not compile")}
    for item, (given, message) in cases.items():
        out = tmp_path / f"out_{len(message)}"
        argv = ["--sim", str(arm), "--recordings", str(tmp_path / "rec.npz"), "--out", str(out), "--quiet",
                "--compare", given or item]
        assert main(argv) == 2, item
        assert message in capsys.readouterr().err, item
        assert not out.exists(), item


def test_partial_learns_the_files_body_parameters(arm):
    """PARTIAL on a model file: V and M are the file's formulas with learnable body parameters that start at the
    file's values and receive gradients (one set shared by V and M)."""
    torch = pytest.importorskip("torch")
    from phast_model.components.rigid_body import LearnedBodies, RigidBodyMass, RigidBodyPotential

    cls = mjcf_system(arm)
    bodies = LearnedBodies(cls())
    pot, mass = RigidBodyPotential(bodies), RigidBodyMass(bodies)
    start = {k: v for k, v in bodies.values().items() if k.endswith(".armature")}
    assert start["shoulder.armature"] == pytest.approx(0.01)  # the file's value
    assert all(v > 0 for v in start.values())  # a rotor inertia to learn on every joint, from a small start
    system = cls(**start)
    rng = np.random.default_rng(6)
    q, p = rng.uniform(-1, 1, (4, 4)), rng.uniform(-1, 1, (4, 4))
    qt, pt = torch.tensor(q), torch.tensor(p)
    M = np.stack([np.stack(r, -1) for r in system.mass_matrix(_comps(q))], -2)
    np.testing.assert_allclose(mass.matrix(qt).detach().numpy(), M, atol=1e-12)
    np.testing.assert_allclose(pot.grad(qt).detach().numpy(), np.stack(system.grad_potential(_comps(q)), -1), atol=1e-12)
    kin = np.stack(system.dH_dq(_comps(q), _comps(p)), -1) - np.stack(system.grad_potential(_comps(q)), -1)
    np.testing.assert_allclose(mass.kinetic_dq(qt, pt).detach().numpy(), kin, atol=1e-10)
    (pot.energy(qt).sum() + mass.velocity(qt, pt).sum()).backward()
    assert bodies.log_mass.grad is not None and torch.count_nonzero(bodies.log_mass.grad) > 0
    assert bodies.values()["link2.mass"] == pytest.approx(0.7)


PLANAR = """
<mujoco model="planar2">
  <option gravity="0 0 -9.81"><flag contact="disable"/></option>
  <worldbody>
    <body name="link1" pos="0 0 1">
      <joint name="j1" type="hinge" axis="0 1 0"/>
      <inertial pos="0 0 -0.2" mass="0.5" diaginertia="0.001 0.001 0.0001"/>
      <body name="link2" pos="0 0 -0.2">
        <joint name="j2" type="hinge" axis="0 1 0"/>
        <inertial pos="0 0 -0.15" mass="0.4" diaginertia="0.002 0.002 0.0001"/>
      </body>
    </body>
  </worldbody>
  <actuator><motor name="m1" joint="j1"/><motor name="m2" joint="j2"/></actuator>
</mujoco>
"""


def test_first_body_inertia_about_its_hinge_is_armature(tmp_path):
    """A moment of the body hung from the world by one hinge, about that hinge's axis, is exactly that joint's
    armature (the C.0 arm's rotor inertia comes out this way); other moments are not."""
    from phast_model.mismatch.report.mjcf_answer import armature_equivalent

    path = tmp_path / "planar2.xml"
    path.write_text(PLANAR)
    tree = read_tree(path)
    assert armature_equivalent(tree, "link1.inertia_y") == "j1"
    assert armature_equivalent(tree, "link1.inertia_x") is None
    assert armature_equivalent(tree, "link2.inertia_y") is None  # link 2 also moves with j1
    cls = mjcf_system(path)
    a, b = cls(**{"link1.inertia_y": 0.005}), cls(**{"j1.armature": 0.004})
    q = np.random.default_rng(7).uniform(-2, 2, (5, 2))
    Ma = np.stack([np.stack(r, -1) for r in a.mass_matrix(_comps(q))], -2)
    Mb = np.stack([np.stack(r, -1) for r in b.mass_matrix(_comps(q))], -2)
    np.testing.assert_allclose(Ma, Mb, atol=1e-15)


def test_written_body_stays_rigid(tmp_path):
    """A calibrated principal moment that breaks A + B >= C is kept; an unchanged one is raised just enough."""
    path = tmp_path / "planar2.xml"
    path.write_text(PLANAR)
    written = calibrated_xml(read_tree(path), {"link2.inertia_y": 0.01})
    assert len(written.notes) == 1 and "link2.inertia_" in written.notes[0]
    m = mujoco.MjModel.from_xml_string(written.text)
    moments = m.body_inertia[2]
    assert moments[1] == pytest.approx(0.01)
    assert moments[0] + moments[2] >= moments[1] - 1e-12
    # a value of full precision (a fit's) still compiles once the text has rounded every moment (the real C.0 arm's
    # link1.inertia_y once made the written model fail, and the fits fall back from MuJoCo)
    c0 = read_tree(Path(__file__).resolve().parents[2] / "examples" / "robots" / "dfki_c0.xml")
    written = calibrated_xml(c0, {"link1.inertia_y": 0.004934953679488724})
    assert len(written.notes) == 1 and "link1.inertia_" in written.notes[0]


def test_recordings_at_a_joint_limit_are_named(tmp_path):
    """A limited joint the recordings drive into its limit is reported (MuJoCo's limit constraint is not fitted)."""
    from phast_model.identify.recordings import Recordings
    from phast_model.mismatch.report.mjcf_answer import joint_limit_contacts

    path = tmp_path / "two_link.urdf"
    path.write_text(URDF)
    tree = read_tree(path)
    assert np.isinf(tree.joint_range[0]).all() and list(tree.joint_range[1]) == [-3.0, 3.0]  # continuous, revolute
    q = np.zeros((2, 50, 2))
    q[1, 20:30, 1] = 2.99
    found = joint_limit_contacts(tree, Recordings(q=q, dt=0.01, angle_dims=(0, 1)))
    assert [(c["joint"], c["trajectories"]) for c in found] == [("j2", [1])]
    assert joint_limit_contacts(tree, Recordings(q=0.5 * q, dt=0.01, angle_dims=(0, 1))) == []


def test_armature_term_folds_into_the_models_own_armature(arm):
    """The mismatch tool's armature term on a MuJoCo model goes into the joint's own ``armature`` (the fused vector field),
    and gives the field of the generic (M(q) + A) construction."""
    from phast_model.mismatch.vocabulary.terms import AugmentedSystem, Term

    base = mjcf_system(arm)()
    aug = AugmentedSystem(base, [Term("armature", 1, 0.004), Term("viscous_damping", 2, 0.02)])
    assert aug.inertial_base is not None
    generic = AugmentedSystem(base, aug.terms)
    generic.inertial_base = None  # the generic path: M(q) + A assembled around the base
    rng = np.random.default_rng(8)
    q, p, u = (_comps(rng.uniform(-1, 1, (6, 4))) for _ in range(3))
    for a, b in zip(aug.rhs(q, p, u), generic.rhs(q, p, u)):
        np.testing.assert_allclose(np.stack(a), np.stack(b), rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(np.stack(aug.dH_dq(q, p)), np.stack(generic.dH_dq(q, p)), rtol=1e-12, atol=1e-13)
    assert base._armature[1] == base.TREE.armature[1]  # the base itself is unchanged
