"""SB3 SAC vs Energy-Casimir on the torque-port damped pendulum (q-only, noisy), same regimes and metrics.

    python benchmarks/control_sac.py --out OUT --agents sac-real --until-flat --reward quiet --q-star 0
    python benchmarks/control_sac.py --out OUT --agents sac-gym --steps 20000 --curve --seed 0

The agents, the options and the outputs: :mod:`benchmarks.sac.cli` (``--help``); the agents' rewards, environments
and training: :mod:`benchmarks.sac`.
"""

from __future__ import annotations

import sys
from pathlib import Path

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository root: benchmarks.sac
    from benchmarks.sac.cli import main

    main()
