"""phast_model.bench.cost (benchmarks/bench_baselines.py): the cost rows and the per-env sum the grid's cost target is
read from."""

from __future__ import annotations

from phast_model.bench.cost import format_total, time_model


def test_total_sums_steps_and_uses_references_where_they_exist() -> None:
    rows = [{"env": "PHAST/WindyPendulum-v0", "model": "transformer", "train_step_ms": 200.0, "train_step_ms_ref": 600.0},
            {"env": "PHAST/WindyPendulum-v0", "model": "gru", "train_step_ms": 100.0}]
    line = format_total(rows)
    assert "sum of 2 models" in line and "300.0 ms" in line and "700.0 ms" in line and "x2.33" in line


def test_phast_row_times_the_reuse_against_the_composed_reference() -> None:
    row = time_model("PHAST/DampedPendulum-v0", "phast-known", batch=4, T=30, H=5, burn_in=10, n_eval=4, reps=1)
    assert row["params"] > 0 and row["train_step_ms"] > 0 and row["train_step_ms_ref"] > 0
    assert row["eval_rollout_s"] > 0
    assert "sum of 1 models" in format_total([row])
