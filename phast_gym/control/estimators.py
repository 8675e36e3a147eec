"""Online, causal port (velocity) estimators for Energy-Casimir control.

For a collocated torque port the port output is ``y_p = G^T dH/dp = qdot``
(paper Sec. 3.5), so every estimator returns ``qdot_hat`` (n,) from the
q-only measurement stream.  One interface (:class:`PortEstimator`):

* ``reset()`` clears the history before an episode;
* ``update(q_meas, info=None, u_prev=None) -> qdot_hat`` consumes the newest
  measurement (angles wrapped, possibly noisy), the env's ``info`` (only the
  oracle reads it) and the port input applied over the last interval (only
  model-based filters use it);
* ``q_estimate() -> q_hat | None``: the estimator's filtered q after the last ``update``
  (None when it has none, e.g. finite differences); the controller's filtered xi feedback
  (``xi_feedback="filtered"``) uses it instead of the raw measurement.

Estimators are built by name through :func:`make_estimator`.  This module is numpy-only and
knows no package above it: torch-based estimators live in a package that depends on this one,
which registers them with :func:`register_estimator` when imported, and may declare them
beforehand with :func:`register_estimator_provider` (names plus the module that registers them)
so that :func:`estimator_names` lists them and :func:`make_estimator` imports that module on
first use.
"""

from __future__ import annotations

import math
import warnings
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from .. import integrate
from ..systems.base import NUMPY, SCALAR, System, wrap


class PortEstimator:
    """Base class: a causal map from the q-measurement stream to ``qdot_hat``."""

    #: registry name
    name: str = ""
    #: True when the estimator reads ground truth (``info["state"]``): simulation only
    privileged: bool = False

    def __init__(self, system: System, dt: float) -> None:
        if not (dt > 0 and math.isfinite(dt)):
            raise ValueError(f"dt must be positive and finite, got {dt!r}")
        self.system = system
        self.dt = float(dt)
        self.n = int(system.n)
        self._angle = np.array([i in system.angle_dims for i in range(self.n)])

    def reset(self) -> None:
        """Forget the measurement history (start of an episode)."""

    def update(self, q_meas: np.ndarray, info: dict | None = None, u_prev: np.ndarray | None = None) -> np.ndarray:
        raise NotImplementedError

    def q_estimate(self) -> np.ndarray | None:
        """Filtered q (n,) after the last :meth:`update` (angles may be unwrapped), or None if this estimator has
        none."""
        return None

    def _wrap_diff(self, d: np.ndarray) -> np.ndarray:
        """Difference of two measurements, wrapped on angular coordinates."""
        return np.where(self._angle, wrap(d), d)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(dt={self.dt})"


def _as_q(q_meas: npt.ArrayLike, n: int) -> np.ndarray:
    q = np.asarray(q_meas, dtype=np.float64).reshape(-1)
    if q.shape != (n,):
        raise ValueError(f"q_meas must have {n} components, got shape {np.shape(q_meas)}")
    return q


class OracleEstimator(PortEstimator):
    """True ``qdot = dH/dp`` from ``info["state"]`` (simulation only, paper Table 7 'oracle')."""

    name = "oracle"
    privileged = True

    def update(self, q_meas: np.ndarray, info: dict | None = None, u_prev: np.ndarray | None = None) -> np.ndarray:
        if info is None or "state" not in info:
            raise ValueError("the oracle estimator needs the env's info['state'] (true (q, p)); pass info to update()")
        x = np.asarray(info["state"], dtype=np.float64)
        n = self.n
        self._q: np.ndarray | None = x[:n].copy()
        return np.array([float(v) for v in self.system.velocity(list(x[:n]), list(x[n:]), SCALAR)])

    def reset(self) -> None:
        self._q = None

    def q_estimate(self) -> np.ndarray | None:
        """The true q (simulation only)."""
        q: np.ndarray | None = getattr(self, "_q", None)
        return None if q is None else q.copy()


class FiniteDifferenceEstimator(PortEstimator):
    """Backward difference ``wrap(q_t - q_{t-1}) / dt`` (0 at the first sample)."""

    name = "fd"

    def reset(self) -> None:
        self._prev: np.ndarray | None = None

    def __init__(self, system: System, dt: float) -> None:
        super().__init__(system, dt)
        self.reset()

    def update(self, q_meas: np.ndarray, info: dict | None = None, u_prev: np.ndarray | None = None) -> np.ndarray:
        q = _as_q(q_meas, self.n)
        out = np.zeros(self.n) if self._prev is None else self._wrap_diff(q - self._prev) / self.dt
        self._prev = q
        return out


