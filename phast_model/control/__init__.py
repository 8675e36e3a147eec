"""Torch-based port estimators for Energy-Casimir control; importing this registers them.

* ``tcn`` (noise-matched), ``tcn-uniform`` (sigma ~ U[0, sigma_max]), ``tcn-cond`` (noise-conditioned):
  FD+TCN observers trained offline (:mod:`.tcn`); factory kwargs ``cache_dir``, ``sigma_max``,
  ``protocol`` (a :class:`~phast_gym.control.ControlProtocol`), ``progress``;
* ``phast-observer`` / ``phast-model`` / ``phast-ukf``: from a trained PHAST run (kwarg ``run``: run dir or
  model); ``phast-ukf`` is the q-only UKF with the learned model as its process model.

Not imported here: :mod:`.lqg_bound` (the LQG floor on the torque of any causal q-only controller at an unstable
equilibrium) and :mod:`.learned_model` (the tables of the learned-model-in-the-loop study).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from phast_gym.control.estimators import register_estimator
from phast_gym.control.evaluation import ControlProtocol
from phast_gym.systems.base import System

from .phast_estimators import PHASTModelEstimator, PHASTObserverEstimator, PHASTProcess, phast_ukf
from .tcn import (
    NOISE_MODES,
    TCNEstimator,
    TCNObserver,
    TCNObserverConfig,
    closed_loop_data,
    get_tcn_observer,
    load_tcn_observer,
    save_tcn_observer,
    train_tcn_observer,
)

#: estimator name -> TCN noise mode
TCN_VARIANTS = {"tcn": "fixed", "tcn-uniform": "uniform", "tcn-cond": "conditioned"}


def _tcn_factory(mode: str):  # noqa: ANN202
    def make(system: System, dt: float, sigma: float = 0.0, protocol: ControlProtocol | None = None,
             cache_dir: str | Path | None = None, sigma_max: float = 0.05, progress: bool = False, seed: int = 0,
             **cfg: Any) -> TCNEstimator:
        protocol = protocol or ControlProtocol(dt=dt)
        if abs(protocol.dt - dt) > 1e-12:
            raise ValueError(f"protocol.dt = {protocol.dt} differs from the plant dt = {dt}")
        c = TCNObserverConfig(noise_mode=mode, sigma=float(sigma) if mode == "fixed" else 0.0,
                              sigma_max=float(sigma_max), seed=seed, **cfg)
        return TCNEstimator(system, dt, get_tcn_observer(protocol, c, cache_dir, progress=progress), sigma=sigma)

    return make


for _name, _mode in TCN_VARIANTS.items():
    register_estimator(_name, _tcn_factory(_mode))
register_estimator("phast-observer",
                   lambda system, dt, sigma=0.0, run=None, **kw: PHASTObserverEstimator(system, dt, run, **kw))
register_estimator("phast-model",
                   lambda system, dt, sigma=0.0, run=None, **kw: PHASTModelEstimator(system, dt, run, **kw))
register_estimator("phast-ukf",
                   lambda system, dt, sigma=0.0, run=None, **kw: phast_ukf(system, dt, run, sigma=sigma, **kw))

__all__ = [
    "NOISE_MODES", "TCN_VARIANTS", "TCNEstimator", "TCNObserver", "TCNObserverConfig", "closed_loop_data",
    "get_tcn_observer", "load_tcn_observer", "save_tcn_observer", "train_tcn_observer", "PHASTObserverEstimator",
    "PHASTModelEstimator", "PHASTProcess", "phast_ukf",
]
