"""``phast-bench``: run the benchmark grid (env x model x seed) with resume, then write tables and figures.

The paper's protocol is the default (1000/200/200 trajectories of T = 200, dataset
seed 42, 50 epochs, 5 seeds)::

    phast-bench --envs all --models all --seeds 0-4 --epochs 50 --out results/

Every run is keyed by a hash of its full configuration: rerunning the same
command skips finished runs and resumes an interrupted sweep.  Outputs:
``OUT/runs/<env>/<model>/seed<k>-<hash>.json`` (one per run), ``OUT/summary.csv``,
``OUT/tables.md`` (paper Table 4 shape + per-benchmark tables) and, with
``--figures``, ``OUT/figures/*.png`` (paper Figures 5-6 shape).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from phast_gym.fileio import ensure_writable_dir
from phast_model.bench import (
    ALL_MODELS,
    KNOWN_MODELS,
    TABLE4_ENVS,
    grid,
    load_result,
    parse_seeds,
    run_sweep,
    write_reports,
)

#: most runs one invocation may ask for (the paper grid is 13 x 10 x 5 = 650)
MAX_RUNS = 20_000


def _parse_list(text: str, all_values: tuple[str, ...], what: str) -> list[str]:
    if text.strip().lower() == "all":
        return list(all_values)
    out = [t.strip() for t in text.split(",") if t.strip()]
    if not out:
        raise ValueError(f"--{what}s is empty: give 'all' or a comma-separated list")
    return out


def parse_kv(items: list[str] | None) -> dict[str, object]:
    """``["lr=3e-4", "batch_size=32"]`` -> {"lr": 0.0003, "batch_size": 32} (values parsed as JSON when possible)."""
    out: dict[str, object] = {}
    for item in items or []:
        if "=" not in item:
            raise ValueError(f"expected KEY=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = json.loads(v)
        except json.JSONDecodeError:
            out[k.strip()] = v
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="phast-bench", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--envs", default="all",
                   help="'all' (the 13 benchmarks of paper Table 4) or comma-separated env ids")
    p.add_argument("--models", default="all",
                   help=f"'all' ({','.join(ALL_MODELS)}) or a comma list from: {','.join(KNOWN_MODELS)}"
                   " (dhnn = full-state ablation)")
    p.add_argument("--seeds", default="0-4", help="model seeds, e.g. '0-4' or '0,1,2' (default 0-4)")
    p.add_argument("--epochs", type=int, default=50)
    p.add_argument("--n-train", type=int, default=1000)
    p.add_argument("--n-val", type=int, default=200)
    p.add_argument("--n-test", type=int, default=200)
    p.add_argument("--T", type=int, default=200, help="samples per trajectory (default 200)")
    p.add_argument("--data-seed", type=int, default=42)
    p.add_argument("--horizons", default="10,50,100")
    p.add_argument("--burn-in", type=int, default=10)
    p.add_argument("--full-state", action="store_true",
                   help="every run sees the full state (q, p) (paper Table 25: PHAST regimes vs DHNN; "
                        "dhnn is always full-state)")
    p.add_argument("--train", action="append", metavar="KEY=VALUE",
                   help="TrainConfig override (repeatable), e.g. batch_size=32")
    p.add_argument("--model-kw", action="append", metavar="KEY=VALUE", help="model constructor override (repeatable)")
    p.add_argument("--out", default="results", help="output directory (default results/)")
    p.add_argument("--backend", choices=("local", "ray"), default="local")
    p.add_argument("--address", default=None,
                   help="Ray cluster to run on (backend ray): 'auto' (the cluster started on this machine by "
                        "'ray start') or HOST:PORT; default: a private local Ray instance for this sweep only")
    p.add_argument("--workers", type=int, default=None, help="parallel runs (default: all cores)")
    p.add_argument("--threads", type=int, default=1, help="torch threads per run (default 1)")
    p.add_argument("--summarize-only", action="store_true",
                   help="do not train: tabulate the finished runs of this grid")
    p.add_argument("--dry-run", action="store_true", help="list the grid with done/pending status and exit")
    p.add_argument("--figures", action="store_true",
                   help="also draw rollout / damping / energy figures (paper Figs. 5-6)")
    p.add_argument("--title", default="phast-bench results", help="title of tables.md")
    p.add_argument("--note", default="", help="text placed under the title of tables.md (e.g. the budget)")
    p.add_argument("--no-progress", action="store_true")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        envs = _parse_list(args.envs, TABLE4_ENVS, "env")
        from phast_gym.registry import resolve_env_id

        envs = [resolve_env_id(e) for e in envs]
        models = _parse_list(args.models, ALL_MODELS, "model")
        bad = [m for m in models if m not in KNOWN_MODELS]
        if bad:
            raise ValueError(f"unknown model(s) {bad}; known: {', '.join(KNOWN_MODELS)}")
        seeds = parse_seeds(args.seeds)
        if args.address and args.backend != "ray":
            raise ValueError("--address is the Ray cluster to run on: add --backend ray")
        for name in ("workers", "threads"):
            v = getattr(args, name)
            if v is not None and v < 1:
                raise ValueError(f"--{name} must be >= 1, got {v}")
        if len(envs) * len(models) * len(seeds) > MAX_RUNS:
            raise ValueError(f"the grid has {len(envs) * len(models) * len(seeds)} runs (more than {MAX_RUNS}); "
                             "ask for fewer envs, models or seeds")
        horizons = tuple(int(h) for h in args.horizons.split(",") if h.strip())
        specs = grid(envs, models, seeds, epochs=args.epochs, n_train=args.n_train, n_val=args.n_val,
                     n_test=args.n_test, T=args.T, data_seed=args.data_seed, horizons=horizons, burn_in=args.burn_in,
                     train=parse_kv(args.train), model_kw=parse_kv(args.model_kw), full_state=args.full_state)
        if not args.dry_run:
            ensure_writable_dir(args.out, "--out")
    except Exception as exc:  # noqa: BLE001 - bad input: one clear line, nothing written
        print(f"phast-bench: error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)
    if args.dry_run:
        done = 0
        for s in specs:
            ok = load_result(out, s) is not None
            done += ok
            print(f"{'done   ' if ok else 'pending'} {s.env_id} {s.model} seed {s.seed}")
        print(f"{len(specs)} runs: {done} done, {len(specs) - done} pending")
        return 0
    if args.summarize_only:
        records = [r for s in specs if (r := load_result(out, s)) is not None]
    else:
        try:
            records = run_sweep(specs, out, backend=args.backend, workers=args.workers, address=args.address,
                                progress=not args.no_progress, threads=args.threads)
        except KeyboardInterrupt:  # Ctrl-C: finished runs are on disk; the same command resumes
            done = sum(load_result(out, s) is not None for s in specs)
            print(f"phast-bench: interrupted; {done}/{len(specs)} runs are finished in {out.absolute()}; "
                  "rerun the same command to resume", file=sys.stderr)
            return 130
    paths = write_reports(records, out, title=args.title, note=args.note)
    if args.figures:
        from phast_model.bench.figures import make_figures

        paths.update({f"figure_{i}": p for i, p in enumerate(make_figures(out, specs))})
    n_fail = sum(r.get("status") == "failed" for r in records)
    n_ran = sum(r.get("status") == "ran" for r in records)
    print(json.dumps({"runs": len(specs), "ran": n_ran, "cached": len(records) - n_ran - n_fail, "failed": n_fail,
                      "missing": len(specs) - len(records), **{k: str(v) for k, v in paths.items()}}, indent=1))
    return 1 if n_fail else 0


if __name__ == "__main__":
    sys.exit(main())
