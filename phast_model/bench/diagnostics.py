"""Why a PHAST regime's benchmark number is what it is: an error decomposition of trained grid runs
(``benchmarks/regime_diagnostics.py`` runs it over a grid's output and writes the tables docs/results.md quotes).

For every finished PHAST run of a ``phast-bench`` grid (its weights are ``work/.../bench_model.pt``) it re-scores
the run's row metric on the test split with one part of the forecast replaced by the truth at a time:

* ``scored``: the benchmark's own number (observer in the loop: the autoregressive rollout, or next-step);
* ``takeover``: the observer runs once at the end of the burn-in, then the core alone (rollout rows);
* ``oracle_state``: the core from the true state (true q, and p with the model's dH/dp = the true velocity), so
  what is left is the learned physics and the time step;
* ``oracle_state_fine``: the same with 4x the model's Strang substeps (what is left is the learned physics);
* ``oracle_state_true_D``: ``oracle_state_fine`` with the env's damping instead of the learned one (models whose
  mass is the env's, i.e. KNOWN; the learned D is only comparable in the env's units);

plus the observer's velocity error at the last burn-in sample, the learned and true dissipation rate
``sum v^T D v / sum v^T M v`` over the test states (1/s; it does not depend on the common scale of the learned V, M
and D, which the data cannot fix), and the share of
the scored error that comes from the 5 worst test trajectories (a large share means a few trajectories decide the
row, e.g. near a separatrix).  On the next-step rows also: ``startup_share``, the share of the scored error made at
the start-up steps t < ``loss_skip`` (history shorter than the observer's backward difference; t = 0 has no velocity
at all), and ``floor_ratio``, the scored number over the first-step information floor of the same test split
(``test_floor_mse`` of :func:`phast_model.bench.floor.first_step_floor`: the best possible t = 0 prediction, scored
on these test trajectories).  Evaluation only; about a second
per run on one core.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from tqdm import tqdm

from phast_gym.datasets import Dataset
from phast_gym.systems import System, split

from ..train.metrics import benchmark_metric, error_keys, squared_error
from ..world.model import PHAST, LatentODEModel
from .figures import load_run_model
from .floor import first_step_floor
from .paper import PAPER
from .runner import BENCH_MODEL_FILE, load_result, load_splits, work_dir
from .spec import PHAST_MODELS, RunSpec, run_key

FINER = 4  # oracle_state_fine: this many times the model's substeps
WORST = 5
FLOOR_DRAWS = 1024  # momenta per test q_0 in the first-step floor


@dataclasses.dataclass
class Diagnosis:
    """One run's error decomposition (None where a part does not apply to the model or row)."""

    env: str
    model: str
    seed: int
    key: str
    metric: str
    recorded: float
    scored: float
    takeover: float | None
    oracle_state: float | None
    oracle_state_fine: float | None
    oracle_state_true_D: float | None
    velocity_rel_err: float | None
    learned_rate: float | None
    true_rate: float
    worst5_share: float
    startup_share: float | None = None
    floor_ratio: float | None = None


def load_trained(out: Path, spec: RunSpec, splits: Mapping[str, Dataset]) -> PHAST:
    """The run's trained model from ``work/.../bench_model.pt`` (:func:`phast_model.bench.figures.load_run_model`)."""
    path = work_dir(out, spec) / BENCH_MODEL_FILE
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing: the run's weights are kept only where it was trained "
                                "(rerun it there, or into a fresh --out)")
    return cast(PHAST, load_run_model(out, spec, splits["train"]))  # a PHAST run's model


