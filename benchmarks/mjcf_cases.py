"""Concealed-effect cases for ``phast-mismatch`` with a MuJoCo model file as the simulator.

    python benchmarks/mjcf_cases.py [--cases furuta arm3 ...] [--seed 0] [--out DIR]

Each case has a nominal MJCF file (``benchmarks/mjcf_models/``).  Its "reality" is the same file edited through
``mujoco.MjSpec`` (the effect hidden in MuJoCo's own terms: a joint's ``frictionloss`` / ``damping``, an actuator's
``gear``, the bodies' ``mass`` / ``ipos`` / ``inertia``), written to a temporary file and simulated by MuJoCo
(RK4, 1 ms) under closed-loop control: each recording interval (dt = 0.01 s) a PD controller (with gravity
compensation from the nominal model for the arm) to smooth random targets computes the motor commands from the
measured, noisy q; the commands actually applied are recorded as ``u``.  The tool gets the recordings (q with
Gaussian noise, u, dt) and the NOMINAL file; the last 25% of the trajectories are held out.

* ``furuta``: rotary pendulum, the arm driven about z, the pendulum unactuated; hidden: pendulum frictionloss.
* ``arm3``: 3-joint arm (yaw, shoulder, elbow), 3 motors; hidden: shoulder damping and elbow frictionloss.
* ``arm3_cad``: the same arm, every non-zero body mass / centre of mass / principal inertia 3-8% off its file
  value (random signs); nothing else.
* ``weak_motor``: the same arm, the shoulder motor's gear 0.85 instead of 1.
* ``cartpole``: a cart on a rail with a hanging pole, force on the cart; hidden: pole-hinge damping and cart
  frictionloss.

A case is right (as in ``phast-mismatch-bench``) when
* effect cases: the found rows (term, joint) are exactly the hidden ones, every coefficient within 30% of the
  hidden MuJoCo value, and the augmented model's held-out rollout RMSE <= 0.7x the calibrated one;
* ``arm3_cad``: no missing-physics row (parameter changes are the expected answer);
* ``weak_motor``: no term other than ``actuator_gain`` on the shoulder, and the shoulder's delivered gain
  (calibrated ``m_shoulder.gear`` times any ``actuator_gain`` coefficient) within 5% of 0.85.

``--out DIR`` writes ``DIR/results.json`` and each case's report in ``DIR/<case>/``.  ``eff/noise`` in the table
is the RMS of q(real) - q(nominal) over the first 100 samples of every trajectory, both driven open loop by the
recorded commands from the true initial state, in units of the q-noise (as in ``phast-mismatch-bench``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from phast_model.bench.mjcf_cases import case_seed, cases, run_case, table

HERE = Path(__file__).resolve().parent
#: the cases, their nominal files beside this script
CASES = cases(HERE / "mjcf_models")


def _commit() -> str | None:
    """The repository's commit (with "+dirty" when the working tree has changes), as the results record it."""
    import subprocess

    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=HERE, capture_output=True, text=True, check=True)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=HERE, capture_output=True, text=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="*", default=None, help=f"case names (default: all): {list(CASES)}")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="write DIR/results.json and each case's report folder DIR/<case>/")
    ap.add_argument("--n-traj", type=int, default=None, help="override every case's number of trajectories")
    ap.add_argument("--T", type=int, default=None, help="override every case's samples per trajectory")
    ap.add_argument("--progress", action="store_true", help="the tool's progress lines")
    args = ap.parse_args(argv)
    bad = sorted(set(args.cases or []) - set(CASES))
    if bad:
        print(f"mjcf_cases: error: unknown case(s) {bad}; known: {list(CASES)}", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    commit = _commit()
    rows = []
    for name in args.cases or list(CASES):
        print(f"[{name}] recording and analysing ...", file=sys.stderr, flush=True)
        rows.append(run_case(CASES[name], case_seed(args.seed, name), out, args.progress, args.n_traj, args.T))
        print(f"[{name}] {rows[-1]['wall_s']:.1f} s: {'right' if rows[-1]['passed'] else 'WRONG'}: {rows[-1]['reason']}",
              file=sys.stderr, flush=True)
        if out is not None:  # after every case, so a long run keeps what it has
            (out / "results.json").write_text(json.dumps(
                {"command": " ".join(["benchmarks/mjcf_cases.py"] + (argv if argv is not None else sys.argv[1:])),
                 "seed": args.seed, "commit": commit, "rows": rows}, indent=1, default=float))
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
