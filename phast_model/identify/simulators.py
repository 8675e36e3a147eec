"""The nominal simulator the mismatch tool compares with the recordings.

A simulator is a :class:`phast_gym.systems.System` subclass (H, M(q), D(q), port:
the interface every env of the suite is built from) plus the keyword arguments
of its constructor.  It is named in one of three ways:

* a registered env id, ``PHAST/Pendulum-v0`` (its registered kwargs apply);
* an importable class, ``my_package.my_module:MyRig``;
* a class in a Python file, ``path/to/rig.py:MyRig``;
* a MuJoCo model file, ``path/to/robot.xml`` (MJCF) or ``path/to/robot.urdf``: its rigid-body tree, joints and
  actuators as a :class:`phast_gym.systems.mjcf.MJCFSystem` whose parameters carry the file's own names.

:func:`load_simulator` resolves the name once; the pipeline then builds every
calibrated / augmented variant through :meth:`Simulator.build`, so a user's rig
and a suite env are handled by the same code.
"""

from __future__ import annotations

import importlib
import importlib.util
import math
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.registry import ENV_KWARGS, make_env_system, resolve_env_id
from phast_gym.systems.base import NUMPY, System


@dataclass(frozen=True)
class Simulator:
    """A nominal simulator: ``build(**overrides)`` -> a fresh :class:`System`."""

    name: str  # env id or "module:Class" / "file.py:Class", as the user gave it
    factory: Callable[..., System] = field(repr=False)
    kwargs: dict[str, Any] = field(default_factory=dict)  # the user's kwargs (before calibration)

    def build(self, **overrides: Any) -> System:
        """The system with the user's kwargs, overridden by ``overrides`` (e.g. calibrated values)."""
        return self.factory(**{**self.kwargs, **overrides})

    def numeric_params(self, system: System | None = None) -> dict[str, float]:
        """The finite float parameters of ``system`` (default: the nominal one): the calibration candidates."""
        s = system if system is not None else self.build()
        out = {}
        for k, v in s.params.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                continue
            out[k] = float(v)
        return out


#: parameter names held fixed as known constants even when a user's rig does not flag them (Param(known=True))
KNOWN_NAMES = ("gravity", "g")


def known_params(system: System) -> set[str]:
    """Parameters of ``system`` that calibration holds fixed unless freed: flagged ``Param(known=True)``, or named like
    a constant of nature (:data:`KNOWN_NAMES`)."""
    specs = getattr(type(system), "PARAMS", {})
    return {k for k in system.params if k in KNOWN_NAMES or (k in specs and getattr(specs[k], "known", False))}


def load_object(spec: str, what: str = "simulator") -> Any:
    """``module.path:Name`` or ``path/to/file.py:Name`` -> the object (a class, a factory); ``what`` names it in the
    errors (ValueError)."""
    target, _, name = spec.rpartition(":")
    if not target or not name:
        hint, noun = ("an env id, ", "Class") if what == "simulator" else ("", "name")
        raise ValueError(f"{what} {spec!r}: expected {hint}'package.module:{noun}' or 'path/to/file.py:{noun}'")
    module = _import_target(spec, target, what)
    obj: object = module
    for part in name.split("."):  # a nested name: module:Outer.Inner
        obj = getattr(obj, part, None)
        if obj is None:
            public = sorted(k for k, v in vars(module).items()
                            if isinstance(v, type) and issubclass(v, System) and v is not System)
            there = f" (System subclasses there: {public or 'none'})" if what == "simulator" else ""
            raise ValueError(f"{what} {spec!r}: {target!r} has no attribute {name!r}{there}")
    return obj


def _import_target(spec: str, target: str, what: str) -> Any:
    """The module of ``target``: a file path ending in .py, else an importable module name."""
    if not target.endswith(".py"):
        try:
            return importlib.import_module(target)
        except Exception as exc:
            raise ValueError(f"{what} {spec!r}: cannot import module {target!r}: {type(exc).__name__}: {exc}") from None
    path = Path(target).expanduser()
    if not path.is_file():
        raise ValueError(f"{what} {spec!r}: file {str(path)!r} not found")
    mod_name = f"_phast_user_sim_{abs(hash(str(path.resolve())))}"
    loader_spec = importlib.util.spec_from_file_location(mod_name, path)
    if loader_spec is None or loader_spec.loader is None:
        raise ValueError(f"{what} {spec!r}: cannot load {str(path)!r} as a Python module")
    module = importlib.util.module_from_spec(loader_spec)
    sys.modules[mod_name] = module
    try:
        loader_spec.loader.exec_module(module)
    except Exception as exc:
        sys.modules.pop(mod_name, None)
        raise ValueError(f"{what} {spec!r}: importing {str(path)!r} failed: {type(exc).__name__}: {exc}") from None
    return module


def _load_class(spec: str) -> type:
    """``module.path:Class`` or ``path/to/file.py:Class`` -> the class object."""
    cls: type = load_object(spec, "simulator")
    return cls


def _check_system_class(cls: object, name: str) -> type[System]:
    if not isinstance(cls, type) or not issubclass(cls, System):
        raise ValueError(f"simulator {name!r} is not a phast_gym.systems.System subclass (got {cls!r}); "
                         "see docs/describe_your_rig.md")
    return cls


