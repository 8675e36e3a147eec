"""Lower bound on the steady-state torque of ANY causal q-only controller holding an unstable equilibrium under noise.

For the linearisation of a 1-dof pendulum plant at q_star (sampled at dt, zero-order-hold torque, noise-free
dynamics, measurements q_t + N(0, sigma^2)) the stationary E[u^2] of a stabilising causal output-feedback controller
is at least the LQG cost with state weight eps -> 0 (LQG is optimal among causal controllers for a linear-Gaussian
plant; the eps -> 0 limit is the minimum-energy stabilising gain on the Kalman estimate).  At an unstable equilibrium
the Kalman error of the unstable mode has a floor (old measurements lose value at the rate of the unstable pole),
so the torque RMS cannot go below ``rms_floor`` however the controller is built.  The script also evaluates the
static feedback u = -k_c q_hat_err - d_inj qdot_hat on the Kalman estimate for given (k_c, d_inj) (the Energy-Casimir
law with xi = q_hat).

``benchmarks/control_lqg_bound.py`` tabulates it (docs/control.md).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import scipy.linalg as sl

from phast_gym.control.controller import potential_curvature
from phast_gym.control.evaluation import ControlProtocol, control_system
from phast_gym.env import parse_actuated_dofs
from phast_gym.systems.base import SCALAR, System


def linearise_system(system: System, q_star: npt.ArrayLike, dt: float, actuated_dofs: Sequence[int] | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Discrete (A, B) of (q - q_star, qdot) about the equilibrium (q_star, p = 0) of an n-dof ``system``, inputs held
    over ``dt`` on the port of ``actuated_dofs`` (G = those columns of I, as :class:`phast_gym.env.PortHamiltonianEnv`;
    default: every coordinate).  All physics is the system's own: Hess V at q_star (``potential_curvature``), M(q_star)
    and D(q_star); at p = 0 the kinetic and damping terms' q-derivatives are second order."""
    q = np.atleast_1d(np.asarray(q_star, dtype=np.float64))
    n = len(q)
    kappa = potential_curvature(system, q)
    m = np.array(system.mass_matrix(list(q), SCALAR), dtype=np.float64).reshape(n, n)
    damp = np.diag([float(v) for v in system.damping(list(q), SCALAR)]) if system.has_damping() else np.zeros((n, n))
    g = np.eye(n)[:, list(parse_actuated_dofs(actuated_dofs, n))]
    minv = np.linalg.inv(m)
    ac = np.block([[np.zeros((n, n)), np.eye(n)], [-minv @ kappa, -minv @ damp]])
    bc = np.vstack([np.zeros((n, g.shape[1])), minv @ g])
    k = g.shape[1]
    mm = sl.expm(np.block([[ac, bc], [np.zeros((k, 2 * n + k))]]) * dt)
    return mm[:2 * n, :2 * n], mm[:2 * n, 2 * n:]


