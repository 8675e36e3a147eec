"""KNOWN / PARTIAL / UNKNOWN default configurations for every registered env (paper Table 1, 13).

* KNOWN: V and M are the env's own physics (``system.potential``, ``system.mass_matrix``), the
  canonicalizer maps ``p = M(q) qdot``; only D is learned (Householder, r = 2, unbounded, d0 learned from a
  least-squares floor of the training data),
  with the identification settings explained in :func:`default_config` (frozen 4th-order
  backward-difference observer, L = 8 (L = 4 with configuration-dependent M), fixed dt, damping-network lr x 100
  (the floor d0 keeps the base lr, see :meth:`phast_model.world.model.PHAST.param_groups`),
  AdamW eps 1e-15 and a 1-epoch lr warm-up: ``KNOWN_TRAIN_DEFAULTS``, trainer settings that :func:`recipe` returns in
  the training config beside the model config).
  Configuration-dependent M(q) (cart-pole, double pendulum) uses the implicit-midpoint core.
* PARTIAL: V = template with learnable coefficients + softplus(rho) * MLP; M = diag + low rank (constant M) or the
  system's mass template ``M0 + cos(phi(q)) M1`` (configuration-dependent M, :class:`TemplateMass`, implicit
  midpoint), with ``p = M(q) qdot``.  Template and mass coefficients, and a learned damping floor d0, start from one
  least squares on the training data (``init_from="data"``, :mod:`phast_model.world.data_init`); ``init_from="physics"``
  is the "V given" variant that fits them to the env's true V and M.  D capped at ``beta_bar = dd`` with d0 fixed
  to the env's base damping on windy systems (Table 13), unbounded with learned d0 otherwise.  KNOWN's
  identification settings with L = 4 on every row (a trainable observer absorbs D).
* UNKNOWN: neural V (MLP, Fourier features on angles); a learned constant M with min(4, n) terms, KNOWN's
  identification settings with L = 4 and ``p = M qdot_hat``, or, where M depends on q, a neural Cholesky factor
  ``M(q) = L L^T`` with ``p = M(q) qdot`` and L_roll over the scored rollout; unbounded D with learned d0.
* Predator-prey (not Hamiltonian): a latent ODE on (prey, predator) whose latent predator density is
  obtained by inverting the prey equation from the observer's qdot; KNOWN = env rhs, PARTIAL =
  Lotka-Volterra template + neural correction (its coefficients start from a least squares on the observed prey,
  ``init_from="data"``), UNKNOWN = neural field + learned latent map; RK4 core.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any, TypedDict

from phast_gym import make_env_system, resolve_env_id
from phast_gym.systems import System

from ..train.config import TrainConfig
from . import data_init
from .envinfo import ENV_INFO
from .model import PHAST, PHASTConfig, build_from_config

REGIMES = ("known", "partial", "unknown")

#: trainer settings of the identification settings (KNOWN; a TrainConfig value given overrides them).  With V, M and the
#: observer fixed the one-step loss is ~1e-6..1e-9 and its gradients ~1e-7..1e-12, below AdamW's default eps = 1e-8,
#: where Adam degenerates to badly conditioned SGD (step lr g / eps); eps = 1e-15 keeps its steps scale-free, and a
#: 1-epoch linear warm-up keeps the first steps at lr x 100 (the damping net) from overshooting while Adam's
#: second-moment estimate is still empty.
KNOWN_TRAIN_DEFAULTS: dict[str, float] = {"adam_eps": 1e-15, "warmup_epochs": 1.0}


class Identification(TypedDict):
    """The :class:`PHASTConfig` fields of the identification settings."""

    observer_trainable: bool
    learn_dt: bool
    damping_lr_mult: float


#: the identification settings (KNOWN, and PARTIAL on separable windy systems; see :func:`default_config`)
IDENTIFICATION: Identification = {"observer_trainable": False, "learn_dt": False, "damping_lr_mult": 100.0}


def _windy(params: dict[str, Any]) -> tuple[float | None, float]:
    """(cap = dd, base damping) of a windy system, or (None, 0) when it has no windy law."""
    dd = params.get("dd") or 0.0
    if dd > 0:
        return float(dd), (float(params.get("d0") or 0.0) + float(params.get("gamma") or 0.0)
                           + float(params.get("b") or 0.0))
    return None, 0.0


def _check_regime(regime: str) -> str:
    regime = regime.lower()
    if regime not in REGIMES:
        raise ValueError(f"regime must be one of {REGIMES}, got {regime!r}")
    return regime


@dataclass(frozen=True)
class Recipe:
    """A regime's recipe for an env: the model config and the training config it is trained with."""

    model: PHASTConfig
    train: TrainConfig


