"""Real-rig options of the double pendulum: compound links (com, inertia) and relative joint coordinates."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
import torch

import phast_gym
from phast_gym.datasets import make_dataset
from phast_gym.integrate import simulate
from phast_gym.systems import NUMPY, SCALAR, TORCH, DoublePendulum, ParameterError

RIG = {"mass1": 1.3, "mass2": 0.8, "length1": 0.9, "length2": 1.2, "com1": 0.4, "com2": 0.55,
       "inertia1": 0.35, "inertia2": 0.3, "gravity": 9.81}

# (q_true, p) at the last of 60 samples of make_dataset(env, n_traj=3, T=60, seed=7, cache=False, u=(0.7, -0.4)),
# recorded with the point-mass code before compound links and joint coordinates were added
BENCHMARK = {
    "PHAST/DoublePendulum-v0": (
        [[-0.9799647680944271, -4.6899871118279], [0.2750461291287851, -0.5661582493269798],
         [0.05036696523876351, -0.6095382689782591]],
        [[-3.2664771543458966, -4.309789374758298], [-2.6737651422616313, -6.420564235588202],
         [-5.98247857711621, 2.905867271367719]]),
    "PHAST/DampedDoublePendulum-v0": (
        [[-0.9048107197330653, -4.4792491100768865], [0.2418307273886283, -0.42616656587308865],
         [0.07987407908747153, -0.6907574103110989]],
        [[-4.077370640727232, -2.7067089217115843], [-2.69519056225798, -5.870761064577587],
         [-6.037013357354889, 2.977100026772017]]),
    "PHAST/WindyDoublePendulum-v0": (
        [[-0.7307710538167943, -4.096634454514017], [0.12797118623812037, -0.10775499571870094],
         [0.1431892490441522, -0.8743381607403582]],
        [[-5.305263593050063, -0.39432812054327443], [-2.4935503660714553, -4.989318066779349],
         [-6.235907568538628, 3.095293336508332]]),
}


def _states(seed: int, size: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random (q, qdot, u) batches, each (size, 2)."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-math.pi, math.pi, (size, 2)), rng.uniform(-3.0, 3.0, (size, 2)), rng.uniform(-2.0, 2.0, (size, 2))


def _momentum(system: DoublePendulum, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
    (m11, m12), (_, m22) = system.mass_matrix((q[:, 0], q[:, 1]), NUMPY)
    return np.stack([m11 * qdot[:, 0] + m12 * qdot[:, 1], m12 * qdot[:, 0] + m22 * qdot[:, 1]], 1)


def _rhs(system: DoublePendulum, q: np.ndarray, p: np.ndarray, u: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    qd, pd = system.rhs((q[:, 0], q[:, 1]), (p[:, 0], p[:, 1]), None if u is None else (u[:, 0], u[:, 1]), NUMPY)
    return np.stack(qd, 1), np.stack(pd, 1)


# --------------------------------------------------------------------------- (e) defaults unchanged
@pytest.mark.parametrize("env_id", list(BENCHMARK))
def test_benchmark_datasets_unchanged(env_id: str) -> None:
    ds = make_dataset(env_id, n_traj=3, T=60, seed=7, cache=False, u=np.array([0.7, -0.4]))
    q_ref, p_ref = BENCHMARK[env_id]
    np.testing.assert_allclose(ds.q_true[:, -1], q_ref, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ds.p[:, -1], p_ref, rtol=0, atol=1e-12)


def test_default_rhs_and_energy_unchanged() -> None:
    """A non-default point-mass pendulum (masses, lengths, windy damping) gives the old code's numbers."""
    s = DoublePendulum(mass1=1.3, mass2=0.8, length1=0.9, length2=1.2, b=0.1, d0=0.2, dd=0.3)
    q, p, u = (0.4, -2.1), (0.3, 1.7), (0.5, -0.2)
    qd, pd = s.rhs(q, p, u, SCALAR)
    np.testing.assert_allclose(qd, (1.0282972867524776, 2.093554799068931), rtol=0, atol=1e-12)
    np.testing.assert_allclose(pd, (-8.261955058822263, 7.872309240430822), rtol=0, atol=1e-12)
    assert s.hamiltonian(q, p, SCALAR) == pytest.approx(-10.389094936807012, abs=1e-12)


