"""The paper-protocol grid one (env, model) block at a time, resumable across sessions (``benchmarks/grid.py``).

Each block runs ``phast-bench`` (all its seeds, one worker, one torch thread) into one output directory whose per-run
JSON is keyed by the hash of the full configuration, so a finished run is never redone.  After every block the
driver refreshes the summary over all 13 rows (drivers that split the rows between them share the tables), the
block's figures and, after a PHAST block, the error decomposition (:mod:`phast_model.bench.diagnostics`), and can
commit the output directory, so a session that ends loses at most the block in progress.  ``estimate_hours`` reads
the measured cost of a training step (:mod:`phast_model.bench.cost`) for a dry run.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from ..train.fit import TrainConfig
from .paper import PAPER
from .runner import load_result
from .spec import ALL_MODELS, BASELINE_MODELS, PHAST_MODELS, RunSpec

GROUPS = {"baselines": BASELINE_MODELS, "phast": PHAST_MODELS, "all": ALL_MODELS}


def grid_envs(text: str) -> list[str]:
    """``"all"`` (the 13 rows of Table 4) or a comma list of env ids, ``PHAST/`` optional."""
    return list(PAPER) if text == "all" else [e if e.startswith("PHAST/") else f"PHAST/{e}" for e in text.split(",")]


def grid_models(text: str) -> tuple[str, ...]:
    """A group of :data:`GROUPS` (baselines, phast, all) or a comma list of model names."""
    return GROUPS.get(text) or tuple(m.strip() for m in text.split(","))


def pending(envs: list[str], models: tuple[str, ...], seeds: list[int], out: Path) -> list[tuple[str, str]]:
    """(env, model) blocks with at least one seed not finished in ``out``."""
    return [(e, m) for e in envs for m in models
            if any(load_result(out, RunSpec(env_id=e, model=m, seed=s)) is None for s in seeds)]


def seeds_left(env: str, model: str, seeds: list[int], out: Path) -> int:
    """How many of ``seeds`` of one block are not finished in ``out``."""
    return sum(load_result(out, RunSpec(env_id=env, model=model, seed=s)) is None for s in seeds)


def estimate_hours(todo: list[tuple[str, str, int]], cost_json: Path) -> float | None:
    """CPU-hours of the (env, model, seeds left) blocks at the paper's protocol: steps per run (epochs x
    ceil(n_train / batch)) x the measured training step, plus the evaluation rollouts; None without the cost file
    or with a block it does not cover."""
    if not cost_json.exists():
        return None
    rows = {(r["env"], r["model"]): r for r in json.loads(cost_json.read_text())["rows"]}
    spec = RunSpec(env_id="PHAST/Pendulum-v0", model="gru")
    steps = spec.epochs * math.ceil(spec.n_train / TrainConfig().batch_size)
    total = 0.0
    for env, model, n in todo:
        r = rows.get((env, model))
        if r is None:
            return None
        total += n * (steps * r["train_step_ms"] / 1e3 + r["eval_rollout_s"])
    return total / 3600


def dry_run(todo: list[tuple[str, str]], seeds: list[int], out: Path, cost: Path) -> str:
    """The blocks left, with their seeds left, and the CPU time they need (:func:`estimate_hours`)."""
    left = [(e, m, seeds_left(e, m, seeds, out)) for e, m in todo]
    lines = [f"  {e} {m} ({n} of {len(seeds)} seeds left)" for e, m, n in left]
    hours = estimate_hours(left, cost)
    lines.append(f"grid: about {hours:.1f} CPU-hours left (training steps timed in {cost})" if hours is not None
                 else f"grid: no estimate ({cost} is missing or does not cover every block)")
    return "\n".join(lines)


def bench(args: list[str]) -> int:
    """``phast-bench ARGS`` in its own process."""
    return subprocess.call([sys.executable, "-m", "phast_model.cli.bench", *args])


def commit(out: Path, message: str, tries: int = 20) -> bool:
    """``git add`` + ``git commit`` of ``out`` only; retried while another git process holds the index."""
    for _ in range(tries):
        add = subprocess.run(["git", "add", "--", str(out)], capture_output=True, text=True)
        if add.returncode == 0:
            res = subprocess.run(["git", "commit", "-q", "-m", message, "--", str(out)], capture_output=True, text=True)
            if res.returncode == 0 or "nothing to commit" in res.stdout + res.stderr:
                return True
        time.sleep(15)
    print(f"grid: could not commit {out} (git busy?); the files are on disk", file=sys.stderr)
    return False


def draw_figures(envs: list[str], seeds: list[int], out: Path) -> list[Path]:
    """``OUT/figures/<env>_rollout.png`` and ``<env>_damping_energy.png`` (paper Figs. 5-6 shape) of each env's best
    PHAST regime and best baseline among the finished runs."""
    from .figures import make_figures

    return make_figures(out, [RunSpec(env_id=e, model=m, seed=s) for e in envs for m in ALL_MODELS for s in seeds])


def run_blocks(todo: list[tuple[str, str]], seeds: str, out: Path, diagnose: Callable[[str, str, str, Path], int],
               redraw: Callable[[str, str, Path], int], run: Callable[[list[str]], int] = bench,
               commit_each: bool = False) -> None:
    """Run every (env, model) block of ``todo`` (seeds ``seeds``, e.g. ``"0-4"``) with ``run`` (``phast-bench``
    arguments -> exit code), then refresh the summary of all 13 rows, ``redraw(env, seeds, out)`` the block's figures
    and, after a PHAST block, ``diagnose(env, model, seeds, out)``; with ``commit_each``, commit ``out``."""
    # the summary always covers all 13 rows: drivers that split the rows between them share OUT's tables
    every = ["--envs", ",".join(PAPER), "--models", ",".join(ALL_MODELS), "--seeds", seeds, "--out", str(out)]
    for env, model in todo:
        t0 = time.time()
        rc = run(["--envs", env, "--models", model, "--seeds", seeds, "--out", str(out), "--workers", "1",
                  "--threads", "1", "--no-progress"])
        run([*every, "--summarize-only", "--title", "Paper protocol (1000/200/200, 50 epochs, seeds " + seeds + ")",
             "--note", "Written by benchmarks/grid.py as blocks finish; rows fill in across sessions."])
        redraw(env, seeds, out)
        if model in PHAST_MODELS:  # the error decomposition of docs/results.md, section 0, kept in step with the tables
            diagnose(env, model, seeds, out)
        print(f"grid: {env} {model} rc={rc} in {time.time() - t0:.0f} s", flush=True)
        if commit_each:
            commit(out, f"grid: {env.split('/')[-1]} {model} seeds {seeds}")
