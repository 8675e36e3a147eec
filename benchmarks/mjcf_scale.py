"""How phast-mismatch scales with a robot's size: an n-joint arm as MJCF, recorded by MuJoCo, analysed end to end.

The arm alternates pitch and yaw hinges (a spatial chain, not a planar one), every joint has a motor, and "reality"
has a frictionloss on the second joint that the file leaves out.  Recordings: smooth random torques on top of
gravity compensation, q noise 0.002 rad.  Prints and writes the wall time against the issue's budgets (3-joint
<= 3 min, 6-joint with 40 x 1000 samples <= 10 min on the 2-core machine) and what was found.

    python benchmarks/mjcf_scale.py --joints 3 --n-traj 20 --T 500 --out /tmp/scale3
    python benchmarks/mjcf_scale.py --joints 6 --n-traj 40 --T 1000 --out /tmp/scale6
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

LINK = 0.25  # m


def arm_xml(n: int, frictionloss: float = 0.0) -> str:
    """An n-link arm: link i is a 0.25 m rod of 1.0 - 0.1 i kg hanging from a pitch (even i) or yaw (odd i) hinge."""
    body = ""
    for i in reversed(range(n)):
        axis = "0 1 0" if i % 2 == 0 else "1 0 0"
        fl = f' frictionloss="{frictionloss}"' if i == 1 and frictionloss else ""
        m = 1.0 - 0.1 * i
        ixx = m * LINK**2 / 12
        inner = body
        body = (f'<body name="link{i + 1}" pos="0 0 {-LINK if i else 0}">'
                f'<joint name="j{i + 1}" type="hinge" axis="{axis}"{fl}/>'
                f'<inertial pos="0.01 0.005 {-LINK / 2}" mass="{m:.2f}" diaginertia="{ixx:.5f} {ixx + 1e-4:.5f} 1e-3"/>'
                f"{inner}</body>")
    motors = "".join(f'<motor name="m{i + 1}" joint="j{i + 1}"/>' for i in range(n))
    return (f'<mujoco model="arm{n}"><option timestep="0.001" integrator="RK4"><flag contact="disable"/></option>'
            f'<worldbody><body name="base" pos="0 0 2">{body}</body></worldbody><actuator>{motors}</actuator></mujoco>')


def record(path_real: str, n: int, n_traj: int, T: int, dt: float, seed: int) -> dict:
    """MuJoCo recordings of the real arm: smooth random torques (scaled per joint by the weight it carries)."""
    from phast_model.identify.mujoco_sim import rollout_q

    rng = np.random.default_rng(seed)
    q0 = rng.uniform(-0.4, 0.4, (n_traj, n))
    v0 = rng.uniform(-0.3, 0.3, (n_traj, n))
    scale = np.array([0.4 * sum(1.0 - 0.1 * k for k in range(i, n)) * LINK for i in range(n)])
    knots = rng.normal(0.0, 1.0, (n_traj, T // 25 + 2, n)) * scale
    t = np.arange(T - 1) / 25
    u = np.stack([np.stack([np.interp(t, np.arange(knots.shape[1]), knots[k, :, j]) for j in range(n)], -1)
                  for k in range(n_traj)])
    q = rollout_q(path_real, q0, v0, u, dt, T - 1)
    q = q + rng.normal(0.0, 0.002, q.shape)
    return {"q": q, "u": u, "dt": dt}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--joints", type=int, default=3)
    ap.add_argument("--n-traj", type=int, default=20)
    ap.add_argument("--T", type=int, default=500)
    ap.add_argument("--dt", type=float, default=0.01)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    from phast_model.mismatch import analyze

    n = args.joints
    with tempfile.TemporaryDirectory() as d:
        nominal, real = Path(d) / f"arm{n}.xml", Path(d) / f"arm{n}_real.xml"
        nominal.write_text(arm_xml(n))
        real.write_text(arm_xml(n, frictionloss=0.05))
        rec = record(str(real), n, args.n_traj, args.T, args.dt, args.seed)
        hold = list(range(args.n_traj - max(1, args.n_traj // 5), args.n_traj))
        t0 = time.perf_counter()
        report = analyze(str(nominal), rec, holdout_trajectories=hold, progress=True)
        wall = time.perf_counter() - t0
        report.write(args.out)
    budget = 180.0 if n <= 3 else 600.0
    found = [{k: m.get(k) for k in ("term", "joint", "mjcf", "coefficient", "ci95")} for m in report.missing_physics]
    f = report.fit
    out = {"joints": n, "n_traj": args.n_traj, "T": args.T, "wall_s": round(wall, 1), "budget_s": budget,
           "within_budget": wall <= budget, "hidden": "frictionloss 0.05 on j2", "found": found,
           "heldout_rollout_rmse": {k: v["rollout_rmse"] for k, v in f.items() if isinstance(v, dict) and "rollout_rmse" in v}}
    (args.out / "scale.json").write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
