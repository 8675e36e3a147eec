"""Learned configuration-dependent mass (PARTIAL templates, UNKNOWN Cholesky factor) and the least-squares start
of the learned physics from q-only data (phast_model.world.data_init)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from phast_gym import make_env_system
from phast_gym.datasets import make_dataset
from phast_gym.systems import NUMPY, split
from phast_model.components import CholeskyMass, TemplateMass
from phast_model.world import data_init
from phast_model.world.core import PHASTCore
from phast_model.world.regimes import build_model

torch.set_num_threads(1)
FAST = settings(max_examples=20, deadline=None)


def _check_mass(mass, q: torch.Tensor) -> None:  # noqa: ANN001
    """SPD, symmetric, velocity = M^-1 p, momentum = M v, kinetic_dq = autograd of p^T M^-1 p / 2."""
    M = mass.matrix(q)
    assert torch.allclose(M, M.transpose(-1, -2))
    assert float(torch.linalg.eigvalsh(M.detach()).min()) > 0
    p = torch.randn(q.shape, dtype=q.dtype)
    v = mass.velocity(q, p)
    assert torch.allclose(v, torch.linalg.solve(M, p.unsqueeze(-1)).squeeze(-1), rtol=1e-6, atol=1e-8)
    assert torch.allclose(mass.momentum(q, v), p, rtol=1e-6, atol=1e-8)
    qq = q.clone().requires_grad_(True)
    T = 0.5 * (p.unsqueeze(-2) @ torch.linalg.solve(mass.matrix(qq), p.unsqueeze(-1))).sum()
    (g,) = torch.autograd.grad(T, qq)
    assert torch.allclose(mass.kinetic_dq(q, p), g, rtol=1e-6, atol=1e-8)


@FAST
@given(kind=st.sampled_from(TemplateMass.KINDS), raw=st.lists(st.floats(-6, 6), min_size=3, max_size=3),
       seed=st.integers(0, 1000))
def test_template_mass_is_spd_everywhere(kind, raw, seed):
    mass = TemplateMass(kind).double()
    with torch.no_grad():
        mass.raw.copy_(torch.tensor(raw))
    torch.manual_seed(seed)
    _check_mass(mass, torch.randn(64, 2, dtype=torch.float64) * 4)


@FAST
@given(n=st.integers(1, 4), n_angles=st.integers(0, 4), seed=st.integers(0, 1000))
def test_cholesky_mass_is_spd_everywhere(n, n_angles, seed):
    torch.manual_seed(seed)
    mass = CholeskyMass(n, tuple(range(min(n, n_angles))), hidden=16).double()
    for prm in mass.net.parameters():  # large random weights: M = L L^T with a positive diagonal whatever the weights
        prm.data.normal_(0, 2.0)
    q = torch.randn(64, n, dtype=torch.float64) * 3
    L = mass.factor(q).detach()
    assert torch.equal(L, torch.tril(L))
    assert float(torch.diagonal(L, dim1=-2, dim2=-1).min()) >= 1e-3
    for prm in mass.net.parameters():  # moderate weights: the numerical identities at a usable conditioning
        prm.data.normal_(0, 0.3)
    _check_mass(mass, torch.randn(32, n, dtype=torch.float64))


@pytest.mark.parametrize("kind, env_kwargs", [("cartpole", {}), ("double_pendulum", {}),
                                               ("double_pendulum_relative", {"coordinates": "relative"})])
def test_template_mass_spans_the_true_mass(kind, env_kwargs):
    """The env's own M(q) is one of the template's matrices (fitted through ``set_linear``)."""
    env_id = "PHAST/WindyCartPole-v0" if kind == "cartpole" else "PHAST/DoublePendulum-v0"
    system = make_env_system(env_id, **env_kwargs)
    q = system.sample_initial(np.random.default_rng(0), 16)[:, :2]
    rows = system.mass_matrix(split(q), NUMPY)
    true = np.stack([np.stack([np.broadcast_to(r, (16,)) for r in row], -1) for row in rows], -2)
    mass = TemplateMass(kind).double()
    B = mass.linear_basis(torch.as_tensor(q)).numpy()  # (16, 3, 2, 2)
    theta = np.linalg.lstsq(B.reshape(16, 3, 4).transpose(0, 2, 1).reshape(-1, 3), true.reshape(-1), rcond=None)[0]
    mass.set_linear(torch.as_tensor(theta))
    np.testing.assert_allclose(mass.matrix(torch.as_tensor(q)).detach().numpy(), true, rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("env_id, truth", [
    ("PHAST/DoublePendulum-v0", {"abc": (2.0, 1.0, 1.0), "coef": (2 * 9.81, 9.81)}),
    ("PHAST/WindyCartPole-v0", {"abc": (2.0, 1.0, 1.0), "coef": (9.81,)}),
])
def test_partial_recovers_template_coefficients_on_noiseless_data(env_id, truth):
    """PARTIAL starts from q-only data, not from the env's physics: the least squares recovers the mass template
    and the potential coefficients up to the scale gauge (fixed for the windy cart-pole by its damping floor)."""
    ds = make_dataset(env_id, 64, T=200, seed=3)
    model = build_model(env_id, "partial")
    assert model.config.mass == "template" and model.config.init_from == "data"
    before = model.potential.template.coef.detach().clone()
    info = model.initialize_from_data(torch.as_tensor(ds.q, dtype=torch.float32), None)
    assert info["init_residual"] < 0.01
    abc = np.array([float(x) for x in model.mass.coefficients()])
    coef = model.potential.template.coef.detach().numpy()
    scale = abc[0] / truth["abc"][0]  # the double pendulum has no physical scale in its data (u = 0, no floor)
    if "Windy" in env_id:
        assert scale == pytest.approx(1.0, rel=0.1)  # the fixed damping floor d0 sets the physical scale
    np.testing.assert_allclose(abc / scale, truth["abc"], rtol=0.03)
    np.testing.assert_allclose(coef / scale, truth["coef"], rtol=0.03)
    assert not torch.equal(before, model.potential.template.coef.detach())


def test_physics_init_is_a_named_variant():
    """init_from="physics" is the "V given" variant: template and mass fitted to the env's true V and M."""
    given_ = build_model("PHAST/DoublePendulum-v0", "partial", init_from="physics")
    data = build_model("PHAST/DoublePendulum-v0", "partial")
    np.testing.assert_allclose(given_.potential.template.coef.detach().numpy(), [2 * 9.81, 9.81], rtol=1e-4)
    np.testing.assert_allclose(data.potential.template.coef.detach().numpy(), [1.0, 1.0])  # untouched until fit
    with pytest.raises(ValueError, match="init_from"):
        build_model("PHAST/DoublePendulum-v0", "partial", init_from="truth")


