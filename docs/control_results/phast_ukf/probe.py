"""Calibration probe of the phast-ukf process noise (seed 100, 2 trials per regime; not the evaluation seed).

    python docs/control_results/phast_ukf/probe.py RUN_DIR OUT.jsonl
"""

import json
import math
import sys
import time

import phast_model.control  # noqa: F401  (registers phast-ukf)
from phast_gym.control import ControlProtocol, evaluate_estimators, make_estimator

CASES = [{"q_star": 0.0, "sigma": 0.05},
         {"q_star": math.pi, "sigma": 0.01, "k_c": 45, "d_inj": 3, "k_xi": 20, "xi_feedback": "filtered"}]
STDS = [(1e-5, 1e-2), (1e-4, 3e-2), (1e-3, 0.1), (1e-2, 0.3)]


def main(run: str, out: str) -> None:
    for case in CASES:
        case = dict(case)
        sig = case.pop("sigma")
        proto = ControlProtocol(env_id="PHAST/WindyPendulum-v0", **case)
        for ps in STDS:
            t = time.time()

            def fac(name, system, dt, sigma, ps=ps):  # noqa: ANN001, ANN202
                return make_estimator(name, system, dt, sigma=sigma, run=run, process_std=ps)

            rows, _ = evaluate_estimators(proto, ["phast-ukf"], [sig], 2, seed=100, factory=fac, progress=False)
            r = next(r for r in rows if r["regime"] == "all")
            rec = {"run": run, "q_star": case["q_star"], "sigma": sig, "process_std": ps, "success": r["success_rate"],
                   "angle": r["success_angle_rate"], "urms": r["u_rms_final"], "verr": r["velocity_error"],
                   "effort": r["effort"], "wall": time.time() - t}
            print(json.dumps(rec), flush=True)
            with open(out, "a") as f:
                f.write(json.dumps(rec) + "\n")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
