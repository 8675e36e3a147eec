"""Model-predictive path-integral control (MPPI) through a learned PHAST core, batched in torch.

Every decision the planner samples ``samples`` input sequences around its current plan (the last one shifted by one
decision: warm start), rolls all of them out at once through the learned core (the Strang step of
:class:`phast_model.world.core.PHASTCore`, at the planning step ``plan_dt``: the learned substep rescaled, as the
UKF's process model does), scores them with a swing-up cost and averages them with the path-integral weights
``exp(-(c - c_min) / (temperature * (c_max - c_min)))`` (Williams et al. 2017; the temperature relative to the cost
spread, so one value suits every plant; the spread of the rollouts that stayed in the model's region: one that left
would flatten every weight).

The cost of a state (q, p), per planning step: ``angle_weight * sum(1 - cos(q_a - q*_a))`` on the angles,
``position_weight * (q_e - q*_e)^2`` on the Euclidean coordinates, ``velocity_weight * |qdot|^2`` and
``input_weight * |u / max_action|^2``; the state at the horizon's end counts ``terminal_weight`` times.  A rollout
that leaves the model's region (a Euclidean coordinate beyond ``x_max``, a non-finite state) costs ``1e6``.

Real time: one rollout of the whole horizon costs ``H`` core steps whatever the batch (the core's small ops are
dispatch-bound on a CPU: about 2 ms per step for a pendulum, 5 ms for a cart-pole at 256 samples eager, 1 ms each
traced: :mod:`.traced`, the default), more than one plant step of 10 ms allows.  :meth:`MPPI.cycle` is therefore a
generator that yields every few core steps: the deployed controller (:class:`phast_model.rl.planner.PlannerPolicy`)
advances it by one slice per plant step and plans the next decision from the state the model predicts for it, so no
plant step waits for a whole plan.
"""

from __future__ import annotations

import math
from collections.abc import Generator, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ..world.model import PHAST
from .traced import Traced

#: the cost of a rollout that leaves the model's region
LEAVE_COST = 1e6


@dataclass(frozen=True)
class MPPISpec:
    """The planner: sampled sequences, horizon (s), planning step (a multiple of the model's step), input noise (a
    fraction of the bound), temperature (a fraction of the cost spread), the cost's weights (module docstring), the
    Euclidean region ``x_max`` (m), the plan's smoothing (the noise's correlation between neighbouring steps) and
    whether the rollout step runs traced (:mod:`.traced`)."""

    samples: int = 256
    horizon_s: float = 1.5
    plan_every: int = 2
    noise: float = 0.6
    temperature: float = 0.05
    angle_weight: float = 1.0
    position_weight: float = 0.05
    velocity_weight: float = 0.005
    input_weight: float = 0.01
    terminal_weight: float = 5.0
    x_max: float = 10.0
    smoothing: float = 0.5
    traced: bool = True  # the rollout step traced once per shape (:mod:`.traced`): same numbers, 2-5x less time

    def __post_init__(self) -> None:
        for k in ("samples", "plan_every"):
            v = getattr(self, k)
            if int(v) != v or v < 1:
                raise ValueError(f"{k} must be a positive integer, got {v!r}")
        for k in ("horizon_s", "noise", "temperature", "x_max"):
            v = getattr(self, k)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"{k} must be a positive number, got {v!r}")
        for k in ("angle_weight", "position_weight", "velocity_weight", "input_weight", "terminal_weight"):
            v = getattr(self, k)
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"{k} must be a finite number >= 0, got {v!r}")
        if not 0 <= self.smoothing < 1:
            raise ValueError(f"smoothing must be in [0, 1), got {self.smoothing!r}")


def path_weights(cost: torch.Tensor, temperature: float) -> torch.Tensor:
    """The path-integral weights (B,) of the sampled costs (B,): ``softmax(-(c - c_min) / (temperature * spread))``
    with the spread of the rollouts that stayed in the model's region (below :data:`LEAVE_COST`)."""
    lo = cost.min()
    inside = cost[cost < LEAVE_COST]
    spread = ((inside.max() if inside.numel() else lo) - lo).clamp(min=1e-9)
    return torch.softmax(-(cost - lo) / (temperature * spread), 0)