def test_known_damping_floor_starts_below_the_smallest_damping():
    ds = make_dataset("PHAST/WindyCartPole-v0", 64, T=200, seed=3)
    model = build_model("PHAST/WindyCartPole-v0", "known")
    info = model.initialize_from_data(torch.as_tensor(ds.q, dtype=torch.float32), None)
    assert 0.25 < info["init_damping_floor"] < 0.35  # min_q D = 0.3 (cart friction, and the pole's wind floor)
    assert float(model.damping.d0) == pytest.approx(model.floor_margin * info["init_damping_floor"], rel=1e-5)
    assert float(model.damping.d0) < 0.3


@pytest.mark.parametrize("env_id, rate", [("PHAST/DampedPendulum-v0", 0.5), ("PHAST/DampedDoublePendulum-v0", None),
                                          ("PHAST/Pendulum-v0", 0.0)])
def test_partial_learned_damping_floor_starts_from_the_data(env_id, rate):
    """A learned floor d0 starts below the data's smallest D in the fitted gauge: where D is 0 at its smallest
    value, at MIN_D0 (not at the generic 0.1 the observer could absorb; regime diagnostics in docs/results.md)."""
    ds = make_dataset(env_id, 64, T=200, seed=3)
    model = build_model(env_id, "partial")
    assert model.damping.learn_d0
    info = model.initialize_from_data(torch.as_tensor(ds.q, dtype=torch.float32), None)
    d0 = float(model.damping.d0)
    assert info["init_d0"] == pytest.approx(d0)
    if rate == 0.0:
        assert d0 == pytest.approx(data_init.MIN_D0, rel=1e-4)
    elif rate is not None:  # 1-dof: the damping rate d0 / M is gauge-free
        m = float(model.mass.matrix(torch.zeros(1, 1))[0, 0, 0])
        assert d0 / m == pytest.approx(model.floor_margin * rate, rel=0.1)
    else:
        assert data_init.MIN_D0 < d0


