"""A PHAST world model of the control plant from a few minutes of driven, noisy, q-only recordings (issue 29).

``control_sac.py``'s ``sac-world`` agent trains inside a PHAST model; the real samples it costs are the model's
training recordings plus the burn-in windows of its episodes.  This module makes that model the way a user with
a real rig would: record the plant (``PHAST/DampedPendulum-v0`` at 0.01 s, the control benchmark's plant) driven
by random piecewise-constant torques from the start regimes of ``phast_gym.control`` (two of the five start
within 0.8 rad of the upright, so the recordings visit it), measured every decision (0.05 s) with noise
``sigma``, and learn a PARTIAL model with ``phast-train --recordings`` (``phast_model.train.rig_fit``): the rig description
(default: the *undamped* ``PHAST/Pendulum-v0`` with a 10% heavier nominal mass) gives the ``1 - cos q`` template,
whose coefficients are refitted, and the joint friction that the description leaves out is learned.

:func:`train_world_model` writes ``OUT/`` (the run directory, usable as ``control_sac.py --phast-run OUT``),
``OUT/recordings.npz`` and ``OUT/world_data.json`` (:data:`WORLD_DATA_FILE`: the recording protocol and
``real_samples``, which ``control_sac.py`` adds to ``sac-world``'s real-env samples).  ``benchmarks/sac_world_data.py``
is its command line.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.control import START_REGIMES, ControlProtocol, sample_start_states
from phast_gym.control.evaluation import control_system
from phast_gym.fileio import atomic_write_text
from phast_gym.integrate import simulate

#: the file that records how a world model's data were taken (read by control_sac.py's world_data_samples)
WORLD_DATA_FILE = "world_data.json"
#: held-out open-loop windows (s): a driven pendulum's whole 10-s recording diverges from any model
HELDOUT_WINDOW_S = 1.0


@dataclass(frozen=True)
class PlantRecording:
    """How the plant is recorded: ``n_traj`` trajectories of ``decisions`` samples at ``repeat`` plant steps each,
    torques ~ N(0, ``torque_std``) clipped at ``max_action`` and held ``hold`` samples, q-noise ``sigma``."""

    n_traj: int = 16
    decisions: int = 200
    repeat: int = 5
    sigma: float = 0.01
    torque_std: float = 5.0
    hold: int = 4
    max_action: float = 10.0
    seed: int = 0
    env_id: str = ControlProtocol.env_id
    regimes: tuple[str, ...] = tuple(START_REGIMES)

    def __post_init__(self) -> None:
        for name in ("n_traj", "decisions", "repeat", "hold"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if self.decisions < 2:
            raise ValueError(f"decisions must be >= 2, got {self.decisions!r}")
        if not self.regimes or any(r not in START_REGIMES for r in self.regimes):
            raise ValueError(f"regimes must be a non-empty subset of {list(START_REGIMES)}, got {list(self.regimes)}")
        for name in ("sigma", "torque_std", "max_action"):
            v = getattr(self, name)
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")

    @property
    def real_samples(self) -> int:
        """Measurements recorded (all of them, the held-out ones included)."""
        return self.n_traj * self.decisions


def start_states(spec: PlantRecording, rng: np.random.Generator) -> np.ndarray:
    """(n_traj, 2) initial states, cycling through the recording's start regimes (seeded)."""
    system = control_system(ControlProtocol(spec.env_id))
    regimes = list(spec.regimes)
    return np.concatenate([sample_start_states(system, regimes[i % len(regimes)], rng, 1) for i in range(spec.n_traj)])


def record_plant(spec: PlantRecording) -> dict[str, Any]:
    """Recordings in the phast-mismatch format: ``q`` (N, T, 1) noisy angles at the decision rate, ``u`` (N, T-1, 1)
    torques held over each interval, ``dt``, ``angle_dims``.  One batched simulation of all trajectories."""
    rng = np.random.default_rng(spec.seed)
    system = control_system(ControlProtocol(spec.env_id))
    x0 = start_states(spec, rng)
    n_hold = -(-(spec.decisions - 1) // spec.hold)
    u_dec = np.clip(rng.normal(0.0, spec.torque_std, (spec.n_traj, n_hold, 1)), -spec.max_action, spec.max_action)
    u_dec = np.repeat(u_dec, spec.hold, axis=1)[:, : spec.decisions - 1]
    u_plant = np.repeat(u_dec, spec.repeat, axis=1)  # zero-order hold at the plant step
    x = simulate(system, x0, (spec.decisions - 1) * spec.repeat, u_plant)
    q = x[:, :: spec.repeat, :1] + spec.sigma * rng.standard_normal((spec.n_traj, spec.decisions, 1))
    return {"q": q, "u": u_dec, "dt": system.dt * spec.repeat, "angle_dims": np.array([0])}


def train_world_model(spec: PlantRecording, out: Path, sim: str, sim_kwargs: dict[str, Any], epochs: int,
                      window_s: float, holdout: tuple[int, ...], seed: int = 0, progress: bool = False) -> dict[str, Any]:
    """Record the plant, train the PARTIAL recordings model into ``out`` and write the recordings and
    :data:`WORLD_DATA_FILE` beside it; returns the run's metrics."""
    from phast_model.train.rig_fit import RigTrainConfig
    from phast_model.train.rig_run import RecordingsSpec, train_recordings_run

    rec = record_plant(spec)
    t0 = time.time()
    metrics = train_recordings_run(
        RecordingsSpec(rec, sim, sim_kwargs, regime="partial", holdout=holdout, rollout_window_s=HELDOUT_WINDOW_S,
                       action_bound=(spec.max_action,)),
        # exactly ``epochs`` epochs of cosine decay: the schedule the documented world models were trained with
        out, RigTrainConfig(epochs=epochs, window_s=window_s, seed=seed, progress=progress, schedule="cosine",
                            patience=None))
    tmp = out / "recordings.tmp.npz"
    np.savez(tmp, **rec)
    tmp.replace(out / "recordings.npz")
    record = {"recording": asdict(spec), "real_samples": spec.real_samples, "sim": sim, "sim_kwargs": sim_kwargs,
              "epochs": epochs, "window_s": window_s, "holdout": list(holdout), "train_seconds": round(time.time() - t0, 1),
              "heldout_rollout_rmse": metrics["heldout"]["phast"]["rollout_rmse"],
              "heldout_nominal_rollout_rmse": metrics["heldout"]["nominal"]["rollout_rmse"]}
    atomic_write_text(out / WORLD_DATA_FILE, json.dumps(record, indent=1))
    return metrics
