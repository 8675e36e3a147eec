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
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sl

from phast_gym.control.controller import potential_curvature
from phast_gym.control.evaluation import ControlProtocol, control_system
from phast_gym.systems.base import SCALAR


def linearise(env_id: str, q_star: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Discrete (A, B) of (q - q_star, qdot) under held torque u for a 1-dof plant."""
    system = control_system(ControlProtocol(env_id=env_id, dt=dt))
    q = np.array([q_star])
    kappa = float(potential_curvature(system, q)[0, 0])
    m = float(system.mass_matrix([q_star], SCALAR)[0][0])
    damp = float(system.damping([q_star], SCALAR)[0]) if system.has_damping() else 0.0
    ac = np.array([[0.0, 1.0], [-kappa / m, -damp / m]])
    bc = np.array([[0.0], [1.0 / m]])
    mm = sl.expm(np.block([[ac, bc], [np.zeros((1, 3))]]) * dt)
    return mm[:2, :2], mm[:2, 2:]


@dataclass(frozen=True)
class ClosedLoop:
    """Linear closed loop z' = f z + g v (z = [x, e], e = x - x_hat posterior, v ~ N(0, sigma^2) the measurement
    noise), torque u = h z, stationary covariance s; ``post`` is the Kalman posterior covariance."""

    f: np.ndarray
    g: np.ndarray
    h: np.ndarray
    s: np.ndarray | None
    post: np.ndarray
    k: np.ndarray
    sigma: float


def closed_loop(a: np.ndarray, b: np.ndarray, sigma: float, gains: tuple[float, float] | None = None,
                eps: float = 1e-6, q_proc: float = 1e-12) -> ClosedLoop:
    """LQG (eps -> 0) or static gains on the stationary Kalman posterior estimate; ``s`` is None when unstable."""
    c = np.array([[1.0, 0.0]])
    r = sigma**2
    p = sl.solve_discrete_are(a.T, c.T, q_proc * np.eye(2), np.array([[r]]))
    gain_l = p @ c.T / float((c @ p @ c.T)[0, 0] + r)
    post = (np.eye(2) - gain_l @ c) @ p
    if gains is None:
        x = sl.solve_discrete_are(a, b, eps * np.eye(2), np.array([[1.0]]))
        k = np.linalg.solve(b.T @ x @ b + 1.0, b.T @ x @ a)
    else:
        k = np.array([[gains[0], gains[1]]])
    # u = -k (x - e); e' = (I - L C) A e - L v
    f = np.block([[a - b @ k, b @ k], [np.zeros((2, 2)), (np.eye(2) - gain_l @ c) @ a]])
    g = np.vstack([np.zeros((2, 1)), -gain_l])
    stable = np.max(np.abs(np.linalg.eigvals(f))) < 1
    s = sl.solve_discrete_lyapunov(f, g @ g.T * r) if stable else None
    return ClosedLoop(f=f, g=g, h=np.hstack([-k, k]), s=s, post=post, k=k, sigma=sigma)


def window_pass_rate(loop: ClosedLoop, window: int = 100, tol: float = 0.05, u_tol: float = 0.25,
                     n: int = 20000, seed: int = 0) -> dict[str, float]:
    """Monte Carlo fraction of stationary ``window``-step windows that pass the protocol's success rule
    (|angle error| < tol at every step and RMS torque < u_tol), and each half of it; batched over windows."""
    if loop.s is None:
        return {"pass": 0.0, "pass_torque": 0.0, "pass_angle": 0.0}
    rng = np.random.default_rng(seed)
    z = rng.multivariate_normal(np.zeros(4), loop.s, size=n)
    u2, worst = np.zeros(n), np.zeros(n)
    for _ in range(window):
        u2 += (z @ loop.h.T)[:, 0] ** 2
        worst = np.maximum(worst, np.abs(z[:, 0]))
        z = z @ loop.f.T + rng.normal(0.0, loop.sigma, size=(n, 1)) @ loop.g.T
    torque_ok, angle_ok = np.sqrt(u2 / window) < u_tol, worst < tol
    return {"pass": float(np.mean(torque_ok & angle_ok)), "pass_torque": float(np.mean(torque_ok)),
            "pass_angle": float(np.mean(angle_ok))}


def torque_floor(a: np.ndarray, b: np.ndarray, sigma: float, gains: tuple[float, float] | None = None,
                 eps: float = 1e-6, q_proc: float = 1e-12) -> dict[str, float]:
    """Stationary RMS torque and angle std of LQG (eps -> 0), or of static gains on the Kalman posterior estimate."""
    return stationary(closed_loop(a, b, sigma, gains, eps, q_proc))


def stationary(loop: ClosedLoop) -> dict[str, float]:
    """Gains, stationary RMS torque, angle std and Kalman posterior stds of ``loop`` (inf when it is unstable)."""
    k, s, h, post = loop.k, loop.s, loop.h, loop.post
    if s is None:
        return {"k_q": float(k[0, 0]), "k_qdot": float(k[0, 1]), "rms_torque": math.inf, "angle_std": math.inf}
    return {"k_q": float(k[0, 0]), "k_qdot": float(k[0, 1]), "rms_torque": float(np.sqrt((h @ s @ h.T)[0, 0])),
            "angle_std": float(np.sqrt(s[0, 0])), "kalman_q_std": float(np.sqrt(post[0, 0])),
            "kalman_qdot_std": float(np.sqrt(post[1, 1]))}


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
