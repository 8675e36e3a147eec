"""PHAST components: PSD/SPD guarantees, Woodbury, passivity, causality, KNOWN == env physics."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from phast_gym import env_ids, make_env_system
from phast_gym.integrate import simulate
from phast_model.components import FDTCNObserver, HouseholderDamping, LowRankMass, NeuralPotential
from phast_model.components.observer import backward_difference_weights
from phast_model.world.core import PHASTCore, composed_strang_step
from phast_model.world.regimes import REGIMES, build_model

torch.set_num_threads(1)
FAST = settings(max_examples=15, deadline=None)


@FAST
@given(n=st.integers(1, 5), rank=st.integers(1, 3), seed=st.integers(0, 10_000),
       cap=st.one_of(st.none(), st.floats(0.05, 3.0)), d0=st.floats(0.0, 1.0))
def test_damping_psd_and_cap(n, rank, seed, cap, d0):
    torch.manual_seed(seed)
    damp = HouseholderDamping(n, rank=rank, cap=cap, d0=d0, learn_d0=cap is None).double()
    for p in damp.net.parameters():  # random, large parameters
        p.data.normal_(0, 2.0)
    q = torch.randn(64, n, dtype=torch.float64) * 3
    D = damp.matrix(q)
    eig = torch.linalg.eigvalsh(D)
    assert eig.min() >= -1e-9
    assert torch.allclose(D, D.transpose(-1, -2))
    beta, k = damp.terms(q)
    assert torch.allclose(k.norm(dim=-1), torch.ones_like(beta), atol=1e-6)
    if cap is not None:
        assert float(beta.sum(-1).max().detach()) <= cap + 1e-9
        assert float(eig.max().detach()) <= float(damp.d0.detach()) + cap + 1e-9  # certified lambda_max bound (Eq. 11)
    v = torch.randn(64, n, dtype=torch.float64)
    assert torch.allclose(damp.force(q, v), (D @ v.unsqueeze(-1)).squeeze(-1), atol=1e-10)  # O(n r) == dense
    assert torch.allclose(damp.diag(q), torch.diagonal(D, dim1=-2, dim2=-1), atol=1e-10)


@pytest.mark.parametrize("cap", [None, 1.0])
def test_one_coordinate_damping_has_no_direction_gauge(cap):
    """n = 1: k = +-1, so D = d0 + sum beta whatever the direction outputs; they get no gradient (a normalized
    scalar's round-off gradient, amplified by Adam, random-walked it to a zero crossing that zeroed D)."""
    torch.manual_seed(0)
    damp = HouseholderDamping(1, rank=2, cap=cap, d0=0.1).double()
    q = torch.linspace(-3, 3, 101, dtype=torch.float64)[:, None]
    with torch.no_grad():  # direction outputs crossing zero inside the data range
        damp.net[-1].weight[:2].zero_()
        damp.net[-1].bias[:2] = torch.tensor([0.0, 1e-6])
    beta, k = damp.terms(q)
    assert torch.equal(k, torch.ones_like(k))
    assert torch.allclose(damp.diag(q)[:, 0], damp.d0 + beta.sum(-1))
    (damp.diag(q).sum() + damp.force(q, torch.randn_like(q)).sum()).backward()
    assert float(damp.net[-1].weight.grad[:2].abs().max()) == 0.0
    assert float(damp.net[-1].weight.grad[2:].abs().max()) > 0.0


@FAST
@given(n=st.integers(1, 5), n_angles=st.integers(0, 2), layers=st.integers(2, 4), seed=st.integers(0, 10_000))
def test_neural_potential_gradient_is_autograds(n, n_angles, layers, seed):
    """The written-out dV/dq equals autograd's, and so do the parameter gradients of a loss on it (what training
    differentiates: a double backward for autograd's)."""
    from phast_model.components.potentials import autograd_grad

    torch.manual_seed(seed)
    angles = tuple(range(min(n_angles, n)))
    pot = NeuralPotential(n, angles, layers=layers, q_scale=0.5 + torch.rand(n - len(angles)), out_scale=3.0).double()
    q = torch.randn(4, 6, n, dtype=torch.float64) * 2
    w = torch.randn(4, 6, n, dtype=torch.float64)
    fast, ref = pot.grad(q), autograd_grad(pot.energy, q)
    assert torch.allclose(fast, ref, atol=1e-12, rtol=1e-10)
    params = list(pot.parameters())  # the output bias does not enter dV/dq: its gradient is None in both
    g_fast = torch.autograd.grad((fast * w).sum(), params, allow_unused=True)
    g_ref = torch.autograd.grad((ref * w).sum(), params, allow_unused=True)
    for a, b, p in zip(g_fast, g_ref, params):
        zero = torch.zeros_like(p)
        assert torch.allclose(zero if a is None else a, zero if b is None else b, atol=1e-12, rtol=1e-10)


@FAST
@given(n=st.integers(1, 6), rank=st.integers(1, 4), seed=st.integers(0, 10_000))
def test_mass_spd_and_woodbury(n, rank, seed):
    torch.manual_seed(seed)
    mass = LowRankMass(n, rank, seed=seed).double()
    mass.raw_d.data.normal_(0, 1.0)
    mass.U.data.normal_(0, 1.0)
    M = mass.matrix()
    assert float(torch.linalg.eigvalsh(M).min()) > 0
    p = torch.randn(7, 3, n, dtype=torch.float64)
    dense = torch.linalg.solve(M, p.reshape(-1, n).T).T.reshape(p.shape)
    assert torch.allclose(mass.velocity(None, p), dense, atol=1e-9, rtol=1e-9)
    assert torch.allclose(mass.momentum(None, mass.velocity(None, p)), p, atol=1e-9)


@FAST
@given(n=st.integers(1, 4), seed=st.integers(0, 10_000))
def test_continuous_time_passivity(n, seed):
    """dH/dt = grad_q H . qdot + grad_p H . pdot = -v^T D v <= 0 for random parameters, u = 0 (Thm. A.1)."""
    torch.manual_seed(seed)
    pot = NeuralPotential(n).double()
    mass = LowRankMass(n, 2, seed=seed).double()
    mass.U.data.normal_(0, 1.0)
    damp = HouseholderDamping(n, rank=2).double()
    for p in damp.net.parameters():
        p.data.normal_(0, 1.0)
    core = PHASTCore(pot, mass, damp, dt=0.05).double()
    q = torch.randn(32, n, dtype=torch.float64, requires_grad=True)
    p = torch.randn(32, n, dtype=torch.float64, requires_grad=True)
    H = core.hamiltonian(q, p)
    gq, gp = torch.autograd.grad(H.sum(), (q, p))
    qdot = gp
    pdot = -gq - damp.force(q, gp)
    dHdt = (gq * qdot).sum(-1) + (gp * pdot).sum(-1)
    assert float(dHdt.max()) <= 1e-9
    assert torch.allclose(dHdt, core.power(q, p), atol=1e-8)


@FAST
@given(n=st.integers(1, 4), seed=st.integers(0, 10_000), cap=st.floats(0.1, 5.0))
def test_damping_half_step_energy_nonincreasing(n, seed, cap):
    """Phi_D(h/2) does not increase the kinetic energy when h lambda_max(D) / (2 lambda_min(M)) <= 2 (Eq. 44)."""
    torch.manual_seed(seed)
    mass = LowRankMass(n, 2, seed=seed).double()
    damp = HouseholderDamping(n, rank=2, cap=cap, d0=0.1, learn_d0=False).double()
    for p in damp.net.parameters():
        p.data.normal_(0, 1.0)
    core = PHASTCore(NeuralPotential(n).double(), mass, damp, dt=0.05).double()
    lam_min = float(torch.linalg.eigvalsh(mass.matrix()).min())
    h = torch.tensor(0.999 * 4.0 * lam_min / (0.1 + cap))  # (almost) the largest step the condition allows
    q = torch.randn(64, n, dtype=torch.float64)
    p = torch.randn(64, n, dtype=torch.float64)
    p1 = core.damping_half_step(q, p, h)
    H0, H1 = core.hamiltonian(q, p), core.hamiltonian(q, p1)
    assert bool((H1 <= H0 + 1e-9 * (1 + H0.abs())).all())


def test_observer_causal():
    obs = FDTCNObserver(2, 0.05, angle_dims=(1,))
    for p in obs.parameters():
        p.data.normal_(0, 0.5)
    q = torch.randn(3, 40, 2)
    base = obs(q)
    q2 = q.clone()
    q2[:, 25:] += torch.randn(3, 15, 2) * 5
    out = obs(q2)
    assert torch.allclose(base[:, :25], out[:, :25])
    assert not torch.allclose(base[:, 25:], out[:, 25:])
    # finite receptive field: the last estimate only depends on the last `window` samples
    assert torch.allclose(obs(q)[:, -1], obs(q[:, -obs.window:])[:, -1], atol=1e-6)


def test_observer_startup_uses_available_order():
    """At t < fd_order the observer uses the backward difference of order t (exact for degree-t polynomials),
    not the order-4 formula with missing history read as zero velocity."""
    dt = 0.1
    obs = FDTCNObserver(1, dt, fd_order=4).double()
    t = torch.arange(12, dtype=torch.float64) * dt
    for deg in (1, 2, 3):
        q = (t**deg + 0.7 * t).reshape(1, -1, 1)
        v = obs(q)[0, :, 0]
        exact = deg * t ** (deg - 1) + 0.7
        assert float(v[0]) == 0.0  # one sample: no velocity information
        for k in range(deg, 12):  # order min(k, 4) >= deg: exact
            assert abs(float(v[k] - exact[k])) < 1e-5, (deg, k)  # float32-initialized weights


def test_backward_difference_exact_on_polynomials():
    for order in (1, 2, 4):
        w = backward_difference_weights(order)
        t = np.arange(-order, 1) * 0.1
        q = 0.3 * t**order + t  # degree `order` polynomial: BDF of that order is exact
        d = np.diff(q)[::-1] / 0.1  # d_k = (q_{t-k} - q_{t-k-1}) / dt
        assert np.isclose((w * d).sum(), 1.0 + (0.3 * order * 0.0 if order > 1 else 0.3), atol=1e-9)


def test_known_model_reproduces_env():
    """KNOWN V, M and the env's true damping, true p, small substeps: the core matches the env's RK4."""
    env = "PHAST/WindyCartPole-v0"
    system = make_env_system(env)
    x0 = system.sample_initial(np.random.default_rng(0), 8)
    traj = simulate(system, x0, 20)
    model = build_model(env, "known", damping="known", substeps=40, learn_dt=False, midpoint_iters=8).double()
    n = system.n
    q = torch.as_tensor(traj[:, 0, :n])
    p = torch.as_tensor(traj[:, 0, n:])
    for _t in range(20):
        q, p = model.step(q, p)
    assert np.allclose(q.numpy(), traj[:, 20, :n], atol=2e-4)
    assert np.allclose(p.numpy(), traj[:, 20, n:], atol=2e-4)


@pytest.mark.parametrize("env_id", env_ids())
def test_every_regime_builds_and_is_finite(env_id):
    for regime in REGIMES:
        model = build_model(env_id, regime)
        x0 = make_env_system(env_id).sample_initial(np.random.default_rng(0), 2)[:, : model.n]
        q = torch.as_tensor(x0, dtype=torch.float32).unsqueeze(1) + 0.001 * torch.randn(2, 16, model.n).cumsum(1)
        out = model(q)
        assert out.shape == q.shape and bool(torch.isfinite(out).all())
        roll = model.rollout(q[:, :10], None, 3)
        assert roll.shape == (2, 3, model.n)


def test_fast_rollout_equals_generic_definition():
    model = build_model("PHAST/WindyPendulum-v0", "partial").double()
    for p in model.observer.parameters():
        p.data.normal_(0, 0.3)
    q = torch.rand(3, 10, 1, dtype=torch.float64) * 2 - 1
    fast = model.rollout(q, None, 15)
    slow = super(type(model), model).rollout(q, None, 15)  # ForecastModel's O(H^2) reference
    assert torch.allclose(fast, slow, atol=1e-9)


def test_rollouts_apply_the_port_input_past_the_burn_in():
    """u covers the burn-in and the horizon: both rollouts read it after the burn-in (they once cropped it to the
    burn-in, so a driven test set was scored as if the port were idle)."""
    model = build_model("PHAST/WindyPendulum-v0", "known").double()
    K, H = 10, 15
    q = torch.rand(3, K, 1, dtype=torch.float64) * 2 - 1
    u = torch.randn(3, K - 1 + H, 1, dtype=torch.float64) * 2
    fast = model.rollout(q, u, H)
    slow = super(type(model), model).rollout(q, u, H)  # ForecastModel's O(H^2) reference
    assert torch.allclose(fast, slow, atol=1e-9)
    assert (fast - model.rollout(q, None, H)).abs().max() > 1e-2  # the input moves the pendulum
    qt, pt = model.infer_state(q)
    ref = []
    for h in range(H):
        qt, pt = model.core(qt, pt, model.port_force(u[:, K - 1 + h]))
        ref.append(qt)
    wrapped = torch.remainder(torch.stack(ref, 1) + math.pi, 2 * math.pi) - math.pi
    assert torch.allclose(model.rollout_takeover(q, u, H), wrapped, atol=1e-9)


def test_bad_config_values_raise():
    with pytest.raises(ValueError, match="regime"):
        build_model("PHAST/WindyPendulum-v0", "magic")
    with pytest.raises(ValueError, match="override"):
        build_model("PHAST/WindyPendulum-v0", "known", not_a_field=1)
    with pytest.raises(ValueError, match="cap"):
        HouseholderDamping(2, cap=-1.0)


def test_predator_prey_latent_inversion_recovers_predators():
    """KNOWN predator-prey: the latent predator density is recovered exactly from the prey velocity."""
    model = build_model("PHAST/PredatorPrey-v0", "known").double()
    x = make_env_system("PHAST/PredatorPrey-v0").sample_initial(np.random.default_rng(0), 32)
    q, p = torch.as_tensor(x[:, :1]), torch.as_tensor(x[:, 1:])
    qdot, _ = model.core.field.rhs(q, p, None)
    assert torch.allclose(model.canonicalize(q, qdot), p, atol=1e-9)


def test_observer_roll_loss_is_the_scored_rollout() -> None:
    # roll_mode="observer" unrolls PHAST.rollout (the observer re-run on predicted samples): over one step it is the
    # teacher-forced one-step error at the drawn start; an unknown mode is a clear error
    import torch

    from phast_gym import make_dataset
    from phast_model.world.interfaces import coordinate_error
    from phast_model.world.regimes import build_model

    ds = make_dataset("PHAST/WindyCartPole-v0", n_traj=3, T=40, seed=5)
    model = build_model("PHAST/WindyCartPole-v0", "unknown", lambda_roll=1.0, roll_horizon=1, roll_mode="observer")
    q, u = model._prep(torch.as_tensor(ds.q), torch.as_tensor(ds.u))
    torch.manual_seed(3)
    loss = model.extra_losses(q, u, None)["roll"]
    torch.manual_seed(3)
    first = max(model.loss_skip, model.observer.window - 1)
    t0 = int(torch.randint(first, q.shape[1] - 1, ()).item())
    expected = (coordinate_error(model(q, u)[:, t0], q[:, t0 + 1], model.angle_dims) ** 2).mean()
    assert torch.allclose(loss, expected, rtol=1e-5, atol=1e-12)
    loss.backward()  # the loss trains the model: gradients reach the potential, the mass and the observer
    for part in (model.potential, model.mass, model.observer):
        assert any(p.grad is not None and bool(p.grad.abs().sum() > 0) for p in part.parameters())
    model.config.roll_mode = "nope"
    with pytest.raises(ValueError, match="roll_mode"):
        model.extra_losses(q, u, None)



@pytest.mark.parametrize("env_id,regime", [("PHAST/Oscillator-v0", "partial"), ("PHAST/WindyPendulum-v0", "unknown"),
                                           ("PHAST/DampedDoublePendulum-v0", "partial"),
                                           ("PHAST/WindyCartPole-v0", "known")])
@pytest.mark.parametrize("need_p", [True, False])
def test_strang_step_reuse_equals_composition(env_id, regime, need_p):
    """strang_step reuses D(q) and dV/dq at each substep's end point; values and parameter gradients equal the
    plain composition of the splitting pieces."""
    model = build_model(env_id, regime, seed=3).double()
    core = model.core
    torch.manual_seed(3)
    for prm in core.parameters():  # move away from the initialization so every term contributes
        prm.data.add_(0.05 * torch.randn_like(prm))
    n = model.system.n
    gen = torch.Generator().manual_seed(0)
    q = torch.randn(16, n, generator=gen, dtype=torch.float64)
    p = torch.randn(16, n, generator=gen, dtype=torch.float64)
    f = torch.randn(16, n, generator=gen, dtype=torch.float64)
    results = []
    for step in (lambda: core.strang_step(q, p, f, need_p=need_p), lambda: composed_strang_step(core, q, p, f, need_p)):
        core.zero_grad(set_to_none=True)
        q1, p1 = step()
        ((q1 ** 2).sum() + (p1 ** 2).sum()).backward()
        grads = [prm.grad.clone() for prm in core.parameters() if prm.grad is not None]
        results.append((q1.detach(), p1.detach(), grads))
    (qa, pa, ga), (qb, pb, gb) = results
    assert torch.equal(qa, qb) and torch.equal(pa, pb)
    assert len(ga) == len(gb) > 0
    for a, b in zip(ga, gb, strict=True):
        assert torch.allclose(a, b, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("regime", ["known", "unknown"])
def test_module_apply_reaches_every_submodule(regime):
    """``nn.Module.apply(fn)`` on a built model visits the damping too (D(q) v is ``Damping.force``, so no damping
    shadows ``apply``), and an init function through it changes the model's parameters."""
    model = build_model("PHAST/WindyPendulum-v0", regime)
    damping = model.core.damping
    assert damping is not None
    seen: list[torch.nn.Module] = []
    assert model.apply(seen.append) is model
    assert len(seen) == len(list(model.modules())) and any(m is damping for m in seen)

    def zero_linear_biases(m: torch.nn.Module) -> None:
        if isinstance(m, torch.nn.Linear) and m.bias is not None:
            torch.nn.init.zeros_(m.bias)

    model.apply(zero_linear_biases)
    biases = [m.bias for m in model.modules() if isinstance(m, torch.nn.Linear) and m.bias is not None]
    assert all(torch.count_nonzero(b) == 0 for b in biases)
    q = torch.zeros(3, model.n, dtype=next(model.parameters()).dtype)
    assert torch.isfinite(damping.force(q, torch.ones_like(q))).all()
