"""SB3 SAC vs Energy-Casimir on the torque-port damped pendulum (q-only, noisy), same regimes and metrics.

    python benchmarks/control_sac.py --out OUT --agents sac-real --until-flat --reward quiet --q-star 0
    python benchmarks/control_sac.py --out OUT --agents sac-gym --steps 20000 --curve --seed 0

The agents, the options and the outputs: :mod:`phast_model.cli.control_sac` (``--help``); the agents' rewards,
environments and training loop: :mod:`phast_model.rl`.
"""

from __future__ import annotations

from phast_model.cli.control_sac import main

if __name__ == "__main__":
    main()