def test_point_mass_formulas_bit_for_bit() -> None:
    """With the defaults M and dV/dq are the point-mass formulas, operation for operation."""
    m1, m2, l1, l2, g = 1.3, 0.8, 0.9, 1.2, 9.81
    s = DoublePendulum(mass1=m1, mass2=m2, length1=l1, length2=l2, gravity=g)
    q, _, _ = _states(0)
    t1, t2 = q[:, 0], q[:, 1]
    (m11, m12), (m21, m22) = s.mass_matrix((t1, t2), NUMPY)
    assert np.array_equal(m11, np.full_like(t1, (m1 + m2) * l1 * l1)) and np.array_equal(m22, np.full_like(t1, m2 * l2 * l2))
    assert np.array_equal(m12, m2 * l1 * l2 * np.cos(t1 - t2)) and np.array_equal(m21, m12)
    dv = s.grad_potential((t1, t2), NUMPY)
    assert np.array_equal(dv[0], (m1 + m2) * g * l1 * np.sin(t1)) and np.array_equal(dv[1], m2 * g * l2 * np.sin(t2))
    assert np.array_equal(s.potential((t1, t2), NUMPY), -(m1 + m2) * g * l1 * np.cos(t1) - m2 * g * l2 * np.cos(t2))


def test_dataset_cache_key_unchanged_by_the_new_parameters() -> None:
    s = phast_gym.make_env_system("PHAST/DampedDoublePendulum-v0")
    assert s.key_params() == {"mass1": 1.0, "mass2": 1.0, "length1": 1.0, "length2": 1.0, "gravity": 9.81,
                              "b": 0.2, "d0": 0.0, "dd": 0.0}
    rig = DoublePendulum(coordinates="relative", com1=0.5)
    assert rig.key_params()["coordinates"] == "relative" and rig.key_params()["com1"] == 0.5
    assert "inertia1" not in rig.key_params()


# --------------------------------------------------------------------------- (b) independent derivation
def _lagrangian(q: np.ndarray, qd: np.ndarray, relative: bool) -> np.ndarray:
    """L = T - V of two rigid links from their kinematics (centre-of-mass velocity + spin), written independently."""
    m1, m2, l1, c1, c2, i1, i2, g = (RIG[k] for k in ("mass1", "mass2", "length1", "com1", "com2", "inertia1", "inertia2",
                                                        "gravity"))
    t1, w1 = q[..., 0], qd[..., 0]
    t2, w2 = (t1 + q[..., 1], w1 + qd[..., 1]) if relative else (q[..., 1], qd[..., 1])
    v1 = np.stack([c1 * np.cos(t1) * w1, c1 * np.sin(t1) * w1], -1)
    v2 = np.stack([l1 * np.cos(t1) * w1 + c2 * np.cos(t2) * w2, l1 * np.sin(t1) * w1 + c2 * np.sin(t2) * w2], -1)
    kinetic = (0.5 * m1 * np.sum(v1**2, -1) + 0.5 * (i1 - m1 * c1**2) * w1**2
               + 0.5 * m2 * np.sum(v2**2, -1) + 0.5 * (i2 - m2 * c2**2) * w2**2)
    height = m1 * (-c1 * np.cos(t1)) + m2 * (-l1 * np.cos(t1) - c2 * np.cos(t2))
    return kinetic - g * height


def _grad(f, x: np.ndarray, h: float = 1e-6) -> np.ndarray:
    out = np.empty_like(x)
    for i in range(x.shape[-1]):
        e = np.zeros(x.shape[-1])
        e[i] = h
        out[..., i] = (f(x + e) - f(x - e)) / (2 * h)
    return out


