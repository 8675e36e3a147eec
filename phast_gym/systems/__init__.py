"""One module per physical system; ``SYSTEMS`` maps names to classes."""

from .base import (
    NUMPY,
    SCALAR,
    TORCH,
    Param,
    ParameterError,
    System,
    angle_diff,
    break_at_wraps,
    const_like,
    fd_velocity,
    namespace,
    solve_spd,
    split,
    stack,
    wrap,
)
from .cartpole import CartPole
from .double_pendulum import DoublePendulum
from .heat_exchange import HeatExchange
from .oscillator import Oscillator
from .particles import LennardJones3, NBody3, PairParticles
from .pendulum import Pendulum
from .predator_prey import PredatorPrey
from .rlc import RLCCircuit

SYSTEMS: dict[str, type[System]] = {
    cls.name: cls
    for cls in (Pendulum, CartPole, Oscillator, DoublePendulum, RLCCircuit, LennardJones3, HeatExchange, NBody3,
                PredatorPrey)
}


def make_system(name: str, **params: object) -> System:
    """Build a system by name with physical parameter kwargs."""
    try:
        cls = SYSTEMS[name]
    except KeyError:
        raise ParameterError(f"unknown system {name!r}; known: {sorted(SYSTEMS)}") from None
    return cls(**params)


__all__ = [
    "NUMPY", "SCALAR", "TORCH", "Param", "ParameterError", "System", "angle_diff", "break_at_wraps", "const_like",
    "fd_velocity", "namespace", "solve_spd", "split", "stack", "wrap", "CartPole", "DoublePendulum", "HeatExchange",
    "Oscillator", "LennardJones3", "NBody3", "PairParticles", "Pendulum", "PredatorPrey", "RLCCircuit", "SYSTEMS",
    "make_system",
]