def map_smoother_weights(w: int, dt: float, sigma: float, sigma_a: float, derivative: bool = True) -> np.ndarray:
    """Row vector ``c`` with ``qdot_hat = c @ q_window`` for the fixed-lag MAP smoother.

    Paper Eq. 32: ``min_q sum_s |q_s - q^meas_s|^2 / sigma^2 + sum_s |q_{s+2} - 2 q_{s+1} + q_s|^2 / (dt^4 sigma_a^2)``
    has the closed form ``q_smooth = (I + lam D2^T D2)^{-1} q^meas`` with ``lam = sigma^2 / (dt^4 sigma_a^2)``;
    Eq. 33 takes ``(q_smooth[w-1] - q_smooth[w-2]) / dt``.  Both are linear in the window, so the whole
    estimator is one precomputed dot product.  ``sigma = 0`` gives plain finite differences.
    ``derivative=False`` returns the weights of the smoothed newest angle ``q_smooth[w-1]`` instead.
    """
    if w < 2:
        raise ValueError(f"MAP window must be >= 2 samples, got {w}")
    if sigma < 0 or sigma_a <= 0:
        raise ValueError(f"MAP smoother needs sigma >= 0 and sigma_a > 0, got sigma={sigma}, sigma_a={sigma_a}")
    lam = sigma**2 / (dt**4 * sigma_a**2)
    d2 = np.zeros((max(w - 2, 0), w))
    for s in range(w - 2):
        d2[s, s : s + 3] = (1.0, -2.0, 1.0)
    a = np.eye(w) + lam * d2.T @ d2
    e = np.zeros(w)
    if derivative:
        e[-1], e[-2] = 1.0 / dt, -1.0 / dt
    else:
        e[-1] = 1.0
    return np.linalg.solve(a, e)  # a is symmetric: c^T = e^T a^{-1}  <=>  c = a^{-1} e


class MAPSmootherEstimator(PortEstimator):
    """Fixed-lag MAP smoother (paper Eq. 32-33), label-free; needs the noise scale sigma.

    Angles are unwrapped inside the window by integrating wrapped increments.  The weights of
    every window length 2..w are precomputed, so ``update`` is a matrix-vector product.
    """

    name = "map"

    def __init__(self, system: System, dt: float, sigma: float = 0.0, window: int = 10, sigma_a: float = 10.0) -> None:
        super().__init__(system, dt)
        if int(window) != window or window < 2:
            raise ValueError(f"MAP window must be an integer >= 2, got {window!r}")
        self.window, self.sigma, self.sigma_a = int(window), float(sigma), float(sigma_a)
        self._weights = {L: map_smoother_weights(L, self.dt, self.sigma, self.sigma_a)
                         for L in range(2, self.window + 1)}
        self._q_weights = {L: map_smoother_weights(L, self.dt, self.sigma, self.sigma_a, derivative=False)
                           for L in range(2, self.window + 1)}
        self.reset()

    def reset(self) -> None:
        self._hist: deque[np.ndarray] = deque(maxlen=self.window)
        self._q: np.ndarray | None = None

    def q_estimate(self) -> np.ndarray | None:
        """The smoothed newest angle of the window (Eq. 32's minimiser at the last sample)."""
        return None if self._q is None else self._q.copy()

    def update(self, q_meas: np.ndarray, info: dict | None = None, u_prev: np.ndarray | None = None) -> np.ndarray:
        self._hist.append(_as_q(q_meas, self.n))
        L = len(self._hist)
        if L < 2:
            self._q = self._hist[-1].copy()
            return np.zeros(self.n)
        win = np.stack(self._hist)  # (L, n)
        inc = self._wrap_diff(np.diff(win, axis=0))
        unwrapped = win[0] + np.concatenate([np.zeros((1, self.n)), np.cumsum(inc, axis=0)])
        self._q = self._q_weights[L] @ unwrapped
        return self._weights[L] @ unwrapped


