"""The LQG floor on the steady-state torque of any causal q-only controller at an unstable equilibrium
(``phast_model.control.lqg_bound``, where the derivation is), tabulated for docs/control.md.

``python benchmarks/control_lqg_bound.py --env PHAST/DampedPendulum-v0 --sigma 0.01,0.05 --pass-grid --out DIR`` writes
``DIR/lqg_bound.json`` and prints one line per sigma.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from phast_gym.fileio import atomic_write_json
from phast_model.control.lqg_bound import best_static_pass_rate, closed_loop, linearise, stationary, torque_floor, window_pass_rate


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--env", default="PHAST/DampedPendulum-v0")
    ap.add_argument("--q-star", type=float, default=math.pi)
    ap.add_argument("--dt", type=float, default=0.01)
    ap.add_argument("--sigma", default="0.01,0.05")
    ap.add_argument("--gains", default="20:3", help="comma-separated k_c:d_inj pairs to evaluate as static feedback on the estimate")
    ap.add_argument("--u-tol", type=float, default=0.25, help="the success rule's RMS-torque tolerance (N m)")
    ap.add_argument("--pass-grid", action="store_true",
                    help="also search static gains k_q in [5, 300], k_qdot in [0.3, 40] (log grid) for the highest "
                         "Monte Carlo rate of 1-s windows that pass the success rule")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    rule = {"u_tol": args.u_tol, "window": round(1.0 / args.dt)}
    a, b = linearise(args.env, args.q_star, args.dt)
    rows = []
    for sigma in (float(s) for s in args.sigma.split(",")):
        loops = {"LQG (eps -> 0): lower bound": closed_loop(a, b, sigma)}
        for pair in args.gains.split(","):
            kc, dinj = (float(v) for v in pair.split(":"))
            loops[f"k_c = {kc:g}, d_inj = {dinj:g} on the Kalman estimate"] = closed_loop(a, b, sigma, gains=(kc, dinj))
        rows += [{"sigma": sigma, "controller": name, **stationary(loop), "window": window_pass_rate(loop, **rule)}
                 for name, loop in loops.items()]
        if args.pass_grid:
            best = best_static_pass_rate(a, b, sigma, np.geomspace(5, 300, 25), np.geomspace(0.3, 40, 25), **rule)
            rows.append({"sigma": sigma, "controller": "best static gains on the Kalman estimate (pass-rate search)",
                         **torque_floor(a, b, sigma, gains=(best["k_q"], best["k_qdot"])),
                         "window": {k: best[k] for k in ("pass", "pass_torque", "pass_angle")}})
    for r in rows:
        print(f"sigma={r['sigma']:g} {r['controller']}: RMS torque {r['rms_torque']:.3f} N m, angle std "
              f"{r['angle_std']:.4f} rad, 1-s windows passing {r['window']['pass']:.3f} "
              f"(torque {r['window']['pass_torque']:.3f}, angle {r['window']['pass_angle']:.3f})")
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        record = {"env": args.env, "q_star": args.q_star, "dt": args.dt, "rule": rule, "rows": rows}
        atomic_write_json(out / "lqg_bound.json", record, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
