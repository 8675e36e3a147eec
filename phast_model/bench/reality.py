"""Concealed-effect "realities" from the env suite: the recordings phast-mismatch-bench, the tests and the examples
analyse (a term of the vocabulary hidden in a simulated system, with noise)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from phast_gym.integrate import simulate
from phast_gym.systems.base import System

from ..identify import delays
from ..identify.simulators import load_simulator
from ..mismatch.vocabulary.terms import AugmentedSystem, Term


def make_reality(env_id: str | type[System], terms: list[Term] | tuple[Term, ...] = (),
                 true_kwargs: Mapping[str, object] | None = None, n_traj: int = 40, T: int = 400,
                 noise_std: float = 0.01, seed: int = 0, u_std: float = 0.0, x0_scale: float = 1.0,
                 coulomb_eps: float = 1e-3) -> dict[str, Any]:
    """Recordings dict (docs/mismatch.md keys) of ``env_id`` with hidden ``terms`` and parameter changes.

    ``env_id``: an env id, ``path/to/rig.py:MyRig`` / ``module:MyRig`` or a System subclass (a user's rig), built with
    ``true_kwargs`` (the reality's parameter values).

    Initial states come from the system's own sampler (scaled by ``x0_scale``);
    ``u_std > 0`` adds a smooth random port input on every coordinate; q gets
    white noise of std ``noise_std``.  Coulomb friction is nearly sharp
    (``coulomb_eps``) so the tool meets a model that is not its own.

    Delays (``input_delay``, ``sensor_delay``) act on a real history: the motion starts ``delays.HISTORY`` samples
    before the recording and the input is defined before it too, so the port delivers the commanded u of earlier
    samples and the sensor reports earlier states (linear interpolation for a fraction of a sample, as the tool's
    model); a delay term at 0 gives the same initial states and inputs without a delay.
    """
    rng = np.random.default_rng(seed)
    base = load_simulator(env_id, true_kwargs).build()
    system = AugmentedSystem(base, list(terms), coulomb_eps=coulomb_eps)
    step = base.dt
    x0 = system.sample_initial(rng, n_traj) * x0_scale  # the base's draws; with armature, the same rates
    # the samples simulated before the recording starts (a delay needs the history)
    pre = delays.HISTORY if any(t.kind.delay for t in terms) else 0
    u = None
    if u_std > 0:
        # smooth input: a random sum of slow sines held over each interval
        t = (np.arange(T - 1 + 2 * pre) - 2 * pre) * step
        freqs = rng.uniform(0.2, 1.5, size=(n_traj, 3, base.n))
        phases = rng.uniform(0, 2 * np.pi, size=(n_traj, 3, base.n))
        u = u_std * np.sum(np.sin(2 * np.pi * freqs[:, :, None, :] * t[None, None, :, None] + phases[:, :, None, :]),
                           axis=1) / np.sqrt(1.5)
    # a nearly sharp Coulomb edge (a kind's ``stiff_edge``) is stiff (force slope c / coulomb_eps): RK4 needs short
    # substeps there, or the "reality" chatters at velocity reversals and holds an integration artefact instead of the
    # stated friction law
    sub = base.substeps * 8 if any(t.kind.stiff_edge for t in terms) else None
    applied = None if u is None else system.delayed_input(u[:, pre:], step, u[:, :pre]) if pre else u
    x = simulate(system, x0, T - 1 + pre, u=applied, substeps=sub)
    q_true = x[..., : base.n]
    if pre:
        q_true = delays.shift(q_true[:, pre:], q_true[:, :pre],
                              delays.delay_samples(system.sensor_delay, step, n_traj, T))
        u = None if u is None else u[:, 2 * pre:]
    q = system.measure(q_true)
    q = q + rng.normal(0.0, noise_std, size=q.shape)
    out: dict[str, Any] = {"q": q, "dt": step, "angle_dims": np.asarray(base.angle_dims, dtype=int)}
    if u is not None:
        out["u"] = u
    return out
