"""``phast-control-eval``: Energy-Casimir closed-loop evaluation over port estimators and noise levels.

Runs five initial-condition regimes x ``--trials-per-regime`` trials for every (sigma, estimator)
through the plant env's ``reset``/``step`` (paper Sec. 4.2, Tables 7-11) and writes

* ``DIR/results.json``: list of rows {sigma, estimator, regime, n_trials, success_rate,
  success_angle_rate, final_error, effort, velocity_error} (regime ``all`` = the 100-trial row);
* ``DIR/protocol.json``: plant, gains, horizon and success criterion used;
* ``DIR/results.md``: tables shaped like the paper's Tables 7-11;
* ``DIR/traces_sigma<s>.png`` (angle and torque traces) and ``DIR/success_by_regime.png`` (Fig. 8).

Example: ``phast-control-eval --estimators oracle,fd,map,tcn,ukf --sigma 0,0.01,0.05 --out runs/control``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from phast_gym.control import (
    START_REGIMES,
    XI_FEEDBACK,
    ControlProtocol,
    ControlRow,
    PortEstimator,
    estimator_names,
    evaluate_estimators,
    make_estimator,
)
from phast_gym.control.estimators import resolve_estimator_name
from phast_gym.control.report import plot_success_by_regime, plot_traces, results_markdown
from phast_gym.fileio import atomic_write_text, ensure_writable_dir
from phast_gym.systems import System

#: upright (q_star = pi) defaults: k_c > m g l = 9.81 with margin, stronger damping injection
UPRIGHT_K_C, UPRIGHT_D_INJ = 20.0, 3.0



def _parse_floats(text: str, what: str) -> list[float]:
    out = []
    for tok in text.split(","):
        tok = tok.strip()
        try:
            v = math.pi if tok.lower() == "pi" else float(tok)
        except ValueError:
            raise ValueError(f"{what}: {tok!r} is not a number") from None
        out.append(v)
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="phast-control-eval", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--estimators", default="oracle,fd,map,tcn,ukf",
                   help=f"comma-separated port estimators, from {estimator_names()}")
    p.add_argument("--sigma", default="0,0.01,0.05", help="comma-separated measurement noise std levels (rad)")
    p.add_argument("--trials-per-regime", type=int, default=20, help="trials per initial-condition regime (5 regimes)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--q-star", default="0", help="target angle: 0 (hanging) or pi (upright, needs k_c > m g l)")
    p.add_argument("--phast-run", default=None, help="phast-train run dir for phast-observer / phast-model / phast-ukf")
    p.add_argument("--seed", type=int, default=0, help="seed of initial states and noise streams")
    p.add_argument("--env", default=ControlProtocol.env_id, help="pendulum-family plant env id")
    p.add_argument("--dt", type=float, default=ControlProtocol.dt, help="control sampling interval (s)")
    p.add_argument("--horizon", type=int, default=ControlProtocol.horizon, help="closed-loop steps per trial")
    p.add_argument("--k-c", type=float, default=None,
                   help="shaping gain (default 0.7; 20 when q_star = pi, which needs k_c > m g l)")
    p.add_argument("--d-inj", type=float, default=None,
                   help="damping-injection gain (default 0.11; 3 when q_star = pi)")
    p.add_argument("--k-xi", type=float, default=ControlProtocol.k_xi, help="xi predictor-corrector gain")
    p.add_argument("--xi-feedback", choices=XI_FEEDBACK, default=ControlProtocol.xi_feedback,
                   help="q fed back into the xi update (Eq. 29): the raw measurement (paper) or the estimator's "
                        "filtered q (UKF posterior, MAP smoothed angle; estimators without one use the measurement)")
    p.add_argument("--tol", type=float, default=ControlProtocol.tol, help="success angle tolerance (rad)")
    p.add_argument("--u-tol", type=float, default=ControlProtocol.u_tol,
                   help="success RMS-torque tolerance (N m) over the final window")
    p.add_argument("--tcn-sigma-max", type=float, default=0.05, help="sigma_max of the U[0, sigma_max] TCN variants")
    p.add_argument("--tcn-cache", default=None, help="directory of trained TCN observers (default DIR/observers)")
    p.add_argument("--no-plots", action="store_true")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    return p


def run(args: argparse.Namespace) -> list[ControlRow]:
    """The evaluation behind the CLI (callable from Python with a parsed namespace)."""
    sigmas = _parse_floats(args.sigma, "--sigma")
    if any(s < 0 or not math.isfinite(s) for s in sigmas):
        raise ValueError(f"--sigma values must be >= 0, got {sigmas}")
    (q_star,) = _parse_floats(args.q_star, "--q-star")
    names = [resolve_estimator_name(s.strip()) for s in args.estimators.split(",") if s.strip()]  # ekf -> ukf
    if not names:
        raise ValueError(f"--estimators is empty: give a comma-separated list from {estimator_names()}")
    if args.trials_per_regime < 1:
        raise ValueError(f"--trials-per-regime must be >= 1, got {args.trials_per_regime}")
    unknown = [n for n in names if n not in estimator_names()]
    if unknown:
        raise ValueError(f"unknown estimator(s) {unknown}; valid names are {estimator_names()}")
    if any(n.startswith("phast") for n in names) and not args.phast_run:
        raise ValueError("phast-observer / phast-model / phast-ukf need --phast-run DIR (a phast-train run directory)")
    upright = abs(math.cos(q_star) + 1) < 1e-9
    k_c = args.k_c if args.k_c is not None else (UPRIGHT_K_C if upright else ControlProtocol.k_c)
    d_inj = args.d_inj if args.d_inj is not None else (UPRIGHT_D_INJ if upright else ControlProtocol.d_inj)
    protocol = ControlProtocol(env_id=args.env, dt=args.dt, horizon=args.horizon, q_star=q_star, k_c=k_c, d_inj=d_inj,
                               k_xi=args.k_xi, tol=args.tol, u_tol=args.u_tol, xi_feedback=args.xi_feedback)
    out = ensure_writable_dir(args.out, "--out")  # before the evaluation, not after it
    cache = Path(args.tcn_cache) if args.tcn_cache else out / "observers"
    if any(n.startswith("tcn") or n.startswith("phast") for n in names):
        import torch

        torch.set_num_threads(max(1, args.threads))
        import phast_model.control  # noqa: F401  (registers the torch estimators)

    def factory(name: str, system: System, dt: float, sigma: float) -> PortEstimator:
        kw: dict[str, Any] = {}
        if name.startswith("tcn"):
            kw = {"protocol": protocol, "cache_dir": cache, "sigma_max": args.tcn_sigma_max,
                  "progress": not args.no_progress}
        elif name.startswith("phast"):
            kw = {"run": args.phast_run}
        return make_estimator(name, system, dt, sigma=sigma, **kw)

    keep = (lambda s, e, r, i: r == "far_unstable" and i == 0) if not args.no_plots else None
    rows, kept = evaluate_estimators(protocol, names, sigmas, args.trials_per_regime, seed=args.seed, factory=factory,
                          progress=not args.no_progress, keep_episodes=keep)
    atomic_write_text(out / "results.json", json.dumps(rows, indent=1))
    atomic_write_text(out / "protocol.json", json.dumps({**protocol.to_dict(), "regimes": START_REGIMES,
                                                     "seed": args.seed, "trials_per_regime": args.trials_per_regime,
                                                     "command": "phast-control-eval " + " ".join(sys.argv[1:])},
                                                    indent=1))
    atomic_write_text(out / "results.md", results_markdown(rows, protocol))
    if not args.no_plots:
        plot_traces(kept, protocol, out)
        plot_success_by_regime(rows, out)
    return rows


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        rows = run(args)
    except ValueError as exc:
        print(f"phast-control-eval: error: {exc}", file=sys.stderr)
        return 2
    for r in rows:
        if r["regime"] == "all":
            print(f"sigma={r['sigma']:g} {r['estimator']:>14s}: success {r['success_rate']:.2f} "
                  f"effort {r['effort']:.1f} "
                  f"|qdot_hat-qdot| {r['velocity_error']:.3f} final {r['final_error']:.2e}")
    print(f"wrote {Path(args.out) / 'results.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
