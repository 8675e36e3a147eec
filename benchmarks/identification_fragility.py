"""How robust is one PHAST run's identified D to rounding-level perturbations of its weights?

    .venv/bin/python benchmarks/identification_fragility.py --env WindyPendulum-v0 --regime known --seed 0 \\
        --perturbations 8 --out docs/results/identification_fragility.json

The study, and how to run it against another checkout's code: benchmarks/fragility.py.
"""

from __future__ import annotations

import sys
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository root: benchmarks.fragility
    from benchmarks.fragility import main

    raise SystemExit(main())