def _check_interface(system: System, name: str) -> None:
    """Call every method the tool uses once, on two sampled states, so a missing or malformed method is reported
    here (naming it) and not deep inside a fit."""
    n = system.n
    where = f"simulator {name!r}"

    def call(method: str, *args: Any) -> Any:
        try:
            return getattr(system, method)(*args)
        except Exception as exc:
            raise ValueError(f"{where}: {type(system).__name__}.{method} failed: {type(exc).__name__}: {exc}") from None

    def vector(method: str, value: object) -> None:
        if not isinstance(value, (tuple, list)) or len(value) != n:
            raise ValueError(f"{where}: {type(system).__name__}.{method} must return a tuple of n={n} components, got "
                             f"{value!r}")
        if not all(np.all(np.isfinite(np.asarray(c, dtype=np.float64))) for c in value):
            raise ValueError(f"{where}: {type(system).__name__}.{method} returned NaN/inf at a sampled state")

    x = np.asarray(call("sample_initial", np.random.default_rng(0), 2), dtype=np.float64)
    if x.shape != (2, 2 * n):
        raise ValueError(f"{where}: sample_initial(rng, 2) must return an array of shape (2, 2n) = (2, {2 * n}), got "
                         f"{x.shape}")
    q, p = tuple(x[:, i] for i in range(n)), tuple(x[:, n + i] for i in range(n))
    if not np.all(np.isfinite(np.asarray(call("potential", q, NUMPY), dtype=np.float64))):
        raise ValueError(f"{where}: {type(system).__name__}.potential returned NaN/inf at a sampled state")
    for method in ("grad_potential", "damping"):
        vector(method, call(method, q, NUMPY))
    M = call("mass_matrix", q, NUMPY)
    if (not isinstance(M, (tuple, list)) or len(M) != n
            or any(not isinstance(r, (tuple, list)) or len(r) != n for r in M)):
        raise ValueError(f"{where}: {type(system).__name__}.mass_matrix must return an n x n nested tuple (n={n})")
    for method in ("velocity", "dH_dq"):
        vector(method, call(method, q, p, NUMPY))
    qdot, pdot = call("rhs", q, p, tuple(np.zeros(2) for _ in range(n)), NUMPY)
    vector("rhs (qdot)", qdot)
    vector("rhs (pdot)", pdot)


#: file suffixes read as MuJoCo models
MODEL_SUFFIXES = (".xml", ".mjcf", ".urdf")


def is_model_file(sim: object) -> bool:
    """Whether ``sim`` names a MuJoCo model file (MJCF / URDF) rather than an env id or a class."""
    return isinstance(sim, (str, Path)) and str(sim).lower().endswith(MODEL_SUFFIXES)


def _model_file_simulator(path: str, kw: dict[str, Any]) -> Simulator:
    from phast_gym.systems.mjcf import mjcf_system

    return Simulator(path, mjcf_system(path), kw)


def load_simulator(sim: str | type[System] | Simulator, kwargs: Mapping[str, Any] | None = None) -> Simulator:
    """Resolve ``sim`` (env id, ``module:Class``, ``file.py:Class``, a System subclass or a Simulator) and check that
    it builds with ``kwargs`` into a port-Hamiltonian system.  Every problem raises a ValueError naming it."""
    kw = dict(kwargs or {})
    if isinstance(sim, Simulator):
        out = Simulator(sim.name, sim.factory, {**sim.kwargs, **kw})
    elif isinstance(sim, type):
        cls = _check_system_class(sim, getattr(sim, "__name__", repr(sim)))
        out = Simulator(f"{cls.__module__}:{cls.__qualname__}", cls, kw)
    elif not isinstance(sim, str) or not sim.strip():
        raise ValueError(f"simulator must be an env id or 'module:Class' / 'file.py:Class', got {sim!r}")
    elif is_model_file(sim):
        out = _model_file_simulator(sim, kw)
    elif ":" in sim and not sim.startswith("phast_gym:"):
        cls = _check_system_class(_load_class(sim), sim)
        out = Simulator(sim, cls, kw)
    else:
        try:
            env_id = resolve_env_id(sim)
        except Exception as exc:  # gymnasium's UnregisteredEnv
            raise ValueError(f"unknown simulator {sim!r}: {exc}") from None
        phys = {k: v for k, v in kw.items() if k not in ENV_KWARGS}
        out = Simulator(env_id, lambda **k: make_env_system(env_id, **k), phys)
    try:
        system = out.build()
    except Exception as exc:
        raise ValueError(f"simulator {out.name!r} failed to build with kwargs {out.kwargs}: {type(exc).__name__}: "
                         f"{exc}") from None
    if not isinstance(system, System):
        raise ValueError(f"simulator {out.name!r} built {type(system).__name__}, not a phast_gym System")
    if not system.hamiltonian_system:
        raise ValueError(f"{out.name} is not a port-Hamiltonian system (no H, M, D to augment); the mismatch tool "
                         "needs one")
    _check_interface(system, out.name)
    return out
