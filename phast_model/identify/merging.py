"""Several systems simulated as one batch: systems of one class that differ only in numbers become one system with
per-sample parameter arrays (:func:`merge_systems`), so a fit's perturbed models and trial steps share one
integration."""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from phast_gym.systems.base import NUMPY, System

__all__ = ["merge_systems", "merged_field_ok"]

class _Unmergeable(Exception):
    """The systems differ in something other than numbers (a flag, a term list): simulate them one by one."""


def _merge_values(vals: Sequence[Any], reps: int) -> Any:
    """One value standing for ``vals`` (one per system), each system's value repeated over its ``reps`` samples.

    Equal values stay as they are (the same arithmetic as a single system); differing floats become a (K*reps,)
    array, differing float arrays a (K*reps, ...) one; tuples, lists, dicts, systems and dataclasses (terms) are merged
    field by field.
    """
    v0 = vals[0]
    t = type(v0)
    if all(v is v0 for v in vals):
        return v0
    if any(type(v) is not t for v in vals):
        raise _Unmergeable
    if t is float or issubclass(t, np.floating):
        if all(v == v0 for v in vals):
            return v0
        return np.repeat(np.asarray(vals, dtype=float), reps)
    if t is tuple or t is list:
        if any(len(v) != len(v0) for v in vals):
            raise _Unmergeable
        return t(_merge_values([v[i] for v in vals], reps) for i in range(len(v0)))
    if t is dict:
        if any(v.keys() != v0.keys() for v in vals):
            raise _Unmergeable
        return {k: _merge_values([v[k] for v in vals], reps) for k in v0}
    if isinstance(v0, System) or (dataclasses.is_dataclass(v0) and not isinstance(v0, type)):
        if any(vars(v).keys() != vars(v0).keys() for v in vals):
            raise _Unmergeable
        out = copy.copy(v0)  # no __init__ / __post_init__: they validate scalars
        for k in vars(v0):
            object.__setattr__(out, k, _merge_values([vars(v)[k] for v in vals], reps))
        return out
    if t is np.ndarray and all(v.shape == v0.shape and np.array_equal(v, v0) for v in vals):
        return v0
    if t is np.ndarray and v0.dtype.kind == "f" and v0.ndim and all(v.shape == v0.shape for v in vals):
        return np.repeat(np.stack(vals), reps, axis=0)  # a parameter array: one row per sample (MJCFSystem broadcasts)
    if t in (str, bool, int) and all(v == v0 for v in vals):  # a differing int or flag is structure, not a number
        return v0
    raise _Unmergeable


def merge_systems(systems: Sequence[System], reps: int) -> System | None:
    """One system that simulates ``len(systems)`` batches of ``reps`` samples, the k-th with ``systems[k]``.

    The systems must be of one class and differ only in float attributes (parameters, coefficients and what
    is derived from them): those become per-sample arrays, so each sample sees its own system's numbers in
    the same operations.  The measurement map runs per system.  None when the systems cannot be merged.
    """
    merged: Any
    if all(s is systems[0] for s in systems):  # one system for every batch: itself (never mutated here)
        return systems[0]
    try:
        merged = _merge_values(list(systems), reps)
    except (_Unmergeable, TypeError):  # TypeError: no instance __dict__ (slots)
        return None
    measures: list[Any] = [getattr(s, "measure", None) for s in systems]
    if measures[0] is not None:
        def measure(out: np.ndarray) -> np.ndarray:
            return np.concatenate([m(out[k * reps: (k + 1) * reps]) for k, m in enumerate(measures)])
        merged.measure = measure
    size = len(systems) * reps
    plan: dict[int, list] = {}
    _take_plan(merged, size, plan)
    # the integrator refines the samples that cross a switching surface on their own: the system of those samples
    merged.select_samples = lambda idx: _take_values(merged, idx, size, plan)
    return merged