class MPPI:
    """MPPI through ``model``'s core towards ``q_star`` (module docstring), inputs on the ``actuated`` coordinates
    bounded by ``max_action``; ``plan`` (H, m) is the current input sequence, one row per planning step."""

    def __init__(self, model: PHAST, spec: MPPISpec, q_star: np.ndarray, max_action: float,
                 actuated: Sequence[int] | None = None, seed: int = 0) -> None:
        from ..world.core import PHASTCore

        if not isinstance(getattr(model, "core", None), PHASTCore):
            raise ValueError(f"MPPI plans through a Hamiltonian PHAST core; this model's core is "
                             f"{type(getattr(model, 'core', None)).__name__}")
        self.model, self.spec = model, spec
        self.n = int(model.n)
        act = list(range(self.n)) if actuated is None else [int(i) for i in actuated]
        self._dtype = next(model.parameters()).dtype
        self.G = torch.eye(self.n, dtype=self._dtype)[:, act]
        self.m = len(act)
        self.max_action = float(max_action)
        self.dt = float(model.dt) * spec.plan_every  # the planning step (s)
        self.horizon = max(2, int(round(spec.horizon_s / self.dt)))
        angle = np.isin(np.arange(self.n), list(model.angle_dims))
        self._angle = torch.as_tensor(angle, dtype=torch.bool)
        self.q_star = torch.as_tensor(np.asarray(q_star, dtype=np.float64).reshape(self.n), dtype=self._dtype)
        self._gen = torch.Generator().manual_seed(int(seed))
        self.plan = torch.zeros(self.horizon, self.m, dtype=self._dtype)
        self._rollout_step = Traced(model, self._step_and_cost, spec.traced)
        self._step = Traced(model, self.step, spec.traced)
        z = torch.zeros(spec.samples, self.n, dtype=self._dtype)
        self._rollout_step.warm(z, z, torch.zeros(spec.samples, self.m, dtype=self._dtype))
        self._step.warm(z[:1], z[:1], torch.zeros(1, self.m, dtype=self._dtype))

    def reset(self) -> None:
        """Forget the plan (a new episode)."""
        self.plan.zero_()

    def shift(self) -> np.ndarray:
        """The plan's first input (m,), applied now; the plan moves on by one step (its last row repeated)."""
        u = self.plan[0].double().numpy().copy()
        self.plan = torch.cat([self.plan[1:], self.plan[-1:]])
        return u

    @torch.no_grad()
    def step(self, q: torch.Tensor, p: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One planning step of the learned core from (q, p) (B, n) under inputs u (B, m) held over it."""
        core = self.model.core
        return core.strang_step(q, p, u @ self.G.T, h=core.h * self.spec.plan_every, substeps=core.substeps)

    def predict(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The state (2n,) one planning step after ``x`` under the input ``u`` (m,), by the model."""
        t = torch.as_tensor(np.asarray(x, dtype=np.float64), dtype=self._dtype)[None]
        ut = torch.as_tensor(np.asarray(u, dtype=np.float64), dtype=self._dtype)[None]
        q, p = self._step(t[:, : self.n], t[:, self.n:], ut)
        return torch.cat([q, p], -1)[0].double().numpy()

    def _step_and_cost(self, q: torch.Tensor, p: torch.Tensor,
                       u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One planning step of the rollouts and its stage cost (the unit :meth:`cycle` repeats)."""
        q, p = self.step(q, p, u)
        return q, p, self.cost(q, p, u)

    def cost(self, q: torch.Tensor, p: torch.Tensor, u: torch.Tensor | None) -> torch.Tensor:
        """The stage cost (B,) of states (B, n) and inputs (B, m) (module docstring)."""
        s = self.spec
        e = q - self.q_star
        ang = torch.where(self._angle, 1.0 - torch.cos(e), torch.zeros_like(e)).sum(-1)
        pos = torch.where(self._angle, torch.zeros_like(e), e * e).sum(-1)
        v = self.model.velocity(q, p)
        c = s.angle_weight * ang + s.position_weight * pos + s.velocity_weight * (v * v).sum(-1)
        if u is not None:
            c = c + s.input_weight * ((u / self.max_action) ** 2).sum(-1)
        out = torch.where(torch.where(self._angle, torch.zeros_like(e), e.abs()).amax(-1) > s.x_max, LEAVE_COST, c)
        return torch.nan_to_num(out, nan=LEAVE_COST, posinf=LEAVE_COST)

    def sample(self) -> torch.Tensor:
        """(samples, H, m) input sequences: the plan plus smoothed Gaussian noise, clipped; the first is the plan."""
        s = self.spec
        eps = torch.randn(s.samples, self.horizon, self.m, generator=self._gen, dtype=self._dtype)
        for h in range(1, self.horizon):  # AR(1) noise of unit variance: smoother than white, same spread
            eps[:, h] = s.smoothing * eps[:, h - 1] + math.sqrt(1 - s.smoothing**2) * eps[:, h]
        eps[0] = 0.0
        return (self.plan + s.noise * self.max_action * eps).clamp(-self.max_action, self.max_action)

    @torch.no_grad()
    def cycle(self, x0: np.ndarray, slices: int = 1) -> Generator[None, None, float]:
        """One MPPI update of the plan from the state ``x0`` = (q, p) (2n,), yielding ``slices - 1`` times on the
        way (module docstring); returns the lowest sampled cost."""
        s = self.spec
        u = self.sample()
        x = torch.as_tensor(np.asarray(x0, dtype=np.float64), dtype=self._dtype)
        q, p = x[: self.n].expand(s.samples, self.n), x[self.n:].expand(s.samples, self.n)
        total = torch.zeros(s.samples, dtype=self._dtype)
        slices = max(1, int(slices))
        for h in range(self.horizon):
            q, p, c = self._rollout_step(q, p, u[:, h].contiguous())
            total = total + c
            if h + 1 < self.horizon and (h + 1) * slices // self.horizon > h * slices // self.horizon:
                yield  # the steps spread evenly over the slices
        total = total + s.terminal_weight * self.cost(q, p, None)
        self.plan = (path_weights(total, s.temperature)[:, None, None] * u).sum(0)
        return float(total.min())

    def optimize(self, x0: np.ndarray, iterations: int = 1) -> float:
        """``iterations`` whole MPPI updates from ``x0`` at once (tests, offline use); the last lowest cost."""
        best = math.inf
        for _ in range(iterations):
            gen = self.cycle(x0)
            try:
                while True:
                    next(gen)
            except StopIteration as stop:
                best = float(stop.value)
        return best