def default_config(env_id: str, regime: str, **env_kwargs: object) -> PHASTConfig:
    """The default :class:`PHASTConfig` of ``regime`` for ``env_id``."""
    env_id = resolve_env_id(env_id)
    regime = _check_regime(regime)
    return _default_config(env_id, regime, make_env_system(env_id, **env_kwargs), env_kwargs)[0]


def train_config(settings: dict[str, float], train: TrainConfig | None = None) -> TrainConfig:
    """``train`` (default ``TrainConfig()``) with a regime's trainer ``settings`` in the fields it leaves None; a
    value given is kept."""
    train = TrainConfig() if train is None else train
    given: dict[str, Any] = {k: v for k, v in settings.items() if getattr(train, k) is None}
    return replace(train, **given)


def recipe(env_id: str, regime: str, train: TrainConfig | None = None, **overrides: Any) -> Recipe:
    """The :class:`Recipe` of ``regime`` for ``env_id``: :func:`default_config` with ``overrides`` (PHASTConfig
    fields), and ``train`` (default ``TrainConfig()``) with the regime's trainer settings where it leaves them None
    (:func:`train_config`)."""
    cfg, _, settings = _config(env_id, regime, overrides)
    return Recipe(cfg, train_config(settings, train))


def _default_config(env_id: str, regime: str, system: System,
                    env_kwargs: Mapping[str, object]) -> tuple[PHASTConfig, dict[str, float]]:
    """(:func:`default_config`, its trainer settings) of a resolved ``env_id`` and checked ``regime`` whose
    ``system`` is already built; the trainer settings are KNOWN_TRAIN_DEFAULTS with the identification settings.

    The measurements behind each choice are in docs/phast_model.md ("Design notes: the regime defaults")."""
    base = PHASTConfig(env_id=env_id, regime=regime, env_kwargs=dict(env_kwargs))
    if not system.hamiltonian_system:
        # learned start-up latents: Eq. 90 scores the first predictions too, where the history is shorter than
        # the backward difference
        return replace(base, kind="latent_ode",
                       ode_field={"known": "known", "partial": "template", "unknown": "neural"}[regime],
                       potential="none", mass="none", damping="none", latent_prior="learned"), {}
    n = system.n
    info = ENV_INFO[env_id]
    tmpl, dims = info.template, None if info.template_dims is None else list(info.template_dims)
    if regime == "known":
        # identification settings: with V and M known the only unknowns are D and the observer, and a trainable
        # observer can absorb D under the one-step loss (only v_hat (1 - dt/2 D) enters q_{t+1} when L = 1), with an
        # O(dt) splitting error relative to D v at L = 1.  So: the observer frozen at its 4th-order backward
        # difference, the env dt, a 100x learning rate on the damping network (not on its floor d0:
        # PHAST.param_groups), KNOWN_TRAIN_DEFAULTS, and L = 8 substeps on the cheap separable (Strang) core, L = 4
        # on the costlier implicit midpoint of a configuration-dependent M(q).
        return replace(base, potential="known", mass="known", damping="householder", damping_cap=None, d0=0.0,
                       learn_d0=True, canonicalizer="mass", substeps=8 if system.separable else 4,
                       **IDENTIFICATION, **info.known), dict(KNOWN_TRAIN_DEFAULTS)
    mass_tmpl = info.partial_mass_template(system)
    if regime == "partial":
        cap, base_d = _windy(system.params)
        mass = ({"mass": "template", "mass_template": mass_tmpl} if mass_tmpl
                else {"mass": "lowrank", "mass_rank": min(4, n)})
        cfg = replace(base, potential="hybrid", template=tmpl, template_dims=dims, **mass,
                      damping_cap=cap, d0=base_d, learn_d0=cap is None, canonicalizer="mass")
        # the identification settings on every row (a trainable observer, a learnable dt and L = 1 let the observer
        # absorb D, as for KNOWN), at L = 4; D capped at dd on windy systems, whose cap also anchors D.  A learned
        # floor d0 starts from the least squares (data_init.initialize_partial).
        return replace(cfg, substeps=4, **IDENTIFICATION), dict(KNOWN_TRAIN_DEFAULTS)
    if not system.separable:
        # a neural M(q) = L L^T; p = M(q) qdot keeps the canonical state consistent with it.  The one-step loss
        # constrains the learned force only at O(dt^2) (q_{t+1} - q_t - dt v ~ dt^2 M^-1 F / 2), so it is joined by
        # L_roll over the scored autoregressive rollout (roll_mode "observer", 10 steps, weight 0.1), and the factor
        # network is wider (128)
        return replace(base, potential="neural", mass="cholesky", mass_hidden=128, damping_cap=None, d0=0.0,
                       learn_d0=True, canonicalizer="mass", lambda_roll=0.1, roll_mode="observer", roll_horizon=10), {}
    # the identification settings, as PARTIAL (frozen observer, so p = M qdot_hat), with the floor d0 starting at
    # MIN_D0 (no physics to fit a floor under)
    return replace(base, potential="neural", mass="lowrank", mass_rank=min(4, n), damping_cap=None,
                   d0=data_init.MIN_D0, learn_d0=True, canonicalizer="mass", substeps=4,
                   **IDENTIFICATION), dict(KNOWN_TRAIN_DEFAULTS)