@pytest.mark.parametrize("coordinates", ["absolute", "relative"])
@pytest.mark.parametrize("b", [0.0, 0.3])
def test_euler_lagrange_of_compound_links(coordinates: str, b: float) -> None:
    """p = dL/dqdot and pdot = dL/dq + u - b qdot (Euler-Lagrange with joint torques) by finite differences of L."""
    rel = coordinates == "relative"
    s = DoublePendulum(**RIG, coordinates=coordinates, b=b)
    q, qd, u = _states(1)
    p = _momentum(s, q, qd)
    np.testing.assert_allclose(p, _grad(lambda v: _lagrangian(q, v, rel), qd), rtol=1e-7, atol=1e-7)
    qdot, pdot = _rhs(s, q, p, u)
    np.testing.assert_allclose(qdot, qd, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(pdot, _grad(lambda x: _lagrangian(x, qd, rel), q) + u - b * qd, rtol=1e-7, atol=1e-7)


def test_relative_equals_absolute_under_the_joint_map() -> None:
    """t = J q with J = [[1, 0], [1, 1]]: p_rel = J^T p_abs, qdot_abs = J qdot_rel, pdot_rel = J^T pdot_abs, and the
    joint torques (tau1, tau2) act as the absolute generalized forces J^-T u = (tau1 - tau2, tau2)."""
    rel, ab = DoublePendulum(**RIG, coordinates="relative"), DoublePendulum(**RIG)
    q, qd, tau = _states(2)
    J = np.array([[1.0, 0.0], [1.0, 1.0]])
    q_abs, qd_abs = q @ J.T, qd @ J.T
    p_abs = _momentum(ab, q_abs, qd_abs)
    p_rel = p_abs @ J
    np.testing.assert_allclose(p_rel, _momentum(rel, q, qd), rtol=1e-12, atol=1e-12)
    u_abs = np.stack([tau[:, 0] - tau[:, 1], tau[:, 1]], 1)
    qdot_a, pdot_a = _rhs(ab, q_abs, p_abs, u_abs)
    qdot_r, pdot_r = _rhs(rel, q, p_rel, tau)
    np.testing.assert_allclose(qdot_r @ J.T, qdot_a, rtol=1e-11, atol=1e-11)
    np.testing.assert_allclose(pdot_r, pdot_a @ J, rtol=1e-11, atol=1e-11)
    np.testing.assert_allclose(rel.hamiltonian((q[:, 0], q[:, 1]), (p_rel[:, 0], p_rel[:, 1])),
                               ab.hamiltonian((q_abs[:, 0], q_abs[:, 1]), (p_abs[:, 0], p_abs[:, 1])), rtol=1e-12, atol=1e-12)


def test_relative_point_mass_is_the_point_mass_pendulum() -> None:
    """Relative coordinates with default links follow the benchmark (absolute) pendulum's trajectory."""
    kw = {"mass1": 1.2, "mass2": 0.7, "length1": 0.8, "length2": 1.1}
    rel, ab = DoublePendulum(coordinates="relative", **kw), DoublePendulum(**kw)
    x_abs = ab.sample_initial(np.random.default_rng(4), 5)
    J = np.array([[1.0, 0.0], [1.0, 1.0]])
    x_rel = np.concatenate([x_abs[:, :2] @ np.linalg.inv(J).T, x_abs[:, 2:] @ J], 1)
    tr_abs, tr_rel = simulate(ab, x_abs, 100), simulate(rel, x_rel, 100)
    np.testing.assert_allclose(tr_rel[..., :2] @ J.T, tr_abs[..., :2], rtol=0, atol=1e-9)


# --------------------------------------------------------------------------- (a) energy
@pytest.mark.parametrize("coordinates", ["absolute", "relative"])
def test_energy_conserved_without_damping(coordinates: str) -> None:
    """H drifts only by the RK4 error: small, and 16x smaller at twice the substeps (4th order)."""
    s = DoublePendulum(**RIG, coordinates=coordinates)
    x0 = s.sample_initial(np.random.default_rng(5), 8)
    drift = []
    for k in (6, 12):
        tr = simulate(s, x0, 300, substeps=k)
        H = s.hamiltonian(tuple(tr[..., i] for i in range(2)), tuple(tr[..., 2 + i] for i in range(2)), NUMPY)
        drift.append(float(np.max(np.abs(H - H[:, :1]))))
    assert drift[1] < 1e-6 and drift[0] / drift[1] > 10.0


def test_power_balance_relative_windy() -> None:
    """dH/dt = -qdot^T D qdot + qdot^T u along the windy relative rig (the damping acts on the joint rates)."""
    s = DoublePendulum(**RIG, coordinates="relative", b=0.1, d0=0.2, dd=0.4)
    q, qd, u = _states(6)
    p = _momentum(s, q, qd)
    qdot, pdot = _rhs(s, q, p, u)
    eps = 1e-6
    H = [s.hamiltonian(tuple((q + k * eps * qdot).T), tuple((p + k * eps * pdot).T)) for k in (-1, 1)]
    diss, supplied = s.power_balance(tuple(q.T), tuple(p.T), tuple(u.T))
    d = np.stack(s.damping(tuple(q.T)), 1)
    np.testing.assert_allclose(d, 0.3 + 0.4 * np.abs(np.sin(q)), rtol=1e-12)
    np.testing.assert_allclose((H[1] - H[0]) / (2 * eps), supplied - diss, rtol=1e-6, atol=1e-6)


# --------------------------------------------------------------------------- (d) namespaces
@pytest.mark.parametrize("coordinates", ["absolute", "relative"])
@pytest.mark.parametrize("dd", [0.0, 0.5])
def test_torch_and_scalar_rhs_equal_numpy(coordinates: str, dd: float) -> None:
    s = DoublePendulum(**RIG, coordinates=coordinates, b=0.1, d0=0.2, dd=dd)
    q, qd, u = _states(7, 16)
    p = _momentum(s, q, qd)
    qdot, pdot = _rhs(s, q, p, u)
    t = [torch.as_tensor(a.T.copy()) for a in (q, p, u)]
    tq, tp = s.rhs(tuple(t[0]), tuple(t[1]), tuple(t[2]), TORCH)
    np.testing.assert_allclose(torch.stack(tq, 1).numpy(), qdot, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(torch.stack(tp, 1).numpy(), pdot, rtol=1e-13, atol=1e-13)
    sq, sp = s.rhs(tuple(q[3].tolist()), tuple(p[3].tolist()), tuple(u[3].tolist()), SCALAR)
    np.testing.assert_allclose(sq + sp, np.concatenate([qdot[3], pdot[3]]), rtol=1e-13, atol=1e-13)
    # the generic (unfused) path of System gives the same vector field
    gq, gp = super(DoublePendulum, s).rhs(tuple(q.T), tuple(p.T), tuple(u.T), NUMPY)
    np.testing.assert_allclose(np.stack(gp, 1), pdot, rtol=1e-12, atol=1e-12)
    assert (s.switching(tuple(q.T), tuple(p.T), NUMPY) is None) == (dd == 0.0)


# --------------------------------------------------------------------------- parameters and env
def test_bad_parameters_raise_naming_the_problem() -> None:
    with pytest.raises(ParameterError, match=r"coordinates='foo' must be one of \['absolute', 'relative'\]"):
        DoublePendulum(coordinates="foo")
    with pytest.raises(ParameterError, match="inertia1=-1"):
        DoublePendulum(inertia1=-1.0)
    with pytest.raises(ParameterError, match="not positive definite"):
        DoublePendulum(com2=0.0)  # default inertia2 = mass2 com2^2 = 0
    with pytest.raises(ParameterError, match="not positive definite"):
        DoublePendulum(inertia2=0.1, com2=1.0, mass2=1.0, inertia1=0.01, length1=1.0)


def test_sample_initial_relative_draws_joint_coordinates() -> None:
    """Relative rigs draw joint angles in [-pi, pi) and joint rates in [-2, 2] like the absolute ones."""
    s = DoublePendulum(**RIG, coordinates="relative")
    x = s.sample_initial(np.random.default_rng(8), 4000)
    q, p = x[:, :2], x[:, 2:]
    qd = np.stack(s.velocity(tuple(q.T), tuple(p.T)), 1)
    assert np.all(np.abs(q) <= math.pi) and np.all(np.abs(qd) <= 2.0 + 1e-9)
    assert np.all(np.std(q, 0) > 1.6) and np.all(np.std(qd, 0) > 1.0)


def test_gym_make_passes_rig_kwargs_to_the_system() -> None:
    kw = {"coordinates": "relative", "com1": 0.4, "inertia1": 0.35, "mass1": 1.3}
    env = gym.make("PHAST/DoublePendulum-v0", **kw)
    try:
        system = env.unwrapped.system
        assert system.coordinates == "relative" and system.c1 == 0.4 and system.i1 == 0.35 and system.c2 == 1.0
        obs, _ = env.reset(seed=0)
        obs2, *_ = env.step(np.array([1.0, -1.0], dtype=np.float32))
        assert np.all(np.isfinite(obs2))
    finally:
        env.close()
    assert phast_gym.make_env_system("PHAST/WindyDoublePendulum-v0", **kw).dd == 0.5
