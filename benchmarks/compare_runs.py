"""Compare the per-run results of two ``phast-bench`` output directories, run by run, bit for bit.

    python benchmarks/compare_runs.py OUT_A OUT_B

Runs are matched by their result path ``runs/<env>/<model>/seed<k>-<confighash>.json`` (the hash is of the full
configuration, so a match is the same run).  Compared per run: ``metrics``, ``best_val``, ``params`` and the
training ``history`` without its wall times (``time_s``); provenance (host, wall times, finish time, commit) is
not compared.  Prints one table row per run (identical or the largest absolute difference) and exits 0 when every
run is in both directories and identical, 1 otherwise, 2 on bad input.  Used to show that ``--backend ray`` gives
the same numbers as ``--backend local`` (docs/ray.md).
"""

from __future__ import annotations

import argparse
import sys

from phast_model.bench.compare import compare_dirs, format_table


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="compare_runs.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("dir_a", help="first phast-bench --out directory (A)")
    p.add_argument("dir_b", help="second phast-bench --out directory (B)")
    args = p.parse_args(argv)
    try:
        rows = compare_dirs(args.dir_a, args.dir_b)
    except ValueError as exc:
        print(f"compare_runs.py: error: {exc}", file=sys.stderr)
        return 2
    print(format_table(rows))
    return 0 if all(r.status == "identical" for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
