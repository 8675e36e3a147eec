"""Fixed-step integrators over component-form state, scalar or batched.

One code path serves the single env (Python floats, ``xp = SCALAR``) and the
batched simulator (NumPy arrays of shape ``(B,)``, ``xp = NUMPY``).  Both run the
same per-sample algorithm, so they agree to ~1e-15 (bitwise where NumPy's float64
sin/cos are libm's).  NumPy only: nothing here loads torch (the torch-fused
variant is :mod:`phast_gym.compiled`, opt-in).

RK4 loses its order where the vector field has a kink (``|sin q|`` wind
damping at ``q = k pi``).  When a system declares a switching function, a
substep whose start and end lie on opposite sides of the switching surface is
split at the crossing, so both pieces are integrated on smooth ground.  The
crossing time is located on the cubic Hermite interpolant of the plain RK4
substep (no extra RK4 passes); only the crossing samples are re-integrated.
Each state's switching value is computed once and carried to the next substep.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple, TypeAlias

import numpy as np
import numpy.typing as npt

from .systems.base import NUMPY, SCALAR, Array, ArrayNamespace, NumpyNamespace, System

#: a system's vector field ``(q, p, u, xp) -> (qdot, pdot)`` in component form (:meth:`System.rhs`)
VectorField: TypeAlias = Callable[[Sequence, Sequence, Sequence | None, ArrayNamespace], tuple[tuple, tuple]]


def rk4(system: System, q: Sequence, p: Sequence, u: Sequence | None, h: Any, xp: ArrayNamespace,
        k1: tuple | None = None) -> tuple[list, list]:
    """One classical RK4 step of length ``h`` (float or per-sample array).

    ``k1``: the vector field at ``(q, p)`` when the caller already has it (it does not depend on ``h``).
    """
    f = system.rhs
    if len(q) == 1:
        return _rk4_1(f, q, p, u, h, xp, k1)
    h2 = 0.5 * h
    k1q, k1p = f(q, p, u, xp) if k1 is None else k1
    k2q, k2p = f([a + h2 * b for a, b in zip(q, k1q)], [a + h2 * b for a, b in zip(p, k1p)], u, xp)
    k3q, k3p = f([a + h2 * b for a, b in zip(q, k2q)], [a + h2 * b for a, b in zip(p, k2p)], u, xp)
    k4q, k4p = f([a + h * b for a, b in zip(q, k3q)], [a + h * b for a, b in zip(p, k3p)], u, xp)
    h6 = h / 6.0
    qn = [a + h6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(q, k1q, k2q, k3q, k4q)]
    pn = [a + h6 * (b1 + 2.0 * (b2 + b3) + b4) for a, b1, b2, b3, b4 in zip(p, k1p, k2p, k3p, k4p)]
    return qn, pn


def _any(c: bool | np.bool_ | Array) -> bool:
    return bool(c) if isinstance(c, (bool, np.bool_)) else bool(c.any())  # ndarray or tensor


def substep(system: System, q: Sequence, p: Sequence, u: Sequence | None, h: float | np.ndarray,
            xp: ArrayNamespace) -> tuple[list, list]:
    """RK4 substep that splits at a crossing of the system's switching surface."""
    q, p, _ = _substep(system, q, p, u, h, xp, system.switching(q, p, xp))
    return q, p


def _substep(system: System, q: Sequence, p: Sequence, u: Sequence | None, h: float | np.ndarray, xp: ArrayNamespace,
             s0: Any) -> tuple[list, list, Any]:
    """:func:`substep` given the switching value ``s0`` at the start; also returns it at the end
    (the next substep's ``s0``, so each state's switching value is computed once).  ``h``: a float or,
    with NumPy arrays, a per-sample (B,) array of substep lengths."""
    k1 = system.rhs(q, p, u, xp)
    qn, pn = rk4(system, q, p, u, h, xp, k1)
    if s0 is None:
        return qn, pn, None
    s1: Any = system.switching(qn, pn, xp)
    cross = s0 * s1 < 0
    if not _any(cross):
        return qn, pn, s1
    if xp is SCALAR:
        qn, pn = split_at_crossing(system, Crossing(q, p, u, h, k1, qn, pn, s0, s1), xp)
        return qn, pn, system.switching(qn, pn, xp)
    if isinstance(s0, np.ndarray):
        # refine only the samples that cross; the rest keep their plain RK4 step
        shape = np.shape(s0)
        idx = np.nonzero(cross)[0]
        sel = lambda c: c[idx] if np.ndim(c) else c  # noqa: E731
        qs, ps, qns, pns = ([sel(c) for c in comps] for comps in (q, p, qn, pn))
        k1s = ([sel(c) for c in k1[0]], [sel(c) for c in k1[1]])
        # a system with per-sample parameters (several systems as one batch) gives the crossing samples' own
        take = getattr(system, "select_samples", None)
        sys_c = system if take is None else take(idx)
        qc, pc = split_at_crossing(sys_c, Crossing(qs, ps, None if u is None else [sel(c) for c in u], sel(h), k1s,
                                                     qns, pns, s0[idx], s1[idx]), xp)
        # rk4 returned fresh arrays: overwrite the crossing samples in place (copy only broadcast scalars)
        qn, pn = ([c if np.shape(c) == shape else np.array(np.broadcast_to(c, shape), dtype=float) for c in comps]
                  for comps in (qn, pn))
        for dst, src_ in zip(qn + pn, qc + pc):
            dst[idx] = src_
        s1 = np.array(s1, dtype=float)  # the system's array: do not write into it
        s1[idx] = sys_c.switching(qc, pc, xp)
        return qn, pn, s1
    # torch: every sample takes two pieces; non-crossing ones split at tau = h (second piece of length 0)
    qc, pc = split_at_crossing(system, Crossing(q, p, u, h, k1, qn, pn, xp.where(cross, s0, -1.0),
                                                xp.where(cross, s1, 1.0)), xp, mask=cross)
    return qc, pc, system.switching(qc, pc, xp)


