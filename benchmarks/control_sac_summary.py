"""One table over training seeds: the rows of several ``control_sac.py`` output folders, grouped by method and setting.

Each SAC row of ``DIR/control_sac.json`` is one training seed; rows of the same method, plant, target and start
regimes are pooled (success rates and errors averaged over seeds, per-seed angle-only successes listed, real
samples and wall time as mean and max).  Energy-Casimir rows are deterministic per evaluation seed and are
averaged the same way.  ``--floor`` (N m) adds the RMS torque as a multiple of a torque floor (the LQG bound of
docs/control.md for sigma = 0.01: 0.087 N m).

The pooling: :mod:`benchmarks.sac.summary`.

    python benchmarks/control_sac_summary.py docs/control_results/sac/upright_mirror_s* --floor 0.087
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> None:
    from benchmarks.sac.summary import load_rows, summarize

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dirs", nargs="+", help="control_sac.py output folders (one training seed each)")
    ap.add_argument("--floor", type=float, default=None, help="torque floor (N m) for the RMS / floor column")
    args = ap.parse_args(argv)
    if args.floor is not None and not args.floor > 0:
        ap.error(f"--floor must be > 0, got {args.floor}")
    try:
        print(summarize(load_rows(args.dirs), args.floor), end="")
    except ValueError as e:
        ap.exit(2, f"error: {e}\n")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository root: benchmarks.sac
    main()
