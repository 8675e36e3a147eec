"""The test suite, laid out like the packages: ``gym/`` (phast_gym), ``world/``, ``components/``, ``train/``,
``baselines/``, ``identify/``, ``mismatch/``, ``control/``, ``rl/``, ``bench/`` (phast_model and the benchmark
scripts' library code), ``examples/`` and ``codebase/`` (the static rules).  Tests import the packages; a script of
``benchmarks/`` or ``examples/`` is run as a subprocess, never imported."""

from pathlib import Path

#: the repository root (the scripts, docs and model files the tests read or run)
ROOT = Path(__file__).resolve().parents[1]
