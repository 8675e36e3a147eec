"""examples/robots/dfki_c0.xml (the DFKI C.0 arm as MJCF, a rigid-body re-parametrisation of the published link
parameters) has exactly the dynamics of PHAST/DoublePendulum-v0 with the published kwargs in relative coordinates."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from phast_gym.registry import make_env_system
from phast_gym.systems.mjcf import mjcf_system
from tests import ROOT

REPO = ROOT
XML = REPO / "examples" / "robots" / "dfki_c0.xml"
DATA = Path(os.environ.get("PHAST_REAL_DATA", REPO.parent / "shared" / "data" / "real")) / "dfki_double_pendulum_c0.npz"

#: the authors' nominal (frictionless) C.0 model, `published_nominal` of dfki_double_pendulum_c0.npz at full precision,
#: as examples/real_double_pendulum_mismatch.py passes it (``links``)
PUBLISHED = {"coordinates": "relative", "mass1": 0.6416937799349799, "mass2": 0.563935954099688, "length1": 0.2,
             "length2": 0.3, "com1": 0.2, "com2": 0.3212669909674605, "inertia1": 0.02671076499939512,
             "inertia2": 0.053878129629650884, "gravity": 9.81}
RTOL = 1e-9
B = 20


def _rel(a, b) -> float:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def _stack(comps) -> np.ndarray:
    """Components (nested tuples of (B,) arrays or floats) -> a (B, ...) array."""
    if isinstance(comps[0], tuple):
        return np.stack([_stack(c) for c in comps], axis=1)
    return np.stack([np.broadcast_to(np.asarray(c, dtype=float), (B,)) for c in comps], axis=1)


@pytest.fixture(scope="module")
def systems():
    cls = mjcf_system(XML)
    return cls(), make_env_system("PHAST/DoublePendulum-v0", **PUBLISHED)


@pytest.fixture(scope="module")
def states():
    rng = np.random.default_rng(0)
    q = rng.uniform(-np.pi, np.pi, size=(B, 2))
    p = rng.uniform(-1.0, 1.0, size=(B, 2))
    u = rng.uniform(-5.0, 5.0, size=(B, 2))
    return q, p, u


def _c(x: np.ndarray) -> tuple:
    return tuple(x[:, i].copy() for i in range(x.shape[1]))


def test_file_is_the_frictionless_two_motor_arm(systems) -> None:
    mj, dp = systems
    assert mj.n == 2 and mj.joint_names == ("joint1", "joint2") and mj.angle_dims == (0, 1)
    assert mj.actuated_dofs == (0, 1)
    assert [a.name for a in mj.TREE.actuators] == ["joint1", "joint2"]
    assert all(a.gear == 1.0 and a.gain == 1.0 and a.bias == (0.0, 0.0, 0.0) for a in mj.TREE.actuators)
    for attr in ("armature", "damping", "frictionloss", "stiffness"):
        assert np.all(getattr(mj.TREE, attr) == 0.0), attr
    assert not mj.has_damping()
    assert mj.params["gravity"] == pytest.approx(PUBLISHED["gravity"], rel=1e-15)
    assert dp.relative


def test_rigid_body_reparametrisation_keeps_the_invariants() -> None:
    """The file's rigid links give the published I1 + m2 l1^2, I2, m2 r2 and m1 r1 + m2 l1, and are physical."""
    t = mjcf_system(XML).TREE
    (m1, m2), (c1, c2) = t.body_mass, -t.body_ipos[:, 2]
    l1 = -t.body_pos[1, 2]
    i1 = t.body_inertia[0, 1] + m1 * c1 ** 2  # about the joint axis (body y)
    i2 = t.body_inertia[1, 1] + m2 * c2 ** 2
    P = PUBLISHED
    assert l1 == P["length1"]
    for got, want in ((i1 + m2 * l1 ** 2, P["inertia1"] + P["mass2"] * P["length1"] ** 2), (i2, P["inertia2"]),
                      (m2 * c2, P["mass2"] * P["com2"]), (m1 * c1 + m2 * l1, P["mass1"] * P["com1"] + P["mass2"] * P["length1"])):
        assert got == pytest.approx(want, rel=1e-12)
    for inertia in t.body_inertia:  # valid principal moments (MuJoCo's triangle inequality)
        a, b, c = inertia
        assert min(inertia) > 0 and a + b >= c and b + c >= a and a + c >= b
    assert P["mass2"] * P["com2"] ** 2 > P["inertia2"]  # why the published link 2 could not be written directly


