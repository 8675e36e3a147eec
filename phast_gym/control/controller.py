"""Energy-Casimir controller (paper Eq. 28-31) as a policy object and a Gymnasium wrapper.

The controller is a port-Hamiltonian system with state ``xi`` and storage
``H_c = k_c/2 |xi - q_star|^2`` interconnected with the plant through the torque
port (paper Fig. 7)::

    u_t      = -k_c (xi_t - q_star) + v_ext_t - d_inj * y_hat_t            (Eq. 28/30)
    xi_{t+1} = xi_t + dt * (y_hat_t + k_xi * wrap(q_fb_t - xi_t))          (Eq. 29/31)

``q_fb = q_meas`` (the paper's Eq. 29, ``xi_feedback="meas"``) or the estimator's filtered
``q_hat`` (``xi_feedback="filtered"``, e.g. the UKF's posterior q): the correction term then
feeds ``k_xi`` times the *estimation* error into xi instead of ``k_xi`` times the raw
measurement noise, which ``k_c`` would otherwise amplify into the torque.

With ``y_hat = y_p = qdot`` and ``k_xi = 0`` the Casimir ``C = q - xi`` is invariant and
with ``v_ext = 0`` the closed-loop storage ``H_cl = H + k_c/2 |xi - q_star|^2`` is
non-increasing (Eq. 27): ``dH_cl/dt <= -d_inj |y_p|^2``.  With ``k_xi > 0`` the correction adds
``k_c k_xi (xi - q_star) . (q_fb - xi)`` to ``dH_cl/dt``; with the exact port and ``q_fb = q`` (the oracle,
noiseless, either ``xi_feedback``) ``C = q - xi`` obeys ``dC/dt = -k_xi C``, so xi started on the leaf
``C = 0`` stays there, the term vanishes and the bound holds for every ``k_xi >= 0`` (the sampled loop,
zero-order-hold torque and Euler xi, adds O(dt^2) per step).  The plant is touched only through
``reset``/``step``; physics (for gain validation) comes from ``env.unwrapped.system``.
"""

from __future__ import annotations

import math
from typing import Any, Protocol, SupportsFloat, runtime_checkable

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from ..systems.base import SCALAR, System, wrap
from .estimators import PortEstimator, make_estimator


