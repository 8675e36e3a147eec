"""A pendulum bench behind a step function: the shape of a driver ``phast-rl --machine`` drives.

    phast-rl --machine examples/machines/pendulum_bench.py:make --env PHAST/Pendulum-v0 \
        --task swingup --budget-s 30 --out runs/bench

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

import numpy as np

from phast_gym.systems.pendulum import Pendulum


class PendulumBench:
    """A simulated bench: the true pendulum is hidden; ``reset`` lets it come to rest hanging (a small angle left),
    ``step`` holds the input for ``dt`` and returns the angle with Gaussian noise ``sigma`` (rad)."""

    def __init__(self, mass: float = 1.15, gamma: float = 0.08, coulomb: float = 0.05, motor_limit: float = 10.0,
                 sigma: float = 0.01, dt: float = 0.01, seed: int = 0) -> None:
        self.system = Pendulum(mass=mass, gamma=gamma)
        self.coulomb, self.motor_limit, self.sigma, self.dt = float(coulomb), float(motor_limit), float(sigma), float(dt)
        self.rng = np.random.default_rng(seed)
        self.substeps = 4
        self.x = np.zeros(2)

    def reset(self) -> np.ndarray:
        self.x = np.array([self.rng.uniform(-0.03, 0.03), 0.0])
        return self._measure()

    def step(self, u: np.ndarray) -> np.ndarray:
        tau = float(np.clip(np.asarray(u, dtype=np.float64).reshape(-1)[0], -self.motor_limit, self.motor_limit))
        h = self.dt / self.substeps
        for _ in range(self.substeps):
            self.x = self._rk4(self.x, tau, h)
        return self._measure()

    def _measure(self) -> np.ndarray:
        q = math.remainder(self.x[0], 2 * math.pi) + self.rng.normal(0.0, self.sigma)
        return np.array([q])

    def _rate(self, x: np.ndarray, tau: float) -> np.ndarray:
        """Hamilton's equations of the hidden pendulum, its pivot friction (viscous in the system, Coulomb here)."""
        (qdot,), (pdot,) = self.system.rhs((float(x[0]),), (float(x[1]),), (tau,))
        return np.array([qdot, pdot - self.coulomb * math.tanh(qdot / 0.05)])

    def _rk4(self, x: np.ndarray, tau: float, h: float) -> np.ndarray:
        k1 = self._rate(x, tau)
        k2 = self._rate(x + 0.5 * h * k1, tau)
        k3 = self._rate(x + 0.5 * h * k2, tau)
        k4 = self._rate(x + h * k3, tau)
        return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)


def make(**kwargs: float) -> PendulumBench:
    """The factory ``phast-rl --machine`` calls (with ``--machine-kwargs``)."""
    return PendulumBench(**kwargs)
