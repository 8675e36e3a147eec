"""The configuration of a PHAST model: :class:`PHASTConfig` (everything saved in ``config.json``), the system it
names (:func:`config_system`) and the scales its neural inputs are normalized by (:func:`system_scales`).

Split out of :mod:`phast_model.world.model`, which re-exports all three.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from typing import Any

import numpy as np

from phast_gym import make_env_system, resolve_env_id
from phast_gym.systems import NUMPY, System, split, stack


@dataclass
class PHASTConfig:
    """Everything needed to rebuild a PHAST model (saved as ``config.json``)."""

    env_id: str
    regime: str = "custom"
    kind: str = "phast"  # "phast" or "latent_ode" (predator-prey)
    potential: str = "known"  # known | template | neural | hybrid
    template: str | None = None  # cosine | quadratic | lennard_jones | gravity
    template_dims: list[int] | None = None
    mass: str = "known"  # known | lowrank | template | cholesky
    mass_rank: int = 1
    mass_template: str | None = None  # mass="template": cartpole | double_pendulum | double_pendulum_relative
    mass_hidden: int = 32  # mass="cholesky": hidden width of the factor network
    #: where learned physics starts: "data" (least squares on the training set at the start of training,
    #: :mod:`phast_model.world.data_init`), "physics" (template and mass fitted to the env's true V and M: the
    #: "V given" variant), "rig" (a recordings run: the rig's nominal V and M at the recorded configurations,
    #: :func:`phast_model.train.rig_fit.fit_recordings`), "motion" (a recordings run: every component fitted to the
    #: recorded force balance), "drives" (a recordings run on a model file: its bodies kept, rotor inertias and joint
    #: friction by least squares on that balance; :mod:`phast_model.train.motion_start`) or "none" (unit
    #: coefficients, identity mass)
    init_from: str = "data"
    damping: str = "householder"  # householder | known | none
    damping_rank: int = 2
    damping_hidden: int = 32
    damping_cap: float | None = None
    d0: float = 0.0
    learn_d0: bool = True
    canonicalizer: str = "identity"  # identity | mass
    integrator: str = "auto"
    substeps: int = 1
    learn_dt: bool = True
    midpoint_iters: int = 4
    observer_hidden: int = 32
    observer_layers: int = 2
    use_tcn: bool = True
    observer_fd_order: int = 4
    observer_trainable: bool = True  # False: the observer stays the backward-difference formula it starts as
    #: the velocity estimate the training loss starts each step from (L_data, Eq. 85, and the states of L_pass,
    #: L_energy and the core's L_roll; the validation loss that selects the epoch too): "observer" (the causal
    #: observer, as at test time) or "central" (:class:`~phast_model.components.observer.CentralDifference` of
    #: accuracy ``train_velocity_order``: non-causal, so for training only; rollouts, metrics and the states of the
    #: saved model keep the causal observer).  "central" needs a frozen observer (the loss would not train it)
    train_velocity: str = "observer"
    train_velocity_order: int = 4
    damping_lr_mult: float = 1.0  # learning-rate multiplier of the damping parameters (see param_groups)
    #: a learned damping floor d0 starts at this fraction of the smallest damping the data show (init_from="data";
    #: below 1 so that the softplus terms above the floor are not pushed negative where D is smallest)
    damping_floor_margin: float = 0.8
    potential_hidden: int = 64
    potential_layers: int = 3
    hybrid_eps: float = 0.01
    ode_field: str = "known"  # latent_ode only: known | template | neural
    #: latent_ode only: the latents of the start-up steps (history shorter than the backward difference):
    #: "constant" (a learned constant at t = 0, the latent map after) or "learned" (LatentODEModel.init_prior)
    latent_prior: str = "constant"
    lambda_pass: float = 0.0
    lambda_energy: float = 0.0
    lambda_roll: float = 0.0
    roll_horizon: int = 10
    #: what L_roll unrolls: "core" (paper Eq. 88: the core alone from the observer's state at a random start) or
    #: "observer" (the autoregressive rollout the benchmark scores: the observer re-run on the predicted window)
    roll_mode: str = "core"
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    #: a user rig or env id for recordings (``path.py:Class``, ``module:Class`` or an env id, with ``env_kwargs``);
    #: None: ``env_id`` names the system (phast_model.identify.simulators.load_simulator resolves it)
    sim: str | None = None
    #: the model's sampling step when it differs from the system's own ``dt`` (recordings: their grid)
    dt: float | None = None
    #: RMS scales of the Euclidean coordinates / of the velocities that normalize neural inputs (None: from the
    #: system's initial-state distribution, :func:`system_scales`; recordings: from the data)
    q_scale: list[float] | None = None
    v_scale: list[float] | None = None
    #: the port's bound per input (a recordings run: the largest recorded |u| unless the user gives one); the world
    #: env's action space.  None: the registered env's
    action_bound: list[float] | None = None
    actuated_dofs: list[int] | None = None
    seed: int = 0
    #: velocity-dependent joint friction: "none" or "joint" (:class:`JointFriction`, a backward-Euler
    #: step in each dissipation half-step); its shapes (coulomb | viscous | quadratic | stribeck), the Coulomb
    #: tanh smoothing and Stribeck velocities (one value or one per joint), the coordinates with friction (None:
    #: all) and the initial coefficient of every law
    friction: str = "none"
    friction_laws: list[str] = field(default_factory=lambda: ["coulomb", "viscous"])
    friction_eps: float | list[float] = 0.01
    friction_vs: float | list[float] = 0.1
    friction_joints: list[int] | None = None
    friction_init: float | dict[str, float] = 1e-3  # one value, or law -> value
    #: damped Newton iterations of the backward-Euler friction step (fewer: faster, the passivity guard still holds)
    friction_newton_iters: int = 8

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PHASTConfig:
        names = {f.name for f in fields(cls)}
        # trainer settings a model config carried before the regime recipes returned a training config
        d = {k: v for k, v in d.items() if k not in _FORMER_TRAIN_FIELDS}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"unknown PHASTConfig field(s) {unknown}; valid: {sorted(names)}")
        return cls(**d)


#: fields of older saved configs that are training settings now (phast_model.world.regimes.recipe); dropped on load
_FORMER_TRAIN_FIELDS = ("adam_eps", "warmup_epochs")


def system_scales(system: System, n_samples: int = 512, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """RMS scale of the Euclidean coordinates and of the velocities under the env's initial distribution
    (normalizes the neural inputs; computed from the system, not retyped)."""
    x = system.sample_initial(np.random.default_rng(seed), n_samples)
    n = system.n
    q, p = x[:, :n], x[:, n:]
    eu = [i for i in range(n) if i not in system.angle_dims]
    q_scale = np.sqrt((q[:, eu] ** 2).mean(0)) + 1e-3 if eu else np.zeros(0)
    v = stack(system.velocity(split(q), split(p), NUMPY))
    v_scale = np.sqrt((np.asarray(v) ** 2).mean(0)) + 1e-3
    return q_scale.astype(np.float32), v_scale.astype(np.float32)


def config_system(cfg: PHASTConfig, system: System | None = None) -> tuple[str, System]:
    """(name, system) of a config: the registered env ``env_id``, or the rig ``sim`` (a user's System class or an env
    id, with ``env_kwargs``), at the config's ``dt`` when it sets one (an instance attribute: the class keeps its own).
    ``system``: the registered env's system already built from ``env_id`` and ``env_kwargs`` (the model then owns
    it; ignored with a ``sim``)."""
    if cfg.sim is None:
        name = resolve_env_id(cfg.env_id)
        system = make_env_system(name, **cfg.env_kwargs) if system is None else system
    else:
        from ..identify.simulators import load_simulator

        name, system = cfg.sim, load_simulator(cfg.sim, cfg.env_kwargs).build()
    if cfg.dt is not None:
        if not (cfg.dt > 0 and math.isfinite(cfg.dt)):
            raise ValueError(f"dt must be positive and finite, got {cfg.dt!r}")
        system.dt = float(cfg.dt)  # an instance attribute over the class default
    return name, system
