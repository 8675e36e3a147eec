"""Why a PHAST regime's benchmark number is what it is: an error decomposition of trained grid runs.

    .venv/bin/python benchmarks/regime_diagnostics.py --out docs/results/full --envs Pendulum-v0 \
        --models phast-known,phast-partial --seeds 0-4 --json docs/results/full/diagnostics.json

What is re-scored, and how: :mod:`phast_model.bench.diagnostics`.  ``benchmarks/grid.py`` runs this after every PHAST
block with ``--merge``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import torch

from phast_gym.fileio import atomic_write_text
from phast_model.bench.diagnostics import diagnose_grid, diagnoses_markdown, merge
from phast_model.bench.paper import PAPER
from phast_model.bench.spec import PHAST_MODELS, parse_seeds
from phast_model.cli.bench import parse_kv


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="docs/results/full", help="the phast-bench output directory")
    ap.add_argument("--envs", default="all", help="'all' or a comma list of env ids")
    ap.add_argument("--models", default=",".join(PHAST_MODELS), help="PHAST models (baselines have no parts)")
    ap.add_argument("--seeds", default="0-4")
    ap.add_argument("--model-kw", action="append", metavar="KEY=VALUE",
                    help="the runs' model overrides, as given to phast-bench (repeatable)")
    ap.add_argument("--json", type=Path, help="write the per-run diagnoses here (JSON)")
    ap.add_argument("--md", type=Path, help="write the per-(env, model) mean table here (Markdown)")
    ap.add_argument("--merge", action="store_true",
                    help="keep the --json file's other blocks (the grid driver refreshes one block at a time)")
    args = ap.parse_args(argv)
    if args.merge and not args.json:
        ap.error("--merge needs --json (the file to merge into)")
    envs = list(PAPER) if args.envs == "all" else [e if e.startswith("PHAST/") else f"PHAST/{e}"
                                                   for e in args.envs.split(",")]
    models = [m.strip() for m in args.models.split(",")]
    bad = [m for m in models if m not in PHAST_MODELS]
    if bad:
        ap.error(f"not PHAST models: {bad} (choose from {list(PHAST_MODELS)})")
    torch.set_num_threads(1)
    diags = diagnose_grid(Path(args.out), envs, models, parse_seeds(args.seeds), parse_kv(args.model_kw))
    if args.merge and args.json.exists():
        diags = merge(json.loads(args.json.read_text()), diags, {(e, m) for e in envs for m in models})
    table = diagnoses_markdown(diags)
    print(table)
    if args.json:
        atomic_write_text(args.json, json.dumps([dataclasses.asdict(d) for d in diags], indent=1) + "\n")
    if args.md:
        atomic_write_text(args.md, table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
