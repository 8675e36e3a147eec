"""Tests of the velocity-dependent joint friction (issue 30): passivity of the force law, the backward-Euler half-step
(never adds kinetic energy, converges, differentiable), its place in the PHAST core and in the model config."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from phast_model.components.friction import LAWS, JointFriction
from phast_model.components.mass import LowRankMass, TemplateMass
from phast_model.components.potentials import Potential
from phast_model.world.core import PHASTCore
from phast_model.world.regimes import build_model

FAST = settings(max_examples=25, deadline=None)
law_sets = st.lists(st.sampled_from(LAWS), min_size=1, max_size=len(LAWS), unique=True).map(tuple)


class ZeroPotential(Potential):
    """V = 0: a free system, so only the friction changes the energy."""

    def energy(self, q: torch.Tensor) -> torch.Tensor:
        return 0.0 * q.sum(-1)

    def grad(self, q: torch.Tensor) -> torch.Tensor:
        return torch.zeros_like(q)


def _inv_softplus(c: float) -> float:
    return c + math.log(-math.expm1(-c))


def _friction(n: int, laws: tuple[str, ...], seed: int, scale: float = 3.0, **kw) -> JointFriction:
    """A float64 friction with random raw coefficients (softplus spans ~e^-scale .. ~scale)."""
    fr = JointFriction(n, laws=laws, **kw).double()
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        fr.raw.copy_(scale * torch.randn(fr.raw.shape, generator=g, dtype=torch.float64))
    return fr


def _lowrank(n: int, seed: int) -> LowRankMass:
    """A random SPD constant mass diag(softplus(d)) + U U^T."""
    mass = LowRankMass(n, 2, seed=seed).double()
    g = torch.Generator().manual_seed(seed + 1)
    with torch.no_grad():
        mass.U.copy_(torch.randn(mass.U.shape, generator=g, dtype=torch.float64))
        mass.raw_d.copy_(torch.randn(n, generator=g, dtype=torch.float64))
    return mass


def _kinetic(mass, q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    return 0.5 * (p * mass.velocity(q, p)).sum(-1)


# ---- the force law ------------------------------------------------------------------
@FAST
@given(laws=law_sets, n=st.integers(1, 4), seed=st.integers(0, 10_000), eps=st.floats(1e-4, 1.0),
       vs=st.floats(1e-3, 2.0))
def test_force_is_passive(laws, n, seed, eps, vs):
    """f_i(v) v_i >= 0 for every coefficient value and every velocity (each shape is odd, phi(v) v >= 0)."""
    joints = tuple(range(0, n, 2))
    fr = _friction(n, laws, seed, joints=joints, eps=eps, vs=vs)
    scales = 10 ** torch.linspace(-4, 2, 256, dtype=torch.float64).unsqueeze(-1)  # |v| from 1e-4 to 1e2
    v = torch.randn(256, n, dtype=torch.float64, generator=torch.Generator().manual_seed(seed)) * scales
    f = fr.force(v)
    assert bool((f * v >= 0).all())
    assert bool((fr.power(v) >= 0).all())
    others = [i for i in range(n) if i not in joints]
    assert bool((f[:, others] == 0).all())


@pytest.mark.parametrize("laws", [(law,) for law in LAWS] + [LAWS])
def test_dforce_matches_autograd(laws):
    fr = _friction(3, laws, 0, joints=(0, 2), eps=(0.05, 0.2), vs=(0.3, 0.1))
    v = torch.randn(64, 3, dtype=torch.float64, requires_grad=True)
    (g,) = torch.autograd.grad(fr.force(v).sum(), v)  # f_i depends on v_i only: the gradient is the diagonal
    assert torch.allclose(fr.dforce(v), g, atol=1e-10, rtol=1e-10)


def test_coefficients_and_validation():
    fr = JointFriction(3, joints=(1,), laws=("coulomb", "stribeck"), init={"coulomb": 0.2, "stribeck": 0.05})
    c = {k: x.detach() for k, x in fr.coefficients().items()}
    assert set(c) == {"coulomb", "stribeck"} and c["coulomb"].shape == (1,)
    assert math.isclose(float(c["coulomb"]), 0.2, rel_tol=1e-5) and math.isclose(float(c["stribeck"]), 0.05, rel_tol=1e-5)
    for bad in ({"laws": ("sticky",)}, {"joints": (3,)}, {"eps": 0.0}, {"init": -1.0}, {"eps": (0.1, 0.2)}):
        with pytest.raises(ValueError):
            JointFriction(3, **{"joints": (0, 1, 2), **bad})


# ---- the backward-Euler half-step ----------------------------------------------------
@FAST
@given(laws=law_sets, n=st.integers(1, 4), seed=st.integers(0, 10_000), tau=st.floats(1e-4, 0.1),
       log_c=st.floats(-3, 3), eps=st.floats(1e-4, 0.1), iters=st.sampled_from([0, 1, 8]))
def test_half_step_never_adds_kinetic_energy(laws, n, seed, tau, log_c, eps, iters):
    """T(p_new) <= T(p) at fixed q for random SPD M, p, coefficients up to c / eps = 1e7 (an explicit step overshoots
    wildly) and any number of Newton iterations (the passivity guard covers an unconverged solve)."""
    fr = _friction(n, laws, seed, scale=1.0, eps=eps, newton_iters=iters)
    with torch.no_grad():
        fr.raw.add_(_inv_softplus(10 ** log_c))
    mass = _lowrank(n, seed)
    g = torch.Generator().manual_seed(seed + 2)
    q = torch.zeros(128, n, dtype=torch.float64)
    p = torch.randn(128, n, generator=g, dtype=torch.float64) * 10 ** torch.linspace(-3, 1, 128, dtype=torch.float64).unsqueeze(-1)
    with torch.no_grad():
        p1 = fr.half_step(mass, q, p, tau)
    T0, T1 = _kinetic(mass, q, p), _kinetic(mass, q, p1)
    assert bool(torch.isfinite(p1).all())
    assert bool((T1 <= T0 * (1 + 1e-12) + 1e-300).all())


@FAST
@given(laws=law_sets, seed=st.integers(0, 10_000), tau=st.floats(1e-4, 0.1), log_c=st.floats(-3, 3))
def test_half_step_never_adds_kinetic_energy_template_mass(laws, seed, tau, log_c):
    """The same with the configuration-dependent M(q) of a double pendulum (relative angles), random q."""
    fr = _friction(2, laws, seed, scale=1.0, eps=1e-3)
    with torch.no_grad():
        fr.raw.add_(_inv_softplus(10 ** log_c))
    mass = TemplateMass("double_pendulum_relative").double()
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        mass.raw.copy_(torch.randn(3, generator=g, dtype=torch.float64))
    q = 3 * torch.randn(128, 2, generator=g, dtype=torch.float64)
    p = 2 * torch.randn(128, 2, generator=g, dtype=torch.float64)
    with torch.no_grad():
        p1 = fr.half_step(mass, q, p, tau)
    assert bool((_kinetic(mass, q, p1) <= _kinetic(mass, q, p) * (1 + 1e-12)).all())


def test_half_step_passive_where_explicit_overshoots():
    """A stiff Coulomb law (tau c / eps = 500): the explicit step p - tau f(M^-1 p) gains energy, backward Euler
    sticks (v_new ~ 0) and loses it; float32 too."""
    mass = _lowrank(2, 0)
    fr = JointFriction(2, laws=("coulomb",), eps=1e-3, init=10.0).double()
    q = torch.zeros(64, 2, dtype=torch.float64)
    p = 0.5 * torch.randn(64, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    tau = 0.05
    with torch.no_grad():
        explicit = p - tau * fr.force(mass.velocity(q, p))
        p1 = fr.half_step(mass, q, p, tau)
    T0 = _kinetic(mass, q, p)
    assert bool((_kinetic(mass, q, explicit) > T0).any())
    assert bool((_kinetic(mass, q, p1) <= T0 * (1 + 1e-12)).all())
    m32, f32 = mass.float(), fr.float()
    with torch.no_grad():
        p32 = f32.half_step(m32, q.float(), p.float(), tau)
    assert p32.dtype == torch.float32
    assert bool((_kinetic(m32, q.float(), p32) <= _kinetic(m32, q.float(), p.float()) * (1 + 1e-5)).all())


@pytest.mark.parametrize("laws", [("coulomb",), ("viscous",), ("quadratic",), ("coulomb", "viscous", "quadratic"),
                                  ("coulomb", "stribeck")])
def test_half_step_converges(laws):
    """Moderate stiffness (tau c / (eps lambda_min(M)) up to ~5): the default 8 iterations solve the backward-Euler
    equation to rounding, agree with a 40-iteration solve, and the guard is inactive (p_new = p - tau f(v_new))."""
    n, tau = 3, 0.01
    mass = _lowrank(n, 3)
    fr = JointFriction(n, laws=laws, init=0.5, eps=0.01).double()
    ref = JointFriction(n, laws=laws, init=0.5, eps=0.01, newton_iters=40).double()
    q = torch.zeros(256, n, dtype=torch.float64)
    p = torch.randn(256, n, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        p1, p_ref = fr.half_step(mass, q, p, tau), ref.half_step(mass, q, p, tau)
        v1 = mass.velocity(q, p1)
        residual = p1 - p + tau * fr.force(v1)
    assert float(residual.abs().max()) < 1e-10
    assert torch.allclose(p1, p_ref, atol=1e-10)


def test_half_step_gradients_match_finite_differences():
    """The implicit-function gradient of p_new in p and in the raw coefficients (converged solve)."""
    n, tau = 2, 0.02
    mass = _lowrank(n, 4)
    fr = _friction(n, ("coulomb", "viscous", "quadratic"), 5, scale=0.5, eps=0.05)
    q = torch.zeros(4, n, dtype=torch.float64)
    p = torch.randn(4, n, dtype=torch.float64, generator=torch.Generator().manual_seed(2)).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: fr.half_step(mass, q, x, tau), (p,), atol=1e-6)
    w = torch.randn(4, n, dtype=torch.float64)
    (g,) = torch.autograd.grad((fr.half_step(mass, q, p, tau) * w).sum(), fr.raw)
    fd = torch.zeros_like(g)
    with torch.no_grad():
        for idx in torch.cartesian_prod(*(torch.arange(s) for s in fr.raw.shape)):
            i = tuple(idx.tolist())
            vals = []
            for sgn in (1, -1):
                fr.raw[i] += sgn * 1e-6
                vals.append(float((fr.half_step(mass, q, p, tau) * w).sum()))
                fr.raw[i] -= sgn * 1e-6
            fd[i] = (vals[0] - vals[1]) / 2e-6
    assert torch.allclose(g, fd, atol=1e-6, rtol=1e-5)


# ---- in the core and the model --------------------------------------------------------
def test_free_core_with_friction_loses_energy_every_step():
    """A free body (V = 0, constant M, no D(q)): the conservative step keeps T, each friction half-step lowers it, so
    H is non-increasing step to step over a rollout; the continuous power is -f(v) v <= 0."""
    n = 3
    mass = _lowrank(n, 6)
    fr = JointFriction(n, laws=("coulomb", "viscous", "stribeck"), init=(2.0, 0.1, 1.0), eps=1e-3).double()
    core = PHASTCore(ZeroPotential(), mass, None, dt=0.05, substeps=2, friction=fr).double()
    g = torch.Generator().manual_seed(0)  # the global RNG's state depends on the tests run before this one
    q = torch.randn(32, n, dtype=torch.float64, generator=g)
    p = 3 * torch.randn(32, n, dtype=torch.float64, generator=g)
    H = [core.hamiltonian(q, p)]
    with torch.no_grad():
        assert bool((core.power(q, p) <= 0).all())
        for _ in range(15):
            q, p = core(q, p)
            H.append(core.hamiltonian(q, p))
    H = torch.stack(H)
    assert bool((H[1:] <= H[:-1] * (1 + 1e-12)).all())
    assert bool((H[-1] < 0.9 * H[0]).all()) and float((H[-1] / H[0]).detach().median()) < 0.5


def test_default_model_has_no_friction():
    """friction="none" (the default): no friction module, parameters as before issue 30 (log_dt, if learned, last)."""
    model = build_model("PHAST/DampedPendulum-v0", "partial")
    assert model.core.friction is None and model.friction is None
    names = [k for k, _ in model.named_parameters()]
    assert not any("friction" in k for k in names) and not any("friction" in k for k in model.state_dict())
    assert names[-1] == "core.damping.net.4.bias" and len(names) == 24


def test_model_with_joint_friction_trains():
    """friction="joint": the module's parameter follows every existing one (the others keep their order and initial
    values), the model runs, and the loss reaches the friction coefficients."""
    base = build_model("PHAST/DampedPendulum-v0", "partial", learn_dt=True)
    model = build_model("PHAST/DampedPendulum-v0", "partial", friction="joint", friction_laws=["coulomb", "quadratic"],
                        friction_init=0.05, learn_dt=True)
    fr = model.friction
    assert isinstance(fr, JointFriction) and fr.laws == ("coulomb", "quadratic") and fr.joints == (0,)
    names = [k for k, _ in model.named_parameters()]
    assert names == [k for k, _ in base.named_parameters()] + ["core.friction.raw"] and "core.log_dt" in names
    assert all(torch.equal(a, b) for a, b in zip(base.parameters(), model.parameters()))
    q = torch.randn(2, 16, 1).cumsum(1) * 0.1
    pred = model(q)
    loss = ((pred[:, :-1] - q[:, 1:]) ** 2).mean()
    loss.backward()
    assert fr.raw.grad is not None and bool(torch.isfinite(fr.raw.grad).all()) and float(fr.raw.grad.abs().sum()) > 0