def _take_plan(v: Any, size: int, plan: dict[int, list]) -> bool:
    """Whether ``v`` (a merged value of :func:`_merge_values`) holds a per-sample (size,) array; ``plan`` gets, for
    each container that does (by id), the keys or indices of its items that do."""
    t = type(v)
    if t is np.ndarray:
        return v.shape[:1] == (size,)
    if t is tuple or t is list:
        items: Any = enumerate(v)
    elif t is dict:
        items = v.items()
    elif isinstance(v, System) or (dataclasses.is_dataclass(v) and not isinstance(v, type)):
        items = vars(v).items()
    else:
        return False
    keys = [k for k, x in items if _take_plan(x, size, plan)]
    if keys:
        plan[id(v)] = keys
    return bool(keys)


def _take_values(v: Any, idx: np.ndarray, size: int, plan: dict[int, list]) -> Any:
    """``v`` restricted to the samples ``idx`` of its ``size``: the containers in ``plan`` (:func:`_take_plan`)
    are copied with their per-sample arrays indexed."""
    t = type(v)
    if t is np.ndarray:
        return v[idx] if v.shape[:1] == (size,) else v
    keys = plan.get(id(v))
    if keys is None:
        return v
    if t is tuple or t is list:
        items = list(v)
        for i in keys:
            items[i] = _take_values(items[i], idx, size, plan)
        return t(items)
    d = dict(v) if t is dict else dict(vars(v))
    for k in keys:
        d[k] = _take_values(d[k], idx, size, plan)
    if t is dict:
        return d
    d.pop("select_samples", None)
    out = object.__new__(t)  # a system or a (frozen) dataclass: no __init__, the fields are set here
    out.__dict__.update(d)
    return out


def merged_field_ok(merged: System, systems: Sequence[System], q: list, p: list, u: list | None) -> bool:
    """Whether the merged system's vector field, switching value and momentum at (q, p, u) (one batch of
    len(systems) x reps samples) equal each system's on its own samples: a cheap guard against a system that
    folds a parameter into something other than elementwise arithmetic.

    A switching function that branches on a parameter in Python (``sin q if dd != 0 else None``) cannot take
    an array parameter: the merged system then uses the first system's, if it gives every system's values here.
    """
    try:
        return _same_field(merged, systems, q, p, u)
    except (ValueError, TypeError, AttributeError, IndexError):  # e.g. `if param != 0` on an array: not mergeable
        return False


def _same_field(merged: System, systems: Sequence[System], q: list, p: list, u: list | None) -> bool:
    """:func:`merged_field_ok` (raises where the merged system cannot evaluate)."""
    K = len(systems)
    B = len(q[0])
    reps = B // K

    def flat(x: object) -> list:
        if x is None:
            return []
        if isinstance(x, (tuple, list)):
            return [c for xi in x for c in flat(xi)]
        return [x]

    with np.errstate(all="ignore"):
        try:
            s_whole = merged.switching(q, p, NUMPY)
        except (ValueError, TypeError):
            merged.switching = systems[0].switching  # type: ignore[method-assign]
            s_whole = merged.switching(q, p, NUMPY)
        whole = flat((merged.rhs(q, p, u, NUMPY), s_whole, merged.momentum(q, p, NUMPY)))
        for k, s in enumerate(systems):
            sl = slice(k * reps, (k + 1) * reps)
            qs, ps = [c[sl] for c in q], [c[sl] for c in p]
            us = None if u is None else [c[sl] for c in u]
            part = flat((s.rhs(qs, ps, us, NUMPY), s.switching(qs, ps, NUMPY), s.momentum(qs, ps, NUMPY)))
            if len(part) != len(whole):
                return False
            for a, b in zip(whole, part):
                a = np.broadcast_to(np.asarray(a, dtype=float), (B,))[sl]
                b = np.broadcast_to(np.asarray(b, dtype=float), (reps,))
                # to rounding: a contraction may sum in another order for another batch size (einsum)
                atol = 1e-12 * float(np.max(np.abs(b), initial=0.0, where=np.isfinite(b)))
                if not np.allclose(a, b, rtol=1e-12, atol=atol, equal_nan=True):
                    return False
    return True
