"""phast_gym: Gymnasium suite of q-only port-Hamiltonian systems with a torque/force port.

``import phast_gym`` registers every ``PHAST/*`` id::

    import gymnasium as gym
    import phast_gym
    env = gym.make("PHAST/WindyPendulum-v0")

This package is numpy-only: it never imports torch.
"""

from .env import PortHamiltonianEnv
from .registry import ENV_TABLE, env_ids, make_env_system, register_all, resolve_env_id
from .systems import SYSTEMS, ParameterError, System, make_system, wrap

register_all()

__version__ = "0.1.0"


def __getattr__(name: str):  # lazy: datasets pull in file I/O helpers only when used
    if name in ("make_dataset", "make_splits", "Dataset", "split_dataset", "PortExcitation"):
        from . import datasets

        return getattr(datasets, name)
    raise AttributeError(f"module 'phast_gym' has no attribute {name!r}")


__all__ = [
    "PortHamiltonianEnv", "ENV_TABLE", "env_ids", "make_env_system", "register_all", "resolve_env_id",
    "SYSTEMS", "ParameterError", "System", "make_system", "wrap", "make_dataset", "make_splits", "Dataset",
    "split_dataset", "PortExcitation",
]
