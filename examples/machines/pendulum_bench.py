"""A pendulum bench behind a step function: the shape of a driver ``phast-rl --machine`` drives.

    phast-rl --machine examples/machines/pendulum_bench.py:make --env PHAST/Pendulum-v0 \
        --task swingup --budget-s 10 --out runs/bench

The loop sees only what a driver gives: ``dt``, ``reset() -> q`` and ``step(u) -> q`` (encoder angles, inputs in
N m).  Nothing sets the state and nothing reads a velocity.  This stand-in hides a simulated pendulum whose physics
differ from the description ``--env`` names: a heavier bob, viscous and Coulomb friction at the pivot, a motor that
saturates at its own limit and encoder noise.  A driver for a real rig has the same three members; for example, over
a serial link::

    class SerialPendulum:
        dt = 0.01

        def __init__(self, port: str = "/dev/ttyUSB0") -> None:
            self.link = open_link(port)            # your rig's I/O

        def reset(self) -> np.ndarray:
            self.link.torque(0.0)
            wait_until_still(self.link)           # the rig comes to rest by itself
            return np.array([self.link.angle()])

        def step(self, u: np.ndarray) -> np.ndarray:
            self.link.torque(float(u[0]))
            self.link.wait_for_tick()             # the driver keeps the clock: return at the next tick
            return np.array([self.link.angle()])

        def close(self) -> None:                  # called when the loop ends
            self.link.torque(0.0)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from phast_gym.env import PortHamiltonianEnv
from phast_gym.systems.base import NUMPY
from phast_gym.systems.pendulum import Pendulum


class FrictionPendulum(Pendulum):
    """The bench's hidden physics: the phast_gym pendulum with Coulomb friction at the pivot (smoothed as
    tanh(qdot / 0.05)) besides its viscous ``gamma``."""

    def __init__(self, coulomb: float = 0.05, **params: Any) -> None:
        super().__init__(**params)
        self.coulomb = float(coulomb)

    def rhs(self, q: Any, p: Any, u: Any, xp: Any = NUMPY) -> tuple[tuple, tuple]:
        (v,), (dp,) = super().rhs(q, p, u, xp)
        return (v,), (dp - self.coulomb * xp.tanh(v / 0.05),)


class PendulumBench:
    """A simulated bench: the true pendulum is hidden in a phast_gym env; ``reset`` lets it come to rest hanging
    (a small angle left), ``step`` holds the input for ``dt`` and returns the angle with Gaussian noise ``sigma``."""

    def __init__(self, mass: float = 1.15, gamma: float = 0.08, coulomb: float = 0.05, motor_limit: float = 10.0,
                 sigma: float = 0.01, dt: float = 0.01, seed: int = 0) -> None:
        system = FrictionPendulum(coulomb, mass=mass, gamma=gamma)
        system.dt = float(dt)
        self.env = PortHamiltonianEnv(system, max_action=motor_limit, obs_noise_std=sigma, dtype=np.float64,
                                      substeps=max(1, math.ceil(4 * dt / Pendulum.dt)))
        self.dt = float(dt)
        self.rng = np.random.default_rng(seed)
        self._seed = int(seed)

    def reset(self) -> np.ndarray:
        state = np.array([self.rng.uniform(-0.03, 0.03), 0.0])
        q, _ = self.env.reset(seed=self._seed, options={"state": state})
        self._seed += 1
        return q

    def step(self, u: np.ndarray) -> np.ndarray:
        q, *_ = self.env.step(np.asarray(u, dtype=np.float64).reshape(1))
        return q


def make(**kwargs: Any) -> PendulumBench:
    """The factory ``phast-rl --machine`` calls (with ``--machine-kwargs``)."""
    return PendulumBench(**kwargs)
