"""The ``armature`` term: reflected rotor inertia added to M_ii, with H, dH/dq and the port kept consistent."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from phast_gym.integrate import simulate
from phast_gym.systems import NUMPY, SCALAR, TORCH, DoublePendulum, Pendulum, System, solve_spd
from phast_model.mismatch.vocabulary.terms import AugmentedSystem, Term

RIG = {"mass1": 1.3, "mass2": 0.8, "length1": 0.9, "length2": 1.2, "com1": 0.4, "com2": 0.55,
       "inertia1": 0.35, "inertia2": 0.3}


def _cols(x: np.ndarray) -> tuple:
    return tuple(x[..., i] for i in range(x.shape[-1]))


def _dH_dt(system: System, q: tuple, p: tuple, u: tuple | None, eps: float = 1e-6) -> np.ndarray:
    """dH/dt along the vector field, by a central difference of H (independent of dH/dq and dH/dp)."""
    qd, pd = system.rhs(q, p, u, NUMPY)
    hp = system.hamiltonian(tuple(a + eps * b for a, b in zip(q, qd)), tuple(a + eps * b for a, b in zip(p, pd)))
    hm = system.hamiltonian(tuple(a - eps * b for a, b in zip(q, qd)), tuple(a - eps * b for a, b in zip(p, pd)))
    return (hp - hm) / (2 * eps)


@pytest.mark.parametrize(("coordinates", "joint", "param"), [("relative", 0, "inertia1"), ("absolute", 0, "inertia1"),
                                                            ("absolute", 1, "inertia2")])
def test_armature_equals_the_added_link_inertia(coordinates: str, joint: int, param: str) -> None:
    """Where the link inertia enters M only at M_ii, armature c on joint i is the same system as inertia_i + c."""
    c = 0.07
    kw = {**RIG, "coordinates": coordinates, "b": 0.1, "d0": 0.05, "dd": 0.2}
    aug = AugmentedSystem(DoublePendulum(**kw), [Term("armature", joint, c), Term("viscous_damping", 1, 0.05)])
    ref = AugmentedSystem(DoublePendulum(**{**kw, param: kw[param] + c}), [Term("viscous_damping", 1, 0.05)])
    x0 = ref.sample_initial(np.random.default_rng(0), 6)
    u = np.random.default_rng(1).uniform(-1.0, 1.0, (6, 200, 2))
    np.testing.assert_allclose(simulate(aug, x0, 200, u=u), simulate(ref, x0, 200, u=u), rtol=0, atol=1e-10)


@pytest.mark.parametrize("case", ["double_pendulum_joint1", "pendulum"])
def test_energy_conserved_with_armature(case: str) -> None:
    if case == "pendulum":
        aug = AugmentedSystem(Pendulum(), [Term("armature", 0, 0.3)])
    else:
        aug = AugmentedSystem(DoublePendulum(**RIG, coordinates="relative"), [Term("armature", 1, 0.05)])
    x0 = aug.sample_initial(np.random.default_rng(2), 8)
    n = aug.n
    q, p = _cols(x0[:, :n]), _cols(x0[:, n:])
    np.testing.assert_allclose(_dH_dt(aug, q, p, None), 0.0, atol=1e-6)
    drift = []
    for k in (6, 12):
        tr = simulate(aug, x0, 300, substeps=k)
        H = aug.hamiltonian(_cols(tr[..., :n]), _cols(tr[..., n:]))
        drift.append(float(np.max(np.abs(H - H[:, :1]))))
    assert drift[1] < 1e-6 and (drift[1] < 1e-12 or drift[0] / drift[1] > 10.0)


def test_dH_dq_at_fixed_p_matches_finite_differences() -> None:
    aug = AugmentedSystem(DoublePendulum(**RIG, coordinates="relative"),
                          [Term("armature", 0, 0.1), Term("armature", 1, 0.04), Term("linear_stiffness", 1, 0.3)])
    x = aug.sample_initial(np.random.default_rng(3), 32)
    q, p = _cols(x[:, :2]), _cols(x[:, 2:])
    eps = 1e-6
    for i in range(2):
        dq = [0.0, 0.0]
        dq[i] = eps
        fd = (aug.hamiltonian(tuple(a + d for a, d in zip(q, dq)), p) - aug.hamiltonian(tuple(a - d for a, d in zip(q, dq)), p))
        np.testing.assert_allclose(aug.dH_dq(q, p)[i], fd / (2 * eps), rtol=1e-6, atol=1e-6)
    # qdot = (M + A)^-1 p, and the armature adds c to M_ii only
    (m11, m12), (m21, m22) = aug.mass_matrix(q)
    (b11, b12), (_, b22) = aug.base.mass_matrix(q)
    assert np.array_equal(m12, b12) and np.array_equal(m21, b12)
    np.testing.assert_allclose(m11 - b11, 0.1, rtol=1e-12)
    np.testing.assert_allclose(m22 - b22, 0.04, rtol=1e-12)
    v = aug.velocity(q, p)
    np.testing.assert_allclose(m11 * v[0] + m12 * v[1], p[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(m21 * v[0] + m22 * v[1], p[1], rtol=1e-12, atol=1e-12)


def test_armature_model_stays_passive_with_friction() -> None:
    aug = AugmentedSystem(DoublePendulum(**RIG, coordinates="relative", b=0.1, d0=0.1, dd=0.3),
                          [Term("armature", 0, 0.08), Term("armature", 1, 0.03), Term("coulomb_friction", 0, 0.2),
                           Term("quadratic_drag", 1, 0.1), Term("stribeck_friction", 1, 0.1, velocity=0.3)])
    x = aug.sample_initial(np.random.default_rng(4), 64)
    q, p = _cols(x[:, :2]), _cols(x[:, 2:])
    u = _cols(np.random.default_rng(5).uniform(-2.0, 2.0, (64, 2)))
    diss, supplied = aug.power_balance(q, p, u)
    assert np.all(diss >= 0) and np.any(diss > 0)
    v = aug.velocity(q, p)
    np.testing.assert_allclose(supplied, v[0] * u[0] + v[1] * u[1], rtol=1e-12)
    np.testing.assert_allclose(_dH_dt(aug, q, p, u), supplied - diss, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(_dH_dt(aug, q, p, None), -aug.power_balance(q, p, None)[0], rtol=1e-6, atol=1e-6)


def test_armature_in_every_namespace() -> None:
    aug = AugmentedSystem(DoublePendulum(**RIG, coordinates="relative", dd=0.2),
                          [Term("armature", 0, 0.08), Term("viscous_damping", 0, 0.1)])
    x = aug.sample_initial(np.random.default_rng(6), 8)
    u = np.random.default_rng(7).uniform(-1.0, 1.0, (8, 2))
    qd, pd = aug.rhs(_cols(x[:, :2]), _cols(x[:, 2:]), _cols(u), NUMPY)
    t = torch.as_tensor(x)
    tq, tp = aug.rhs(tuple(t[:, :2].unbind(-1)), tuple(t[:, 2:].unbind(-1)), tuple(torch.as_tensor(u).unbind(-1)), TORCH)
    np.testing.assert_allclose(torch.stack(tq + tp, 1).numpy(), np.stack(qd + pd, 1), rtol=1e-13, atol=1e-13)
    sq, sp = aug.rhs(tuple(x[2, :2].tolist()), tuple(x[2, 2:].tolist()), tuple(u[2].tolist()), SCALAR)
    np.testing.assert_allclose(sq + sp, np.stack(qd + pd, 1)[2], rtol=1e-13, atol=1e-13)


def test_sample_initial_keeps_the_base_rates() -> None:
    base = DoublePendulum(**RIG, coordinates="relative")
    aug = AugmentedSystem(base, [Term("armature", 1, 0.2)])
    xa, xb = aug.sample_initial(np.random.default_rng(8), 16), base.sample_initial(np.random.default_rng(8), 16)
    np.testing.assert_array_equal(xa[:, :2], xb[:, :2])
    np.testing.assert_allclose(np.stack(aug.velocity(_cols(xa[:, :2]), _cols(xa[:, 2:])), 1),
                               np.stack(base.velocity(_cols(xb[:, :2]), _cols(xb[:, 2:])), 1), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("n", [1, 2, 3, 6])
def test_solve_spd_matches_numpy(n: int) -> None:
    rng = np.random.default_rng(n)
    a = rng.normal(size=(10, n, n))
    M = a @ a.transpose(0, 2, 1) + 0.5 * np.eye(n)
    b = rng.normal(size=(10, n))
    x = solve_spd([[M[:, i, j] for j in range(n)] for i in range(n)], [b[:, i] for i in range(n)])
    np.testing.assert_allclose(np.stack(x, 1), np.linalg.solve(M, b[..., None])[..., 0], rtol=1e-10, atol=1e-10)


def test_armature_term_validation_and_text() -> None:
    with pytest.raises(ValueError, match="armature .* must be >= 0"):
        Term("armature", 0, -0.1)
    with pytest.raises(ValueError, match="must be >= 0"):
        Term("armature", 0, float("nan"))
    with pytest.raises(ValueError, match="coordinates 0..0"):
        AugmentedSystem(Pendulum(), [Term("armature", 1, 0.1)])
    t = Term("armature", 1, 0.025)
    assert t.component == "inertia" and t.expression() == "M11 += 0.025 (reflected rotor inertia)"
    aug = AugmentedSystem(DoublePendulum(), [t])
    assert not aug.separable and AugmentedSystem(Pendulum(), [Term("armature", 0, 0.1)]).separable
