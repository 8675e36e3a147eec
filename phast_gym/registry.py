"""The one registration table of every ``PHAST/*`` id (Gymnasium style)."""

from __future__ import annotations

import gymnasium as gym
from gymnasium.envs.registration import get_env_id, parse_env_id

from .systems import System, make_system

#: id -> (system name, registered kwargs, one-line description)
ENV_TABLE: dict[str, tuple[str, dict[str, float], str]] = {
    "PHAST/Pendulum-v0": ("pendulum", {}, "frictionless pendulum"),
    "PHAST/DampedPendulum-v0": ("pendulum", {"gamma": 0.5}, "pendulum with viscous damping gamma = 0.5"),
    "PHAST/WindyPendulum-v0": (
        "pendulum", {"d0": 0.3, "dd": 0.5, "init_p_std": 4.0}, "pendulum with wind damping 0.3 + 0.5|sin theta|"),
    "PHAST/WindyCartPole-v0": ("cartpole", {}, "cart-pole, cart friction 0.3, wind damping on the pole"),
    "PHAST/Oscillator-v0": ("oscillator", {}, "2-D harmonic oscillator, omega = 1"),
    "PHAST/DampedOscillator-v0": ("oscillator", {"gamma": 0.1}, "2-D oscillator with damping 0.1"),
    "PHAST/DoublePendulum-v0": ("double_pendulum", {}, "frictionless double pendulum (chaotic)"),
    "PHAST/DampedDoublePendulum-v0": ("double_pendulum", {"b": 0.2}, "double pendulum, damping 0.2 on both rates"),
    "PHAST/WindyDoublePendulum-v0": (
        "double_pendulum", {"d0": 0.3, "dd": 0.5}, "double pendulum, wind damping 0.3 + 0.5|sin theta_i|"),
    "PHAST/RLCCircuit-v0": ("rlc", {}, "series RLC circuit, R = 0.5, L = C = 1, source voltage port"),
    "PHAST/LennardJones3-v0": ("lennard_jones3", {}, "3 Lennard-Jones particles in 2-D with friction 0.1"),
    "PHAST/HeatExchange-v0": ("heat_exchange", {}, "two coupled thermal masses with heat loss"),
    "PHAST/NBody3-v0": ("nbody3", {}, "3 bodies, softened gravity, friction 0.05"),
    "PHAST/PredatorPrey-v0": ("predator_prey", {}, "logistic Lotka-Volterra, prey observed"),
}

#: kwargs of the env that are not physical parameters of the system
ENV_KWARGS = ("actuated_dofs", "max_action", "obs_noise_std", "observe", "dtype", "target", "render_mode", "substeps")

MAX_EPISODE_STEPS = 200


def env_ids() -> list[str]:
    """All registered ids, in table order."""
    return list(ENV_TABLE)


def resolve_env_id(env_id: str) -> str:
    """Accept ``PHAST/Name-v0``, ``Name-v0`` or ``phast_gym:PHAST/Name-v0`` (Gymnasium's id grammar, the
    namespace defaulting to ``PHAST``)."""
    key = env_id.split(":", 1)[1] if env_id.startswith("phast_gym:") else env_id
    try:
        namespace, name, version = parse_env_id(key)
    except gym.error.Error:
        namespace, name, version = None, key, None
    full = get_env_id(namespace or "PHAST", name, version)
    if full not in ENV_TABLE:
        raise gym.error.UnregisteredEnv(f"unknown env id {env_id!r}; registered ids: {env_ids()}")
    return full


def make_env_system(env_id: str, **kwargs: object) -> System:
    """The physics of a registered env (registered kwargs overridden by ``kwargs``).

    Env-only kwargs (noise, actuation, ...) are ignored, so callers can pass
    the same kwargs they give ``gym.make``.
    """
    name, defaults, _ = ENV_TABLE[resolve_env_id(env_id)]
    phys = {k: v for k, v in {**defaults, **kwargs}.items() if k not in ENV_KWARGS}
    return make_system(name, **phys)


def register_all() -> None:
    """Register every id of :data:`ENV_TABLE` (idempotent)."""
    for env_id, (system, defaults, _) in ENV_TABLE.items():
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            entry_point="phast_gym.env:PortHamiltonianEnv",
            kwargs={"system": system, **defaults},
            max_episode_steps=MAX_EPISODE_STEPS,
        )
