"""Compiled batched simulator: the same RK4 and the same physics, fused by ``torch.compile``.

:func:`phast_gym.integrate.simulate` runs the batched integrator one NumPy operation at a time; on
the dataset's batch sizes (about 10^3 trajectories) each operation costs more in dispatch than in
arithmetic, and NumPy's float64 sin/cos are scalar.  :func:`simulate_compiled` traces one sampling
interval (all RK4 substeps, the kink splitting of the windy damping laws, the post-step
projection) through the system's own ``rhs`` / ``switching`` / ``post_step`` on torch tensors
(``xp = TORCH``, so there is still one source of physics) and lets TorchInductor fuse it into a
single vectorized CPU kernel.  It agrees with :func:`~phast_gym.integrate.simulate` to ~1e-11
and, once compiled, is faster on all but the cheapest systems, whose NumPy path is already cheap
(measured speed-ups per system: docs/envs.md, "Compiled backend").

The catch is the compile: seconds to about a minute per system and batch shape the first time
(TorchInductor keeps an on-disk cache, so later processes pay only the tracing).  It pays off for
large or many datasets, not for one 1400 x 200 dataset (which NumPy generates in well under a
second), so it is opt-in: ``make_dataset(..., backend="compiled")``.  Needs a C++ compiler (TorchInductor's CPU
backend); ``benchmarks/envs.py --compiled`` measures it against the single env.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeAlias

import numpy as np

from .integrate import Crossing, check_batch, rk4, split_at_crossing, step
from .systems.base import NUMPY, SCALAR, TORCH, System

if TYPE_CHECKING:
    import torch

    #: one compiled sampling interval: (q, p, u) -> (q, p, x, overflow), q and p as (n, B) tensors, x the (B, 2n) rows
    IntervalFn: TypeAlias = Callable[[torch.Tensor, torch.Tensor, torch.Tensor | None],
                                     tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]]

#: compiled one-interval functions, keyed by the system's identity and the integration settings
_COMPILED: dict[tuple, IntervalFn] = {}
#: distinct (system, substeps, port, batch shape) graphs one process may hold before dynamo gives up
RECOMPILE_LIMIT = 256


def _crossing_capacity(batch: int) -> int:
    """Samples per substep the gathered kink refinement handles: 8 + 2% of the batch.  About 1.3% of
    the windy pendulum's dataset samples cross its kink in a substep (mean 17.5 of 1400, so 37 is 4.6
    standard deviations away); fast-whirling batches cross more often and overflow to NumPy."""
    return min(batch, 8 + batch // 48)


def _gathered_substep(system: System, q: list, p: list, u: list | None, h: float, s0: Any, capacity: int) -> tuple:
    """One RK4 substep for all samples, then the kink split (:func:`~phast_gym.integrate.split_at_crossing`)
    for at most ``capacity`` crossing samples, gathered into a fixed-size batch so the graph has static
    shapes.  Returns (q, p, s, overflow): ``overflow`` is True when more samples crossed than fit (the caller
    then redoes the interval on the NumPy path)."""
    import torch

    k1 = system.rhs(q, p, u, TORCH)
    qn, pn = rk4(system, q, p, u, h, TORCH, k1)
    s1 = system.switching(qn, pn, TORCH)
    assert s1 is not None  # only systems with a kink come here
    cross = s0 * s1 < 0
    overflow = cross.sum() > capacity
    # stream compaction by a prefix sum (static shapes; fuses, unlike nonzero): slot j <- j-th crossing sample.
    # Unused slots hold sample 0; if it does not cross, its split is at tau = h, i.e. its plain step again.
    slot = torch.where(cross, torch.cumsum(cross, 0) - 1, capacity).clamp(max=capacity)
    idx = torch.zeros(capacity + 1, dtype=torch.int64).scatter(0, slot, torch.arange(cross.shape[0]))[:capacity]
    full = lambda c: torch.broadcast_to(torch.as_tensor(c, dtype=s0.dtype), s0.shape)  # noqa: E731
    sel = lambda c: full(c)[idx]  # noqa: E731
    cs = cross[idx]
    qc, pc = split_at_crossing(system, Crossing(
        [sel(c) for c in q], [sel(c) for c in p], None if u is None else [sel(c) for c in u], h,
        ([sel(c) for c in k1[0]], [sel(c) for c in k1[1]]), [sel(c) for c in qn], [sel(c) for c in pn],
        torch.where(cs, s0[idx], -1.0), torch.where(cs, s1[idx], 1.0)), TORCH, mask=cs)
    qn = [full(a).index_put((idx,), torch.as_tensor(b)) for a, b in zip(qn, qc)]
    pn = [full(a).index_put((idx,), torch.as_tensor(b)) for a, b in zip(pn, pc)]
    return qn, pn, s1.index_put((idx,), torch.as_tensor(system.switching(qc, pc, TORCH))), overflow


def _interval_fn(system: System, k: int, with_u: bool) -> IntervalFn:
    """The compiled map (q, p, u) -> (q, p, x, overflow) over one sampling interval: q, p as (n, B) tensors and
    the same state as (B, 2n) rows ``x``."""
    import torch

    key = (type(system).__name__, system.name, repr(sorted(system.params.items())), k, with_u)
    fn = _COMPILED.get(key)
    if fn is not None:
        return fn
    h = system.dt / k
    smooth = system.switching([0.0] * system.n, [0.0] * system.n, SCALAR) is None

    def interval(q: torch.Tensor, p: torch.Tensor, u: torch.Tensor | None
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        qs, ps = list(q.unbind(0)), list(p.unbind(0))
        us = None if u is None else list(u.unbind(0))
        s = None if smooth else system.switching(qs, ps, TORCH)
        overflow = torch.zeros((), dtype=torch.bool)
        for _ in range(k):
            if smooth:
                qs, ps = rk4(system, qs, ps, us, h, TORCH)
            else:
                qs, ps, s, over = _gathered_substep(system, qs, ps, us, h, s, _crossing_capacity(q.shape[1]))
                overflow = overflow | over
        qs, ps = system.post_step(qs, ps, TORCH)
        shape = q.shape[1:]
        comps = [torch.broadcast_to(torch.as_tensor(c, dtype=q.dtype), shape) for c in qs + ps]
        # the state twice: (n, B) blocks for the next interval, (B, 2n) rows for the output's layout
        return torch.stack(comps[: len(qs)]), torch.stack(comps[len(qs):]), torch.stack(comps, dim=1), overflow

    fn = torch.compile(interval, dynamic=False, fullgraph=True)
    _COMPILED[key] = fn
    return fn


def simulate_compiled(
    system: System,
    x0: np.ndarray,
    n_steps: int,
    u: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
    substeps: int | None = None,
) -> np.ndarray:
    """:func:`phast_gym.integrate.simulate` (same arguments, same (B, n_steps + 1, 2n) result) with each
    sampling interval compiled.  A stochastic system's Langevin kick is drawn in NumPy between intervals,
    in the same order as ``simulate``, so the same ``rng`` gives the same trajectories."""
    try:
        import torch
        import torch._dynamo
    except ImportError as exc:  # pragma: no cover - torch is a dependency of the model package
        raise ImportError("simulate_compiled needs torch (pip install torch==2.13.0)") from exc
    x0, u = check_batch(system, x0, n_steps, u, rng)
    n = system.n
    k = system.substeps if substeps is None else int(substeps)
    if k < 1:
        raise ValueError(f"substeps must be a positive integer, got {substeps!r}")
    fn = _interval_fn(system, k, u is not None)
    q = torch.from_numpy(np.ascontiguousarray(x0[:, :n].T))
    p = torch.from_numpy(np.ascontiguousarray(x0[:, n:].T))
    u_t = None if u is None else torch.from_numpy(np.ascontiguousarray(u.transpose(1, 2, 0)))  # (n_steps, n, B)
    out = np.empty((x0.shape[0], n_steps + 1, 2 * n))
    out[:, 0] = x0
    with torch._dynamo.config.patch(recompile_limit=RECOMPILE_LIMIT, accumulated_recompile_limit=RECOMPILE_LIMIT):
        for t in range(n_steps):
            q0, p0, ut = q, p, None if u_t is None else u_t[t]
            x: torch.Tensor | None  # the (B, 2n) rows, None when the interval ran on the NumPy path
            try:
                q, p, x, overflow = fn(q0, p0, ut)
            except Exception as exc:
                if t > 0:
                    raise
                # the first call compiles: TorchInductor's CPU backend needs a working C++ compiler
                first = (str(exc).strip().splitlines() or [""])[0][:300]
                raise RuntimeError(f"backend='compiled' could not compile {system.name} "
                                   f"({type(exc).__name__}: {first}); "
                                   "it needs torch.compile's CPU backend (a C++ compiler); "
                                   "backend='numpy' needs neither") from exc
            if overflow:  # more kink crossings than the gather holds: this interval on the NumPy path
                qs, ps = step(system, list(q0.numpy()), list(p0.numpy()), None if ut is None else list(ut.numpy()),
                              NUMPY, substeps=k)
                q, p = (torch.from_numpy(np.stack(np.broadcast_arrays(*c, subok=False))) for c in (qs, ps))
                x = None
            if system.stochastic:
                assert rng is not None  # check_batch demands one of a stochastic system
                p = torch.from_numpy(np.ascontiguousarray(system.stochastic_kick(p.numpy().T, rng).T))
                x = None
            if x is None:
                out[:, t + 1, :n], out[:, t + 1, n:] = q.numpy().T, p.numpy().T
            else:
                out[:, t + 1] = x.numpy()
    return out