class ProcessModel:
    """Interface: the physics a model-based filter predicts with, on the canonical state x = (q, p).

    * ``propagate(X, u)``: a batch of states (S, 2n) advanced over one control interval with the
      port input u held;
    * ``velocity(x)``: the port output qdot = dH/dp at one state (2n,) -> (n,).

    :class:`PlantPhysics` is the plant's own ``System``; the torch layer adds a learned PHAST run
    (estimator ``phast-ukf``), so a user without the plant's equations can filter with what the
    model learned.
    """

    n: int

    def propagate(self, X: np.ndarray, u: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    def velocity(self, x: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError


class PlantPhysics(ProcessModel):
    """The plant's own ``System`` integrated with numpy components (exact for the simulated plant)."""

    def __init__(self, system: System, dt: float, substeps: int | None = None) -> None:
        if not system.hamiltonian_system:
            raise ValueError(f"the UKF needs a port-Hamiltonian system (q, p), got {system.name}")
        self.system, self.n, self.dt = system, system.n, float(dt)
        self.substeps = int(substeps or max(1, math.ceil(system.substeps * self.dt / type(system).dt)))

    def propagate(self, X: np.ndarray, u: np.ndarray) -> np.ndarray:
        n = self.n
        q = [X[:, i].copy() for i in range(n)]
        p = [X[:, n + i].copy() for i in range(n)]
        qn, pn = integrate.step(self.system, q, p, [float(v) for v in u], NUMPY, dt=self.dt, substeps=self.substeps)
        return np.stack([np.broadcast_to(np.asarray(c, dtype=np.float64), (X.shape[0],))
                         for c in list(qn) + list(pn)], -1)

    def velocity(self, x: np.ndarray) -> np.ndarray:
        n = self.n
        return np.array([float(v) for v in self.system.velocity(list(x[:n]), list(x[n:]), SCALAR)])


class UnscentedParams(NamedTuple):
    """The sigma-point spread ``alpha``, secondary scaling ``kappa`` and prior-distribution ``beta`` (2: Gaussian)
    of the unscented transform."""

    alpha: float = 1.0
    kappa: float = 0.0
    beta: float = 2.0


DEFAULT_UNSCENTED = UnscentedParams()


class UKFEstimator(PortEstimator):
    """Unscented Kalman filter on (q, p) with a :class:`ProcessModel` (default: the plant's own physics).

    Prediction propagates all 4n + 1 sigma points at once under the applied port input ``u_prev``;
    the measurement is the wrapped q.  Returns ``qdot_hat = dH/dp`` of the process model at the
    posterior mean.  With ``process=None`` it assumes the physics of ``system`` (exact for the simulated
    plant; see the mismatch tool for real hardware); ``process_std`` is the (q, p) random-walk noise
    per sqrt(s) that absorbs the process model's error; ``unscented`` the transform's (alpha, kappa, beta).
    Registered as ``"ukf"`` (``"ekf"``: a deprecated alias).
    """

    name = "ukf"

    def __init__(
        self,
        system: System,
        dt: float,
        sigma: float = 0.0,
        substeps: int | None = None,
        p0_std: float = 10.0,
        process_std: tuple[float, float] = (1e-5, 1e-2),
        min_meas_std: float = 1e-3,
        unscented: UnscentedParams = DEFAULT_UNSCENTED,
        process: ProcessModel | None = None,
    ) -> None:
        super().__init__(system, dt)
        self.process = process if process is not None else PlantPhysics(system, self.dt, substeps)
        if self.process.n != self.n:
            raise ValueError(f"the process model has n = {self.process.n}, the plant n = {self.n}")
        n = self.n
        self.r = max(float(sigma), float(min_meas_std)) ** 2
        self.p0_std = float(p0_std)
        qs, ps = process_std
        self.Q = np.diag([qs**2 * self.dt] * n + [ps**2 * self.dt] * n)
        alpha, kappa, beta = unscented
        d = 2 * n
        lam = alpha**2 * (d + kappa) - d
        self._gamma = math.sqrt(d + lam)
        wm = np.full(2 * d + 1, 0.5 / (d + lam))
        wc = wm.copy()
        wm[0] = lam / (d + lam)
        wc[0] = wm[0] + (1 - alpha**2 + beta)
        self._wm, self._wc = wm, wc
        self.reset()

    def reset(self) -> None:
        self._x: np.ndarray | None = None
        self._P: np.ndarray | None = None
        self._last_q: np.ndarray | None = None

    def _sigma_points(self) -> np.ndarray:
        assert self._x is not None and self._P is not None  # after the first update
        P = 0.5 * (self._P + self._P.T)
        try:
            L = np.linalg.cholesky(P)
        except np.linalg.LinAlgError:
            L = np.linalg.cholesky(P + 1e-9 * np.eye(len(P)))
        S = self._gamma * L.T
        return np.concatenate([self._x[None], self._x[None] + S, self._x[None] - S])

    def update(self, q_meas: np.ndarray, info: dict | None = None, u_prev: np.ndarray | None = None) -> np.ndarray:
        z = _as_q(q_meas, self.n)
        n = self.n
        if self._x is None:
            # first sample: q from the measurement, p unknown (broad prior)
            self._x = np.concatenate([z, np.zeros(n)])
            self._P = np.diag([self.r] * n + [self.p0_std**2] * n)
        else:
            u = np.zeros(n) if u_prev is None else np.asarray(u_prev, dtype=np.float64).reshape(n)
            X = self.process.propagate(self._sigma_points(), u)
            x = self._wm @ X
            dX = X - x
            P = (self._wc[:, None] * dX).T @ dX + self.Q
            # measurement z = wrap(q): innovation wrapped, angles of the state stay unwrapped
            Zs = X[:, :n]
            zhat = self._wm @ Zs
            dZ = Zs - zhat
            S = (self._wc[:, None] * dZ).T @ dZ + self.r * np.eye(n)
            C = (self._wc[:, None] * dX).T @ dZ
            K = np.linalg.solve(S.T, C.T).T
            innov = self._wrap_diff(z - zhat)
            self._x = x + K @ innov
            self._P = P - K @ S @ K.T
        return self.process.velocity(self._x)

    def q_estimate(self) -> np.ndarray | None:
        """Posterior mean of q (angles unwrapped)."""
        return None if self._x is None else self._x[: self.n].copy()

    @property
    def state(self) -> np.ndarray | None:
        """Posterior mean (q, p) (angles unwrapped) or None before the first update."""
        return None if self._x is None else self._x.copy()


# --------------------------------------------------------------------------- registry
#: name -> factory(system, dt, sigma=..., **kwargs) -> PortEstimator
ESTIMATORS: dict[str, Callable[..., PortEstimator]] = {}
#: deprecated name -> the estimator's name now ("ekf" has always built the unscented Kalman filter)
DEPRECATED_NAMES: dict[str, str] = {"ekf": "ukf"}
#: name -> module whose import registers it (declared by the providing package, see register_estimator_provider)
PROVIDERS: dict[str, str] = {}


def register_estimator(name: str, factory: Callable[..., PortEstimator]) -> None:
    """Register a factory ``factory(system, dt, sigma=0.0, **kwargs) -> PortEstimator`` under ``name``."""
    ESTIMATORS[name] = factory


def register_estimator_provider(module: str, names: Iterable[str]) -> None:
    """Declare that importing ``module`` registers the estimators ``names``.

    For packages above this one whose estimators are costly to import (torch): they call this from
    their light top-level ``__init__``; :func:`estimator_names` then lists the names and
    :func:`make_estimator` imports ``module`` the first time one of them is built.  The dependency
    points one way: this package never names the providers itself.
    """
    if isinstance(names, str):
        raise TypeError("names must be an iterable of estimator names, not one string")
    for name in names:
        PROVIDERS[str(name)] = str(module)


register_estimator("oracle", lambda system, dt, sigma=0.0, **kw: OracleEstimator(system, dt, **kw))
register_estimator("fd", lambda system, dt, sigma=0.0, **kw: FiniteDifferenceEstimator(system, dt, **kw))
register_estimator("map", lambda system, dt, sigma=0.0, **kw: MAPSmootherEstimator(system, dt, sigma=sigma, **kw))
register_estimator("ukf", lambda system, dt, sigma=0.0, **kw: UKFEstimator(system, dt, sigma=sigma, **kw))


def resolve_estimator_name(name: str) -> str:
    """``name``, or the current name of a deprecated one, with a DeprecationWarning (``"ekf"`` -> ``"ukf"``)."""
    new = DEPRECATED_NAMES.get(name)
    if new is None:
        return name
    warnings.warn(f"estimator name {name!r} is deprecated: it is an unscented Kalman filter, use {new!r}",
                  DeprecationWarning, stacklevel=3)
    return new


def estimator_names() -> list[str]:
    """Every known estimator name (registered, or declared by a provider and imported on demand)."""
    return sorted(set(ESTIMATORS) | set(PROVIDERS))


def make_estimator(name: str, system: System, dt: float, sigma: float = 0.0, **kwargs: Any) -> PortEstimator:
    """Build the estimator ``name`` for ``system`` sampled every ``dt`` with measurement noise ``sigma``.

    ``sigma`` is the assumed noise scale (used by the MAP smoother, the Kalman filter and
    noise-conditioned observers; ignored by the others).  Unknown names raise ValueError listing
    the valid ones; a deprecated name (``"ekf"``) builds its successor with a DeprecationWarning.
    """
    name = resolve_estimator_name(name)
    if name not in ESTIMATORS and name in PROVIDERS:
        import importlib

        importlib.import_module(PROVIDERS[name])
    if name not in ESTIMATORS:
        raise ValueError(f"unknown port estimator {name!r}; valid names are {estimator_names()}")
    if not (sigma >= 0 and math.isfinite(sigma)):
        raise ValueError(f"sigma must be >= 0 and finite, got {sigma!r}")
    return ESTIMATORS[name](system, dt, sigma=sigma, **kwargs)
