"""benchmarks/grid.py: one block at a time, and a summary over all 13 rows whatever rows a driver runs."""

from __future__ import annotations

from pathlib import Path

import pytest
from repo_scripts import load_script

from phast_model.bench.paper import PAPER


@pytest.fixture()
def grid_mod():  # noqa: ANN201
    return load_script("benchmarks/grid.py", "grid_driver")


def test_driver_on_some_rows_summarizes_all_rows(grid_mod, monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    calls: list[list[str]] = []
    diagnosed: list[tuple[str, str]] = []
    monkeypatch.setattr(grid_mod, "bench", lambda args: calls.append(list(args)) or 0)
    monkeypatch.setattr(grid_mod, "diagnose", lambda env, model, seeds, out: diagnosed.append((env, model)) or 0)
    drawn: list[str] = []
    monkeypatch.setattr(grid_mod, "redraw_figures", lambda env, seeds, out: drawn.append(env) or 0)
    rc = grid_mod.main(["--envs", "Pendulum-v0,RLCCircuit-v0", "--models", "phast-known,gru", "--seeds", "0",
                        "--out", str(tmp_path)])
    assert rc == 0
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


def test_figures_only_draws_from_finished_runs_and_trains_nothing(grid_mod, monkeypatch: pytest.MonkeyPatch,
                                                                  tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    seen: list = []
    monkeypatch.setattr(grid_mod, "bench", lambda args: pytest.fail("--figures-only trained"))
    monkeypatch.setattr("phast_model.bench.figures.make_figures", lambda out, specs: seen.extend(specs) or [])
    assert grid_mod.main(["--figures-only", "--envs", "RLCCircuit-v0", "--seeds", "0-1", "--out", str(tmp_path)]) == 0
    assert {(s.env_id, s.seed) for s in seen} == {("PHAST/RLCCircuit-v0", 0), ("PHAST/RLCCircuit-v0", 1)}
    assert len(seen) == 2 * 10  # every model of the grid: the best PHAST and the best baseline are picked from them


def test_dry_run_estimates_the_cpu_time_left(grid_mod, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Steps per run (50 epochs x 16 batches) x the measured step, plus the evaluation, for every seed left."""
    import json

    cost = tmp_path / "cost.json"
    cost.write_text(json.dumps({"rows": [{"env": "PHAST/Pendulum-v0", "model": "gru", "train_step_ms": 90.0,
                                          "eval_rollout_s": 36.0}]}))
    rc = grid_mod.main(["--envs", "Pendulum-v0", "--models", "gru", "--seeds", "0-1", "--out", str(tmp_path / "out"),
                        "--dry-run", "--cost", str(cost)])
    assert rc == 0
    text = capsys.readouterr().out
    assert "(2 of 2 seeds left)" in text
    assert "about 0.1 CPU-hours left" in text  # 2 x (800 x 0.09 s + 36 s) = 216 s
    assert grid_mod.estimate_hours([("PHAST/Pendulum-v0", "gru", 2)], cost) == pytest.approx(216 / 3600)
    assert grid_mod.estimate_hours([("PHAST/Pendulum-v0", "lstm", 1)], cost) is None  # not timed: no guess
