"""The port-Hamiltonian system interface: one place for each system's physics.

Every formula (H, its gradients, M(q), D(q), the initial-state sampler) is
written once, in *component form*: ``q`` and ``p`` are sequences of ``n``
coordinates, each of which may be

* a Python ``float`` (the single env's fast path, ``xp = SCALAR``),
* a NumPy array of shape ``(B,)`` (the batched simulator, ``xp = NUMPY``),
* a torch tensor of any shape (the PHAST model's KNOWN components,
  ``xp = TORCH``; autograd flows through).

Vector results are returned as tuples of components.  Use :func:`namespace`
to pick ``xp`` from an example coordinate, and :func:`split` / :func:`stack`
to move between a ``(..., n)`` array and component form.

The dynamics are the port-Hamiltonian ones of docs/envs.md (paper Eq. 1-3)::

    qdot = dH/dp = M(q)^-1 p
    pdot = -dH/dq - D(q) qdot + G u
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar, Protocol, TypeAlias, TypeVar

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    import torch

Components = Sequence[Any]
#: one coordinate of a formula, for a helper whose result has its argument's kind: a Python float (``SCALAR``), a
#: NumPy array (``NUMPY``) or a torch tensor (``TORCH``)
Coord = TypeVar("Coord", float, np.ndarray, "torch.Tensor")
_T = TypeVar("_T")
#: an array of the formulas written over numpy or torch arrays (never Python floats), such as the rigid-body tree's
#: (:mod:`.tree_dynamics`): a NumPy array, or a torch tensor where autograd flows through (torch only when type
#: checking)
Array: TypeAlias = "np.ndarray | torch.Tensor"


class ArrayNamespace(Protocol):
    """The array namespace ``xp`` the physics formulas are written over: :data:`SCALAR` (Python floats),
    :data:`NUMPY` (NumPy arrays) or :data:`TORCH` (torch tensors).

    A coordinate is a float, an ndarray or a tensor (phast_gym never imports torch), so the element
    type stays ``Any``; the protocol fixes which functions a formula may call on ``xp``.
    """

    name: str

    def sin(self, x: Any, /) -> Any: ...
    def cos(self, x: Any, /) -> Any: ...
    def sqrt(self, x: Any, /) -> Any: ...
    def exp(self, x: Any, /) -> Any: ...
    def tanh(self, x: Any, /) -> Any: ...
    def abs(self, x: Any, /) -> Any: ...
    def log(self, x: Any, /) -> Any: ...
    def sign(self, x: Any, /) -> Any: ...
    def where(self, c: Any, a: Any, b: Any, /) -> Any: ...
    def clip_min(self, x: Any, lo: float, /) -> Any:
        """``max(x, lo)`` elementwise."""


# --------------------------------------------------------------------------- namespaces
class _ScalarNamespace:
    """Array namespace over Python floats (fast path of the single env)."""

    name = "scalar"
    sin = staticmethod(math.sin)
    cos = staticmethod(math.cos)
    sqrt = staticmethod(math.sqrt)
    exp = staticmethod(math.exp)
    tanh = staticmethod(math.tanh)
    abs = staticmethod(abs)

    @staticmethod
    def log(x: float) -> float:
        return math.log(x)

    @staticmethod
    def sign(x: float) -> float:
        return (x > 0) - (x < 0) + 0.0

    @staticmethod
    def clip_min(x: float, lo: float) -> float:
        return x if x > lo else lo

    @staticmethod
    def where(c: bool, a: _T, b: _T) -> _T:
        return a if c else b


class NumpyNamespace:
    """Array namespace over NumPy arrays (batched simulator)."""

    name = "numpy"
    sin = staticmethod(np.sin)
    cos = staticmethod(np.cos)
    sqrt = staticmethod(np.sqrt)
    exp = staticmethod(np.exp)
    tanh = staticmethod(np.tanh)
    abs = staticmethod(np.abs)
    log = staticmethod(np.log)
    sign = staticmethod(np.sign)
    where = staticmethod(np.where)

    @staticmethod
    def clip_min(x: npt.ArrayLike, lo: float) -> np.ndarray:
        return np.maximum(x, lo)


class _TorchNamespace:
    """Array namespace over torch tensors (imported lazily: phast_gym is numpy-only)."""

    name = "torch"

    def __getattr__(self, item: str) -> Any:
        import torch

        if item == "clip_min":
            return lambda x, lo: torch.clamp(x, min=lo)
        return getattr(torch, item)


SCALAR = _ScalarNamespace()
NUMPY = NumpyNamespace()
TORCH: ArrayNamespace = _TorchNamespace()  # torch's own functions (through __getattr__) but clip_min
_NAMESPACES: tuple[ArrayNamespace, ...] = (SCALAR, NUMPY, TORCH)  # mypy checks that each implements the protocol


def namespace(x: object) -> ArrayNamespace:
    """Pick the namespace matching one coordinate ``x`` (float, ndarray or tensor)."""
    if isinstance(x, (float, int)):
        return SCALAR
    if isinstance(x, (np.ndarray, np.generic)):
        return NUMPY
    if type(x).__module__.startswith("torch"):
        return TORCH
    raise TypeError(f"unsupported coordinate type {type(x).__name__}")


def split(x: Array) -> tuple:
    """``(..., n)`` array or tensor -> tuple of ``n`` components."""
    if isinstance(x, np.ndarray):
        return tuple(x[..., i] for i in range(x.shape[-1]))
    return tuple(x.unbind(-1))


def stack(components: Components, like: Any = None) -> Any:
    """Tuple of components -> ``(..., n)`` array (numpy or torch, as the components)."""
    first = components[0]
    if type(first).__module__.startswith("torch"):
        import torch

        shape = torch.broadcast_shapes(*[c.shape for c in components if hasattr(c, "shape")])
        return torch.stack([c.expand(shape) if hasattr(c, "expand") else torch.full(shape, float(c))
                            for c in components], -1)
    arrs = np.broadcast_arrays(*[np.asarray(c, dtype=np.float64) for c in components])
    return np.stack(arrs, -1)


def const_like(x: Coord, c: float) -> Coord:
    """The constant ``c`` with the type and shape of coordinate ``x``."""
    if type(x) is np.ndarray:
        r = x * 0.0  # the same values as x * 0.0 + c, one temporary fewer (datasets build (N, T) ones)
        r += c
        return r
    return x * 0.0 + c


def solve_spd(M: Sequence[Components], b: Components) -> tuple:
    """Solve ``M x = b`` for a symmetric positive definite ``n x n`` M in component form (nested tuple).

    Gaussian elimination without pivoting (stable for SPD matrices) using only arithmetic, so it
    runs on floats, NumPy arrays and torch tensors alike (autograd flows through); meant for the
    small n (1..6) of the suite, where it beats stacking into a batched ``linalg.solve``.
    """
    n = len(b)
    if n == 1:
        return (b[0] / M[0][0],)
    a = [list(row) for row in M]
    y = list(b)
    for k in range(n - 1):
        for i in range(k + 1, n):
            f = a[i][k] / a[k][k]
            for j in range(k + 1, n):
                a[i][j] = a[i][j] - f * a[k][j]
            y[i] = y[i] - f * y[k]
    x: list = [None] * n
    for i in range(n - 1, -1, -1):
        r = y[i]
        for j in range(i + 1, n):
            r = r - a[i][j] * x[j]
        x[i] = r / a[i][i]
    return tuple(x)


def wrap(a: Coord) -> Coord:
    """Wrap angles into ``[-pi, pi)`` (paper Appendix F): ``(a + pi) mod 2 pi - pi``."""
    if type(a) is np.ndarray and a.ndim and a.dtype.kind == "f":
        # same values, faster: x mod 2 pi = x where 0 <= x < 2 pi, so the slow float remainder
        # only runs on the entries outside that range (whirling trajectories)
        x = a + math.pi
        out = (x < 0.0) | (x >= 2.0 * math.pi)
        if out.any():
            x[out] %= 2.0 * math.pi
        x -= math.pi
        return x
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def angle_diff(a: np.ndarray, b: np.ndarray, angle_dims: Sequence[int]) -> np.ndarray:
    """``a - b`` (NumPy arrays, coordinates on the last axis), wrapped into ``[-pi, pi)`` on the angular
    coordinates ``angle_dims`` (paper Appendix F)."""
    d = a - b
    if len(angle_dims):
        idx = list(angle_dims)
        d[..., idx] = wrap(d[..., idx])
    return d


def fd_velocity(q: np.ndarray, dt: float, angle_dims: Sequence[int]) -> np.ndarray:
    """Finite-difference velocities ``(..., T, n) -> (..., T-1, n)``, wrapped on angular coordinates."""
    return angle_diff(q[..., 1:, :], q[..., :-1, :], angle_dims) / dt


def break_at_wraps(y: np.ndarray, axis: int = -1) -> np.ndarray:
    """A float copy of a wrapped angle series with NaN where it jumps by more than pi along ``axis``, so a
    line plot breaks at the wrap instead of drawing a vertical line across ``[-pi, pi)``."""
    y = np.array(y, dtype=float)
    jump = np.abs(np.diff(y, axis=axis)) > math.pi
    tail = [slice(None)] * y.ndim
    tail[axis] = slice(1, None)
    y[tuple(tail)][jump] = np.nan
    return y


# --------------------------------------------------------------------------- parameters
class ParameterError(ValueError, TypeError):
    """A physical parameter kwarg is unknown or out of its valid range."""


@dataclass(frozen=True)
class Param:
    """A documented physical parameter: default, constraint and meaning.

    A parameter with ``choices`` is a string option (e.g. a coordinate convention) instead of a
    number; its value must be one of them.  ``extension`` marks a parameter that is not part of the
    benchmark envs' definition: while at its default it is left out of :meth:`System.key_params`, so the
    dataset cache keys of the benchmark envs do not depend on it.  ``known`` marks a constant of nature or a
    value the user knows for certain (gravity): tools that calibrate a simulator (phast-mismatch) hold it fixed
    unless the user frees it.
    """

    default: float | str | None
    doc: str
    constraint: str = "positive"  # "positive", "nonnegative" or "any" (numbers only)
    choices: tuple[str, ...] = ()
    extension: bool = False
    known: bool = False

    def __post_init__(self) -> None:
        if self.choices and self.default not in self.choices:
            raise ValueError(f"Param default {self.default!r} is not one of its choices {self.choices}")


# --------------------------------------------------------------------------- system
class System:
    """A port-Hamiltonian system: parameters plus H, dH/dq, dH/dp, M, D, port.

    Subclasses set the class attributes and implement ``potential``,
    ``grad_potential``, ``velocity``, ``mass_matrix``, ``damping`` and
    ``sample_initial`` (and ``dH_dq`` when M depends on q).
    """

    #: short name used in registration and the dataset cache key
    name: ClassVar[str] = ""
    #: number of generalized coordinates
    n: ClassVar[int] = 1
    #: indices of angular coordinates (wrapped in observations and metrics)
    angle_dims: ClassVar[tuple[int, ...]] = ()
    #: sampling interval of the env (one ``step``); an instance may override it (a control rate, a config's ``dt``)
    dt: float = 0.05
    #: RK4 substeps per ``dt`` (chosen so 50 steps match a 1e-10 ODE solve within 1e-5); an instance may override it
    substeps: int = 4
    #: default bound of the port input
    default_max_action: ClassVar[float] = 50.0
    #: True when H = p^T M^-1 p / 2 + V(q) with M constant (leapfrog applies; dH/dq = dV/dq)
    separable: ClassVar[bool] = True
    #: True for port-Hamiltonian systems (False: a plain ODE such as predator-prey)
    hamiltonian_system: ClassVar[bool] = True
    #: names of the coordinates, for plots and docs (an instance may override it: DoublePendulum's relative angles)
    coordinate_names: tuple[str, ...] = ("q",)
    #: physical parameters (constructor kwargs) with defaults and constraints
    #: physical parameters (constructor kwargs) with defaults and constraints; the constructor sets each as an
    #: attribute of the same name, so a subclass declares their types too (``mass: float``; a choice is ``str``)
    PARAMS: ClassVar[dict[str, Param]] = {}

    def __init__(self, **params: Any) -> None:
        unknown = sorted(set(params) - set(self.PARAMS))
        if unknown:
            raise ParameterError(
                f"{type(self).__name__}: unknown parameter(s) {unknown}; "
                f"valid names are {sorted(self.PARAMS)}"
            )
        values: dict[str, float | str | None] = {}
        for key, spec in self.PARAMS.items():
            val = params.get(key, spec.default)
            if spec.choices:
                if not isinstance(val, str) or val not in spec.choices:
                    raise ParameterError(
                        f"{type(self).__name__}: parameter {key}={val!r} must be one of {list(spec.choices)} "
                        f"({spec.doc})"
                    )
            elif val is not None:
                try:
                    val = float(val)
                except (TypeError, ValueError):
                    raise ParameterError(f"{type(self).__name__}: parameter {key}={val!r} is not a number") from None
                if not math.isfinite(val):
                    raise ParameterError(f"{type(self).__name__}: parameter {key}={val} is not finite")
                if spec.constraint == "positive" and val <= 0:
                    raise ParameterError(f"{type(self).__name__}: parameter {key}={val} must be > 0 ({spec.doc})")
                if spec.constraint == "nonnegative" and val < 0:
                    raise ParameterError(f"{type(self).__name__}: parameter {key}={val} must be >= 0 ({spec.doc})")
            values[key] = val
        self.params = values
        for key, val in values.items():
            setattr(self, key, val)
        self._finalize()
        self._damped = self.has_damping()  # cached: rhs runs once per RK4 stage
        self._const_d = self.constant_damping()  # floats: rhs skips building constant arrays

    def _finalize(self) -> None:
        """Derived constants (e.g. default inertia); called after parameters are set."""

    def key_params(self) -> dict[str, float | str | None]:
        """The parameters that identify this system in cache keys: :attr:`params` without the
        ``extension`` parameters that are at their default (so adding one keeps old keys valid)."""
        return {k: v for k, v in self.params.items()
                if not (k in self.PARAMS and self.PARAMS[k].extension and v == self.PARAMS[k].default)}

    def __repr__(self) -> str:
        kw = ", ".join(f"{k}={v!r}" for k, v in self.params.items())
        return f"{type(self).__name__}({kw})"

    # ---- energy ------------------------------------------------------------
    def potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> Any:
        """Potential energy V(q)."""
        raise NotImplementedError

    def grad_potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        """dV/dq, as n components."""
        raise NotImplementedError

    def mass_matrix(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple[tuple, ...]:
        """Mass matrix M(q) as an n x n nested tuple of components."""
        raise NotImplementedError

    def velocity(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        """Generalized velocity qdot = dH/dp = M(q)^-1 p."""
        raise NotImplementedError

    def momentum(self, q: Components, v: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        """Canonical momentum p = M(q) qdot for the generalized velocity ``v`` (the inverse of :meth:`velocity`)."""
        return tuple(sum(mij * vj for mij, vj in zip(row, v)) for row in self.mass_matrix(q, xp))

    def kinetic(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> Any:
        """Kinetic energy p^T M(q)^-1 p / 2."""
        v = self.velocity(q, p, xp)
        return 0.5 * sum(pi * vi for pi, vi in zip(p, v))

    def hamiltonian(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> Any:
        """Total energy H(q, p) = kinetic + potential."""
        return self.kinetic(q, p, xp) + self.potential(q, xp)

    def energy(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> Any:
        """The energy reported in ``info["energy"]`` (H, or a Lyapunov function for ODEs)."""
        return self.hamiltonian(q, p, xp)

    def dH_dq(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        """dH/dq at fixed p; equals dV/dq when M is constant."""
        return self.grad_potential(q, xp)

    def dH_dp(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        """dH/dp = M(q)^-1 p."""
        return self.velocity(q, p, xp)

    # ---- dissipation and port -------------------------------------------
    def damping(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        """Diagonal of D(q) (every system of the suite has a diagonal D)."""
        return tuple(const_like(qi, 0.0) for qi in q)

    def has_damping(self) -> bool:
        """False when D is identically zero (lets integrators skip work)."""
        return True

    def constant_damping(self) -> tuple[float, ...] | None:
        """Diagonal of D as n floats when D does not depend on q, else None.

        Systems with a constant D define ``damping`` through this method (one formula); ``rhs``
        then multiplies by floats instead of building constant arrays every RK4 stage.
        """
        return None

    def nonconservative_force(self, q: Components, v: Components, u: Components | None,
                              xp: ArrayNamespace = NUMPY) -> tuple:
        """Everything in pdot but -dH/dq at the rates ``v``: ``-D(q) v + G u`` (a system with friction laws or an
        actuator model beyond ``G u`` overrides it, e.g. a MuJoCo model's frictionloss and actuator gains)."""
        d = self.damping(q, xp)
        f = tuple(-di * vi for di, vi in zip(d, v))
        return f if u is None else tuple(ui + fi for ui, fi in zip(u, f))

    def switching(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> Any | None:
        """A scalar whose sign changes where the vector field has a kink (or None).

        The integrator splits a substep at such a crossing so RK4 keeps its
        order on non-smooth damping laws such as ``|sin q|``.
        """
        return None

    # ---- dynamics ------------------------------------------------------------
    def rhs(self, q: Components, p: Components, u: Components | None,
            xp: ArrayNamespace = NUMPY) -> tuple[tuple, tuple]:
        """Vector field (qdot, pdot) with the port force ``u`` = G u (n components), Eq. 1-3.

        Hot path of both the single env and the batched simulator: one call per RK4 stage.
        """
        v = self.velocity(q, p, xp)
        # separable H: dH/dq = dV/dq (skip the dH_dq indirection)
        dq = self.grad_potential(q, xp) if self.separable else self.dH_dq(q, p, xp)
        if self._damped:
            d = self._const_d if self._const_d is not None else self.damping(q, xp)
            if u is None:
                return tuple(v), tuple([-a - b * c for a, b, c in zip(dq, d, v)])
            return tuple(v), tuple([f - a - b * c for a, b, c, f in zip(dq, d, v, u)])
        if u is None:
            return tuple(v), tuple([-a for a in dq])
        return tuple(v), tuple([f - a for a, f in zip(dq, u)])

    def power_balance(self, q: Components, p: Components, u: Components | None,
                      xp: ArrayNamespace = NUMPY) -> tuple[Any, Any]:
        """(dissipated power v^T D v, supplied power v^T G u): dH/dt = -first + second."""
        v = self.velocity(q, p, xp)
        d = self.damping(q, xp)
        diss = sum(di * vi * vi for di, vi in zip(d, v))
        supplied = sum(vi * ui for vi, ui in zip(v, u)) if u is not None else 0.0 * diss
        return diss, supplied

    def post_step(self, q: list, p: list, xp: ArrayNamespace = NUMPY) -> tuple[list, list]:
        """Projection applied after every step (e.g. populations stay >= 0)."""
        return q, p

    def stochastic_kick(self, p: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noise added to p once per step, p of shape (..., n) (default: none)."""
        return p

    # ---- initial states -------------------------------------------------
    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """Sample ``size`` initial states ``(q, p)`` from the env's initial-state distribution (docs/envs.md) -> (size,
        2n)."""
        raise NotImplementedError

    # ---- helpers -------------------------------------------------------------
    @property
    def stochastic(self) -> bool:
        """True when steps inject noise (Langevin temperature)."""
        return False
