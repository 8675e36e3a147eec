"""A hold a motor survives: near the target the learned policy hands off to Energy-Casimir control built from the
LEARNED world model (its V and M; no m g l is given), with the learned model as the process model of a UKF.

Why this hold: a SAC policy balances on differences of noisy frames and chatters at the upright, far above the
quiet criterion's RMS torque (measured in docs/control.md).  A smoothness cost would trade precision
for quiet inside the same learned reflex.  Energy-Casimir control is passive by construction, its torque is
``-k_c wrap(xi - q*) - d_inj qdot_hat`` and needs a velocity, not a difference of frames: with a model-based UKF it
held at 1.1-1.2x the LQG floor.  Here both come from the world model the loop has just fitted:

* the gains: ``k_c = kc_factor * mgl_hat`` with ``mgl_hat = -min eig Hess V_hat(q*)`` (the learned potential's
  curvature at the upright; ``k_c > mgl_hat`` makes q* a strict minimum of the shaped potential) and
  ``d_inj = zeta * 2 sqrt(I_hat (k_c - mgl_hat))`` (damping ratio ``zeta`` of the linearised loop, ``I_hat`` the
  learned mass at q*); with the true pendulum (mgl 9.81, I 1) the defaults give the upright study's 20 and 3;
* the velocity: a UKF on (q, p) whose process model is the learned core (:class:`PHASTProcess`), fed every plant
  measurement and the applied input (also while the policy acts, so it has converged at the handoff).

:class:`HybridPolicy` runs the SB3 policy (every ``decision_steps`` plant steps, input held) until the UKF's estimate
is within ``enter_angle`` rad and ``enter_rate`` rad/s of the target, then the hold (every plant step); it hands
back if the angle leaves ``exit_angle``.  The region is on the angles and their rates only (a cart may be anywhere).

Plants whose input does not act on every coordinate (a cart-pole, force on the cart only) get :class:`LQRHold`
instead: Energy-Casimir control needs a collocated port on every degree of freedom, LQR on the learned model's
linearisation at the target does not (same learned V, M and UKF; see its docstring).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch

from phast_gym.control import EnergyCasimirController
from phast_gym.control.controller import potential_curvature
from phast_gym.control.estimators import UKFEstimator
from phast_gym.systems.base import NUMPY, ArrayNamespace, Components, System, angle_diff, wrap

from ..control.phast_estimators import PHASTProcess
from ..world.model import PHAST
from .observation import ObsBuilder
from .types import Policy

#: the holds: ``auto`` (Energy-Casimir when the input acts on every coordinate, else LQR), ``energy-casimir``, ``lqr``
HOLD_KINDS = ("auto", "energy-casimir", "lqr")


@dataclass(frozen=True)
class HoldConfig:
    """The hold: on or off, its kind (:data:`HOLD_KINDS`); Energy-Casimir: its gains relative to the learned model
    (``kc_factor``, ``zeta``), the Casimir correction ``k_xi``, the xi feedback (``filtered``: the UKF's q); LQR: the
    state weights on the angle errors, the Euclidean position errors and every rate (input weight 1) and its UKF's
    momentum process noise (per sqrt(s); Energy-Casimir keeps the UKF's default 0.01), with ``lqr_ukf_p_per_inertia``
    per unit of the smallest diagonal entry of the learned mass at the target (the momenta of a lighter pole are
    smaller: 0.03 at the 1-kg pole at 1 m, 0.0054 at PILCO's 0.5 kg at 0.6 m); the handoff region (angles and angular
    rates only); whether the UKF steps the learned core traced (:mod:`phast_model.control.traced`: the same numbers
    in less time)."""

    enabled: bool = True
    kind: str = "auto"
    kc_factor: float = 2.04
    zeta: float = 0.47
    k_xi: float = 5.0
    xi_feedback: str = "filtered"
    enter_angle: float = 0.3
    enter_rate: float = 1.5
    exit_angle: float = 0.8
    lqr_angle: float = 1.0
    lqr_position: float = 0.1
    lqr_rate: float = 0.0
    lqr_ukf_p_std: float = 0.03
    lqr_ukf_p_per_inertia: bool = False
    traced: bool = True

    def __post_init__(self) -> None:
        if self.kind not in HOLD_KINDS:
            raise ValueError(f"hold kind must be one of {HOLD_KINDS}, got {self.kind!r}")
        for k in ("lqr_angle", "lqr_position", "lqr_rate", "lqr_ukf_p_std"):
            v = getattr(self, k)
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"{k} must be a finite number >= 0, got {v!r}")
        if not self.kc_factor > 1.0:
            raise ValueError(f"kc_factor must be > 1 (k_c > m g l makes the target a minimum), got {self.kc_factor!r}")
        for k in ("zeta", "k_xi", "enter_angle", "enter_rate", "exit_angle"):
            v = getattr(self, k)
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"{k} must be a finite number >= 0, got {v!r}")
        if self.exit_angle < self.enter_angle:
            raise ValueError(f"exit_angle ({self.exit_angle}) must be >= enter_angle ({self.enter_angle})")

    def enters(self, angle_err: np.ndarray, rates: np.ndarray) -> bool:
        """Inside the handoff region: every angle error below ``enter_angle`` and every angle rate below
        ``enter_rate`` (the deployed policy's handoff, and the end of the agent's world-model task with a goal)."""
        return bool(np.abs(angle_err).max() < self.enter_angle and np.abs(rates).max() < self.enter_rate)


class LearnedSystem(System):
    """The learned model's physics as a phast_gym :class:`System` (what the Energy-Casimir controller validates its
    gains against): V_hat, grad V_hat and M_hat of the PHAST model, in the units of the port (G is the identity on
    the actuated coordinates, so they are physical torques).  Build it with :func:`learned_system`."""

    name = "learned"

    def __init__(self, model: PHAST, dt: float) -> None:
        self.model = model
        self.dt = float(dt)
        self.slope = np.zeros(int(model.n))  # removed from grad V_hat (:meth:`level_at`)
        self.q_ref = np.zeros(int(model.n))
        super().__init__()

    def level_at(self, q_star: np.ndarray) -> np.ndarray:
        """Make ``q_star`` an equilibrium: subtract the learned potential's slope there, V_hat(q) - s . (q - q*)
        with s = grad V_hat(q*).  The hold's premise is that the target is an equilibrium of the plant (it holds there
        with a vanishing input); a learned potential misses that by its error (a neural V at the upright: 0.7 N m
        against a curvature of 10), and a hold built on the slope would push the plant off by slope / stiffness.
        Returns s (0 for a template whose equilibria are exact)."""
        self.slope = np.zeros(self.n)
        self.q_ref = np.asarray(q_star, dtype=np.float64)
        self.slope = np.asarray(self.grad_potential(list(q_star)), dtype=np.float64)
        return self.slope

    def _q(self, q: Components) -> torch.Tensor:
        return torch.as_tensor(np.asarray([float(c) for c in q], dtype=np.float64)[None], dtype=torch.float64)

    def potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> float:
        with torch.no_grad():
            v = float(self.model.potential(self._q(q)).reshape(-1)[0])
        return v - float(self.slope @ (np.asarray([float(c) for c in q]) - self.q_ref))

    def grad_potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        g = self.model.potential.grad(self._q(q).requires_grad_(True)).detach().reshape(-1).numpy()
        return tuple(float(v) for v in g - self.slope)

    def mass_matrix(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple[tuple, ...]:
        with torch.no_grad():
            m = self.model.mass.matrix(self._q(q)).reshape(self.n, self.n).numpy()
        return tuple(tuple(float(v) for v in row) for row in m)

    def velocity(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        m = np.array(self.mass_matrix(q))
        return tuple(np.linalg.solve(m, np.asarray([float(c) for c in p])))

    def damping(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return tuple(0.0 for _ in range(self.n))

    def has_damping(self) -> bool:
        return False


def learned_system(model: PHAST, dt: float) -> LearnedSystem:
    """A :class:`LearnedSystem` of the model's size and angles (the class attributes ``n`` and ``angle_dims``)."""
    cls = type("LearnedSystem", (LearnedSystem,), {"n": int(model.n), "angle_dims": tuple(model.angle_dims)})
    return cls(model, dt)


