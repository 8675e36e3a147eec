"""Where the loop's data come from when the plant is not a simulation: a real machine behind a step function, and
recordings made before the loop started.

**A machine** (:class:`Machine`) is what a rig's driver gives: ``reset()`` brings the rig to its start by itself
(a pendulum left to hang still, a cart homed) and returns the measured coordinates q; ``step(u)`` applies the
inputs u (m,) for one control period ``dt`` seconds and returns the measured q (n,).  Nothing sets its state and
nothing reads its velocity.  A Gymnasium env whose observation is q and action u is a machine as it is
(``reset`` returning ``(obs, info)``, ``step`` the 5-tuple).  :func:`load_machine` calls a factory named as
``path/to/driver.py:make`` or ``module:make`` with keyword arguments; :class:`MachinePlant` adapts the machine to
the loop's plant interface, with the rig description (a phast_gym ``System``) for the coordinates' meaning.
On a machine the quiet criterion is judged on the measured angles (:func:`phast_model.rl.plant.quiet_metrics`):
there is nothing else.  The step function keeps the real-time clock (it returns at the next tick); the loop's
controller is called once per step in between.

**Recordings** (:func:`load_prior`) in the ``phast-train --recordings`` format, sampled at the loop's decision
rate, are learning data from before the loop: cut into pieces of one episode's length, they join the plant
episodes the world model is fitted to, and their seconds count as plant time used for learning.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from phast_gym.env import parse_actuated_dofs
from phast_gym.systems.base import System


class Machine(Protocol):
    """A rig behind a step function (module docstring): q-only measurements, inputs in, its own resets."""

    dt: float

    def reset(self) -> object: ...

    def step(self, u: np.ndarray) -> object: ...


def load_machine(spec: str, kwargs: dict[str, Any] | None = None) -> Machine:
    """The machine made by the factory ``spec`` called with ``kwargs`` (a class is a factory too); ValueError when
    it cannot be loaded or called, or lacks ``reset``, ``step`` or a positive ``dt``."""
    from ..identify.simulators import load_object

    factory = load_object(spec, "machine")
    if not callable(factory):
        raise ValueError(f"machine {spec!r} is not callable (a factory or class returning the machine), got "
                         f"{factory!r}")
    try:
        inspect.signature(factory).bind(**(kwargs or {}))
    except TypeError as exc:
        raise ValueError(f"machine {spec!r} does not take --machine-kwargs {sorted(kwargs or {})}: {exc}") from None
    except ValueError:  # a builtin without a signature: let the call decide
        pass
    machine = factory(**(kwargs or {}))
    missing = [k for k in ("reset", "step") if not callable(getattr(machine, k, None))]
    if missing:
        raise ValueError(f"machine {spec!r} returned {type(machine).__name__} without {missing}: a machine has "
                         "reset() -> q and step(u) -> q (docs/control.md, 'A machine of your own')")
    dt = machine_dt(machine)
    if not isinstance(dt, (int, float)) or not (dt > 0 and math.isfinite(dt)):
        raise ValueError(f"machine {spec!r}: its 'dt' (seconds per step) must be a positive number, got {dt!r}")
    return machine


def machine_dt(machine: object) -> Any:
    """The machine's ``dt``, or that of the env inside a Gymnasium wrapper (``gym.make`` wraps; wrappers do not
    forward attributes)."""
    dt = getattr(machine, "dt", None)
    return dt if dt is not None else getattr(getattr(machine, "unwrapped", None), "dt", None)


def _measured(out: object, n: int, where: str) -> np.ndarray:
    """q (n,) from what a machine returned: q itself, ``(q, info)`` or a Gymnasium step's 5-tuple."""
    q = out[0] if isinstance(out, tuple) else out
    q = np.asarray(q, dtype=np.float64).reshape(-1)
    if q.shape != (n,):
        raise ValueError(f"{where} returned {q.shape[0]} measured coordinates, the rig description has n={n}")
    if not np.all(np.isfinite(q)):
        raise ValueError(f"{where} returned a non-finite measurement {q.tolist()}")
    return q


