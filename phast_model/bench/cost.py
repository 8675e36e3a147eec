"""CPU cost of every model of the grid per env: one training step and the evaluation rollouts
(``benchmarks/bench_baselines.py`` tabulates it; ``benchmarks/grid.py --dry-run`` reads its JSON).

For each (env, model), on one torch thread: trainable parameters; milliseconds
per optimizer step on a batch of 64 trajectories x T = 200 (forward + backward
+ AdamW, min over ``reps`` after one warm-up step); seconds for the
evaluation's open-loop rollouts (``n_eval`` = 200 test trajectories, burn-in 10,
H = 100, as :func:`phast_model.train.metrics.evaluate` runs them).

Where a slower reference of the same computation exists it is timed in the
same run and the ratio printed:

* Transformer training step: torch's ``nn.TransformerEncoder`` on the same
  weights (unfused attention, dropout on the attention weights too);
* Transformer and VPT rollouts: :meth:`ForecastModel.rollout`, the interface's
  definition that re-runs the whole prefix at every step;
* PHAST (all regimes but the predator-prey latent ODE) training step:
  :func:`phast_model.world.core.composed_strang_step`, the Strang step that
  evaluates D(q) and dV/dq afresh in every splitting piece instead of reusing
  them at each substep's end point, with the neural potential's gradient by
  autograd (a double backward in training) instead of its written-out chain rule;
* S5 training step: :func:`phast_model.baselines.ssm.scan_diag`, the log-depth
  prefix scan under autograd, instead of the 2x2 scan with an adjoint backward.

Training-step time x (n_train / 64) x epochs estimates a run's training cost.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from phast_gym.datasets import Dataset, make_dataset

from ..world.interfaces import ForecastModel, coordinate_error
from ..world.rollout import batched_rollout
from .runner import build_run_model, full_state_view
from .spec import RunSpec

#: models whose evaluation rollout has a prefix-recomputing reference worth timing
ROLLOUT_REFERENCE = frozenset({"transformer", "vpt"})


def _torch_encoder_reference(model: Any, x: torch.Tensor) -> torch.Tensor:
    """The Transformer baseline's hidden states through torch's ``nn.TransformerEncoder`` (same weights)."""
    from ..baselines.transformer import sinusoidal_encoding

    T = x.shape[1]
    h = model.embed(x) + sinusoidal_encoding(T, model.d_model, x.device, x.dtype)
    mask = torch.triu(torch.ones(T, T, dtype=torch.bool, device=x.device), diagonal=1)
    return model.encoder(h, mask=mask, is_causal=True)


def train_step_ms(model: ForecastModel, q: torch.Tensor, u: torch.Tensor | None, reps: int) -> float:
    """Min over ``reps`` (after one warm-up) of one AdamW step on the next-step loss, in ms."""
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
    model.train()
    times = []
    for _ in range(reps + 1):
        t0 = time.perf_counter()
        opt.zero_grad()
        e = coordinate_error(model(q, u)[:, :-1], q[:, 1:], model.angle_dims)
        (e * e).mean().backward()
        opt.step()
        times.append(time.perf_counter() - t0)
    return 1e3 * min(times[1:])


def rollout_s(model: ForecastModel, q: np.ndarray, u: np.ndarray | None, burn_in: int, H: int,
              fn: Callable[..., torch.Tensor] | None = None) -> float:
    """Seconds of the evaluation's batched open-loop rollouts (``fn`` replaces ``model.rollout``)."""
    if fn is not None:
        model.rollout = fn  # type: ignore[method-assign]
    try:
        t0 = time.perf_counter()
        batched_rollout(model, q, u, burn_in, H)
        return time.perf_counter() - t0
    finally:
        model.__dict__.pop("rollout", None)


def _compose_core_steps(model: Any) -> None:
    """Make ``model``'s core step by :func:`composed_strang_step` and its neural potentials' gradients by autograd
    (the reference without the reuse and the written-out gradient)."""
    from ..components.potentials import NeuralPotential, Potential
    from ..world.core import composed_strang_step

    core = model.core
    core.forward = lambda q, p, f=None, need_p=True: composed_strang_step(core, q, p, f, need_p)
    for mod in model.modules():
        if isinstance(mod, NeuralPotential):
            mod.grad = functools.partial(Potential.grad, mod)  # type: ignore[method-assign]


