"""Lower bound on the steady-state torque of ANY causal q-only controller holding an unstable equilibrium under noise.

For the linearisation of a 1-dof pendulum plant at q_star (sampled at dt, zero-order-hold torque, noise-free
dynamics, measurements q_t + N(0, sigma^2)) the stationary E[u^2] of a stabilising causal output-feedback controller
is at least the LQG cost with state weight eps -> 0 (LQG is optimal among causal controllers for a linear-Gaussian
plant; the eps -> 0 limit is the minimum-energy stabilising gain on the Kalman estimate).  At an unstable equilibrium
the Kalman error of the unstable mode has a floor (old measurements lose value at the rate of the unstable pole),
so the torque RMS cannot go below ``rms_floor`` however the controller is built.  The script also evaluates the
static feedback u = -k_c q_hat_err - d_inj qdot_hat on the Kalman estimate for given (k_c, d_inj) (the Energy-Casimir
law with xi = q_hat).

``python benchmarks/control_lqg_bound.py --env PHAST/DampedPendulum-v0 --sigma 0.01,0.05 --out DIR`` writes
``DIR/lqg_bound.json`` and prints one line per sigma.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

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


def torque_floor(a: np.ndarray, b: np.ndarray, sigma: float, gains: tuple[float, float] | None = None,
                 eps: float = 1e-6, q_proc: float = 1e-12) -> dict[str, float]:
    """Stationary RMS torque and angle std of LQG (eps -> 0), or of static gains on the Kalman posterior estimate."""
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
    # z = [x, e], e = x - x_hat (posterior); u = -k (x - e); e' = (I - L C) A e - L v
    f = np.block([[a - b @ k, b @ k], [np.zeros((2, 2)), (np.eye(2) - gain_l @ c) @ a]])
    if np.max(np.abs(np.linalg.eigvals(f))) >= 1:
        return {"k_q": float(k[0, 0]), "k_qdot": float(k[0, 1]), "rms_torque": math.inf, "angle_std": math.inf}
    g = np.vstack([np.zeros((2, 1)), -gain_l])
    s = sl.solve_discrete_lyapunov(f, g @ g.T * r)
    h = np.hstack([-k, k])
    return {"k_q": float(k[0, 0]), "k_qdot": float(k[0, 1]), "rms_torque": float(np.sqrt((h @ s @ h.T)[0, 0])),
            "angle_std": float(np.sqrt(s[0, 0])), "kalman_q_std": float(np.sqrt(post[0, 0])),
            "kalman_qdot_std": float(np.sqrt(post[1, 1]))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--env", default="PHAST/DampedPendulum-v0")
    ap.add_argument("--q-star", type=float, default=math.pi)
    ap.add_argument("--dt", type=float, default=0.01)
    ap.add_argument("--sigma", default="0.01,0.05")
    ap.add_argument("--gains", default="20:3", help="comma-separated k_c:d_inj pairs to evaluate as static feedback on the estimate")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    a, b = linearise(args.env, args.q_star, args.dt)
    rows = []
    for sigma in (float(s) for s in args.sigma.split(",")):
        rows.append({"sigma": sigma, "controller": "LQG (eps -> 0): lower bound", **torque_floor(a, b, sigma)})
        for pair in args.gains.split(","):
            kc, dinj = (float(v) for v in pair.split(":"))
            rows.append({"sigma": sigma, "controller": f"k_c = {kc:g}, d_inj = {dinj:g} on the Kalman estimate",
                         **torque_floor(a, b, sigma, gains=(kc, dinj))})
    for r in rows:
        print(f"sigma={r['sigma']:g} {r['controller']}: RMS torque {r['rms_torque']:.3f} N m, angle std {r['angle_std']:.4f} rad")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "lqg_bound.json").write_text(json.dumps({"env": args.env, "q_star": args.q_star, "dt": args.dt, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
