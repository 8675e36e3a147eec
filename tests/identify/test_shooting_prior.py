"""The shooting fit's Gaussian prior (a maximum a posteriori fit): it decides a direction the data leave free, leaves
a pinned one to the data, and enters the elimination test and the intervals."""

from __future__ import annotations

import numpy as np

from phast_model.identify.shooting import Prior
from phast_model.mismatch.vocabulary.candidates import ScaledTerm

from .test_shooting_batch import _setup


def _oscillator():  # noqa: ANN202 - the shooter, a one-value build and window states
    sh, fam, _, X = _setup("PHAST/DampedOscillator-v0", {}, ["omega"], [ScaledTerm("actuator_gain", 1, 0.1)], 1.0)
    X = sh.fit_states(fam.build(np.zeros(2)), X).X
    return sh, fam, X


def test_prior_decides_a_free_direction_and_leaves_the_sum_to_the_data() -> None:
    """g0 and g1 act only through their sum: without a prior the split is arbitrary; with one on g1 at 0 the sum goes
    to g0, and the sum is the one the data pin either way."""
    sh, fam, X = _oscillator()
    truth = sh.fit(lambda g: fam.build(np.array([g[0], 0.0])), X, np.array([0.03]))

    def build(g: np.ndarray):  # noqa: ANN202
        return fam.build(np.array([g[0] + g[1], 0.0]))

    prior = Prior(np.array([0.0, 1.0 / 0.01**2]), np.array([0.0, 0.0]))
    fit = sh.fit(build, X, np.array([0.0, 0.03]), prior=prior)
    assert abs(fit.g.sum() - truth.g[0]) < 0.01 * abs(truth.g[0])
    assert abs(fit.g[1]) < 0.05 * abs(truth.g[0])  # the prior's centre, up to the pull of the data's curvature
    assert fit.objective == fit.cost + prior.cost(fit.g)
    assert fit.objective <= sh.fit(build, X, np.array([0.0, 0.03]), max_iter=0, prior=prior).objective
    cov = fit.covariance()
    assert cov[1, 1] <= 0.01**2 * 1.5 * max(fit.chi2_red, 1.0)  # the prior bounds the variance the data leave free
    assert np.all(np.isfinite(cov))


def test_zero_precision_is_no_prior() -> None:
    sh, fam, X = _oscillator()

    def build(g: np.ndarray):  # noqa: ANN202
        return fam.build(g)

    plain = sh.fit(build, X, np.zeros(2))
    flat = sh.fit(build, X, np.zeros(2), prior=Prior(np.zeros(2), np.array([1.0, -1.0])))
    np.testing.assert_allclose(flat.g, plain.g, rtol=1e-9, atol=1e-12)
    assert flat.objective == flat.cost


def test_without_keeps_the_other_globals_prior() -> None:
    """Dropping a global keeps the prior of the others, and the objective the elimination test compares is the
    penalized one."""
    sh, fam, X = _oscillator()
    prior = Prior(np.array([1.0 / 0.05**2, 0.0]), np.array([0.02, 0.0]))
    fit = sh.fit(lambda g: fam.build(g), X, np.array([0.02, 0.05]), prior=prior)
    dropped = fit.without(1)
    assert dropped.prior is not None and dropped.prior.precision.shape == (1,)
    assert dropped.objective == dropped.cost + dropped.prior.cost(dropped.g)
    assert dropped.objective >= fit.objective - 1e-9