@pytest.mark.parametrize("regime, mass", [("partial", "template"), ("unknown", "cholesky")])
def test_configuration_dependent_mass_uses_implicit_midpoint(regime, mass):
    model = build_model("PHAST/WindyCartPole-v0", regime)
    assert model.config.mass == mass and model.config.canonicalizer == "mass"
    assert isinstance(model.core, PHASTCore) and model.core.integrator == "implicit_midpoint"
    q = torch.randn(4, 30, 2)
    out = model(q)
    assert out.shape == q.shape and torch.isfinite(out).all()
    out.pow(2).mean().backward()  # gradients flow through the learned M(q) (incl. the autograd kinetic_dq)
    grads = [p.grad for p in model.mass.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    assert any(float(g.abs().max()) > 0 for g in grads)


@pytest.mark.parametrize("with_port", [False, True])
def test_predator_prey_partial_starts_from_the_observed_prey(with_port):
    """The Lotka-Volterra template starts from a least squares on the prey alone (the predator is latent), not from
    the env's rhs: the identified rates are the env's; the predation coefficient is the latent's unit, identified
    by a port input and otherwise fixed so the mean latent equals the mean prey density."""
    env_id = "PHAST/PredatorPrey-v0"
    u = 0.5 * np.sin(0.3 * np.arange(199))[None, :, None] if with_port else None
    ds = make_dataset(env_id, 64, T=200, seed=3, u=u, cache=False)
    model = build_model(env_id, "partial")
    assert model.config.init_from == "data"
    np.testing.assert_allclose(model.core.field.coef.detach().numpy()[[0, 1, 3, 4]], 0.0)  # neutral until fit
    q = torch.as_tensor(ds.q, dtype=torch.float32)
    ut = None if u is None else torch.as_tensor(np.broadcast_to(u, (64, 199, 1)).copy(), dtype=torch.float32)
    info = model.initialize_from_data(q, ut)
    c = np.array([info[f"lv_c{i}"] for i in range(1, 6)])
    a, b, cc, d, K, mu = 1.0, 0.1, 0.4, 0.1, 100.0, 0.01
    np.testing.assert_allclose(c[[0, 1, 3, 4]], [a - mu, -a / K, d, -(cc + mu)], rtol=0.06, atol=2e-3)
    if with_port:
        assert c[2] == pytest.approx(-b, rel=0.06)
    else:
        lat = model.canonicalize(q.reshape(-1, 1)[::7], torch.zeros(1)).detach()  # latent of qdot = 0, finite
        assert torch.isfinite(lat).all() and c[2] < 0
    assert np.allclose(model.core.field.coef.detach().numpy(), c, rtol=1e-5)
    phys = build_model(env_id, "partial", init_from="physics").core.field.coef.detach().numpy()
    np.testing.assert_allclose(phys, [a - mu, -a / K, -b, d, -(cc + mu)], rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("excite", [False, True])
def test_an_excited_port_fixes_the_scale_of_the_partial_start(excite):
    """Free motion leaves (V, M, D) -> c (V, M, D) open and the constant mass starts neutral (M = 1); with the port
    driven, the least squares identifies M itself (here m l^2 = 2, m g l = 19.62) and with it the input gain."""
    from phast_gym.datasets import PortExcitation

    env, kw = "PHAST/DampedPendulum-v0", {"mass": 2.0}
    u = PortExcitation(2.0).for_env(env, 64, 200) if excite else None
    ds = make_dataset(env, 64, T=200, seed=3, u=u, **kw)
    model = build_model(env, "partial", env_kwargs=kw)
    model.initialize_from_data(torch.as_tensor(ds.q, dtype=torch.float32),
                               torch.as_tensor(ds.u, dtype=torch.float32) if excite else None)
    minv = float(model.velocity(torch.zeros(1, 1), torch.ones(1, 1)).detach()[0, 0])
    coef = float(model.potential.template.coef.detach()[0])
    assert coef * minv == pytest.approx(9.81, rel=0.05)  # the free dynamics are identified either way
    if excite:
        assert minv == pytest.approx(0.5, rel=0.1) and coef == pytest.approx(19.62, rel=0.1)
    else:
        assert minv == pytest.approx(1.0, rel=0.02)  # the neutral gauge: the scale is not in the data