def _true_velocity(system: System, q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """qdot = M(q)^-1 p of the env, (..., n)."""
    return np.stack(system.velocity(split(q), split(p)), -1)


def true_state(model: PHAST, test: Dataset, t: int | slice) -> tuple[torch.Tensor, torch.Tensor]:
    """(q, p) of the model from the env's true state at sample(s) ``t``: p = M_model(q) qdot, so that the model's
    dH/dp is the true velocity (whatever its canonicalizer)."""
    dtype = next(model.parameters()).dtype
    q, p = np.asarray(test.q_true[:, t]), np.asarray(test.p[:, t])
    v = _true_velocity(model.system, q, p)
    qt, vt = torch.as_tensor(q, dtype=dtype), torch.as_tensor(v, dtype=dtype)
    return qt, model.mass.momentum(qt, vt)


def _error_kind(metric: str) -> str:
    """The error of a row metric without its mode and horizon: rollout_theta_wrap_mse_h100 -> theta_wrap_mse."""
    return re.sub(r"_h\d+$", "", metric.removeprefix("rollout_"))


def diagnose(model: PHAST, spec: RunSpec, test: Dataset, recorded: float, H: int = 100,
             floor: float | None = None) -> Diagnosis:
    """Scored, takeover and oracle-start errors of one trained PHAST run on its row metric (``floor``: the row's
    first-step floor, next-step rows)."""
    metric, K, ang = benchmark_metric(spec.env_id), spec.burn_in, tuple(model.angle_dims)
    dtype = next(model.parameters()).dtype
    q = torch.as_tensor(test.q, dtype=dtype)
    u = None if test.u is None else torch.as_tensor(test.u, dtype=dtype)
    rollout_row = metric.startswith("rollout_")
    target = test.q[:, K:K + H] if rollout_row else test.q[:, 1:]

    def score(pred: np.ndarray) -> float:
        return error_keys("", squared_error(pred, target, ang), ang)[_error_kind(metric)]

    res: dict[str, Any] = dict(takeover=None, oracle_state=None, oracle_state_fine=None, oracle_state_true_D=None,
                               velocity_rel_err=None, learned_rate=None, startup_share=None, floor_ratio=None)
    with torch.no_grad():
        scored_pred = (model.rollout(q[:, :K], u, H) if rollout_row else model(q, u))
        scored_pred = scored_pred.numpy()[:, :target.shape[1]]
        se = squared_error(scored_pred, target, ang)
        se_traj = se.mean(axis=tuple(range(1, target.ndim)))
        worst = np.sort(se_traj)[::-1][:WORST].sum() / max(se_traj.sum(), 1e-300)
        if not rollout_row:
            se_t = se.mean(axis=(0, 2))
            res["startup_share"] = float(se_t[:model.loss_skip].sum() / max(se_t.sum(), 1e-300))
        v_all = _true_velocity(model.system, test.q_true, test.p)
        true_rate = float((v_all * np.asarray(test.damping) * v_all).sum() / (v_all * np.asarray(test.p)).sum())
        if not isinstance(model, LatentODEModel):
            res.update(_oracle_parts(model, test, q, u, K, H, rollout_row, score))
    scored = score(scored_pred)
    if floor is not None and not rollout_row:
        res["floor_ratio"] = scored / floor
    return Diagnosis(env=spec.env_id, model=spec.model, seed=spec.seed, key=run_key(spec), metric=metric,
                     recorded=recorded, scored=scored, worst5_share=float(worst), true_rate=true_rate, **res)


def _oracle_parts(model: PHAST, test: Dataset, q: torch.Tensor, u: torch.Tensor | None, K: int, H: int,
                  rollout_row: bool, score: Callable[[np.ndarray], float]) -> dict[str, float]:
    from ..components.damping import KnownDamping
    from ..world.interfaces import wrap_angles

    out: dict[str, float] = {}
    qa, pa = true_state(model, test, slice(None))
    va = model.velocity(qa, pa)  # the true velocity
    v_obs = model.observer(q[:, :K][:, -model.observer.window:])[:, -1]
    v_true = va[:, K - 1]
    out["velocity_rel_err"] = float(((v_obs - v_true) ** 2).mean().sqrt() / (v_true ** 2).mean().sqrt())
    dva = torch.zeros_like(va) if model.core.damping is None else model.core.damping.force(qa, va)
    out["learned_rate"] = float((va * dva).sum() / (va * pa).sum())

    def oracle(substeps: int) -> float:
        step: dict[str, float | torch.Tensor] = {"h": model.core.h * model.core.substeps / substeps,
                                                 "substeps": substeps}
        if rollout_row:
            return score(model.integrate(qa[:, K - 1], pa[:, K - 1], u, K - 1, H, **step)[0].numpy())
        f = None if u is None else model.port_force(u)
        q1, _ = model.core(qa[:, :-1], pa[:, :-1], f, **step)
        return score(wrap_angles(q1, model.angle_dims).numpy())

    if rollout_row:
        out["takeover"] = score(cast(torch.Tensor, model.rollout_takeover(q[:, :K], u, H)).numpy())
    out["oracle_state"] = oracle(model.core.substeps)
    out["oracle_state_fine"] = oracle(FINER * model.core.substeps)
    if model.config.mass == "known" and model.core.damping is not None:
        learned, model.core.damping = model.core.damping, KnownDamping(model.system)
        try:
            out["oracle_state_true_D"] = oracle(FINER * model.core.substeps)
        finally:
            model.core.damping = learned
    return out


def diagnose_grid(out: Path, envs: list[str], models: list[str], seeds: list[int],
                  model_kw: Mapping[str, object] | None = None) -> list[Diagnosis]:
    """:func:`diagnose` for every finished run of the grid whose weights are on disk (others are skipped)."""
    todo = [RunSpec(env_id=e, model=m, seed=s, model_kw=dict(model_kw or {}))
            for e in envs for m in models for s in seeds]
    found = [(s, r) for s in todo if (r := load_result(out, s)) is not None
             and (work_dir(out, s) / BENCH_MODEL_FILE).exists()]
    diags: list[Diagnosis] = []
    splits_cache: dict[str, dict[str, Dataset]] = {}
    floors: dict[tuple[str, int, int, int, int, int], float] = {}
    for spec, rec in tqdm(found, desc="diagnose", unit="run"):
        if spec.env_id not in splits_cache:
            splits_cache = {spec.env_id: load_splits(spec)}
        splits = splits_cache[spec.env_id]
        model = load_trained(out, spec, splits)
        diags.append(diagnose(model, spec, splits["test"], float(rec["metrics"][benchmark_metric(spec.env_id)]),
                              floor=_floor(spec, floors)))
    return diags


def _floor(spec: RunSpec, cache: dict[tuple[str, int, int, int, int, int], float]) -> float | None:
    """The first-step floor of ``spec``'s test split (next-step rows; None on rollout rows), computed once."""
    if benchmark_metric(spec.env_id).startswith("rollout_"):
        return None
    key = (spec.env_id, spec.n_train, spec.n_val, spec.n_test, spec.T, spec.data_seed)
    if key not in cache:
        cache[key] = float(first_step_floor(spec.env_id, spec.n_train, spec.n_val, spec.n_test, spec.T, spec.data_seed,
                                            draws=FLOOR_DRAWS)["test_floor_mse"])
    return cache[key]


def merge(old: list[dict[str, Any]], new: list[Diagnosis], redone: set[tuple[str, str]]) -> list[Diagnosis]:
    """``new`` plus the entries of ``old`` (a --json file) outside the (env, model) blocks just diagnosed whose run key
    is still the current one (a bumped model revision retires them)."""
    kept = []
    for e in old:
        d = Diagnosis(**e)
        spec = RunSpec(env_id=d.env, model=d.model, seed=d.seed)
        if (d.env, d.model) not in redone and run_key(spec) == d.key:
            kept.append(d)
    order = {e: i for i, e in enumerate(PAPER)}
    models = {m: i for i, m in enumerate(PHAST_MODELS)}
    return sorted(kept + new, key=lambda d: (order.get(d.env, len(order)), models.get(d.model, 9), d.seed))


def _fmt(x: float | None) -> str:
    return "—" if x is None else f"{x:.3g}"


def diagnoses_markdown(diags: list[Diagnosis]) -> str:
    """Mean over seeds per (env, model): the table docs/results.md quotes."""
    cols = ["recorded", "scored", "takeover", "oracle_state", "oracle_state_fine", "oracle_state_true_D",
            "velocity_rel_err", "learned_rate", "true_rate", "worst5_share", "startup_share", "floor_ratio"]
    lines = ["| env | model | seeds | " + " | ".join(cols) + " |", "|" + "---|" * (len(cols) + 3)]
    groups: dict[tuple[str, str], list[Diagnosis]] = {}
    for d in diags:
        groups.setdefault((d.env, d.model), []).append(d)
    for (env, model), ds in groups.items():
        vals = []
        for c in cols:
            xs = [getattr(d, c) for d in ds if getattr(d, c) is not None]
            vals.append(_fmt(float(np.mean(xs)) if xs else None))
        lines.append(f"| {env.split('/')[-1]} | {model} | {len(ds)} | " + " | ".join(vals) + " |")
    return "\n".join(lines) + "\n"
