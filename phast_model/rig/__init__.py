"""A world model of a real rig from its recordings (``phast-train --recordings``): ``fit`` (loading, KNOWN /
PARTIAL / UNKNOWN on a rig, multiple-shooting training), ``heldout`` (the held-out score), ``run`` (the run pipeline and its
metrics) and ``plots``.  The names of ``fit`` and ``heldout`` are re-exported here (``from phast_model.rig import RigTrainConfig``)."""

from .fit import (
    BURN_IN_S,
    REGIMES,
    RigData,
    RigFit,
    RigTrainConfig,
    ShootWindows,
    build,
    cut_windows,
    data_scales,
    fit_recordings,
    fit_states,
    friction_start,
    load_rig_data,
    nominal_config,
    rig_config,
    simulate,
)
from .heldout import HeldoutWindows, heldout_rollouts, heldout_windows, rollout_windows

__all__ = [
    "BURN_IN_S", "REGIMES", "HeldoutWindows", "RigData", "RigFit", "RigTrainConfig", "ShootWindows", "build",
    "cut_windows", "data_scales", "fit_recordings", "fit_states", "friction_start", "heldout_rollouts",
    "heldout_windows", "load_rig_data", "nominal_config", "rig_config", "rollout_windows", "simulate",
]
