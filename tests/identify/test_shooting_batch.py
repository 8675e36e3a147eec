"""The batched parameter Jacobian of the shooting fit equals one simulation per parameter (fast)."""

from __future__ import annotations

import numpy as np
import pytest

from phast_gym.systems.base import System
from phast_model.bench.reality import make_reality
from phast_model.identify.merging import merge_systems
from phast_model.identify.recordings import Recordings
from phast_model.identify.shooting import Shooter, Windows, smooth
from phast_model.identify.simulators import load_simulator
from phast_model.mismatch import Term
from phast_model.mismatch.vocabulary.candidates import Family, ScaledTerm

ARM = {"coordinates": "relative", "mass1": 0.6417, "mass2": 0.5639, "length1": 0.2, "length2": 0.3,
       "com1": 0.2, "com2": 0.3213, "inertia1": 0.02671, "inertia2": 0.05388, "gravity": 9.81}


def _setup(env: str, kwargs: dict, params: list[str], terms: list[ScaledTerm], u_std: float = 0.0,
           steps: bool = False) -> tuple[Shooter, Family, np.ndarray, np.ndarray]:
    """A shooter on 6 short windows of a small reality, a family and a point g of it."""
    rec = make_reality(env, [Term("coulomb_friction", 0, 0.05)], true_kwargs=kwargs, n_traj=2, T=40, noise_std=0.002,
                       seed=4, u_std=u_std)
    t = None
    if steps:  # jittered sample times: the per-interval time base
        t = np.cumsum(np.full((2, 40), float(rec["dt"])) * (1 + 0.05 * np.random.default_rng(0).uniform(-1, 1, (2, 40))), 1)
    sim = load_simulator(env, kwargs)
    sys0 = sim.build()
    r = Recordings(np.asarray(rec["q"]), float(rec["dt"]), None if "u" not in rec else np.asarray(rec["u"]), sys0.angle_dims, t=t)
    w = Windows.cut(r, 20, stride=2)
    qs, vs = smooth(w.q, w.dt, 7)
    X = np.concatenate([qs[:, 0], vs[:, 0]], -1)
    sh = Shooter(w, np.full(sys0.n, 0.002), 2, np.ones(2 * sys0.n))
    fam = Family(sim, {}, [(p, float(sys0.params[p])) for p in params], terms, 0.01)
    g = np.linspace(0.05, -0.04, len(params) + len(terms))
    return sh, fam, g, X


def _one_by_one(sh: Shooter, fam: Family, g: np.ndarray, X: np.ndarray, r: np.ndarray, g_step: float) -> np.ndarray:
    Jg = np.empty(r.shape + (g.size,))
    for j in range(g.size):
        gp = g.copy()
        gp[j] += g_step
        Jg[..., j] = (sh.residual(fam.build(gp), X) - r) / g_step
    return Jg


