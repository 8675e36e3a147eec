"""The phast demo: run every stage in order and collect their headline numbers.

Stages are optional modules next to this file, ``examples/demo_<stage>.py``, each exposing
``run(out_dir: pathlib.Path) -> dict``: datasets, world_model, control, mismatch.  A missing
stage is skipped with a message; a failing stage is reported and the others still run.
Each stage writes into ``OUT/<stage>/``; the summary goes to ``OUT/summary.json``::

    python examples/demo.py --out demo_out            # what `make demo` runs
    python examples/demo.py --stages datasets,control  # a subset
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import pathlib
import sys
import time
import traceback

os.environ.setdefault("MPLBACKEND", "Agg")

STAGES = ("datasets", "world_model", "control", "mismatch")
HERE = pathlib.Path(__file__).resolve().parent


def run_stage(stage: str, out: pathlib.Path) -> dict:
    """Import ``demo_<stage>`` and run it into ``out/<stage>``; never raises (status in the dict)."""
    try:
        mod = importlib.import_module(f"demo_{stage}")
    except ModuleNotFoundError as exc:
        if exc.name == f"demo_{stage}":
            print(f"[demo] stage '{stage}': examples/demo_{stage}.py not found, skipped", flush=True)
            return {"status": "skipped", "reason": f"examples/demo_{stage}.py missing"}
        raise
    stage_dir = out / stage
    stage_dir.mkdir(parents=True, exist_ok=True)
    print(f"[demo] stage '{stage}' ...", flush=True)
    t0 = time.perf_counter()
    try:
        result = mod.run(stage_dir)
        status = "ok"
    except Exception as exc:  # one broken stage must not hide the others' results
        traceback.print_exc()
        result, status = {"error": f"{type(exc).__name__}: {exc}"}, "failed"
    wall = time.perf_counter() - t0
    print(f"[demo] stage '{stage}' {status} in {wall:.1f} s: {json.dumps(result, default=str)[:400]}", flush=True)
    return {"status": status, "wall_s": round(wall, 2), "results": result}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="demo_out", help="output directory (default: demo_out)")
    ap.add_argument("--stages", default=",".join(STAGES), help=f"comma-separated subset of {','.join(STAGES)}")
    args = ap.parse_args(argv)
    stages = [s.strip() for s in args.stages.split(",") if s.strip()]
    unknown = [s for s in stages if s not in STAGES]
    if unknown:
        ap.error(f"unknown stage(s) {unknown}; choose from {list(STAGES)}")
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(HERE))
    try:
        import torch

        torch.set_num_threads(max(1, min(2, os.cpu_count() or 1)))
    except ImportError:
        pass

    t0 = time.perf_counter()
    summary = {"stages": {s: run_stage(s, out) for s in stages}}
    summary["wall_s"] = round(time.perf_counter() - t0, 2)
    tmp = out / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2, default=str))
    os.replace(tmp, out / "summary.json")

    print("\n[demo] summary")
    for s, r in summary["stages"].items():
        print(f"  {s:12s} {r['status']:8s} {r.get('wall_s', 0):7.1f} s  {json.dumps(r.get('results', r.get('reason')), default=str)[:160]}")
    print(f"  total {summary['wall_s']:.1f} s; written {out / 'summary.json'}")
    return 1 if any(r["status"] == "failed" for r in summary["stages"].values()) else 0


if __name__ == "__main__":
    raise SystemExit(main())
