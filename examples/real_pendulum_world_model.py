"""A PHAST world model of a real pendulum arm in free swing, learned from its encoder angles alone.

Data: ``multiarm_single_pendulum.npz`` (Kaheman et al. 2022, MIT License; one 55 s swing at 1 kHz cut into 6
segments; ``--data PATH`` or ``$PHAST_REAL_DATA``, see ``examples/real_pendulum_mismatch.py``).  The rig is
``PHAST/Pendulum-v0`` with the authors' published fit (viscous friction only).  PARTIAL keeps the cosine potential
template and a constant mass, refits them and learns a passive friction law; segments 5-6 are held out and scored
whole (each after a 0.1 s burn-in, open loop for ~9 s) against the published model, by the same code.  Free swing
has no input, so the scale of H is not identified (the rig's values fix it); the trajectories are.

    python examples/real_pendulum_world_model.py --out runs/real_pendulum [--json headline.json]
"""

from __future__ import annotations

import sys
from pathlib import Path

from real_pendulum_mismatch import DEFAULT_DATA, load

from phast_model.train.rig_fit import RigTrainConfig
from phast_model.train.rig_run import RecordingsSpec, example_cli, headline, train_recordings_run

#: segments 5-6 (0-based 4, 5)
HOLDOUT = (4, 5)
#: the 1 kHz encoder at 5 ms (a ~1.4 Hz swing), in 2-s training windows: the swing's slow decay and its exact period
#: decide a 9-s open-loop rollout, and 0.2-s windows do not see them (measured: 2.27x the published model's error)
DECIMATE, WINDOW_S = 5, 2.0
#: Gauss-Newton iterations of the window states per epoch: one left the 2-s windows' states behind the model
#: (0.714x the published model's error), three reach 0.428x
STATE_ITERS = 3
#: phast-mismatch's augmented model on the same held-out segments (docs/mismatch.md, "A real pendulum")
REFERENCE = {"phast-mismatch augmented / published": 0.345}


def run(data: Path, out: Path, regime: str = "partial", epochs: int = RigTrainConfig().epochs,
        progress: bool = True, seed: int = 0) -> dict:
    rec, kwargs = load(data)
    spec = RecordingsSpec(rec, "PHAST/Pendulum-v0", kwargs, regime, HOLDOUT, None, decimate=DECIMATE)
    # UNKNOWN starts from the recorded motion (phast_model.train.motion_start): no window warm-up is needed
    train = RigTrainConfig(epochs=epochs, window_s=WINDOW_S, state_iters=STATE_ITERS, progress=progress, seed=seed)
    metrics = train_recordings_run(spec, out, train)
    return headline(metrics, regime, REFERENCE, out)


def main(argv: list[str] | None = None) -> int:
    return example_cli(argv, __doc__.split("\n\n")[0], DEFAULT_DATA, run, "real_pendulum_world_model")


if __name__ == "__main__":
    sys.exit(main())
