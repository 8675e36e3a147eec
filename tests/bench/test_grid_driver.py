"""phast_model.bench.grid_driver (benchmarks/grid.py): one block at a time, and a summary over all 13 rows whatever rows
a driver runs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from phast_model.bench import grid_driver
from phast_model.bench.paper import PAPER
from phast_model.bench.spec import parse_seeds
from tests import ROOT

GRID = ROOT / "benchmarks" / "grid.py"


def test_driver_on_some_rows_summarizes_all_rows(tmp_path: Path) -> None:
    calls: list[list[str]] = []
    diagnosed: list[tuple[str, str]] = []
    drawn: list[str] = []
    envs = grid_driver.grid_envs("Pendulum-v0,RLCCircuit-v0")
    todo = grid_driver.pending(envs, grid_driver.grid_models("phast-known,gru"), [0], tmp_path)
    grid_driver.run_blocks(todo, "0", tmp_path, diagnose=lambda env, model, seeds, out: diagnosed.append((env, model)) or 0,
                           redraw=lambda env, seeds, out: drawn.append(env) or 0, run=lambda args: calls.append(list(args)) or 0)
    runs = [c for c in calls if "--summarize-only" not in c]
    summaries = [c for c in calls if "--summarize-only" in c]
    blocks = [(c[c.index("--envs") + 1], c[c.index("--models") + 1]) for c in runs]
    assert blocks == [("PHAST/Pendulum-v0", "phast-known"), ("PHAST/Pendulum-v0", "gru"),
                      ("PHAST/RLCCircuit-v0", "phast-known"), ("PHAST/RLCCircuit-v0", "gru")]
    assert len(summaries) == len(runs)
    for c in summaries:  # every refresh covers the 13 rows, not only this driver's two
        assert c[c.index("--envs") + 1].split(",") == list(PAPER)
    assert diagnosed == [("PHAST/Pendulum-v0", "phast-known"), ("PHAST/RLCCircuit-v0", "phast-known")]
    assert drawn == [e for e, _ in blocks]  # each block's row redrawn after it
    assert grid_driver.grid_models("baselines") == grid_driver.GROUPS["baselines"]


def test_figures_only_draws_from_finished_runs_and_trains_nothing(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    seen: list = []
    monkeypatch.setattr("phast_model.bench.figures.make_figures", lambda out, specs: seen.extend(specs) or [])
    assert grid_driver.draw_figures(grid_driver.grid_envs("RLCCircuit-v0"), parse_seeds("0-1"), tmp_path) == []
    assert {(s.env_id, s.seed) for s in seen} == {("PHAST/RLCCircuit-v0", 0), ("PHAST/RLCCircuit-v0", 1)}
    assert len(seen) == 2 * 10  # every model of the grid: the best PHAST and the best baseline are picked from them
    out = tmp_path / "out"  # the script: no run finished, nothing drawn, nothing trained
    done = subprocess.run([sys.executable, str(GRID), "--figures-only", "--envs", "RLCCircuit-v0", "--seeds", "0-1",
                           "--out", str(out)], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "" and not (out / "runs").exists()


def test_dry_run_estimates_the_cpu_time_left(tmp_path: Path) -> None:
    """Steps per run (50 epochs x 16 batches) x the measured step, plus the evaluation, for every seed left."""
    cost = tmp_path / "cost.json"
    cost.write_text(json.dumps({"rows": [{"env": "PHAST/Pendulum-v0", "model": "gru", "train_step_ms": 90.0,
                                          "eval_rollout_s": 36.0}]}))
    done = subprocess.run([sys.executable, str(GRID), "--envs", "Pendulum-v0", "--models", "gru", "--seeds", "0-1",
                           "--out", str(tmp_path / "out"), "--dry-run", "--cost", str(cost)],
                          capture_output=True, text=True, check=True)
    assert "(2 of 2 seeds left)" in done.stdout
    assert "about 0.1 CPU-hours left" in done.stdout  # 2 x (800 x 0.09 s + 36 s) = 216 s
    assert grid_driver.estimate_hours([("PHAST/Pendulum-v0", "gru", 2)], cost) == pytest.approx(216 / 3600)
    assert grid_driver.estimate_hours([("PHAST/Pendulum-v0", "lstm", 1)], cost) is None  # not timed: no guess
