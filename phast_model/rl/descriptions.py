"""Rig descriptions the loop fits PHAST from when the plant's own class declares no PARTIAL templates.

PARTIAL (the rig path's default) keeps the description's structure and refits every coefficient: a cosine potential
on the angles and the description's mass template.  ``PHAST/WindyCartPole-v0`` is the phast_gym :class:`CartPole`,
which declares none, so without this the cart-pole could be fitted only UNKNOWN (a neural potential and mass learned
from seconds of data).  :class:`CartPoleDescription` is that same class with its templates declared: the pole's
``1 - cos theta`` potential (coordinate 1) and the cart-pole mass matrix template (``M(theta)`` with the ``cos theta``
coupling); its dissipation is learned as the rig path's joint friction with the viscous law only
(``PHAST_FRICTION_LAWS``): the cart-pole's damping is viscous (cart 0.3, the pole's wind 0.3 + 0.5 |sin theta|), and
a Coulomb term fitted from a few seconds of large excitation came out at 0.2-0.5 N on both coordinates (true 0).  A
UKF whose model sticks at rest then misestimates the pole near the upright and the LQR hold limit-cycles far above the
true-model UKF's torque (measured in docs/control.md).
"""

from __future__ import annotations

from phast_gym.registry import resolve_env_id
from phast_gym.systems.cartpole import CartPole


class CartPoleDescription(CartPole):
    """The cart-pole with its PARTIAL templates declared (module docstring)."""

    PHAST_TEMPLATES = {"potential": "cosine", "dims": [1], "mass": "cartpole"}
    PHAST_FRICTION_LAWS = ("viscous",)


#: plant env id -> the rig description (``module:Class``) the loop fits from by default
DESCRIPTIONS = {"PHAST/WindyCartPole-v0": f"{__name__}:CartPoleDescription"}

#: plant env id -> ``phast-rl`` option defaults that differ from the loop's (the option's dest -> value); an option
#: given
#: on the command line wins.  The cart-pole's (docs/control.md, "The cart-pole"): 10 N does not lift its 1-kg pole at
#: 1 m above the horizontal, so the bound is 30 N; pumping needs 5-s episodes and a light |qdot|^2 weight; SAC needs
#: more decisions than on the pendulum, and the last training (no plant episode) is free of plant time; the agent's
#: task ends in the LQR hold's region (``hold_goal``).
PRESETS: dict[str, dict[str, object]] = {
    "PHAST/WindyCartPole-v0": {"max_action": 30.0, "episode_decisions": 100, "velocity_weight": 0.01,
                               "position_weight": 0.1, "agent_steps": 15_000, "refit_steps": 8_000,
                               "final_steps": 20_000, "keep_best": True, "hold_goal": True},
}


#: agent -> ``phast-rl`` option defaults of that agent, over the plant's (:data:`PRESETS`).  The planner
#: (``--agent mpc``) needs no long episodes to learn from: one 2.5-s excitation episode and 2.5-s episodes of its own
#: (PILCO's length; ``excitation_default``: --excitation-episodes without --recordings); its hold is LQR of the
#: learned linearisation on every plant (``hold``: on the stand-in machine's 5-s models the Energy-Casimir hold kept a
#: +-0.12 rad limit cycle where LQR on the same model held within 0.04 rad; docs/control.md), whose UKF takes the
#: momentum noise per unit of the learned mass (a light pole).
AGENT_PRESETS: dict[str, dict[str, object]] = {
    "mpc": {"episode_s": 2.5, "excitation_default": 1, "hold": "lqr", "lqr_ukf_p_per_inertia": True},
}


def loop_preset(env_id: str, agent: str = "sac") -> dict[str, object]:
    """The ``phast-rl`` option defaults of ``env_id`` (:data:`PRESETS`; empty for a plant without one), then those of
    ``agent`` (:data:`AGENT_PRESETS`)."""
    try:
        key = resolve_env_id(env_id)
    except Exception:  # gymnasium's UnregisteredEnv: left to the plant's own check
        return dict(AGENT_PRESETS.get(agent, {}))
    return {**PRESETS.get(key, {}), **AGENT_PRESETS.get(agent, {})}


def friction_laws(sim: str) -> tuple[str, ...] | None:
    """The joint-friction laws the description ``sim`` declares (``PHAST_FRICTION_LAWS``), None if it declares none."""
    if ":" not in sim or sim.startswith("phast_gym:"):
        return None
    from ..identify.simulators import load_simulator

    laws = getattr(type(load_simulator(sim).build()), "PHAST_FRICTION_LAWS", None)
    return None if laws is None else tuple(laws)


def default_description(env_id: str) -> str:
    """The rig description of ``env_id``: its entry of :data:`DESCRIPTIONS`, else the env id itself."""
    try:
        key = resolve_env_id(env_id)
    except Exception:  # gymnasium's UnregisteredEnv: left to the plant's own check
        return env_id
    return DESCRIPTIONS.get(key, env_id)