def _config(env_id: str, regime: str,
            overrides: dict[str, Any]) -> tuple[PHASTConfig, System | None, dict[str, float]]:
    """(the default config of ``regime`` with ``overrides``, the env's system when the config still names it, the
    regime's trainer settings)."""
    names = {f.name for f in fields(PHASTConfig)}
    bad = sorted(set(overrides) - names)
    if bad:
        raise ValueError(f"unknown override(s) {bad}; valid PHASTConfig fields: {sorted(names)}")
    env_id = resolve_env_id(env_id)
    regime = _check_regime(regime)
    env_kwargs = dict(overrides.get("env_kwargs", {}))
    system = make_env_system(env_id, **env_kwargs)
    default, settings = _default_config(env_id, regime, system, env_kwargs)
    cfg = replace(default, **overrides)
    same = cfg.sim is None and cfg.env_id == env_id and cfg.env_kwargs == env_kwargs
    return cfg, system if same else None, settings


def build_model(env_id: str, regime: str, **overrides: Any) -> PHAST:
    """PHAST model of ``regime`` ("known", "partial", "unknown") for ``env_id``; ``overrides`` replace
    :class:`PHASTConfig` fields (e.g. ``damping_cap=1.0``, ``substeps=4``, ``seed=1``, ``env_kwargs={...}``).  Its
    training config: :func:`recipe`.

    The env's system is built once: the default config reads it and the model is built on it (unless the overrides
    name another system: ``env_id``, ``env_kwargs`` or ``sim``)."""
    cfg, system, _ = _config(env_id, regime, overrides)
    return build_from_config(cfg, system=system)
