"""A learned model's step traced for a controller's hot loop (``torch.jit.trace``).

On a CPU the PHAST core's ops are small and dispatch-bound: one planning step of 256 cart-pole rollouts is ~80 tiny
tensor ops behind Python module calls (about 5 ms eager, 1 ms traced, with the same numbers to the last bit).  The
planner (:mod:`.mppi`) and the learned-model UKF (:class:`.phast_estimators.PHASTProcess`) run the same function on
the same shapes every plant step, so tracing it once per input shape removes the Python overhead.

The trace holds the model's parameters as constants with the values they have at the first call of each shape:
rebuild the :class:`Traced` after the model changes (the loop builds a new controller after every fit).  The first
call of each shape keeps the eager function instead of the trace when tracing fails, when the tracer warns that a
tensor's value steered Python control flow (the trace would keep one branch), or when the trace's result at that
call differs from the eager one in any bit.  ``torch.jit.trace`` is deprecated in favour of ``torch.compile``, whose
CPU backend compiles C++ for tens of seconds per shape: too slow for a controller built after every fit.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import torch

#: the tracer's warnings that a tensor's value reached Python (a branch, a loop count, an index): the trace would
#: hold what it was at the example inputs, so such a function stays eager
UNSAFE = ("Converting a tensor to a Python", "Iterating over a tensor")
#: the calls after which TorchScript's profiling executor has optimized a traced graph
PROFILING_RUNS = 3

TensorFn = Callable[..., tuple[torch.Tensor, ...]]


class Traced:
    """``fn`` (tensors -> tuple of tensors, no autograd) traced per input shape with ``model``'s parameters frozen;
    ``enabled`` False: ``fn`` itself (module docstring)."""

    def __init__(self, model: torch.nn.Module, fn: TensorFn, enabled: bool = True) -> None:
        self.model, self.fn, self.enabled = model, fn, bool(enabled)
        self._calls: dict[tuple[tuple[int, ...], ...], TensorFn] = {}

    @torch.no_grad()
    def __call__(self, *args: torch.Tensor) -> tuple[torch.Tensor, ...]:
        if not self.enabled:
            return self.fn(*args)
        key = tuple(tuple(a.shape) for a in args)
        call = self._calls.get(key)
        if call is None:
            call = self._calls[key] = self._trace(args)
        return call(*args)

    def warm(self, *args: torch.Tensor) -> None:
        """Trace for the shapes of ``args`` now (a controller's set-up, so no plant step pays for it)."""
        key = tuple(tuple(a.shape) for a in args)
        if self.enabled and key not in self._calls:
            call = self._calls[key] = self._trace(args)
            for _ in range(PROFILING_RUNS if call is not self.fn else 0):  # TorchScript optimizes a graph after its
                call(*args)  # first runs: do them now

    def _trace(self, args: tuple[torch.Tensor, ...]) -> TensorFn:
        """The trace of ``fn`` at ``args``, or ``fn`` where it is not safe (module docstring)."""
        params = [p for p in self.model.parameters() if p.requires_grad]
        for p in params:
            p.requires_grad_(False)
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                traced = torch.jit.trace(self.fn, args, check_trace=False)
            ok = not any(str(w.message).startswith(UNSAFE) for w in caught) and all(
                _same(a, b) for a, b in zip(traced(*args), self.fn(*args), strict=True))
        except (AttributeError, RuntimeError, TypeError, ValueError):  # AttributeError: a torch without torch.jit
            ok = False
        finally:
            for p in params:
                p.requires_grad_(True)
        return traced if ok else self.fn


def _same(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Equal in every element, NaN where the other is NaN."""
    return a.shape == b.shape and bool(torch.allclose(a, b, rtol=0.0, atol=0.0, equal_nan=True))