@dataclass(frozen=True)
class HoldGains:
    """The hold's gains and the learned quantities they come from."""

    k_c: float
    d_inj: float
    mgl_hat: float
    inertia_hat: float
    slope_removed: tuple[float, ...] = ()  # grad V_hat at the target, levelled (:meth:`LearnedSystem.level_at`)


def hold_gains(system: System, q_star: np.ndarray, cfg: HoldConfig) -> HoldGains:
    """k_c and d_inj from the learned potential's curvature and mass at ``q_star`` (module docstring)."""
    need = max(float(-np.linalg.eigvalsh(potential_curvature(system, q_star)).min()), 0.0)
    inertia = float(np.linalg.eigvalsh(np.array(system.mass_matrix(list(q_star)))).max())
    k_c = cfg.kc_factor * need if need > 0 else 1.0
    return HoldGains(k_c, cfg.zeta * 2.0 * math.sqrt(inertia * (k_c - need)), need, inertia)


def make_energy_casimir_hold(model: PHAST, q_star: np.ndarray, dt: float, sigma: float, max_action: float,
                             cfg: HoldConfig) -> tuple[EnergyCasimirController, HoldGains]:
    """The Energy-Casimir controller of the learned model at the plant step ``dt``, with the learned-model UKF."""
    system = learned_system(model, dt)
    slope = system.level_at(q_star)
    gains = replace(hold_gains(system, q_star, cfg), slope_removed=tuple(float(v) for v in slope))
    est = UKFEstimator(system, dt, sigma=sigma, process=PHASTProcess(model, dt, cfg.traced))
    ctrl = EnergyCasimirController(est, q_star=q_star, k_c=gains.k_c, d_inj=gains.d_inj, k_xi=cfg.k_xi, dt=dt,
                                   max_action=max_action, system=system, xi_feedback=cfg.xi_feedback)
    return ctrl, gains


