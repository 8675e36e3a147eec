"""KNOWN / PARTIAL / UNKNOWN default configurations for every registered env (paper Table 1, 13).

* KNOWN: V and M are the env's own physics (``system.potential``, ``system.mass_matrix``), the
  canonicalizer maps ``p = M(q) qdot``; only D is learned (Householder, r = 2, unbounded, d0 learned from a
  least-squares floor of the training data),
  with the identification settings explained in :func:`default_config` (frozen 4th-order
  backward-difference observer, L = 8 (L = 4 with configuration-dependent M), fixed dt, damping-network lr x 100
  (the floor d0 keeps the base lr, see :meth:`phast_model.model.PHAST.param_groups`),
  AdamW eps 1e-15 and a 1-epoch lr warm-up: ``KNOWN_TRAIN_DEFAULTS``).
  Configuration-dependent M(q) (cart-pole, double pendulum) uses the implicit-midpoint core.
* PARTIAL: V = template with learnable coefficients + softplus(rho) * MLP; M = diag + low rank (constant M) or the
  system's mass template ``M0 + cos(phi(q)) M1`` (configuration-dependent M, :class:`TemplateMass`, implicit
  midpoint), with ``p = M(q) qdot``.  Template and mass coefficients, and a learned damping floor d0, start from one
  least squares on the training data (``init_from="data"``, :mod:`phast_model.data_init`); ``init_from="physics"``
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

from dataclasses import fields, replace
from typing import Any

from phast_gym import env_ids, make_env_system, resolve_env_id

from . import data_init
from .envinfo import ENV_INFO
from .interfaces import ForecastModel
from .model import PHASTConfig, build_from_config

REGIMES = ("known", "partial", "unknown")

#: trainer defaults of the identification settings (KNOWN; a TrainConfig value overrides them).  With V, M and the
#: observer fixed the one-step loss is ~1e-6..1e-9 and its gradients ~1e-7..1e-12, below AdamW's default eps = 1e-8,
#: where Adam degenerates to badly conditioned SGD (step lr g / eps); eps = 1e-15 keeps its steps scale-free, and a
#: 1-epoch linear warm-up keeps the first steps at lr x 100 (the damping net) from overshooting while Adam's
#: second-moment estimate is still empty.
KNOWN_TRAIN_DEFAULTS: dict[str, float] = {"adam_eps": 1e-15, "warmup_epochs": 1.0}
#: the identification settings (KNOWN, and PARTIAL on separable windy systems; see :func:`default_config`)
IDENTIFICATION: dict[str, Any] = {"observer_trainable": False, "learn_dt": False, "damping_lr_mult": 100.0,
                                  **KNOWN_TRAIN_DEFAULTS}


def _windy(params: dict[str, Any]) -> tuple[float | None, float]:
    """(cap = dd, base damping) of a windy system, or (None, 0) when it has no windy law."""
    dd = params.get("dd") or 0.0
    if dd > 0:
        return float(dd), float(params.get("d0") or 0.0) + float(params.get("gamma") or 0.0) + float(params.get("b") or 0.0)
    return None, 0.0


def default_config(env_id: str, regime: str, **env_kwargs: Any) -> PHASTConfig:
    """The default :class:`PHASTConfig` of ``regime`` for ``env_id``."""
    env_id = resolve_env_id(env_id)
    regime = regime.lower()
    if regime not in REGIMES:
        raise ValueError(f"regime must be one of {REGIMES}, got {regime!r}")
    system = make_env_system(env_id, **env_kwargs)
    base = PHASTConfig(env_id=env_id, regime=regime, env_kwargs=dict(env_kwargs))
    if not system.hamiltonian_system:
        # learned start-up latents: Eq. 90 scores the first predictions too, where the history is shorter than
        # the backward difference (docs/results.md: predator-prey UNKNOWN 0.029 -> 0.011, first-step floor 0.0106)
        return replace(base, kind="latent_ode", ode_field={"known": "known", "partial": "template", "unknown": "neural"}[regime],
                       potential="none", mass="none", damping="none", latent_prior="learned")
    n = system.n
    info = ENV_INFO[env_id]
    tmpl, dims = info.template, None if info.template_dims is None else list(info.template_dims)
    if regime == "known":
        # identification settings (measured, docs/phast_model.md): with V and M known the only unknowns are D and
        # the observer; a trainable observer can absorb D under the one-step loss (gauge: only v_hat (1 - dt/2 D)
        # enters q_{t+1} when L = 1), and the L = 1 splitting error is O(dt) relative to D v.  KNOWN therefore keeps
        # the observer at its 4th-order backward-difference init, uses L >= 4 substeps, the env dt, a 100x
        # learning rate on the damping network (the only physics left to learn; not on its floor d0, which at x 100
        # overshot min_q D and killed the softplus terms below it: PHAST.param_groups) and KNOWN_TRAIN_DEFAULTS.
        # L = 8 on the cheap explicit (separable, Strang) core: halving the splitting error moved the windy pendulum's
        # best-achievable R^2 (Fourier-basis least squares under the same loss) from 0.994 to 0.996 and seed 4 from
        # 0.985 to 0.995; configuration-dependent M(q) (implicit midpoint, costlier per substep) keeps L = 4.
        return replace(base, potential="known", mass="known", damping="householder", damping_cap=None, d0=0.0,
                       learn_d0=True, canonicalizer="mass", substeps=8 if system.separable else 4, **IDENTIFICATION)
    mass_tmpl = info.partial_mass_template(system)
    if regime == "partial":
        cap, base_d = _windy(system.params)
        mass = {"mass": "template", "mass_template": mass_tmpl} if mass_tmpl else {"mass": "lowrank", "mass_rank": min(4, n)}
        cfg = replace(base, potential="hybrid", template=tmpl, template_dims=dims, **mass,
                      damping_cap=cap, d0=base_d, learn_d0=cap is None, canonicalizer="mass")
        # identification settings on every row: with a trainable observer, a learnable dt and L = 1 the observer
        # absorbs D under the one-step loss (the gauge of the KNOWN comment above), and the core alone is no model
        # of the system.  Seed 0 at the paper's protocol, PARTIAL before -> after (benchmarks/regime_diagnostics.py,
        # docs/results.md "Why each regime's number is what it is"): learned dissipation rate on the pendulum
        # 0.30 -> 0.001 (true 0), damped pendulum 0.30 -> 0.50 (true 0.5); takeover rollout 1.52 -> 0.017 and
        # 0.22 -> 3.2e-4; the scored rollout 0.020 -> 0.012 and 7.8e-4 -> 8.4e-4; double pendulum: rate 0.28 ->
        # 0.0014 (true 0), scored 0.0059 -> 2.5e-4; windy cart-pole (capped D): damping R^2 0.025 -> 0.899, rollout
        # mixed MSE 0.0059 -> 5.7e-4.  On the windy pendulum the cap
        # anchors D as well (damping R^2 0.88 against -1.61 before).  L = 4 (0.88) beat L = 8 (0.84) there at half
        # the cost of the learned potential's autograd gradients.  A learned floor d0 starts from the least
        # squares (data_init.initialize_partial).
        return replace(cfg, substeps=4, **IDENTIFICATION)
    if not system.separable:
        # a neural M(q) = L L^T; p = M(q) qdot keeps the canonical state consistent with it.  The one-step loss
        # constrains the learned force only at O(dt^2) (q_{t+1} - q_t - dt v ~ dt^2 M^-1 F / 2), so it is joined by
        # L_roll over the scored autoregressive rollout (roll_mode "observer", 10 steps, weight 0.1), and the factor
        # network is wider (128): windy cart-pole rollout mixed MSE(H=100), seed 0 (seeds 1, 2), measured in
        # docs/phast_model.md: 0.138 (0.198, -) before, 0.078 (0.099, 0.123) with L_roll, 0.096 (0.120, -) with the
        # wider factor, 0.070 with both; L_roll over the core alone (Eq. 88) gave 1.02
        return replace(base, potential="neural", mass="cholesky", mass_hidden=128, damping_cap=None, d0=0.0,
                       learn_d0=True, canonicalizer="mass", lambda_roll=0.1, roll_mode="observer", roll_horizon=10)
    # the identification settings, as PARTIAL (frozen observer, so p = M qdot_hat), with the floor d0 starting at
    # MIN_D0 (no physics to fit a floor under): seed 0, pendulum, before -> after: learned dissipation rate 0.30 ->
    # 0.001 (true 0), takeover rollout 2.11 -> 0.018, scored 0.041 -> 0.016; damped pendulum 0.30 -> 0.50 (true
    # 0.5), 2.03 -> 0.0017, 0.0044 -> 0.0022
    return replace(base, potential="neural", mass="lowrank", mass_rank=min(4, n), damping_cap=None,
                   d0=data_init.MIN_D0, learn_d0=True, canonicalizer="mass", substeps=4, **IDENTIFICATION)


def build_model(env_id: str, regime: str, **overrides: Any) -> ForecastModel:
    """PHAST model of ``regime`` ("known", "partial", "unknown") for ``env_id``; ``overrides`` replace
    :class:`PHASTConfig` fields (e.g. ``damping_cap=1.0``, ``substeps=4``, ``seed=1``, ``env_kwargs={...}``)."""
    names = {f.name for f in fields(PHASTConfig)}
    bad = sorted(set(overrides) - names)
    if bad:
        raise ValueError(f"unknown override(s) {bad}; valid PHASTConfig fields: {sorted(names)}")
    cfg = default_config(env_id, regime, **overrides.get("env_kwargs", {}))
    cfg = replace(cfg, **overrides)
    return build_from_config(cfg)


def all_defaults() -> dict[str, dict[str, PHASTConfig]]:
    """Every env id x regime default config (documentation and tests)."""
    return {e: {r: default_config(e, r) for r in REGIMES} for e in env_ids()}
