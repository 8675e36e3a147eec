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

from phast_gym.fileio import atomic_write_text  # noqa: E402

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
    print(f"[demo] stage '{stage}' {status} in {wall:.1f} s", flush=True)
    return {"status": status, "wall_s": round(wall, 2), "results": result}


def _fmt(v: object, spec: str = ".3g") -> str:
    return format(v, spec) if isinstance(v, (int, float)) else "?"


def _datasets(r: dict) -> tuple[str, str]:
    return (f"generated {r.get('n_traj', '?')} trajectories (T = 200) of each of {r.get('systems', '?')} systems",
            f"all of them, batched and plotted, in {_fmt(r.get('generate_and_plot_s'), '.2f')} s")


def _world_model(r: dict) -> tuple[str, str]:
    found = [f"{label} {_fmt(r[k])}" for k, label in (("rollout_theta_wrap_mse_h100", "rollout wrap-MSE at H = 100:"),
                                                      ("theta_wrap_mse", "next-step"), ("damping_r2", "damping R^2"))
             if k in r]
    return (f"trained PHAST ({r.get('regime', '?')} knowledge) on {r.get('env', '?')} in {_fmt(r.get('train_wall_time_s'), '.0f')} s",
            "; ".join(found))


def _control(r: dict) -> tuple[str, str]:
    names = [k.removeprefix("success_") for k in r if k.startswith("success_")]
    return (f"Energy-Casimir control of the damped pendulum at q-noise sigma = {_fmt(r.get('sigma'), 'g')}, "
            f"velocity estimators {', '.join(names)}",
            "success rate " + ", ".join(f"{n} {_fmt(r[f'success_{n}'], '.2f')}" for n in names))


def _mismatch(r: dict) -> tuple[str, str]:
    found = "; ".join(f"{t} {c} [{lo}, {hi}]" for t, c, (lo, hi) in r.get("synthetic_found", [])) or "nothing"
    text = (f"found {found}; held-out rollout RMSE {_fmt(r.get('synthetic_rollout_rmse_calibrated'))} -> "
            f"{_fmt(r.get('synthetic_rollout_rmse_augmented'))}")
    did = f"pendulum recordings hiding {r.get('synthetic_hidden', '?')}"
    if "real_improvement_vs_published" in r:
        did += "; a real pendulum arm against its published model"
        terms = ", ".join(t for t, _ in r.get("real_found", [])) or "nothing"
        text += f"; real arm: {terms}, {_fmt(r['real_improvement_vs_published'], '.2f')}x better held out"
    elif "real_skipped" in r:
        text += "; real arm skipped (no data file)"
    return did, text


#: stage -> (what it did, what it found) from its results; the picture is the result's "figure"
HEADLINES = {"datasets": _datasets, "world_model": _world_model, "control": _control, "mismatch": _mismatch}


def summary_table(summary: dict, out: pathlib.Path, width: int = 44) -> str:
    """The stages as a table a person reads: what each did, what it found (headline numbers), where its picture is."""
    import textwrap

    head = ("stage", "time", "what it did", "what it found", "picture")
    rows = []
    for stage, rec in summary["stages"].items():
        res = rec.get("results") or {}
        if rec["status"] == "ok":
            did, found = HEADLINES.get(stage, lambda r: ("", json.dumps(r, default=str)[:120]))(res)
            pic = res.get("figure")
            pic = os.path.relpath(pic, out) if pic else "-"
        else:
            did, found, pic = rec["status"], res.get("error") or rec.get("reason", ""), "-"
        rows.append((stage, f"{rec.get('wall_s', 0):.0f} s", did, found, pic))
    widths = [max(len(head[0]), *(len(r[0]) for r in rows)), 5, width, width, max(len(head[4]), *(len(r[4]) for r in rows))]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths)).rstrip(), "  ".join("-" * w for w in widths)]
    for row in rows:
        cells = [textwrap.wrap(c, w, break_on_hyphens=False) or [""] for c, w in zip(row, widths)]
        for k in range(max(len(c) for c in cells)):
            lines.append("  ".join((c[k] if k < len(c) else "").ljust(w) for c, w in zip(cells, widths)).rstrip())
    return f"[demo] summary (pictures under {out})\n" + "\n".join(lines)


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
    atomic_write_text(out / "summary.json", json.dumps(summary, indent=2, default=str))

    print("\n" + summary_table(summary, out))
    print(f"total {summary['wall_s']:.1f} s; all numbers in {out / 'summary.json'}")
    return 1 if any(r["status"] == "failed" for r in summary["stages"].values()) else 0


if __name__ == "__main__":
    raise SystemExit(main())