@dataclass(frozen=True)
class LQRGains:
    """The LQR hold's gain row(s) K (u = -K [q - q_ref, qdot]) and what they come from: the learned model's
    linearisation at the target (the upright's unstable pole, rad/s) and the stationary RMS input of this K on the
    learned linearisation with a Kalman estimate at the plant's sigma (:mod:`phast_model.control.lqg_bound`)."""

    k: list[list[float]]
    unstable_pole: float
    rms_input_linear: float


class LQRHold:
    """A hold for a plant whose input does not act on every coordinate (a cart-pole, force on the cart only): LQR on
    the LEARNED model linearised at the target, on the state estimate of a UKF whose process model is the learned core.

    Why not Energy-Casimir: its shaping force ``-k_c (xi - q*)`` acts on every coordinate, so it needs a collocated
    input on each; with the force on the cart only it cannot shape the pole's potential.  The natural alternative with
    the same ingredients (learned V, M at the target; the learned-model UKF for q and qdot) is the linear-quadratic
    regulator of the learned linearisation: ``linearise_system`` of :mod:`phast_model.control.lqg_bound` applied to the
    :class:`LearnedSystem` (Hess V_hat, M_hat; learned friction left out, it only adds damping), weights
    ``HoldConfig.lqr_*`` on (angle errors, position errors, rates) and 1 on the input.  Small weights keep it near the
    minimum-energy (LQG) gain, i.e. near the torque floor: angle 1, position 0.1, rates 0 cost 1.07x the floor on the
    true cart-pole's linearisation (docs/control.md).  At the handoff the position reference is set to where the
    cart is (:meth:`engage`), so the hold does not spend force dragging the cart back.

    Interface of :class:`HybridPolicy`'s hold (as :class:`EnergyCasimirController`): ``reset``, ``act`` (the estimator
    update with the last applied input), ``torque(y_hat)``, ``engage``, ``estimator``, ``system``, ``y_hat`` and
    ``u_prev`` (the applied input; the UKF gets it as the n-wide generalized force G u)."""

    def __init__(self, model: PHAST, q_star: np.ndarray, dt: float, sigma: float, max_action: float,
                 actuated: Sequence[int], cfg: HoldConfig) -> None:
        from ..control.lqg_bound import closed_loop, linearise_system, lqr_gain, stationary

        self.system = learned_system(model, dt)
        n = self.system.n
        self.q_star = np.asarray(q_star, dtype=np.float64).reshape(n)
        self.actuated = [int(i) for i in actuated]
        self.G = np.eye(n)[:, self.actuated]
        self._angle = np.array([i in self.system.angle_dims for i in range(n)])
        a, b = linearise_system(self.system, self.q_star, dt, self.actuated)
        w = np.concatenate([np.where(self._angle, cfg.lqr_angle, cfg.lqr_position), np.full(n, cfg.lqr_rate)])
        self.k = lqr_gain(a, b, w)
        lam = np.log(np.abs(np.linalg.eigvals(a)).max()) / dt
        self.gains = LQRGains(self.k.tolist(), float(lam),
                              float(stationary(closed_loop(a, b, max(sigma, 1e-6), gains=self.k))["rms_torque"]))
        self.dt, self.max_action = float(dt), float(max_action)
        p_std = cfg.lqr_ukf_p_std
        if cfg.lqr_ukf_p_per_inertia:
            p_std *= float(np.diag(np.array(self.system.mass_matrix(list(self.q_star)))).min())
        self.estimator = UKFEstimator(self.system, dt, sigma=sigma, process=PHASTProcess(model, dt, cfg.traced),
                                      process_std=(1e-5, p_std))
        self.q_ref = self.q_star.copy()
        self.y_hat = np.zeros(n)
        self._force: np.ndarray | None = None

    @property
    def u_prev(self) -> np.ndarray | None:
        return self._force

    @u_prev.setter
    def u_prev(self, u: np.ndarray | None) -> None:
        """The input applied this step (m,), kept as the generalized force G u the UKF propagates."""
        self._force = None if u is None else self.G @ np.asarray(u, dtype=np.float64).reshape(len(self.actuated))

    def reset(self, q_meas: np.ndarray) -> None:
        self.estimator.reset()
        self.q_ref, self.y_hat, self._force = self.q_star.copy(), np.zeros(self.system.n), None

    def act(self, q_meas: np.ndarray) -> None:
        """The UKF update with this measurement and the input applied last step."""
        n = self.system.n
        self.y_hat = np.asarray(self.estimator.update(np.asarray(q_meas, dtype=np.float64)[:n], None, self._force),
                                dtype=np.float64).reshape(n)

    def engage(self, q_hat: np.ndarray) -> None:
        """At the handoff: the Euclidean coordinates' reference := where they are (the angles keep q*)."""
        self.q_ref = np.where(self._angle, self.q_star, np.asarray(q_hat, dtype=np.float64))

    def torque(self, y_hat: np.ndarray) -> np.ndarray:
        """u = -K [q_hat - q_ref (angles wrapped), qdot_hat], clipped."""
        q_hat = self.estimator.q_estimate()
        q_hat = self.q_ref if q_hat is None else np.asarray(q_hat, dtype=np.float64)
        e = np.where(self._angle, wrap(q_hat - self.q_ref), q_hat - self.q_ref)
        u = -self.k @ np.concatenate([e, np.asarray(y_hat, dtype=np.float64)])
        return np.clip(u, -self.max_action, self.max_action)