def _s5_log_depth_step_ms(env_id: str, ds: Dataset, q: torch.Tensor, u: torch.Tensor | None, reps: int) -> float:
    """S5's training step with the log-depth scan under autograd (the reference of the 2x2 scan)."""
    from ..baselines import ssm

    ref = _build(env_id, "s5", ds)
    fast, ssm.scan_complex_diag = ssm.scan_complex_diag, ssm.scan_diag  # type: ignore[assignment]
    try:
        return train_step_ms(ref, q, u, reps)
    finally:
        ssm.scan_complex_diag = fast


def _build(env_id: str, model_name: str, ds: Dataset) -> ForecastModel:
    spec = RunSpec(env_id, model_name, full_state=model_name == "dhnn")
    torch.manual_seed(0)
    return build_run_model(spec, ds)


def time_model(env_id: str, model_name: str, batch: int = 64, T: int = 200, H: int = 100, burn_in: int = 10,
               n_eval: int = 200, reps: int = 3, reference: bool = True) -> dict[str, Any]:
    """Cost row of one (env, model); ``*_ref`` entries where a reference exists and ``reference`` is set."""
    ds = make_dataset(env_id, max(batch, n_eval), T=T, seed=42)
    if model_name == "dhnn":  # the full-state ablation sees (q, p)
        ds = full_state_view(ds)
    model = _build(env_id, model_name, ds)
    q = torch.as_tensor(ds.q[:batch], dtype=torch.float32)
    u = torch.as_tensor(ds.u[:batch], dtype=torch.float32) if ds.u.size else None
    row: dict[str, Any] = {"env": env_id, "model": model_name, "params": model.n_parameters(),
                           "train_step_ms": train_step_ms(model, q, u, reps)}
    if reference and model_name == "transformer":
        ref = _build(env_id, model_name, ds)
        ref.encode = lambda x: _torch_encoder_reference(ref, x)  # type: ignore[assignment]
        row["train_step_ms_ref"] = train_step_ms(ref, q, u, reps)
    if reference and model_name.startswith("phast-") and hasattr(model, "core") and hasattr(model.core, "strang_step"):
        ref = _build(env_id, model_name, ds)
        _compose_core_steps(ref)
        row["train_step_ms_ref"] = train_step_ms(ref, q, u, reps)
    if reference and model_name == "s5":
        row["train_step_ms_ref"] = _s5_log_depth_step_ms(env_id, ds, q, u, reps)
    q_eval, u_eval = ds.q[:n_eval], (ds.u[:n_eval] if ds.u.size else None)
    row["eval_rollout_s"] = rollout_s(model, q_eval, u_eval, burn_in, H)
    if reference and model_name in ROLLOUT_REFERENCE:
        def definition(qb: torch.Tensor, ub: torch.Tensor | None, h: int) -> torch.Tensor:
            return ForecastModel.rollout(model, qb, ub, h)

        row["eval_rollout_s_ref"] = rollout_s(model, q_eval, u_eval, burn_in, H, definition)
    return row


def format_row(r: dict[str, Any]) -> str:
    def ratio(key: str) -> str:
        return f" (ref {r[key + '_ref']:.4g}, x{r[key + '_ref'] / r[key]:.1f})" if key + "_ref" in r else ""

    return (f"{r['env']:28s} {r['model']:14s} params {r['params']:7d}  step {r['train_step_ms']:7.1f} ms"
            f"{ratio('train_step_ms')}  eval rollout {r['eval_rollout_s']:6.2f} s{ratio('eval_rollout_s')}")


def format_total(rows: list[dict[str, Any]]) -> str:
    """One env's training step summed over its models, against the same sum with the reference implementations
    (the grid's cost per step; the target for the 10 models of the grid is 1.2 s on one thread)."""
    env = rows[0]["env"]
    fast = sum(r["train_step_ms"] for r in rows)
    ref = sum(r.get("train_step_ms_ref", r["train_step_ms"]) for r in rows)
    return (f"{env:28s} sum of {len(rows)} models: step {fast:7.1f} ms "
            f"(with the references {ref:.1f} ms, x{ref / fast:.2f})")
