"""The planning agent of ``phast-rl --agent mpc``: MPPI through the learned PHAST core (:mod:`phast_model.control.mppi`)
on the learned-model UKF's state, with the same hand-off to the quiet hold near the target as the SAC agent's.

:class:`PlannerPolicy` is the deployed controller (a :class:`phast_model.rl.types.Controller`, a
:class:`.hold.HybridPolicy` whose agent is the planner).  Every plant step it updates the UKF of the hold (the learned
core as process model) with the measurement and the input it applied.  Every ``decision`` plant steps (the planning
step, ``plan_every`` model steps) it applies the first input of the plan that finished during the last interval and
starts the next MPPI update from the state the model predicts one planning step ahead (that input held); the update
advances by one slice per plant step (:meth:`phast_model.control.mppi.MPPI.cycle`), so no plant step computes a whole
plan: the controller's time per step stays under the plant's dt on one core (measured as ``controller_ms``).  Inside
the hold's region (:class:`.hold.HoldConfig`) the hold acts and the planner rests; it starts again, warm, when the hold
hands back.
"""

from __future__ import annotations

from collections.abc import Generator, Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from ..control.mppi import MPPI, MPPISpec
from ..world.model import PHAST
from .hold import HoldConfig, HoldGains, HybridPolicy, LQRGains, make_hold
from .plant import PlantSpec

#: the agents of ``phast-rl --agent``: ``mpc`` (this module) or ``sac`` (an SB3 agent trained in the world model)
AGENTS = ("mpc", "sac")


class PlannerAgent:
    """The MPPI planner seen as the hybrid policy's agent: its action space (inputs in [-1, 1]) and ``predict``, the
    plan's current first input scaled to [-1, 1] (what the planner would apply now, for the record)."""

    def __init__(self, mppi: MPPI) -> None:
        self.mppi = mppi
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(mppi.m,), dtype=np.float32)

    def predict(self, observation: np.ndarray, state: tuple[np.ndarray, ...] | None = None,
                episode_start: np.ndarray | None = None,
                deterministic: bool = False) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        return (self.mppi.plan[0].double().numpy() / self.mppi.max_action).astype(np.float32), None


class PlannerPolicy(HybridPolicy):
    """MPPI in the learned model, then the hold (module docstring).  ``decision`` plant steps per planning step;
    ``use_hold`` False: the planner alone (the UKF is still the hold's)."""

    def __init__(self, mppi: MPPI, hold: Any, decision: int, max_action: float, q_star: np.ndarray,
                 cfg: HoldConfig, angle_dims: Sequence[int], use_hold: bool = True) -> None:
        super().__init__(PlannerAgent(mppi), 1, decision, max_action, q_star, hold, cfg, angle_dims)
        self.mppi, self.use_hold = mppi, bool(use_hold)
        self._cycle: Generator[None, None, float] | None = None
        self._u = np.zeros(mppi.m)

    def reset(self, q_meas: np.ndarray) -> None:
        super().reset(q_meas)
        self.mppi.reset()
        self._cycle, self._u = None, np.zeros(self.mppi.m)

    def _advance(self) -> None:
        """One slice of the MPPI update in flight (none when it has finished)."""
        if self._cycle is None:
            return
        try:
            next(self._cycle)
        except StopIteration:
            self._cycle = None

    def _finish(self) -> None:
        while self._cycle is not None:
            self._advance()

    def _decide(self) -> None:
        """At a decision: the finished plan's first input held from now, the next update started from the model's
        prediction of the state one planning step on."""
        state = getattr(self.hold.estimator, "state", None) if self.hold is not None else None
        self._finish()
        if state is None:
            return
        self._u = np.clip(self.mppi.shift(), -self.max_action, self.max_action)
        x1 = self.mppi.predict(state, self._u)
        self._cycle = self.mppi.cycle(x1, self.decision_steps)

    def act(self, q_meas: np.ndarray) -> np.ndarray:
        assert self.hold is not None
        self.hold.act(q_meas)  # the UKF update with the input applied last step
        if self.use_hold:
            self._update_mode()
        if self.holding:
            self._cycle = None
            u = np.clip(self.hold.torque(self.hold.y_hat), -self.max_action, self.max_action)
        else:
            if self._t % self.decision_steps == 0:
                self._decide()
            else:
                self._advance()
            u = self._u
        self.hold.u_prev = u
        self._t += 1
        return np.asarray(u, dtype=np.float64).copy()


def planner_policy(model: PHAST, spec: MPPISpec, q_star: np.ndarray, plant: PlantSpec, hold_cfg: HoldConfig,
                   actuated: Sequence[int], seed: int = 0) -> tuple[PlannerPolicy, HoldGains | LQRGains]:
    """The deployed planner on ``model`` for ``plant``: MPPI every ``spec.plan_every`` decisions of the plant's
    ``decision_steps`` steps, the hold of :func:`.hold.make_hold` (its UKF is the planner's state estimate; it takes
    over near the target when ``hold_cfg.enabled``) and the hold's gains."""
    mppi = MPPI(model, spec, q_star, plant.max_action, actuated, seed)
    hold, gains = make_hold(model, q_star, plant.dt, plant.sigma, plant.max_action, hold_cfg, actuated)
    return PlannerPolicy(mppi, hold, plant.decision_steps * spec.plan_every, plant.max_action, q_star, hold_cfg,
                         tuple(int(i) for i in model.angle_dims), hold_cfg.enabled), gains
