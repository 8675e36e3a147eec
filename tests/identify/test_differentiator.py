"""One swappable differentiator (as PySINDy's ``pysindy.differentiation``): the cubic Savitzky-Golay default gives the
numbers of the direct scipy calls it replaced, and another one reaches every filter of the weak form, the weak-form
identification and the residual map."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest
from scipy.signal import savgol_filter

from phast_gym.registry import make_env_system
from phast_model.bench.reality import make_reality
from phast_model.identify.recordings import Recordings
from phast_model.identify.signals import SAVGOL, Differentiator, SavitzkyGolay, odd, smooth, time_scale
from phast_model.identify.simulators import load_simulator
from phast_model.mismatch import Term
from phast_model.mismatch.friction import fit_law, momentum_balance, weak_form
from phast_model.mismatch.friction.weakid import WeakModel, identify
from phast_model.mismatch.locate import locate, residual_force

ENV = "PHAST/Pendulum-v0"


@dataclass
class Counting:
    """The default filter, counting its calls (to see that every filter goes through the object passed)."""

    inner: Differentiator = SAVGOL
    calls: dict[str, int] = field(default_factory=lambda: {"smooth": 0, "derivative": 0})

    def fit_window(self, window: int, T: int) -> int:
        return self.inner.fit_window(window, T)

    def smooth(self, x: np.ndarray, window: int, axis: int = 1) -> np.ndarray:
        self.calls["smooth"] += 1
        return self.inner.smooth(x, window, axis)

    def derivative(self, x: np.ndarray, window: int, dt: float, order: int = 1, axis: int = 1) -> np.ndarray:
        self.calls["derivative"] += 1
        return self.inner.derivative(x, window, dt, order, axis)


@pytest.fixture(scope="module")
def rec() -> Recordings:
    d = make_reality(ENV, [Term("coulomb_friction", 0, 0.05)], n_traj=4, T=300, noise_std=1e-3, seed=2)
    return Recordings(d["q"], d["dt"], None, tuple(d["angle_dims"]))


def test_the_default_is_the_direct_scipy_call(rec):
    q, dt = rec.q, rec.dt
    assert isinstance(SAVGOL, Differentiator) and SAVGOL == SavitzkyGolay(3)
    assert np.array_equal(SAVGOL.smooth(q, 21), savgol_filter(q, 21, 3, axis=1, mode="interp"))
    for order in (1, 2):
        assert np.array_equal(SAVGOL.derivative(q, 21, dt, order),
                              savgol_filter(q, 21, 3, deriv=order, delta=dt, axis=1, mode="interp"))
    # the window rule of smooth() and of the residual map: odd, >= 5, at most the largest odd number <= T
    for T in range(3, 60):
        for w in range(0, 70):
            assert SAVGOL.fit_window(w, T) == odd(min(max(w, 5), T - (1 - T % 2)))
            assert SAVGOL.fit_window(w, T) == odd(min(max(w, 5), T - 1 + T % 2 - 1))
    qs, vs = smooth(q, dt, 21)
    assert np.array_equal(qs, savgol_filter(q, 21, 3, axis=1, mode="interp"))
    assert np.array_equal(vs, savgol_filter(q, 21, 3, deriv=1, delta=dt, axis=1, mode="interp"))


def test_the_weak_form_filters_through_its_differentiator(rec):
    sys0 = make_env_system(ENV)
    counting = Counting()
    wf, wf_counted = weak_form(sys0, rec), weak_form(sys0, rec, differentiator=counting)
    assert wf_counted.filter.differentiator is counting and counting.calls["smooth"] >= 3 and counting.calls["derivative"] >= 3
    assert np.array_equal(wf.total, wf_counted.total) and np.array_equal(wf.own, wf_counted.own)
    before = dict(counting.calls)
    law = fit_law(sys0, rec, [("coulomb_friction", 0)], weak=wf_counted)
    assert counting.calls["smooth"] > before["smooth"]  # the law's basis is filtered by the same object
    assert law.terms[0].coefficient == fit_law(sys0, rec, [("coulomb_friction", 0)], weak=wf).terms[0].coefficient


def test_another_differentiator_changes_the_answer_only_through_the_filter(rec):
    """A quintic Savitzky-Golay filter: the weak form and the residual map move, and every call goes through it."""
    sys0 = make_env_system(ENV)
    quintic = SavitzkyGolay(polyorder=5)
    assert quintic.fit_window(3, 100) == 7
    wf5 = weak_form(sys0, rec, differentiator=quintic)
    assert not np.array_equal(wf5.total, weak_form(sys0, rec).total)
    counting = Counting(quintic)
    r, *_ = residual_force(sys0, rec, 21, counting)
    assert counting.calls == {"smooth": 2, "derivative": 3}  # q, qdot, d/dt p; S*pdot; qddot
    assert np.array_equal(r, residual_force(sys0, rec, 21, quintic)[0])
    assert not np.array_equal(r, residual_force(sys0, rec, 21)[0])
    bal = momentum_balance(sys0, rec, 21, counting)
    assert np.all(np.isfinite(bal.dp))
    located, _ = locate(sys0, rec, 21, 0.01, differentiator=counting)
    assert located and located[0]["coordinate"] == 0
    assert time_scale(rec.q, rec.dt, quintic) != time_scale(rec.q, rec.dt)


def test_the_weak_form_identification_takes_a_differentiator(rec):
    sim = load_simulator(ENV)
    model = WeakModel(sim, {}, ["mass"], [], [0], 0.01, 0.0, 21)
    counting = Counting()
    fit, fit_counted = identify(model, rec, [("coulomb_friction", 0)]), identify(
        WeakModel(sim, {}, ["mass"], [], [0], 0.01, 0.0, 21, counting), rec, [("coulomb_friction", 0)])
    assert counting.calls["derivative"] > 0
    assert fit.law.terms[0].coefficient == fit_counted.law.terms[0].coefficient