def potential_curvature(system: System, q: np.ndarray, h: float = 1e-4) -> np.ndarray:
    """Hessian of the plant potential V at q by central differences of ``System.grad_potential``."""
    q = np.asarray(q, dtype=np.float64)
    n = len(q)
    hess = np.zeros((n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = h
        gp = np.array([float(v) for v in system.grad_potential(list(q + e), SCALAR)])
        gm = np.array([float(v) for v in system.grad_potential(list(q - e), SCALAR)])
        hess[:, j] = (gp - gm) / (2 * h)
    return 0.5 * (hess + hess.T)


def validate_gains(
    k_c: float, d_inj: float, k_xi: float, dt: float, q_star: np.ndarray, system: System | None = None,
    grad_tol: float = 1e-6
) -> None:
    """Refuse gains/targets for which the closed loop cannot stabilise ``q_star``; explain why.

    * ``k_c``, ``d_inj``, ``k_xi`` must be finite and >= 0 (negative gains inject energy:
      passivity, Eq. 27, needs ``d_inj >= 0``; ``k_c < 0`` makes ``H_c`` concave).
    * With the plant's physics: ``q_star`` must be an equilibrium of V (``grad V(q_star) = 0``),
      otherwise the minimum of ``H_cl`` on the Casimir leaf is not at ``q_star``; and the shaped
      potential ``V(q) + k_c/2 |q - q_star|^2`` must have a strict minimum there:
      ``Hess V(q_star) + k_c I > 0`` (upright pendulum, q_star = pi: ``k_c > m g l``).
    """
    for name, v in (("k_c", k_c), ("d_inj", d_inj), ("k_xi", k_xi)):
        if not isinstance(v, (int, float, np.floating, np.integer)) or not math.isfinite(float(v)):
            raise ValueError(f"{name} must be a finite number, got {v!r}")
        if v < 0:
            raise ValueError(
                f"{name} = {v} is negative: Energy-Casimir gains must be >= 0 "
                "(a negative d_inj injects energy, a negative k_c makes the controller storage concave, "
                "a negative k_xi makes the xi update unstable)"
            )
    if not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"dt must be positive and finite, got {dt!r}")
    if k_xi * dt >= 2.0:
        raise ValueError(f"k_xi * dt = {k_xi * dt:.3g} >= 2: the explicit xi correction (Eq. 29) is unstable; "
                         "lower k_xi")
    if not np.all(np.isfinite(q_star)):
        raise ValueError(f"q_star must be finite, got {q_star}")
    if system is None:
        return
    if len(q_star) != system.n:
        raise ValueError(f"q_star must have {system.n} components for {system.name}, got {len(q_star)}")
    if not system.hamiltonian_system:
        raise ValueError(f"{system.name} is not a port-Hamiltonian mechanical system: Energy-Casimir control does "
                         "not apply")
    grad = np.array([float(v) for v in system.grad_potential(list(q_star), SCALAR)])
    if np.max(np.abs(grad)) > grad_tol * max(1.0, float(np.max(np.abs(potential_curvature(system, q_star))))):
        raise ValueError(
            f"q_star = {q_star.tolist()} is not an equilibrium of the plant potential (grad V = {grad.tolist()}): "
            "the closed loop would settle where grad V(q) + k_c (q - q_star) = 0, not at q_star"
        )
    hess = potential_curvature(system, q_star)
    eig_min = float(np.linalg.eigvalsh(hess + k_c * np.eye(system.n)).min())
    if eig_min <= 0:
        need = float(-np.linalg.eigvalsh(hess).min())
        raise ValueError(
            f"k_c = {k_c} does not make q_star = {q_star.tolist()} a strict minimum of the shaped potential "
            f"V(q) + k_c/2 |q - q_star|^2 (smallest curvature {eig_min:.4g} <= 0): need k_c > {need:.4g} "
            "(for the upright pendulum this is k_c > m g l)"
        )


#: sources of the q fed back into the xi update (Eq. 29): the raw measurement or the estimator's filtered q
XI_FEEDBACK = ("meas", "filtered")


class EnergyCasimirController:
    """Energy-Casimir policy with internal state ``xi`` (paper Eq. 28-31).

    ``wrap_target`` (default True) applies the shaping force to ``wrap(xi - q_star)`` on angular
    coordinates: the paper's Eq. 28 writes ``xi - q_star`` on the covering space, which would make a spinning
    pendulum unwind every revolution it made; on the circle the storage is periodic.

    ``xi_feedback="filtered"`` corrects xi towards the estimator's filtered q (:meth:`PortEstimator.q_estimate`)
    instead of the raw measurement; estimators without one (finite differences) fall back to the measurement.

    Usage in a user loop: ``obs, info = env.reset(); ctrl.reset(obs, info)`` then each step
    ``u = ctrl.act(obs, info); obs, r, term, trunc, info = env.step(u)``.
    """

    def __init__(
        self,
        estimator: PortEstimator,
        q_star: float | np.ndarray = 0.0,
        k_c: float = 5.0,
        d_inj: float = 2.0,
        k_xi: float = 5.0,
        dt: float | None = None,
        max_action: float | None = None,
        system: System | None = None,
        wrap_target: bool = True,
        xi_feedback: str = "meas",
    ) -> None:
        if xi_feedback not in XI_FEEDBACK:
            raise ValueError(f"xi_feedback must be one of {XI_FEEDBACK}, got {xi_feedback!r}")
        if not isinstance(estimator, PortEstimator):
            raise ValueError(f"estimator must be a PortEstimator (see make_estimator), got {type(estimator).__name__}")
        self.estimator = estimator
        self.system = system if system is not None else estimator.system
        self.dt = float(estimator.dt if dt is None else dt)
        n = self.system.n
        self.q_star = np.broadcast_to(np.asarray(q_star, dtype=np.float64), (n,)).copy()
        validate_gains(k_c, d_inj, k_xi, self.dt, self.q_star, self.system)
        self.k_c, self.d_inj, self.k_xi = float(k_c), float(d_inj), float(k_xi)
        self.max_action = None if max_action is None else float(max_action)
        self.wrap_target = bool(wrap_target)
        self.xi_feedback = xi_feedback
        self._angle = np.array([i in self.system.angle_dims for i in range(n)])
        self.xi = np.zeros(n)
        self.u_prev: np.ndarray | None = None
        self.y_hat = np.zeros(n)

    def _wrap(self, d: np.ndarray) -> np.ndarray:
        return np.where(self._angle, wrap(d), d)

    def shaping_error(self) -> np.ndarray:
        """``xi - q_star``; wrapped on angles when ``wrap_target`` (H_c = k_c/2 wrap(xi - q_star)^2 lives on the
        circle)."""
        d = self.xi - self.q_star
        return self._wrap(d) if self.wrap_target else d

    def torque(self, y_hat: np.ndarray, v_ext: np.ndarray | float = 0.0) -> np.ndarray:
        """The port input of the current ``xi`` and port estimate ``y_hat`` (Eq. 28), clipped to ``max_action``."""
        u = -self.k_c * self.shaping_error() + np.asarray(v_ext, dtype=np.float64) - self.d_inj * y_hat  # Eq. 28
        return u if self.max_action is None else np.clip(u, -self.max_action, self.max_action)

    def reset(self, obs: np.ndarray, info: dict | None = None, xi0: np.ndarray | None = None) -> None:
        """Start an episode: ``xi`` := the measured q, represented nearest to q_star (Casimir C = 0)."""
        q = np.asarray(obs, dtype=np.float64).reshape(-1)[: self.system.n]
        self.xi = self.q_star + self._wrap(q - self.q_star) if xi0 is None else np.asarray(xi0, dtype=np.float64).copy()
        self.u_prev = None
        self.y_hat = np.zeros(self.system.n)
        self.estimator.reset()

    def act(self, obs: np.ndarray, info: dict | None = None, v_ext: np.ndarray | float = 0.0) -> np.ndarray:
        """Port input ``u_t`` for measurement ``obs`` (Eq. 28); advances ``xi`` (Eq. 29)."""
        n = self.system.n
        q_meas = np.asarray(obs, dtype=np.float64).reshape(-1)[:n]
        y_hat = np.asarray(self.estimator.update(q_meas, info, self.u_prev), dtype=np.float64).reshape(n)
        if not np.all(np.isfinite(y_hat)):
            raise ValueError(f"port estimator {self.estimator.name!r} returned a non-finite estimate {y_hat}")
        u = self.torque(y_hat, v_ext)
        q_fb = q_meas
        if self.xi_feedback == "filtered":
            q_hat = self.estimator.q_estimate()
            if q_hat is not None:
                q_fb = np.asarray(q_hat, dtype=np.float64).reshape(n)
        self.xi = self.xi + self.dt * (y_hat + self.k_xi * self._wrap(q_fb - self.xi))  # Eq. 29
        self.u_prev = u
        self.y_hat = y_hat
        return u

    def storage(self, q: np.ndarray, p: np.ndarray) -> float:
        """Closed-loop storage ``H_cl = H(q, p) + k_c/2 |xi - q_star|^2`` (Eq. 27) at the current xi."""
        h = float(self.system.hamiltonian(list(np.asarray(q, float)), list(np.asarray(p, float)), SCALAR))
        return h + 0.5 * self.k_c * float(np.sum(self.shaping_error() ** 2))


@runtime_checkable
class PortPlant(Protocol):
    """What the closed loop reads of the unwrapped plant env (a phast_gym :class:`PortHamiltonianEnv` has it): its
    physics, sampling interval and input bound."""

    system: System
    dt: float
    max_action: float


class EnergyCasimirWrapper(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """The wrapped env's action becomes the external input ``v_ext`` of the closed loop.

    ``env = EnergyCasimirWrapper(gym.make("PHAST/Pendulum-v0"), estimator="map", k_c=5, d_inj=2)``:
    ``step(v_ext)`` computes the controller torque from the last observation, applies it through
    the inner ``env.step`` and returns the inner transition; ``info`` gains ``u`` (applied
    torque), ``xi``, ``y_hat`` and ``v_ext``.  ``estimator`` is a name (built with the plant's
    system, dt and ``obs_noise_std``) or a :class:`PortEstimator`.
    """

    def __init__(
        self,
        env: gym.Env,
        estimator: str | PortEstimator = "oracle",
        q_star: float | np.ndarray = 0.0,
        k_c: float = 5.0,
        d_inj: float = 2.0,
        k_xi: float = 5.0,
        estimator_kwargs: dict[str, Any] | None = None,
        xi_feedback: str = "meas",
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, estimator=estimator, q_star=q_star, k_c=k_c, d_inj=d_inj,
                                                 k_xi=k_xi, estimator_kwargs=estimator_kwargs, xi_feedback=xi_feedback)
        gym.Wrapper.__init__(self, env)
        base = env.unwrapped
        if not (isinstance(base, PortPlant) and isinstance(base.system, System)):
            raise ValueError("EnergyCasimirWrapper needs a phast_gym PortHamiltonianEnv (env.unwrapped.system, dt, "
                             "max_action)")
        system = base.system
        if getattr(base, "observe", "q") != "q":
            raise ValueError("EnergyCasimirWrapper expects q-only observations (observe='q')")
        if tuple(getattr(base, "actuated_dofs", range(system.n))) != tuple(range(system.n)):
            raise ValueError("Energy-Casimir control here needs a fully actuated plant (collocated port on every dof)")
        dt = float(base.dt)
        if isinstance(estimator, str):
            estimator = make_estimator(estimator, system, dt, sigma=float(getattr(base, "obs_noise_std", 0.0)),
                                       **(estimator_kwargs or {}))
        self.controller = EnergyCasimirController(estimator, q_star, k_c, d_inj, k_xi, dt=dt,
                                                  max_action=float(base.max_action), system=system,
                                                  xi_feedback=xi_feedback)
        self.action_space = base.action_space
        self._obs: np.ndarray | None = None
        self._info: dict | None = None

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        obs, info = self.env.reset(**kwargs)
        self.controller.reset(obs, info)
        self._obs, self._info = obs, info
        return obs, info

    def step(self, action: npt.ArrayLike) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict]:
        if self._obs is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        v = np.asarray(action, dtype=np.float64)
        if v.shape != self.action_space.shape or not np.all(np.isfinite(v)):
            raise ValueError(f"v_ext must be a finite array of shape {self.action_space.shape}, got {np.shape(action)}")
        xi = self.controller.xi.copy()
        u = self.controller.act(self._obs, self._info, v_ext=v)
        obs, reward, terminated, truncated, info = self.env.step(u.astype(self.action_space.dtype))
        info = dict(info, u=u, xi=xi, y_hat=self.controller.y_hat.copy(), v_ext=v)
        self._obs, self._info = obs, info
        return obs, reward, terminated, truncated, info