#: Illinois iterations locating a crossing on the substep's cubic interpolant
CROSSING_ITERATIONS = 4


class Crossing(NamedTuple):
    """A plain RK4 substep of length ``h`` from (q, p) to (qn, pn) under ``u`` whose switching values ``s0``, ``s1``
    at its ends have opposite signs; ``k1``: the vector field at the start.  (A named tuple: torch.compile traces
    it.)"""

    q: Sequence
    p: Sequence
    u: Sequence | None
    h: Any
    k1: tuple
    qn: Sequence
    pn: Sequence
    s0: Any
    s1: Any


def split_at_crossing(system: System, c: Crossing, xp: ArrayNamespace, mask: Any = None) -> tuple[list, list]:
    """Integrate a substep known to cross the switching surface in two smooth pieces.

    The crossing time is located on the cubic Hermite interpolant of q over the plain RK4 substep
    ((q, qdot) at both ends), which costs no extra RK4 evaluations: the interpolant is
    O(h^4) accurate and a split that misses the kink by dt leaves an O(dt^2) error.  The first
    piece reuses ``k1`` (the field at the start does not depend on the step length).  ``mask``:
    samples that really cross (the others take the whole substep as the first piece).
    """
    where = xp.where
    q, p, u, h, k1 = c.q, c.p, c.u, c.h, c.k1
    v0 = k1[0]
    v1 = system.velocity(c.qn, c.pn, xp)
    # q(th) = q + th (c1 + th (c2 + th c3)) on th = t / h in [0, 1] (cubic Hermite)
    coef = []
    for a, b, va, vb in zip(q, c.qn, v0, v1):
        d, c1, hv1 = b - a, h * va, h * vb
        coef.append((a, c1, 3.0 * d - 2.0 * c1 - hv1, c1 + hv1 - 2.0 * d))

    def s_at(th: Any) -> Any:
        # D = D(q) (docs/envs.md): switching functions depend on q; p is passed for the signature
        return system.switching([a + th * (c1 + th * (c2 + th * c3)) for a, c1, c2, c3 in coef], p, xp)

    # regula falsi (Illinois) on th in [a, b]
    s0 = c.s0
    a, sa, b, sb = 0.0 * s0, s0, 1.0 + 0.0 * s0, c.s1
    for _ in range(CROSSING_ITERATIONS):
        th = a + (b - a) * sa / (sa - sb)
        st = s_at(th)
        left = sa * st < 0
        b, sb = where(left, th, b), where(left, st, sb * 0.5)
        a, sa = where(left, a, th), where(left, sa * 0.5, st)
    tau = h * (a + (b - a) * sa / (sa - sb))
    if mask is not None:
        tau = where(mask, tau, h)
    q1, p1 = rk4(system, q, p, u, tau, xp, k1)
    return rk4(system, q1, p1, u, h - tau, xp)


def step(
    system: System,
    q: Sequence,
    p: Sequence,
    u: Sequence | None,
    xp: ArrayNamespace = SCALAR,
    dt: float | np.ndarray | None = None,
    substeps: int | None = None,
) -> tuple[list, list]:
    """Advance (q, p) by one sampling interval ``dt`` with ``u`` held (zero-order hold).

    ``dt``: a float or, for batched NumPy states, a per-sample (B,) array of interval lengths.
    """
    dt = system.dt if dt is None else dt
    k = system.substeps if substeps is None else substeps
    h = dt / k
    s = system.switching(q, p, xp)
    if xp is SCALAR and s is None:
        # fast path of the single env: smooth field, Python floats, no switching test per substep
        if system.n == 1:
            f = system.rhs
            for _ in range(k):
                q, p = _rk4_1(f, q, p, u, h)
        else:
            for _ in range(k):
                q, p = rk4(system, q, p, u, h, xp)
        return system.post_step(list(q), list(p), xp)
    for _ in range(k):
        q, p, s = _substep(system, q, p, u, h, xp, s)
    return system.post_step(list(q), list(p), xp)


