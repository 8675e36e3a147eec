"""Port estimators built from a trained PHAST run (``phast_model.api.load_run``).

* ``phast-observer``: the run's causal FD+TCN observer (trained only through next-step prediction)
  applied to the q-measurement history.  The run was trained at its env's dt; when the control
  plant is sampled faster by an integer factor k, the observer reads every k-th measurement
  ending at the current one (still causal, no resampling of the network).
* ``phast-model``: model-based port output ``dH_hat/dp (q, p)`` of the learned Hamiltonian from the
  full state ``info["state"]`` (paper Table 8, full-state).
* ``phast-ukf``: the q-only UKF of ``phast_gym.control`` with the learned PHAST model as its process
  model (:class:`PHASTProcess`), for a user who has recordings but not the plant's equations.
"""

from __future__ import annotations

import math
from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np
import torch

from phast_gym.control.estimators import PortEstimator, ProcessModel, UKFEstimator
from phast_gym.systems.base import System

from .traced import Traced

if TYPE_CHECKING:
    from ..world.model import PHAST


def _load(run: str | Path | torch.nn.Module | None) -> PHAST:
    if isinstance(run, torch.nn.Module):
        return cast("PHAST", run.eval())  # a PHAST model (or one with its interface) given in memory
    if run is None:
        raise ValueError("PHAST-based estimators need a trained run: pass --phast-run DIR "
                         "(a phast-train run directory)")
    from ..api import load_run

    return load_run(run)


class PHASTObserverEstimator(PortEstimator):
    """qdot_hat from the observer of a PHAST run, fed a (possibly strided) window of q measurements."""

    name = "phast-observer"

    def __init__(self, system: System, dt: float, run: str | Path | torch.nn.Module) -> None:
        super().__init__(system, dt)
        self.model = _load(run)
        obs = self.model.observer
        ratio = float(obs.dt) / self.dt
        self.stride = int(round(ratio))
        if self.stride < 1 or abs(ratio - self.stride) > 1e-6:
            raise ValueError(f"the PHAST observer was trained at dt = {obs.dt}; the plant dt = {self.dt} "
                             "must divide it")
        if self.model.n != system.n:
            raise ValueError(f"the PHAST run has n = {self.model.n}, the plant n = {system.n}")
        self.window = int(obs.window)
        self._dtype = next(self.model.parameters()).dtype
        self.reset()

    def reset(self) -> None:
        self._len = (self.window - 1) * self.stride + 1
        self._hist: deque[np.ndarray] = deque(maxlen=self._len)

    @torch.no_grad()
    def update(self, q_meas: np.ndarray, info: dict | None = None, u_prev: np.ndarray | None = None) -> np.ndarray:
        q_meas = np.asarray(q_meas, dtype=np.float64).reshape(self.n)
        if not self._hist:
            self._hist.extend([q_meas] * (self._len - 1))
        self._hist.append(q_meas)
        h = np.stack(self._hist)[:: -self.stride][::-1]  # every stride-th sample, ending now
        v = self.model.observer(torch.as_tensor(h, dtype=self._dtype)[None])[0, -1]
        return v.double().numpy().copy()


class PHASTModelEstimator(PortEstimator):
    """Model-based port output ``dH_hat/dp`` of a PHAST run at the true (q, p) (full-state, paper Table 8)."""

    name = "phast-model"
    privileged = True

    def __init__(self, system: System, dt: float, run: str | Path | torch.nn.Module) -> None:
        super().__init__(system, dt)
        self.model = _load(run)
        self._dtype = next(self.model.parameters()).dtype

    @torch.no_grad()
    def update(self, q_meas: np.ndarray, info: dict | None = None, u_prev: np.ndarray | None = None) -> np.ndarray:
        if info is None or "state" not in info:
            raise ValueError("phast-model is a full-state estimator: it needs info['state'] (q, p)")
        x = torch.as_tensor(np.asarray(info["state"], dtype=np.float64), dtype=self._dtype)
        n = self.n
        return self.model.velocity(x[None, :n], x[None, n:])[0].double().numpy().copy()


class PHASTProcess(ProcessModel):
    """A trained PHAST run as a filter's process model on its own canonical state (q, p = M_hat qdot).

    One control interval ``dt`` is ``k`` Strang substeps of the learned core (Eq. 78) with the learned
    substep rescaled to ``dt`` (so a learned time-scale correction carries over), ``k`` chosen so the
    substep is no longer than the one the run was trained with.  The port input enters through the
    run's G (``PHAST.port_force``).  All sigma points go through the network in one batch, traced once per batch
    shape (:mod:`.traced`; ``traced=False``: eager).
    """

    def __init__(self, model: PHAST, dt: float, traced: bool = True) -> None:
        from ..world.core import PHASTCore

        if not isinstance(getattr(model, "core", None), PHASTCore):
            raise ValueError(f"phast-ukf needs a Hamiltonian PHAST run (PHASTCore); this run's core is "
                             f"{type(getattr(model, 'core', None)).__name__}")
        self.model, self.n, self.dt = model, int(model.n), float(dt)
        core = model.core
        ratio = self.dt / float(model.dt)
        self.substeps = max(1, math.ceil(core.substeps * ratio - 1e-9))
        self._h_scale = ratio * core.substeps / self.substeps
        self._dtype = next(model.parameters()).dtype
        self._step = Traced(model, self._interval, traced)
        sigma_points = 4 * self.n + 1  # the UKF's on a (q, p) state
        self._step.warm(torch.zeros(sigma_points, 2 * self.n, dtype=self._dtype),
                        torch.zeros(sigma_points, self.n, dtype=self._dtype))

    def _interval(self, x: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor]:
        """The states (B, 2n) one control interval on under the inputs (B, m)."""
        n, core = self.n, self.model.core
        q, p = core.strang_step(x[:, :n], x[:, n:], self.model.port_force(u), h=core.h * self._h_scale,
                                substeps=self.substeps)
        return (torch.cat([q, p], -1),)

    @torch.no_grad()
    def propagate(self, X: np.ndarray, u: np.ndarray) -> np.ndarray:
        x = torch.as_tensor(np.asarray(X, dtype=np.float64), dtype=self._dtype)
        ut = torch.as_tensor(np.asarray(u, dtype=np.float64), dtype=self._dtype).expand(x.shape[0], -1).contiguous()
        return self._step(x, ut)[0].double().numpy()

    @torch.no_grad()
    def velocity(self, x: np.ndarray) -> np.ndarray:
        xt = torch.as_tensor(np.asarray(x, dtype=np.float64), dtype=self._dtype)[None]
        return self.model.velocity(xt[:, : self.n], xt[:, self.n:])[0].double().numpy().copy()


def phast_ukf(system: System, dt: float, run: str | Path | torch.nn.Module | None, sigma: float = 0.0,
              **kw: Any) -> UKFEstimator:
    """The q-only UKF with a trained PHAST run as process model (``--estimators phast-ukf --phast-run DIR``).

    Everything but the process model is the plant-physics UKF's (``ukf``), its process noise included: on
    the windy pendulum (calibration seed 100, KNOWN and PARTIAL runs, docs/control.md) larger process noise
    only raised the velocity error and the upright torque."""
    model = _load(run)
    if model.n != system.n:
        raise ValueError(f"the PHAST run has n = {model.n}, the plant n = {system.n}")
    est = UKFEstimator(system, dt, sigma=sigma, process=PHASTProcess(model, dt), **kw)
    est.name = "phast-ukf"
    return est