def make_hold(model: PHAST, q_star: np.ndarray, dt: float, sigma: float, max_action: float, cfg: HoldConfig,
              actuated: Sequence[int] | None = None) -> tuple[EnergyCasimirController | LQRHold, HoldGains | LQRGains]:
    """The hold of ``cfg.kind`` from the learned model: Energy-Casimir when the input acts on every coordinate
    (``actuated`` None or all of them) and ``kind`` is ``auto``, else :class:`LQRHold`."""
    n = int(model.n)
    act = list(range(n)) if actuated is None else [int(i) for i in actuated]
    full = sorted(act) == list(range(n))
    if cfg.kind == "energy-casimir" or (cfg.kind == "auto" and full):
        if not full:
            raise ValueError(f"an Energy-Casimir hold needs an input on every coordinate; this plant drives {act} of "
                             f"{n}")
        return make_energy_casimir_hold(model, q_star, dt, sigma, max_action, cfg)
    hold = LQRHold(model, q_star, dt, sigma, max_action, act, cfg)
    return hold, hold.gains


class HybridPolicy:
    """The deployed controller (a :class:`phast_model.rl.types.Controller`): the SB3 policy, and the hold near the
    target (module docstring).  ``holding`` says which acts; ``handoffs`` counts entries into the hold."""

    def __init__(self, agent: Policy, frames: int, decision_steps: int, max_action: float, q_star: np.ndarray,
                 hold: EnergyCasimirController | LQRHold | None = None, cfg: HoldConfig | None = None,
                 angle_dims: Sequence[int] | None = None) -> None:
        self.agent, self.decision_steps, self.max_action = agent, int(decision_steps), float(max_action)
        self.q_star = np.asarray(q_star, dtype=np.float64)
        self.builder = ObsBuilder(frames, angle_dims=angle_dims)
        self.hold, self.cfg = hold, cfg or HoldConfig()
        self.holding = False
        self.handoffs = 0
        self._t = 0
        self._u = np.zeros(0)
        self._obs = np.zeros(0, dtype=np.float32)

    def reset(self, q_meas: np.ndarray) -> None:
        self._obs = self.builder.reset(q_meas)
        self.holding, self.handoffs, self._t = False, 0, 0
        if self.hold is not None:
            self.hold.reset(q_meas)

    def _policy_input(self, q_meas: np.ndarray) -> np.ndarray:
        if self._t % self.decision_steps == 0:
            if self._t > 0:
                self._obs = self.builder.push(q_meas)
            a, _ = self.agent.predict(self._obs, deterministic=True)
            self._u = np.clip(np.asarray(a, dtype=np.float64).reshape(-1), -1, 1) * self.max_action
        return self._u

    def _update_mode(self) -> None:
        """Enter the hold inside the handoff region of the UKF's estimate (angles and their rates), leave it outside
        ``exit_angle``."""
        assert self.hold is not None
        q_hat = self.hold.estimator.q_estimate()
        if q_hat is None:
            return
        dims = list(self.hold.system.angle_dims)
        d = angle_diff(np.asarray(q_hat, dtype=np.float64), self.q_star, dims)
        err = float(np.abs(d[dims]).max())
        if self.holding and err > self.cfg.exit_angle:
            self.holding = False
        elif not self.holding and self.cfg.enters(d[dims], self.hold.y_hat[dims]):
            self.holding = True
            self.handoffs += 1
            if isinstance(self.hold, LQRHold):
                self.hold.engage(self.q_star + d)
            else:
                self.hold.xi = self.q_star + d

    def act(self, q_meas: np.ndarray) -> np.ndarray:
        u_policy = self._policy_input(q_meas)
        if self.hold is None:
            self._t += 1
            return u_policy
        self.hold.act(q_meas)  # UKF update with the input applied last step, xi update
        self._update_mode()
        if self.holding:  # Eq. 28 with xi as the handoff left it
            u = np.clip(self.hold.torque(self.hold.y_hat), -self.max_action, self.max_action)
        else:
            u = u_policy
        self.hold.u_prev = u
        self._t += 1
        return u