class MachinePlant:
    """A :class:`Machine` as the loop's plant (the ``reset`` / ``step`` of a phast_gym env): the requested start
    state is ignored (the machine resets itself), inputs are clipped at ``max_action``, ``info["state"]`` holds the
    measured q and NaN momenta (nothing else is known), and the description ``system`` gives the coordinates'
    meaning (angles, the actuated ones)."""

    def __init__(self, machine: Machine, system: System, actuated_dofs: list[int] | None, max_action: float,
                 name: str = "machine") -> None:
        self.machine, self.system, self.name = machine, system, name
        self.n = int(system.n)
        self.actuated_dofs = list(parse_actuated_dofs(actuated_dofs, self.n))
        self.m = len(self.actuated_dofs)
        self.max_action = float(max_action)
        self.dt = float(machine_dt(machine))

    def _info(self, q: np.ndarray) -> dict[str, Any]:
        return {"state": np.concatenate([q, np.full(self.n, np.nan)]), "measured_only": True}

    def reset(self, seed: int | None = None,
              options: Mapping[str, object] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        q = _measured(self.machine.reset(), self.n, f"{self.name}.reset()")
        return q, self._info(q)

    def step(self, u: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        u = np.clip(np.asarray(u, dtype=np.float64).reshape(self.m), -self.max_action, self.max_action)
        q = _measured(self.machine.step(u), self.n, f"{self.name}.step(u)")
        return q, 0.0, False, False, self._info(q)

    def close(self) -> None:
        close = getattr(self.machine, "close", None)
        if callable(close):
            close()


# --------------------------------------------------------------------------- recordings from before the loop
@dataclass(frozen=True)
class Prior:
    """Recordings in the loop's format (:func:`phast_model.rl.plant.to_recordings`), cut to one episode's length,
    and the recorded seconds they came from (all of it counts as plant time used for learning)."""

    recordings: dict[str, Any]
    seconds: float
    source: str

    @property
    def pieces(self) -> int:
        return int(self.recordings["q"].shape[0])


def load_prior(path: str | Path | Mapping[str, object], system: System, actuated_dofs: list[int], decision_dt: float,
               episode_decisions: int) -> Prior:
    """Read recordings (the rig format: ``q`` (N, T, n), ``u`` (N, T-1, m), ``dt`` or ``t``) of the described rig,
    check them (:func:`phast_model.identify.recordings.validate`), check they are sampled at the loop's decision step
    and cut them into consecutive pieces of ``episode_decisions`` intervals; ValueError naming the problem."""
    from ..identify.recordings import load_raw, validate

    raw, src = load_raw(path)
    rec = validate(raw, system.n, tuple(system.angle_dims), src, min_samples=2,
                   actuated_dofs=tuple(actuated_dofs) if len(actuated_dofs) < system.n else None)
    if not rec.uniform:
        raise ValueError(f"{src}: the loop needs uniformly sampled recordings (its world model steps every "
                         f"{decision_dt} s)")
    if not math.isclose(rec.dt, decision_dt, rel_tol=1e-3):
        raise ValueError(f"{src}: sampled every {rec.dt:g} s, but the loop decides every {decision_dt:g} s; record at "
                         f"that rate or set the decision step (phast-rl --dt and the decision steps)")
    W = episode_decisions + 1
    if rec.T < W:
        raise ValueError(f"{src}: {rec.T} samples per recording, fewer than one episode's {W} "
                         f"({episode_decisions * decision_dt:g} s); lower --episode-s")
    seconds = float(rec.n_traj * (rec.T - 1) * rec.dt)
    L, k = W - 1, (rec.T - 1) // (W - 1)  # pieces share their boundary sample: every recorded interval is used once
    q = np.stack([rec.q[:, j * L: j * L + W] for j in range(k)], 1).reshape(-1, W, system.n)
    u = np.zeros((q.shape[0], L, len(actuated_dofs)))
    if rec.u is not None:
        u = np.stack([rec.u[:, j * L: j * L + L] for j in range(k)], 1).reshape(-1, L, system.n)[
            ..., list(actuated_dofs)]
    out: dict[str, Any] = {"q": q, "u": u, "dt": float(decision_dt),
                           "angle_dims": np.array(list(system.angle_dims), dtype=np.int64)}
    if len(actuated_dofs) < system.n:
        out["actuated_dofs"] = np.array(list(actuated_dofs), dtype=np.int64)
    return Prior(out, seconds, src)


def join_recordings(a: dict[str, Any] | None, b: dict[str, Any] | None) -> dict[str, Any]:
    """Two sets of loop recordings of the same piece length as one (``a``'s trajectories first)."""
    if a is None or b is None:
        out = a if b is None else b
        if out is None:
            raise ValueError("no recordings to fit the world model to")
        return out
    if a["q"].shape[1:] != b["q"].shape[1:]:
        raise ValueError(f"recordings of different piece shapes {a['q'].shape[1:]} and {b['q'].shape[1:]}")
    return {**a, "q": np.concatenate([a["q"], b["q"]]), "u": np.concatenate([a["u"], b["u"]])}
