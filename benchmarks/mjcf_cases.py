"""Concealed-effect cases for ``phast-mismatch`` with a MuJoCo model file as the simulator.

    python benchmarks/mjcf_cases.py [--cases furuta arm3 ...] [--seed 0] [--out DIR]

The cases, their hidden effects and what counts as right are described in :mod:`phast_model.bench.mjcf_cases`
(its model files ship with the package).  ``--out DIR`` writes ``DIR/results.json`` and each case's report in
``DIR/<case>/``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from phast_model.bench.mjcf_cases import case_seed, cases, run_case, table
from phast_model.train.provenance import code_commit

CASES = cases()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="*", default=None, help=f"case names (default: all): {list(CASES)}")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="write DIR/results.json and each case's report folder DIR/<case>/")
    ap.add_argument("--n-traj", type=int, default=None, help="override every case's number of trajectories")
    ap.add_argument("--T", type=int, default=None, help="override every case's samples per trajectory")
    ap.add_argument("--progress", action="store_true", help="the tool's progress lines")
    ap.add_argument("--threads", type=int, default=1, help="MuJoCo threads for the rollouts (default 1)")
    args = ap.parse_args(argv)
    bad = sorted(set(args.cases or []) - set(CASES))
    if bad:
        print(f"mjcf_cases: error: unknown case(s) {bad}; known: {list(CASES)}", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    commit = code_commit(short=True, dirty=True)
    rows = []
    for name in args.cases or list(CASES):
        print(f"[{name}] recording and analysing ...", file=sys.stderr, flush=True)
        rows.append(run_case(CASES[name], case_seed(args.seed, name), out, args.progress, args.n_traj, args.T,
                             args.threads))
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