def test_mass_matrix_potential_and_rhs_match_double_pendulum(systems, states) -> None:
    mj, dp = systems
    q, p, u = states
    Q, P, U = _c(q), _c(p), _c(u)
    assert _rel(_stack(mj.mass_matrix(Q)), _stack(dp.mass_matrix(Q))) < RTOL
    assert _rel(_stack(mj.grad_potential(Q)), _stack(dp.grad_potential(Q))) < RTOL
    dV = np.asarray(mj.potential(Q)) - np.asarray(dp.potential(Q))  # equal up to a constant
    assert np.ptp(dV) < RTOL * np.max(np.abs(dp.potential(Q)))
    (v_mj, f_mj), (v_dp, f_dp) = mj.rhs(Q, P, U), dp.rhs(Q, P, U)
    assert _rel(_stack(v_mj), _stack(v_dp)) < RTOL
    assert _rel(_stack(f_mj), _stack(f_dp)) < RTOL
    (_, f0_mj), (_, f0_dp) = mj.rhs(Q, P, None), dp.rhs(Q, P, None)  # unforced
    assert _rel(_stack(f0_mj), _stack(f0_dp)) < RTOL


def test_mujoco_own_mass_matrix_and_forward_dynamics_match(systems, states) -> None:
    """MuJoCo itself (mj_fullM after mj_forward, and its forward dynamics qacc) gives DoublePendulum's M(q) and pdot,
    with the motor torques."""
    import mujoco

    _, dp = systems
    K = PUBLISHED["mass2"] * PUBLISHED["length1"] * PUBLISHED["com2"]
    m = mujoco.MjModel.from_xml_path(str(XML))
    d = mujoco.MjData(m)
    q, p, u = states
    M_dp = _stack(dp.mass_matrix(_c(q)))
    qdot = np.stack(dp.velocity(_c(q), _c(p)), axis=1)
    (_, f_dp) = dp.rhs(_c(q), _c(p), _c(u))  # pdot = u - dH/dq|_p (the motors at gear 1)
    worst_M = worst_a = 0.0
    for b in range(B):
        d.qpos[:], d.qvel[:], d.ctrl[:] = q[b], qdot[b], u[b]
        mujoco.mj_forward(m, d)
        M = np.zeros((2, 2))
        mujoco.mj_fullM(m, d, M)  # MuJoCo 4 signature (m, d, dst)
        worst_M = max(worst_M, _rel(M, M_dp[b]))
        # pdot = d/dt (M qdot) = M qddot + Mdot qdot; relative coordinates: dM/dq2 = -m2 l1 r2 sin q2 [[2, 1], [1, 0]]
        Mdot = -K * np.sin(q[b, 1]) * qdot[b, 1] * np.array([[2.0, 1.0], [1.0, 0.0]])
        pdot = M @ d.qacc + Mdot @ qdot[b]
        worst_a = max(worst_a, _rel(pdot, [f_dp[0][b], f_dp[1][b]]))
    assert worst_M < RTOL
    assert worst_a < RTOL


@pytest.mark.skipif(not DATA.exists(), reason="real recordings not available")
def test_published_kwargs_are_the_recordings_nominal_model() -> None:
    with np.load(DATA, allow_pickle=False) as z:
        p = dict(zip((str(s) for s in z["published_names"]), (float(v) for v in z["published_nominal"])))
    assert p["Ir"] == p["b1"] == p["b2"] == p["cf1"] == p["cf2"] == 0.0
    got = {"mass1": p["m1"], "mass2": p["m2"], "length1": p["l1"], "length2": p["l2"], "com1": p["r1"], "com2": p["r2"],
           "inertia1": p["I1"], "inertia2": p["I2"], "gravity": p["g"]}
    assert got == {k: v for k, v in PUBLISHED.items() if k != "coordinates"}
