"""The shooting fit's Levenberg-Marquardt against library solvers on the same problem (issue: fits at MuJoCo's speed).

    python benchmarks/shooting_solvers.py [--case arm3_drives] [--window 30] [--out shooting_solvers.json]

The problem: a bench case's MuJoCo model file (:mod:`phast_model.bench.mjcf_cases`, its hidden drives: rotor inertia,
damping and frictionloss written into the model) fitted to its recordings by multiple shooting, as the mismatch tool
fits them: every window's state free, MuJoCo at the fits' RK4 step, the hidden values log-parametrized from half their
true values.  The same residual (:class:`phast_model.identify.shooting.Shooter`) goes to each solver:

* ``ours``: :meth:`Shooter.fit`, Levenberg-Marquardt with the window states eliminated (Schur complement) and the
  Jacobian's 1 + 2n + P directions simulated as one batch per linearization;
* ``scipy_sparse_fd``: ``scipy.optimize.least_squares`` (trust-region reflective) with ``jac_sparsity``: scipy
  finite-differences the arrow-shaped Jacobian in 2n + P grouped calls;
* ``scipy_our_jacobian``: the same solver given our batched Jacobian (a sparse matrix): the solver alone compared;
* ``mujoco_minimize``: ``mujoco.minimize.least_squares`` given our batched Jacobian (it finite-differences densely
  otherwise: one residual per column, thousands here).

Printed and written: CPU seconds, final chi^2/dof, residual evaluations (window batches simulated), and each fitted
value against the truth.
"""

from __future__ import annotations

import argparse
import copy
import json
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

JOINT_FIELDS = {"armature": "dof_armature", "damping": "dof_damping", "frictionloss": "dof_frictionloss"}


def _problem(case_name: str, seed: int, window: int) -> dict[str, Any]:
    """The case's recordings, its tool-style shooting setup and the hidden values (name, dof, field, truth)."""
    from phast_model.bench import mjcf_cases as mc
    from phast_model.identify.mujoco_sim import load_mjmodel, mujoco_simulated
    from phast_model.identify.recordings import Recordings
    from phast_model.identify.simulators import load_simulator
    from phast_model.mismatch.fitting.problem import prepare
    from phast_model.mismatch.options import Options, Progress

    case = mc.cases()[case_name]
    hidden = [h for h in mc.hidden_effects(case, mc.case_seed(seed, case_name)) if h.kind == "joint"]
    with tempfile.TemporaryDirectory() as tmp:
        real = mc.write_real(case, hidden, tmp)
        rec = mc.record(case, real, case.n_traj, case.T, mc.case_seed(seed, case_name))
    path = str(mc.nominal_path(case))
    sim = load_simulator(path)
    sys0 = sim.build()
    cols = list(sys0.actuated_dofs)
    u = np.zeros(rec["q"].shape[:2] + (sys0.n,))[:, :-1]
    u[..., cols] = rec["u"]
    train = Recordings(q=rec["q"], u=u, dt=rec["dt"], angle_dims=tuple(sys0.angle_dims))
    problem = prepare(sim, sys0, train, Options().with_(shoot_window=window), Progress(False))
    model = load_mjmodel(path)
    jnt = {model.joint(j).name: int(model.jnt_dofadr[j]) for j in range(model.njnt)}
    values = [(f"{h.target}.{h.attr}", jnt[h.target], JOINT_FIELDS[h.attr], float(h.value)) for h in hidden]
    return {"problem": problem, "model": model, "base": mujoco_simulated(path), "values": values}


def _builder(p: dict[str, Any]) -> Callable[[np.ndarray], Any]:
    """g -> the MuJoCo-simulated system whose hidden values are half the truth times exp(g)."""
    from phast_model.identify.mujoco_sim import rollout_q

    base, model, values = p["base"], p["model"], p["values"]
    cols = list(base.actuated_dofs)

    def build(g: np.ndarray) -> Any:
        m = copy.copy(model)
        for (_, dof, field, truth), gk in zip(values, g):
            getattr(m, field)[dof] = 0.5 * truth * float(np.exp(gk))
        system = copy.copy(base)
        step = float(model.opt.timestep)

        def external_rollout(q0, v0, n_steps, u, dt, max_substeps=None):  # noqa: ANN001, ANN202
            ctrl = None if u is None else np.broadcast_to(u, (q0.shape[0], n_steps, u.shape[-1]))[..., cols]
            return rollout_q(m, q0, v0, ctrl, float(np.mean(dt)), n_steps, step, max_substeps)

        system.external_rollout = external_rollout
        return system

    return build


