"""Recordings at jittered (non-uniform) sample times: validation, simulation between the recorded times,
comparison stride, and the Recordings helpers that carry t (fast)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from phast_gym.registry import make_env_system
from phast_gym.systems.base import NUMPY
from phast_model.identify.recordings import Recordings, validate
from phast_model.identify.shooting import (
    Shooter,
    Windows,
    angle_diff,
    compared_samples,
    estimate_noise,
    simulate_qv,
    smooth,
    substeps_for,
)

ENV = "PHAST/DampedPendulum-v0"
N, T, DT, NOISE = 3, 150, 0.05, 1e-4


def _exact(system, x0: np.ndarray, steps: np.ndarray, u: np.ndarray | None) -> np.ndarray:
    """q at the recorded times, from (q, p) = x0, by DOP853 at tight tolerance (u held over each interval)."""
    out, x = [x0[0]], np.array(x0, dtype=float)
    for j, h in enumerate(steps):
        uj = None if u is None else [u[j]]

        def f(_, y, uj=uj):
            dq, dp = system.rhs([y[0]], [y[1]], uj, NUMPY)
            return np.array([dq[0], dp[0]], dtype=float)

        x = solve_ivp(f, (0.0, h), x, method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]
        out.append(x[0])
    return np.array(out)


def _jittered_times(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    steps = DT * rng.uniform(0.6, 1.8, size=(N, T - 1))
    steps[rng.random((N, T - 1)) < 0.03] = 4 * DT  # logger gaps
    t = 10.0 + np.concatenate([np.zeros((N, 1)), np.cumsum(steps, 1)], 1)  # absolute times
    return steps, t


@pytest.fixture(scope="module", params=[False, True], ids=["free", "with_u"])
def jittered(request) -> dict:
    system = make_env_system(ENV)
    rng = np.random.default_rng(7 if request.param else 3)
    steps, t = _jittered_times(rng)
    u = rng.normal(0.0, 1.0, size=(N, T - 1, 1)) if request.param else None
    x0 = np.c_[rng.uniform(-2, 2, N), rng.normal(0, 2, N)]  # (q, p): unit mass and length
    q = np.stack([_exact(system, x0[i], steps[i], None if u is None else u[i, :, 0]) for i in range(N)])[..., None]
    q = q + rng.normal(0.0, NOISE, q.shape)
    raw = {"q": q, "t": t}
    if u is not None:
        raw["u"] = u
    return {"system": system, "raw": raw, "steps": steps}


def _shoot(system, rec: Recordings, length: int = 30, stride: int = 1):
    qs, vs = smooth(rec.q, rec.dt, 9, rec.t)
    win = Windows.cut(rec, length, stride=stride)
    sh = Shooter(win, np.full(rec.n, NOISE), substeps_for(system, rec.dt), np.array([1.0, 2.0]))
    X0 = np.concatenate([qs[win.traj, win.start], vs[win.traj, win.start]], 1)
    return sh, sh.fit_states(system, X0)


# --------------------------------------------------------------------------- (a) simulation between the recorded times
def test_shooting_at_recorded_times_fits_to_noise(jittered):
    rec = validate(jittered["raw"], 1, (0,))
    assert not rec.uniform and rec.t.shape == (N, T)
    np.testing.assert_allclose(rec.steps, jittered["steps"], rtol=1e-9)
    _, fit = _shoot(jittered["system"], rec)
    assert 0.7 < fit.chi2_red < 1.5, fit.chi2_red


def test_pretending_uniform_times_does_not_fit(jittered):
    raw = dict(jittered["raw"])
    raw["dt"] = float(np.median(jittered["steps"]))
    raw.pop("t")
    rec = validate(raw, 1, (0,))
    assert rec.uniform and rec.t is None
    _, fit = _shoot(jittered["system"], rec)
    assert fit.chi2_red > 100, fit.chi2_red


# --------------------------------------------------------------------------- (d) comparison stride
def test_stride_reduces_residuals_and_recovers_the_same_states(jittered):
    rec = validate(jittered["raw"], 1, (0,))
    sh1, fit1 = _shoot(jittered["system"], rec, length=31)
    sh5, fit5 = _shoot(jittered["system"], rec, length=31, stride=5)
    obs = compared_samples(31, 5)
    assert list(obs) == [0, 5, 10, 15, 20, 25, 30]
    assert fit1.r.shape == (sh1.w.count, 31) and fit5.r.shape == (sh5.w.count, len(obs))
    assert fit5.n_obs == sh5.w.count * len(obs) and fit5.dof == fit5.n_obs - fit5.X.size
    assert 0.5 < fit5.chi2_red < 2.0, fit5.chi2_red
    # the same window states within the stride fit's own (Gauss-Newton) uncertainty
    cov5 = np.linalg.inv(np.einsum("wla,wlb->wab", fit5.JX, fit5.JX))
    sd5 = np.sqrt(np.diagonal(cov5, axis1=1, axis2=2))
    z = np.abs(fit5.X - fit1.X) / sd5
    assert np.max(z) < 5.0, np.max(z)
    # the last sample is compared even when (L - 1) is not a multiple of the stride
    assert list(compared_samples(30, 5)) == [0, 5, 10, 15, 20, 25, 29]
    assert list(compared_samples(30, 1)) == list(range(30))


def test_stride_one_is_the_plain_residual(jittered):
    rec = validate(jittered["raw"], 1, (0,))
    system = jittered["system"]
    w1 = Windows.cut(rec, 30)
    assert w1.stride == 1 and w1.steps.shape == (w1.count, 29)
    X = np.c_[w1.q[:, 0], np.zeros(w1.count)]
    sh = Shooter(w1, np.full(1, NOISE), substeps_for(system, rec.dt), np.array([1.0, 2.0]))
    r = sh.residual(system, X)
    dt, sub = sh._time_base()
    sim = simulate_qv(system, X[:, :1], X[:, 1:], 29, w1.u, w1.steps, sub)
    np.testing.assert_array_equal(r, np.clip(angle_diff(sim, w1.q, (0,)) / NOISE, -1e6, 1e6).reshape(w1.count, -1))
    # a gap gets more substeps: no substep longer than dt / substeps
    assert np.all(w1.steps / sub[None, :] <= rec.dt / substeps_for(system, rec.dt) * (1 + 1e-9))


# --------------------------------------------------------------------------- (c) simulate_qv time bases
def test_simulate_qv_scalar_and_filled_array_dt_agree():
    system = make_env_system("PHAST/DoublePendulum-v0")
    rng = np.random.default_rng(1)
    B, K = 5, 40
    q0, v0 = rng.uniform(-1, 1, (B, 2)), rng.normal(0, 1, (B, 2))
    u = rng.normal(0, 0.5, (B, K, 2))
    a = simulate_qv(system, q0, v0, K, u, 0.02, 3)
    b = simulate_qv(system, q0, v0, K, u, np.full((B, K), 0.02), 3)
    c = simulate_qv(system, q0, v0, K, u, np.full(K, 0.02), np.full(K, 3))
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)
    assert substeps_for(system, 0.02) == 6 and list(substeps_for(system, np.array([[0.01, 0.02, 0.05]]))) == [3, 6, 15]


def test_simulate_qv_per_sample_steps_with_a_kinked_field():
    """Per-sample substep lengths through the switching-surface split (|sin q| wind damping)."""
    system = make_env_system(ENV, dd=0.4)
    assert system.switching([0.3], [0.0], NUMPY) is not None
    rng = np.random.default_rng(2)
    B, K = 6, 60
    q0, v0 = rng.uniform(-0.5, 0.5, (B, 1)), rng.normal(0, 3, (B, 1))  # swings through q = 0
    steps = DT * rng.uniform(0.6, 1.8, (B, K))
    sub = substeps_for(system, steps)
    batch = simulate_qv(system, q0, v0, K, None, steps, sub)
    alone = np.concatenate([simulate_qv(system, q0[i:i + 1], v0[i:i + 1], K, None, steps[i:i + 1], sub) for i in range(B)])
    np.testing.assert_array_equal(batch, alone)
    # and against a fine reference with the same per-sample times (the kink split keeps RK4 accurate)
    fine = simulate_qv(system, q0, v0, K, None, steps, sub * 16)
    assert np.max(np.abs(batch - fine)) < 1e-5
    with pytest.raises(ValueError, match="per-sample steps"):
        simulate_qv(system, q0, v0, K, None, steps[:, :-1], 3)


# --------------------------------------------------------------------------- (b) validation
def _raw(t=None, **kw) -> dict:
    rng = np.random.default_rng(0)
    steps = DT * rng.uniform(0.6, 1.8, size=(N, T - 1))
    tt = np.concatenate([np.zeros((N, 1)), np.cumsum(steps, 1)], 1)
    d = {"q": np.sin(tt)[..., None], "t": tt if t is None else t}
    d.update(kw)
    return d


def test_validation_errors_name_the_problem():
    good = _raw()
    rec = validate(good, 1, (0,))
    assert abs(rec.dt - np.median(np.diff(good["t"], axis=1))) < 1e-15
    t = good["t"].copy()
    t[1, 5] = np.nan
    with pytest.raises(ValueError, match=r"'t' contains NaN/inf \(first at trajectory 1, index 5\)"):
        validate(_raw(t), 1, (0,))
    t = good["t"].copy()
    t[2, 121] = t[2, 120]
    with pytest.raises(ValueError, match=r"t is not strictly increasing at trajectory 2, index 120 \(t=.*, next=.*\)"):
        validate(_raw(t), 1, (0,))
    t = good["t"].copy()
    t[0, 60] = t[0, 58]
    with pytest.raises(ValueError, match="trajectory 0, index 59"):
        validate(_raw(t), 1, (0,))
    with pytest.raises(ValueError, match=r"'t' must have shape \(T,\)"):
        validate(_raw(good["t"][:, :-1]), 1, (0,))
    with pytest.raises(ValueError, match=r"'t' must have shape"):
        validate(_raw(good["t"][:2]), 1, (0,))
    with pytest.raises(ValueError, match="disagrees with the median step"):
        validate(_raw(dt=2 * DT), 1, (0,))
    validate(_raw(dt=float(np.median(np.diff(good["t"], axis=1)))), 1, (0,))  # consistent dt is fine
    uni = {"q": np.sin(np.arange(T) * DT)[None, :, None], "t": np.arange(T) * DT}
    with pytest.raises(ValueError, match="disagrees"):
        validate({**uni, "dt": DT * 1.01}, 1, (0,))
    rec = validate({**uni, "dt": DT}, 1, (0,))
    assert rec.uniform and rec.sim_dt == DT
    # a wild gap is still a valid recording
    t = good["t"].copy()
    t[0, 80:] += 30 * DT
    assert validate(_raw(t), 1, (0,)).steps[0, 79] > 20 * DT
    # (T,) times are shared by all trajectories
    rec = validate(_raw(good["t"][0]), 1, (0,))
    assert rec.t.shape == (N, T) and np.array_equal(rec.t[2], good["t"][0])


def test_csv_with_per_trajectory_jittered_times(tmp_path):
    from phast_model.identify.recordings import load_raw

    d = _raw()
    rows = ["traj,t,q0,u0"] + [f"{i},{float(d['t'][i, j])!r},{float(d['q'][i, j, 0])!r},{0.1 * j!r}" for i in range(N) for j in range(T)]
    path = tmp_path / "rec.csv"
    path.write_text("\n".join(rows) + "\n")
    raw, src = load_raw(path)
    rec = validate(raw, 1, (0,), src)
    assert not rec.uniform
    np.testing.assert_array_equal(rec.t, d["t"])
    np.testing.assert_array_equal(rec.steps, np.diff(d["t"], axis=1))
    assert rec.u.shape == (N, T - 1, 1)


# --------------------------------------------------------------------------- (e) helpers carry t
def test_helpers_carry_t():
    d = _raw()
    d["u"] = np.arange(N * T, dtype=float).reshape(N, T, 1)
    rec = validate(d, 1, (0,))
    t = d["t"]
    s = rec.subset([2, 0])
    np.testing.assert_array_equal(s.t, t[[2, 0]])
    ts = rec.time_slice(10, 50)
    np.testing.assert_array_equal(ts.t, t[:, 10:50])  # absolute times
    assert ts.steps.shape == (N, 39) and ts.u.shape == (N, 39, 1) and ts.q.shape == (N, 40, 1)
    w = rec.windows(40)
    assert w.n_traj == N * 3 and w.T == 40
    np.testing.assert_array_equal(w.t[4], t[1, 40:80])
    np.testing.assert_array_equal(w.q[4], rec.q[1, 40:80])
    np.testing.assert_array_equal(w.u[4], rec.u[1, 40:79])
    np.testing.assert_array_equal(w.steps[4], np.diff(t[1, 40:80]))
    assert rec.windows(100) is rec  # fewer than two windows per trajectory
    with pytest.raises(ValueError, match="stride"):
        rec.decimate(3)
    free = rec.subset(slice(None))
    free.u = None
    dec = free.decimate(3)
    np.testing.assert_array_equal(dec.t, t[:, ::3])
    assert abs(dec.dt - np.median(np.diff(t[:, ::3], axis=1))) < 1e-15
    np.testing.assert_array_equal(dec.q, rec.q[:, ::3])
    # uniform recordings keep the scalar time base everywhere (simulated exactly as before)
    uni = Recordings(rec.q, DT)
    assert uni.uniform and uni.t is None and uni.sim_dt == DT and np.all(uni.steps == DT)
    assert uni.decimate(2).dt == 2 * DT and uni.windows(40).t is None
    assert Windows.cut(uni, 30).steps is None
    # resampled: a uniform grid for filters
    res = rec.resampled()
    assert res.uniform and abs(res.dt - rec.dt) < 1e-15
    np.testing.assert_allclose(res.q[..., 0], np.sin(res.t - res.t[:, :1] + t[:, :1]), atol=1e-4)


def test_noise_estimate_at_jittered_times():
    rng = np.random.default_rng(0)
    n_traj, n_t, dt = 4, 3000, 0.002
    steps = dt * rng.uniform(0.6, 1.8, (n_traj, n_t - 1))
    t = np.c_[np.zeros(n_traj), np.cumsum(steps, 1)]
    q = 1.5 * np.sin(8 * t)[..., None] + rng.normal(0, 1e-4, (n_traj, n_t, 1))
    assert estimate_noise(q)[0] > 1e-3  # plain 4th differences count the jitter as noise
    assert abs(estimate_noise(q, t)[0] - 1e-4) < 1e-5
    tu = np.broadcast_to(np.arange(n_t) * dt, (n_traj, n_t))
    qu = 1.5 * np.sin(8 * tu)[..., None] + rng.normal(0, 1e-4, (n_traj, n_t, 1))
    np.testing.assert_array_equal(estimate_noise(qu, tu), estimate_noise(qu))  # uniform t: the plain estimate


def test_smoothing_at_jittered_times():
    rng = np.random.default_rng(1)
    steps = 0.01 * rng.uniform(0.6, 1.8, (2, 399))
    t = np.c_[np.zeros(2), np.cumsum(steps, 1)]
    q = np.sin(2 * t)[..., None] + rng.normal(0, 1e-4, (2, 400, 1))
    qs, vs = smooth(q, float(np.median(steps)), 15, t)
    inner = slice(10, -10)
    assert np.max(np.abs(qs[:, inner, 0] - np.sin(2 * t[:, inner]))) < 3e-4
    assert np.max(np.abs(vs[:, inner, 0] - 2 * np.cos(2 * t[:, inner]))) < 5e-3
    _, v_plain = smooth(q, float(np.median(steps)), 15)  # ignoring the times is far worse
    assert np.max(np.abs(v_plain[:, inner, 0] - 2 * np.cos(2 * t[:, inner]))) > 0.1