def linearise(env_id: str, q_star: npt.ArrayLike, dt: float, actuated_dofs: Sequence[int] | None = None,
              env_kwargs: Mapping[str, object] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Discrete (A, B) of (q - q_star, qdot) under held inputs for the registered plant ``env_id`` sampled at ``dt``
    (:func:`linearise_system`; a 1-dof pendulum: the 2 x 2 and 2 x 1 of the torque floor)."""
    system = control_system(ControlProtocol(env_id=env_id, dt=dt, env_kwargs=dict(env_kwargs or {})))
    return linearise_system(system, q_star, dt, actuated_dofs)


@dataclass(frozen=True)
class ClosedLoop:
    """Linear closed loop z' = f z + g v (z = [x, e], e = x - x_hat posterior, v ~ N(0, sigma^2 I_n) the measurement
    noise of the n coordinates), inputs u = h z, stationary covariance s; ``post`` is the Kalman posterior
    covariance."""

    f: np.ndarray
    g: np.ndarray
    h: np.ndarray
    s: np.ndarray | None
    post: np.ndarray
    k: np.ndarray
    sigma: float


def lqr_gain(a: np.ndarray, b: np.ndarray, state_weights: np.ndarray) -> np.ndarray:
    """The discrete LQR gain K (m, 2n) of u = -K x: state weights ``diag(state_weights)``, input weight I."""
    m = b.shape[1]
    x = sl.solve_discrete_are(a, b, np.diag(np.asarray(state_weights, dtype=np.float64)), np.eye(m))
    return np.linalg.solve(b.T @ x @ b + np.eye(m), b.T @ x @ a)


def closed_loop(a: np.ndarray, b: np.ndarray, sigma: float, gains: npt.ArrayLike | None = None,
                eps: float = 1e-6, q_proc: float = 1e-12) -> ClosedLoop:
    """LQG (eps -> 0) or static gains on the stationary Kalman posterior estimate; ``s`` is None when unstable.

    ``a`` (2n, 2n), ``b`` (2n, m) of :func:`linearise`; every coordinate q is measured with noise ``sigma``.  ``gains``:
    None (LQG: state weight ``eps`` I, input weight I), a pair (k_q, k_qdot) for n = 1, or the (m, 2n) gain matrix K
    of u = -K x_hat."""
    n2, m = b.shape
    n = n2 // 2
    c = np.hstack([np.eye(n), np.zeros((n, n))])
    r = sigma**2
    p = sl.solve_discrete_are(a.T, c.T, q_proc * np.eye(n2), r * np.eye(n))
    gain_l = p @ c.T @ np.linalg.inv(c @ p @ c.T + r * np.eye(n))
    post = (np.eye(n2) - gain_l @ c) @ p
    if gains is None:
        k = lqr_gain(a, b, np.full(n2, eps))
    else:
        k = np.asarray(gains, dtype=np.float64).reshape(m, n2)
    # u = -k (x - e); e' = (I - L C) A e - L v
    f = np.block([[a - b @ k, b @ k], [np.zeros((n2, n2)), (np.eye(n2) - gain_l @ c) @ a]])
    g = np.vstack([np.zeros((n2, n)), -gain_l])
    stable = np.max(np.abs(np.linalg.eigvals(f))) < 1
    s = sl.solve_discrete_lyapunov(f, g @ g.T * r) if stable else None
    return ClosedLoop(f=f, g=g, h=np.hstack([-k, k]), s=s, post=post, k=k, sigma=sigma)


def window_pass_rate(loop: ClosedLoop, window: int = 100, tol: float = 0.05, u_tol: float = 0.25,
                     n: int = 20000, seed: int = 0, angle_dims: Sequence[int] = (0,)) -> dict[str, float]:
    """Monte Carlo fraction of stationary ``window``-step windows that pass the protocol's success rule
    (|error| < tol on every coordinate of ``angle_dims`` at every step and RMS input < u_tol), and each half of it;
    batched over windows."""
    if loop.s is None:
        return {"pass": 0.0, "pass_torque": 0.0, "pass_angle": 0.0}
    rng = np.random.default_rng(seed)
    dims, m, nq = list(angle_dims), loop.h.shape[0], loop.g.shape[1]
    z = rng.multivariate_normal(np.zeros(len(loop.s)), loop.s, size=n)
    u2, worst = np.zeros(n), np.zeros(n)
    for _ in range(window):
        u2 += np.sum((z @ loop.h.T) ** 2, axis=1) / m
        worst = np.maximum(worst, np.abs(z[:, dims]).max(axis=1))
        z = z @ loop.f.T + rng.normal(0.0, loop.sigma, size=(n, nq)) @ loop.g.T
    torque_ok, angle_ok = np.sqrt(u2 / window) < u_tol, worst < tol
    return {"pass": float(np.mean(torque_ok & angle_ok)), "pass_torque": float(np.mean(torque_ok)),
            "pass_angle": float(np.mean(angle_ok))}


def torque_floor(a: np.ndarray, b: np.ndarray, sigma: float, gains: npt.ArrayLike | None = None,
                 eps: float = 1e-6, q_proc: float = 1e-12, angle_dims: Sequence[int] = (0,)) -> dict[str, float]:
    """Stationary RMS input and angle std of LQG (eps -> 0), or of static gains on the Kalman posterior estimate."""
    return stationary(closed_loop(a, b, sigma, gains, eps, q_proc), angle_dims)


def stationary(loop: ClosedLoop, angle_dims: Sequence[int] = (0,)) -> dict[str, Any]:
    """Gains, stationary RMS input (over the m inputs), std of the first angle of ``angle_dims`` and Kalman posterior
    stds of ``loop`` (inf when it is unstable).  A 1-dof loop reports its gains as ``k_q``, ``k_qdot``; a larger one
    as the (m, 2n) matrix ``k``."""
    k, s, h, post = loop.k, loop.s, loop.h, loop.post
    n = k.shape[1] // 2
    i = int(list(angle_dims)[0])
    gains: dict[str, object] = ({"k_q": float(k[0, 0]), "k_qdot": float(k[0, 1])} if k.shape == (1, 2)
                             else {"k": k.tolist()})
    if s is None:
        return {**gains, "rms_torque": math.inf, "angle_std": math.inf}
    return {**gains, "rms_torque": float(np.sqrt(np.trace(h @ s @ h.T) / h.shape[0])),
            "angle_std": float(np.sqrt(s[i, i])), "kalman_q_std": float(np.sqrt(post[i, i])),
            "kalman_qdot_std": float(np.sqrt(post[n + i, n + i]))}


def lqg_floor(env_id: str, sigma: float, q_star: npt.ArrayLike = math.pi, dt: float = 0.01,
              actuated_dofs: Sequence[int] | None = None, env_kwargs: Mapping[str, object] | None = None,
              eps: float = 1e-6) -> dict[str, Any]:
    """The LQG floor of a registered plant at its equilibrium ``q_star`` (a scalar: that value on every angle, 0 on
    the other coordinates; or one value per coordinate), q-only measurements with noise ``sigma`` every ``dt``, inputs
    on ``actuated_dofs``: :func:`linearise` + :func:`closed_loop` (LQG, state weight ``eps`` -> 0) + :func:`stationary`.
    ``rms_torque`` is the lowest stationary RMS input of any causal q-only controller that holds q_star (the pendulum
    at pi, sigma 0.01: 0.087 N m; docs/control.md)."""
    system = control_system(ControlProtocol(env_id=env_id, dt=dt, env_kwargs=dict(env_kwargs or {})))
    return {"env": env_id, **system_lqg_floor(system, sigma, q_star, dt, actuated_dofs, eps)}


def system_lqg_floor(system: System, sigma: float, q_star: npt.ArrayLike = math.pi, dt: float = 0.01,
                     actuated_dofs: Sequence[int] | None = None, eps: float = 1e-6) -> dict[str, Any]:
    """:func:`lqg_floor` of a system (a registered plant's or a user's rig class), sampled at ``dt``."""
    q = np.asarray(q_star, dtype=np.float64)
    if q.ndim == 0:
        q = np.array([float(q) if i in system.angle_dims else 0.0 for i in range(system.n)])
    a, b = linearise_system(system, q, dt, actuated_dofs)
    dims = tuple(system.angle_dims) or (0,)
    return {"q_star": q.tolist(), "sigma": sigma, "dt": dt,
            "actuated_dofs": list(parse_actuated_dofs(actuated_dofs, system.n)), "eps": eps,
            **stationary(closed_loop(a, b, sigma, eps=eps), dims)}


def best_static_pass_rate(a: np.ndarray, b: np.ndarray, sigma: float, k_q: np.ndarray, k_qdot: np.ndarray,
                          **rule: Any) -> dict[str, float]:
    """The highest window pass rate over a grid of static gains (k_q, k_qdot) on the Kalman estimate."""
    best = {"pass": -1.0}
    for kq in k_q:
        for kd in k_qdot:
            rate = window_pass_rate(closed_loop(a, b, sigma, gains=(float(kq), float(kd))), **rule)
            if rate["pass"] > best["pass"]:
                best = {"k_q": float(kq), "k_qdot": float(kd), **rate}
    return best
