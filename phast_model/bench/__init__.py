"""The benchmark harness: run grids of (env, model, seed) with config-hash resume, then tabulate.

>>> from phast_model.bench import grid, run_sweep, write_reports
>>> specs = grid(["PHAST/WindyPendulum-v0"], ["phast-partial", "dlinoss"], [0, 1], epochs=50)
>>> records = run_sweep(specs, "results/", backend="local")
>>> write_reports(records, "results/")

The library code of the repository's benchmark scripts (``benchmarks/``) lives here too: the grid driver
(:mod:`.grid_driver`), the cost of a training step (:mod:`.cost`), the error decomposition of trained runs
(:mod:`.diagnostics`), the acceptance runs of the PHAST world model (:mod:`.acceptance`), the robustness of an
identified D to rounding (``benchmarks/fragility.py``), run-by-run comparison of two grids (:mod:`.compare`) and the
mismatch tool's concealed-effect cases on MuJoCo model files (:mod:`.mjcf_cases`, its files shipped as package data) and
the concealed-effect realities of ``phast-mismatch-bench`` (:mod:`.reality`).
"""

from .executors import Executor, LocalExecutor, RayExecutor, make_executor
from .paper import PAPER, PAPER_FULL_STATE, TABLE4_ENVS, PaperRow
from .runner import build_run_model, grid, load_result, result_path, run_one, run_sweep, work_dir
from .spec import ALL_MODELS, BASELINE_MODELS, KNOWN_MODELS, PHAST_MODELS, RunSpec, parse_seeds, run_key
from .summary import aggregate, markdown_tables, write_reports, write_summary_csv

__all__ = ["Executor", "LocalExecutor", "RayExecutor", "make_executor", "PAPER", "PAPER_FULL_STATE", "TABLE4_ENVS",
           "PaperRow", "build_run_model", "grid", "load_result", "result_path", "run_one", "run_sweep", "work_dir",
           "ALL_MODELS", "BASELINE_MODELS", "KNOWN_MODELS", "PHAST_MODELS", "RunSpec", "parse_seeds", "run_key",
           "aggregate", "markdown_tables", "write_reports", "write_summary_csv"]