def _rk4_1(f: VectorField, q: Sequence, p: Sequence, u: Sequence | None, h: Any, xp: ArrayNamespace = SCALAR,
           k1: tuple | None = None) -> tuple[list, list]:
    """:func:`rk4` for one coordinate (floats or arrays): the same operations in the same order
    (so the single env and the batched path agree), without the per-component loops."""
    h2 = 0.5 * h
    q0, p0 = q[0], p[0]
    (a1,), (b1,) = f(q, p, u, xp) if k1 is None else k1
    (a2,), (b2,) = f([q0 + h2 * a1], [p0 + h2 * b1], u, xp)
    (a3,), (b3,) = f([q0 + h2 * a2], [p0 + h2 * b2], u, xp)
    (a4,), (b4,) = f([q0 + h * a3], [p0 + h * b3], u, xp)
    h6 = h / 6.0
    return [q0 + h6 * (a1 + 2.0 * (a2 + a3) + a4)], [p0 + h6 * (b1 + 2.0 * (b2 + b3) + b4)]


def check_batch(system: System, x0: npt.ArrayLike, n_steps: int, u: npt.ArrayLike | None,
                rng: np.random.Generator | None) -> tuple[np.ndarray, np.ndarray | None]:
    """Validate a batched simulator's inputs (shared by :func:`simulate` and the compiled backend)."""
    x0 = np.asarray(x0, dtype=np.float64)
    n = system.n
    if x0.ndim != 2 or x0.shape[1] != 2 * n:
        raise ValueError(f"x0 must have shape (B, {2 * n}), got {x0.shape}")
    if not np.isfinite(x0).all():
        raise ValueError("x0 must be finite")
    if int(n_steps) != n_steps or n_steps < 0:
        raise ValueError(f"n_steps must be a non-negative integer, got {n_steps!r}")
    if u is not None:
        u = np.asarray(u, dtype=np.float64)
        if u.shape != (x0.shape[0], n_steps, n):
            raise ValueError(f"u must have shape {(x0.shape[0], n_steps, n)}, got {u.shape}")
    if system.stochastic and rng is None:
        raise ValueError(f"{system.name} is stochastic (temperature > 0): pass rng")
    return x0, u


def simulate(
    system: System,
    x0: np.ndarray,
    n_steps: int,
    u: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
    substeps: int | None = None,
    xp: ArrayNamespace = NUMPY,
) -> np.ndarray:
    """Integrate a batch of trajectories at once.

    Parameters
    ----------
    x0 : (B, 2n) initial states ``(q, p)``.
    n_steps : number of sampling intervals; the result has ``n_steps + 1`` samples.
    u : optional (B, n_steps, n) generalized port force ``G u`` held over each interval.
    rng : generator for stochastic systems (Langevin temperature).
    substeps : RK4 substeps per step (default: the system's).
    xp : a NumPy namespace (default ``NUMPY``: NumPy arithmetic and libm sin/cos, the same as the
        single env's, never loads torch).

    Returns
    -------
    (B, n_steps + 1, 2n) float64 array of states.
    """
    x0, u = check_batch(system, x0, n_steps, u, rng)
    n = system.n
    if not isinstance(xp, NumpyNamespace):
        raise ValueError("simulate integrates NumPy arrays: xp must be a NumPy namespace such as NUMPY, "
                         f"got {getattr(xp, 'name', xp)!r}")
    out = np.empty((x0.shape[0], n_steps + 1, 2 * n))
    out[:, 0] = x0
    q = [x0[:, i].copy() for i in range(n)]
    p = [x0[:, n + i].copy() for i in range(n)]
    k = system.substeps if substeps is None else substeps
    h = system.dt / k
    s = system.switching(q, p, xp)
    # the switching value is carried from substep to substep unless the step ends with a projection or noise
    fresh_s = s is not None and (system.stochastic or type(system).post_step is not System.post_step)
    u_t = None if u is None else np.ascontiguousarray(u.transpose(1, 2, 0))  # (n_steps, n, B): contiguous rows
    for t in range(n_steps):
        ut = None if u_t is None else list(u_t[t])
        for _ in range(k):
            q, p, s = _substep(system, q, p, ut, h, xp, s)
        q, p = system.post_step(q, p, xp)
        if system.stochastic:
            assert rng is not None  # check_batch demands one of a stochastic system
            pk = system.stochastic_kick(np.stack(p, -1), rng)
            p = [pk[:, i] for i in range(n)]
        if fresh_s:
            s = system.switching(q, p, xp)
        for i in range(n):
            out[:, t + 1, i] = q[i]
            out[:, t + 1, n + i] = p[i]
    return out