CASES = {
    # dd: the switching function branches on it (`if dd != 0`), so the merged system takes the first one's
    "cartpole_terms": ("PHAST/WindyCartPole-v0", {}, ["d0", "d_cart", "dd"],
                       [ScaledTerm("coulomb_friction", 0, 0.3), ScaledTerm("quadratic_drag", 1, 0.01),
                        ScaledTerm("sensor_offset", 1, 0.01)], 0.0, False),
    "arm_params": ("PHAST/DoublePendulum-v0", ARM, ["mass1", "mass2", "com1", "com2", "inertia1", "inertia2"],
                   [ScaledTerm("coulomb_friction", 1, 0.08), ScaledTerm("armature", 0, 0.002)], 0.5, True),
    "oscillator_port": ("PHAST/DampedOscillator-v0", {}, ["omega"],
                        [ScaledTerm("actuator_gain", 1, 0.1), ScaledTerm("stribeck_friction", 0, 0.04, 0.5)], 1.0, False),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_batched_parameter_jacobian_equals_one_simulation_per_parameter(case: str) -> None:
    env, kwargs, params, terms, u_std, steps = CASES[case]
    sh, fam, g, X = _setup(env, kwargs, params, terms, u_std, steps)
    systems = [fam.build(g + 1e-4 * e) for e in np.eye(g.size)]
    assert merge_systems(systems, X.shape[0]) is not None  # the batched path is the one under test
    r = sh.residual(fam.build(g), X)
    n0 = sh.n_sims

    def one_simulation(system: System, X: np.ndarray) -> np.ndarray:
        raise AssertionError("the merged batch was not used")

    sh.residual = one_simulation  # type: ignore[method-assign]
    Jg = sh._jac_params(fam.build, g, X, r, 1e-4)
    del sh.residual
    assert sh.n_sims - n0 == g.size
    ref = _one_by_one(sh, fam, g, X, r, 1e-4)
    assert Jg.shape == ref.shape and np.all(np.isfinite(Jg))
    # the residual differences, not the Jacobian: a rounding of the residual is amplified by 1 / g_step
    np.testing.assert_allclose(Jg * 1e-4 + r[..., None], ref * 1e-4 + r[..., None], rtol=1e-9, atol=1e-9 * np.abs(r).max())
    assert np.max(np.abs(Jg - ref)) <= 1e-6 * np.max(np.abs(ref))


def test_systems_that_differ_in_more_than_numbers_are_simulated_one_by_one() -> None:
    sh, fam, g, X = _setup(*CASES["cartpole_terms"])
    other = Family(fam.sim, {}, [], [ScaledTerm("viscous_damping", 1, 0.1)], 0.01)
    systems = [fam.build(g), other.build(np.zeros(1))]
    assert merge_systems(systems, X.shape[0]) is None
    R = sh.residuals_of(systems, X)
    np.testing.assert_array_equal(R[1], sh.residual(systems[1], X))


class _Folding(System):
    """A system that folds its parameter into a Python branch (`if k > 1`): an array parameter would be wrong."""

    name = "folding"
    n = 1
    dt = 0.05
    substeps = 2
    PARAMS = {}

    def __init__(self, k: float) -> None:
        self.k = k
        self.params = {}
        self._damped = False
        self._const_d = None

    def velocity(self, q, p, xp=None):  # noqa: ANN001, ANN201
        return (p[0],)

    def mass_matrix(self, q, xp=None):  # noqa: ANN001, ANN201
        return ((q[0] * 0.0 + 1.0,),)

    def grad_potential(self, q, xp=None):  # noqa: ANN001, ANN201
        return (q[0] * (np.max(self.k) if np.ndim(self.k) else self.k),)


def test_guard_falls_back_when_the_merged_field_differs() -> None:
    rng = np.random.default_rng(0)
    q = rng.normal(size=(3, 12, 1)).cumsum(1) * 0.01
    w = Windows(np.arange(3), np.zeros(3, int), 12, q, None, (), 0.05)
    sh = Shooter(w, np.full(1, 0.01), 2, np.ones(2))
    X = np.concatenate([q[:, 0], np.zeros((3, 1))], -1)
    systems = [_Folding(1.0), _Folding(2.0)]
    assert merge_systems(systems, 3) is not None  # merges, but the guard sees the wrong field
    R = sh.residuals_of(systems, X)
    for k, s in enumerate(systems):
        np.testing.assert_array_equal(R[k], sh.residual(s, X))


def test_parameter_columns_batched_equal_one_by_one() -> None:
    """:meth:`Shooter.columns` of parameter directions (mergeable) and of term candidates (not) match one-by-one."""
    sh, fam, g, X = _setup(*CASES["arm_params"])
    r = sh.residual(fam.build(g), X)
    fit = type("Fit", (), {"X": X})()
    builds = [lambda e=e: fam.build(g + 1e-3 * e) for e in np.eye(g.size)[:3]]
    builds.append(lambda: Family(fam.sim, {}, [], [ScaledTerm("viscous_damping", 0, 0.1)], 0.01).build(np.ones(1)))
    assert merge_systems([b() for b in builds[:3]], X.shape[0]) is not None
    assert merge_systems([b() for b in builds], X.shape[0]) is None
    for bs in (builds[:3], builds):
        cols = sh.columns(bs, fit, r, [1e-3] * len(bs))
        for k, b in enumerate(bs):
            np.testing.assert_array_equal(cols[..., k], (sh.residual(b(), X) - r) / 1e-3)


@pytest.mark.parametrize("case", sorted(CASES))
def test_one_linearization_gives_the_fit_the_separate_simulations_give(case: str) -> None:
    """linearize: residual, state and parameter Jacobians from one batch equal the separate simulations exactly; the
    fit with the damping tries batched in rungs equals the tries one at a time."""
    env, kwargs, params, terms, u_std, steps = CASES[case]
    sh, fam, g, X = _setup(env, kwargs, params, terms, u_std, steps)
    system = fam.build(g)
    r, JX, Jg = sh.linearize(fam.build, system, g, X, 1e-4)
    r0 = sh.residual(system, X)
    np.testing.assert_array_equal(r, r0)
    np.testing.assert_array_equal(JX, sh.jac_X(system, X, r0))
    np.testing.assert_array_equal(Jg, sh._jac_params(fam.build, g, X, r0, 1e-4))
    batched = sh.fit(fam.build, X, g, max_iter=4)
    sh.LADDER = (1,) * 8  # type: ignore[misc]
    single = sh.fit(fam.build, X, g, max_iter=4)
    np.testing.assert_array_equal(batched.g, single.g)
    np.testing.assert_array_equal(batched.X, single.X)


def test_linearized_drop_predicts_the_refit() -> None:
    """ShootFit.without(j): one Gauss-Newton step with g_j held at zero lands where the nonlinear refit does (to the
    fit's statistical precision) and gives its statistics."""
    sh, fam, g, X = _setup("PHAST/DampedOscillator-v0", {}, ["omega"], [ScaledTerm("coulomb_friction", 0, 0.04),
                           ScaledTerm("viscous_damping", 0, 0.05)], 1.0, False)
    fit = sh.fit(fam.build, X, np.zeros(3))
    j = 2  # the damping term
    drop = fit.without(j)
    keep = [i for i in range(g.size) if i != j]
    fam2 = fam.with_(terms=fam.terms[:1])
    refit = sh.fit(fam2.build, drop.X, drop.g)
    sd = np.sqrt(np.diag(refit.covariance()))
    assert np.all(np.abs(drop.g - refit.g) <= 0.2 * sd)
    assert drop.g.size == len(keep) and abs(drop.cost - refit.cost) <= 0.05 * refit.cost + 1.0


def test_a_long_fit_says_where_it_is():
    """The heartbeat of a shooting fit: the iteration, chi^2/dof and the time left at most (every 30 s by default;
    here at every iteration), and the fit's numbers are those of a fit without it."""
    from phast_model.identify.shooting import Heartbeat

    sh, fam, g, X = _setup("PHAST/Pendulum-v0", {}, ["length"], [])
    quiet = sh.fit(fam.build, X, g, max_iter=3)
    said: list[str] = []
    sh.heartbeat = Heartbeat(said.append, every=0.0)
    loud = sh.fit(fam.build, X, g, max_iter=3)
    assert said and all("of at most 3" in m and "chi2/dof" in m and "s left)" in m for m in said)
    assert loud.cost == quiet.cost and np.array_equal(loud.g, quiet.g)


def test_widened_covariance_stays_a_covariance_where_the_inverse_rounds_below_zero() -> None:
    """A near-singular inverse can leave a variance at -1e-20: the widened covariance is finite with non-negative
    variances, each at least the sandwich's, and the well-conditioned block keeps its correlation."""
    from phast_model.identify.shooting import _widened

    cov = np.array([[4.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, -1e-20]])
    out = _widened(cov, np.array([1.0, 9.0, 2.5e-3]))
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(np.diag(out), [4.0, 9.0, 2.5e-3])
    np.testing.assert_allclose(out[0, 1] / np.sqrt(out[0, 0] * out[1, 1]), 0.5)
    assert out[2, 0] == out[2, 1] == 0.0
    out = _widened(cov, np.array([1.0, 1.0, -1e-22]))  # both at round-off: zero, not NaN
    assert out[2, 2] == 0.0
