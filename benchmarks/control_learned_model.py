"""Summarise the learned-model-in-the-loop study: the plant-physics UKF next to ``phast-ukf`` (the same filter
with a trained PHAST run as its process model), one row per (target, sigma, process model).

Reads the ``results.json`` / ``protocol.json`` that ``phast-control-eval`` wrote into the sub-directories of
``--dir`` (one per target and PHAST run, named ``<plant>_<target>_<run>``, e.g. ``windy_q0_known`` or
``windy_up_partial_excited``), the ``metrics.json`` of each run and the run itself (its linearisation), and writes
``summary.md`` + ``summary.json`` there.  The evaluation commands are listed in docs/control.md.

    R=docs/control_results/phast_ukf/runs
    python benchmarks/control_learned_model.py --dir docs/control_results/phast_ukf \
        --runs known=$R/windy_known_s0 partial=$R/windy_partial_s0 unknown=$R/windy_unknown_s0
"""
from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

from phast_gym.fileio import atomic_write_text
from phast_model.control.learned_model import runs_markdown, summarize_runs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dir", required=True, help="directory holding one phast-control-eval output per sub-directory")
    ap.add_argument("--runs", nargs="+", default=[], metavar="REGIME=RUN_DIR", help="the PHAST runs, for their metrics")
    args = ap.parse_args(argv)
    runs = {}
    for item in args.runs:
        name, sep, path = item.partition("=")
        if not sep:
            ap.error(f"--runs takes REGIME=RUN_DIR, got {item!r}")
        runs[name] = Path(path)
    root = Path(args.dir)
    rows, metrics = summarize_runs(root, runs)
    if not rows:
        ap.error(f"no phast-control-eval results under {root}")
    atomic_write_text(root / "summary.json", json.dumps({"models": metrics, "rows": [asdict(r) for r in rows]}, indent=1))
    text = runs_markdown(rows, metrics)
    atomic_write_text(root / "summary.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