def _sparse_jacobian(JX: np.ndarray, Jg: np.ndarray) -> Any:
    """The arrow-shaped Jacobian (W*L*n, W*2n + P) of window blocks JX (W, L*n, 2n) and shared columns Jg."""
    from scipy import sparse

    blocks = sparse.block_diag(list(JX), format="csr")
    return sparse.hstack([blocks, sparse.csr_matrix(Jg.reshape(-1, Jg.shape[-1]))], format="csr")


def _sparsity(W: int, rows: int, nx: int, P: int) -> Any:
    return _sparse_jacobian(np.ones((W, rows, nx)), np.ones((W, rows, P)))


def run_solvers(p: dict[str, Any], which: list[str], max_iter: int) -> dict[str, Any]:
    from scipy.optimize import least_squares

    problem, build = p["problem"], _builder(p)
    shooter = problem.shooter(problem.shooting.windows)
    shooter.heartbeat = None
    X0, P = problem.shooting.X0, len(p["values"])
    W, nx = X0.shape
    g0 = np.zeros(P)
    out: dict[str, Any] = {}

    def split(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return z[: W * nx].reshape(W, nx), z[W * nx:]

    def residual(z: np.ndarray) -> np.ndarray:
        X, g = split(z)
        return shooter.residual(build(g), X).ravel()

    def jacobian(z: np.ndarray) -> Any:
        X, g = split(z)
        _, JX, Jg = shooter.linearize(build, build(g), g, X, 1e-4)
        return _sparse_jacobian(JX, Jg)

    z0 = np.concatenate([X0.ravel(), g0])
    rows = shooter.residual(build(g0), X0).shape[1]
    for name in which:
        shooter.n_sims = 0
        c0 = time.process_time()
        if name == "ours":
            fit = shooter.fit(build, X0, g0, max_iter=max_iter, stats=False)
            z, iters = np.concatenate([fit.X.ravel(), fit.g]), fit.iterations
        elif name in ("scipy_sparse_fd", "scipy_our_jacobian"):
            jac = {"jac_sparsity": _sparsity(W, rows, nx, P)} if name == "scipy_sparse_fd" else {"jac": jacobian}
            res = least_squares(residual, z0, method="trf", x_scale="jac", max_nfev=max_iter * 10, **jac)
            z, iters = res.x, int(res.nfev)
        else:
            from mujoco import minimize

            def vec_residual(zs: np.ndarray) -> np.ndarray:
                zs = zs.reshape(z0.size, -1)
                return np.stack([residual(zs[:, k]) for k in range(zs.shape[1])], axis=1)

            z, trace = minimize.least_squares(z0, vec_residual, jacobian=lambda zz, r: jacobian(zz.ravel()).toarray(),
                                              max_iter=max_iter, verbose=0, x_scale="jac")
            z, iters = z.ravel(), len(trace)
        cpu = time.process_time() - c0
        r = residual(z)
        X, g = split(z)
        fitted = {nm: 0.5 * truth * float(np.exp(gk)) for (nm, _, _, truth), gk in zip(p["values"], g)}
        out[name] = {"cpu_s": cpu, "chi2_per_dof": float(r @ r) / max(r.size - z.size, 1), "iterations": iters,
                     "window_batches_simulated": shooter.n_sims, "fitted": fitted,
                     "max_rel_error": max(abs(fitted[nm] / truth - 1) for nm, _, _, truth in p["values"])}
        print(f"{name:20s} {cpu:7.1f} s CPU  chi2/dof {out[name]['chi2_per_dof']:.4g}  iterations/evaluations "
              f"{iters:4d}  window batches {shooter.n_sims:6d}  worst value off by {out[name]['max_rel_error']:.2%}",
              flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", default="arm3_drives", help="an MJCF bench case whose hidden values are joint attributes")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--window", type=int, default=30, help="shooting window [samples]")
    ap.add_argument("--max-iter", type=int, default=50)
    ap.add_argument("--solvers", default="ours,scipy_our_jacobian,scipy_sparse_fd,mujoco_minimize")
    ap.add_argument("--out", type=Path, default=None, help="write the results as JSON")
    args = ap.parse_args(argv)
    p = _problem(args.case, args.seed, args.window)
    print(f"{args.case}: {p['problem'].shooting.windows.count} windows of {args.window} samples, "
          f"{len(p['values'])} values: {[v[0] for v in p['values']]}", flush=True)
    results = run_solvers(p, args.solvers.split(","), args.max_iter)
    if args.out is not None:
        from phast_gym.fileio import atomic_write_text
        from phast_model.train.provenance import code_commit

        atomic_write_text(args.out, json.dumps({"command": "benchmarks/shooting_solvers.py", "case": args.case,
                                                "commit": code_commit(short=True, dirty=True), "results": results},
                                               indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
