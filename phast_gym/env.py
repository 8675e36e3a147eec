"""One generic port-Hamiltonian Gymnasium env, driven by a :class:`System`.

Observation: q only (angles wrapped into [-pi, pi)), optionally noisy, or the
full state with ``observe="qp"``.  Action: the port input u (torque, force or
voltage) on the actuated coordinates, ``G`` = the selected columns of I.
See docs/envs.md for the contract; every registered id documents its
system's parameters in :mod:`phast_gym.systems`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from . import integrate
from .reward import regulation_reward
from .systems import SCALAR, ParameterError, System, make_system

_TWO_PI = 2.0 * math.pi


def _real_array(x: object, what: str, err: type[Exception]) -> np.ndarray:
    """``x`` as a float64 array if it holds real numbers (bool, int, float); complex values (whose imaginary part
    would be dropped), strings and objects raise ``err`` naming ``what``."""
    try:
        raw = np.asarray(x)
    except (TypeError, ValueError) as exc:
        raise err(f"{what} must be real numbers: {exc}") from None
    if raw.dtype.kind not in "biuf":
        kind = {"c": "complex", "U": "string", "S": "bytes", "O": "object"}.get(raw.dtype.kind, str(raw.dtype))
        raise err(f"{what} must be real numbers, got {kind} values {x!r}")
    return raw.astype(np.float64)


def parse_actuated_dofs(actuated_dofs: Sequence[int] | None, n: int) -> tuple[int, ...]:
    """Distinct integer indices in [0, n) (default: all n); anything else (0.5, True, duplicates) is a
    ParameterError."""
    if actuated_dofs is None:
        return tuple(range(n))
    try:
        vals = list(np.asarray(actuated_dofs, dtype=object).reshape(-1))
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"actuated_dofs must be distinct indices in [0, {n}): {exc}") from None
    if not all(isinstance(i, (int, np.integer)) and not isinstance(i, (bool, np.bool_)) for i in vals):
        raise ParameterError(f"actuated_dofs must be integer indices in [0, {n}), got {list(actuated_dofs)}")
    dofs = [int(i) for i in vals]
    if not dofs or len(set(dofs)) != len(dofs) or any(not 0 <= i < n for i in dofs):
        raise ParameterError(f"actuated_dofs must be distinct indices in [0, {n}), got {dofs}")
    return tuple(dofs)


def _parse_target(target: Sequence[float] | None, n: int) -> list[float]:
    """The control target q* as n finite floats (default: the origin)."""
    if target is None:
        return [0.0] * n
    out = [float(v) for v in _real_array(target, "target", ParameterError).reshape(-1)]
    if len(out) != n:
        raise ParameterError(f"target must have length {n}, got {len(out)}")
    if not all(math.isfinite(v) for v in out):
        raise ParameterError(f"target must be finite, got {out}")
    return out


def _observation_space(angle: list[bool], observe: str, dtype: np.dtype) -> spaces.Box:
    """Wrapped angles in [-pi, pi], other coordinates (and p, when observed) unbounded."""
    lo = np.array([-math.pi if a else -np.inf for a in angle])
    hi = np.array([math.pi if a else np.inf for a in angle])
    if observe == "qp":
        lo = np.concatenate([lo, np.full(len(angle), -np.inf)])
        hi = np.concatenate([hi, np.full(len(angle), np.inf)])
    return spaces.Box(lo.astype(dtype), hi.astype(dtype), dtype=dtype)


class PortHamiltonianEnv(gym.Env):
    """A q-only port-Hamiltonian system with a torque/force port as its action.

    ## Dynamics
    ``qdot = dH/dp``, ``pdot = -dH/dq - D(q) qdot + G u``, integrated with
    RK4 substeps (split at kinks of the damping law), zero-order hold on u.

    ## Observation
    ``q`` (n,), angles wrapped into ``[-pi, pi)``, plus ``N(0, obs_noise_std^2)``
    noise; ``observe="qp"`` returns ``(q, p)`` (2n,).

    ## Action
    ``Box(-max_action, max_action, (m,))``: generalized forces on
    ``actuated_dofs`` (default: all n).  Out-of-range actions are clipped
    (``info["action_clipped"]``); NaN/inf or wrongly shaped actions raise
    ``ValueError`` and leave the env unchanged.

    ## Reward
    ``-(|wrap(q - target)|^2 + 0.1 |qdot|^2 + 0.001 |u|^2)`` (:func:`phast_gym.reward.regulation_reward`).

    ## Info
    ``state`` (true (q, p), unwrapped), ``energy`` (H), ``damping`` (diag of
    D(q)), ``t`` (seconds since reset), ``action_clipped`` (steps only).

    ## Arguments
    system: name of the system or a :class:`System` instance; actuated_dofs;
    max_action; obs_noise_std; observe ("q" or "qp"); dtype (float32
    default); target; render_mode ("rgb_array"); substeps (integration
    accuracy override); and the system's physical parameters as kwargs.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}

    def __init__(
        self,
        system: str | System,
        *,
        actuated_dofs: Sequence[int] | None = None,
        max_action: float | None = None,
        obs_noise_std: float = 0.0,
        observe: str = "q",
        dtype: npt.DTypeLike = np.float32,
        target: Sequence[float] | None = None,
        render_mode: str | None = None,
        substeps: int | None = None,
        **params: object,
    ) -> None:
        if isinstance(system, System):
            if params:
                raise ParameterError("pass physical parameters to the System, not alongside an instance")
            self.system = system
        else:
            self.system = make_system(system, **params)
        sysm = self.system
        n = sysm.n
        self.n = n
        self.dt = float(sysm.dt)
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.dt))}
        if substeps is not None and (int(substeps) != substeps or substeps < 1):
            raise ParameterError(f"substeps must be a positive integer, got {substeps!r}")
        self.substeps = int(substeps) if substeps is not None else sysm.substeps

        self.actuated_dofs = parse_actuated_dofs(actuated_dofs, n)
        self.m = len(self.actuated_dofs)
        self.max_action = float(sysm.default_max_action if max_action is None else max_action)
        if not (self.max_action > 0 and math.isfinite(self.max_action)):
            raise ParameterError(f"max_action must be positive and finite, got {max_action!r}")
        self.obs_noise_std = float(obs_noise_std)
        if not (self.obs_noise_std >= 0 and math.isfinite(self.obs_noise_std)):
            raise ParameterError(f"obs_noise_std must be >= 0, got {obs_noise_std!r}")
        if observe not in ("q", "qp"):
            raise ParameterError(f"observe must be 'q' or 'qp', got {observe!r}")
        self.observe = observe
        self.dtype = np.dtype(dtype)
        if self.dtype not in (np.float32, np.float64):
            raise ParameterError(f"dtype must be float32 or float64, got {self.dtype}")
        self.target = _parse_target(target, n)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ParameterError(f"render_mode must be one of {self.metadata['render_modes']}, got {render_mode!r}")
        self.render_mode = render_mode

        self._angle = [i in sysm.angle_dims for i in range(n)]
        self._G = np.eye(n)[:, list(self.actuated_dofs)]
        self.observation_space = _observation_space(self._angle, observe, self.dtype)
        self.action_space = spaces.Box(-self.max_action, self.max_action, shape=(self.m,), dtype=self.dtype)
        self._q: list[float] = [0.0] * n
        self._p: list[float] = [0.0] * n
        self._t = 0.0
        self._last_u: list[float] = [0.0] * self.m
        self._action_shape = (self.m,)
        self._has_damping = sysm.has_damping()
        self._stochastic = sysm.stochastic
        self._plain_obs = observe == "q" and self.obs_noise_std == 0.0

    # ------------------------------------------------------------------ helpers
    @property
    def state(self) -> np.ndarray:
        """True state (q, p), angles unwrapped, float64 (2n,)."""
        return np.array(self._q + self._p)

    def _wrap_obs(self, v: list[float]) -> list[float]:
        return [((x + math.pi) % _TWO_PI - math.pi) if a else x for x, a in zip(v, self._angle)]

    def _obs(self) -> np.ndarray:
        q = self._q
        if self._plain_obs:  # q only, no noise: the common case, kept cheap
            return np.array([((x + math.pi) % _TWO_PI - math.pi) if a else x for x, a in zip(q, self._angle)],
                            dtype=self.dtype)
        if self.observe == "qp":
            vals = q + self._p
            if self.obs_noise_std > 0:
                vals = list(np.add(vals, self.np_random.normal(0.0, self.obs_noise_std, 2 * self.n)))
            vals = self._wrap_obs(vals[: self.n]) + vals[self.n :]
        else:
            if self.obs_noise_std > 0:
                q = list(np.add(q, self.np_random.normal(0.0, self.obs_noise_std, self.n)))
            vals = self._wrap_obs(q)
        return np.array(vals, dtype=self.dtype)

    def _info(self) -> dict[str, np.ndarray | float]:
        sysm = self.system
        q = self._q
        if self._has_damping:
            damping = np.array(sysm.damping(q, SCALAR), dtype=np.float64)
        else:
            damping = np.zeros(self.n)
        return {
            "state": np.array(q + self._p),
            "energy": float(sysm.energy(q, self._p, SCALAR)),
            "damping": damping,
            "t": self._t,
        }

    # ------------------------------------------------------------------ API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        n = self.n
        x0 = None
        if options and options.get("state") is not None:  # validated before anything changes (seed included)
            x0 = _real_array(options["state"], "options['state']", ValueError).reshape(-1)
            if x0.shape != (2 * n,):
                raise ValueError(f"options['state'] must have length 2n = {2 * n} (q then p), "
                                 f"got shape {np.shape(options['state'])}")
            if not np.all(np.isfinite(x0)):
                raise ValueError(f"options['state'] must be finite, got {x0}")
            self._check_state(x0)
        super().reset(seed=seed)
        if x0 is None:
            x0 = self.system.sample_initial(self.np_random, 1)[0]
        self._q = [float(v) for v in x0[:n]]
        self._p = [float(v) for v in x0[n:]]
        self._t = 0.0
        self._last_u = [0.0] * self.m
        return self._obs(), self._info()

    def _check_state(self, x0: np.ndarray) -> None:
        """A state the physics is defined at (energy, forces and damping finite), checked before anything is
        assigned: e.g. coincident Lennard-Jones particles are a ValueError and the env keeps its state."""
        n, sysm = self.n, self.system
        q, p = [float(v) for v in x0[:n]], [float(v) for v in x0[n:]]
        try:
            with np.errstate(all="raise"):
                qdot, pdot = sysm.rhs(q, p, None, SCALAR)
                vals = [sysm.energy(q, p, SCALAR), *qdot, *pdot]
                if self._has_damping:
                    vals += list(sysm.damping(q, SCALAR))
            finite = all(math.isfinite(float(v)) for v in vals)
        except (ZeroDivisionError, OverflowError, FloatingPointError, ValueError) as exc:
            raise ValueError(f"options['state'] {x0.tolist()} is outside the domain of {sysm.name} "
                             f"({type(exc).__name__}: {exc}); the env keeps its previous state") from None
        if not finite:
            raise ValueError(f"options['state'] {x0.tolist()} gives non-finite energy or forces in {sysm.name}; "
                             "the env keeps its previous state")

    def _validate_action(self, action: object) -> tuple[list[float], bool]:
        """Action -> (clipped values as floats, clipped flag); ValueError on bad input (env untouched)."""
        if type(action) is np.ndarray and action.shape == self._action_shape and action.dtype.kind == "f":
            vals = action.tolist()  # fast path: the usual float array of the right shape
        else:
            a = _real_array(action, "action", ValueError)
            if a.shape != self._action_shape:
                raise ValueError(f"action must have shape ({self.m},) (actuated dofs {list(self.actuated_dofs)}), "
                                 f"got {a.shape}")
            vals = a.tolist()
        hi = self.max_action
        out = []
        clipped = False
        for v in vals:
            if not math.isfinite(v):
                raise ValueError(f"action must be finite, got {vals}")
            if v > hi:
                v, clipped = hi, True
            elif v < -hi:
                v, clipped = -hi, True
            out.append(float(v))
        return out, clipped

    def step(self, action: object) -> tuple[np.ndarray, float, bool, bool, dict]:
        u, clipped = self._validate_action(action)
        sysm = self.system
        if self.m == self.n:
            u_full = u
        else:
            u_full = [0.0] * self.n
            for i, ui in zip(self.actuated_dofs, u):
                u_full[i] = ui
        # the scalar integrator returns lists of Python floats (inputs are floats): no conversion needed
        q, p = integrate.step(sysm, self._q, self._p, u_full, SCALAR, dt=self.dt, substeps=self.substeps)
        if self._stochastic:
            p = [float(v) for v in sysm.stochastic_kick(np.array(p), self.np_random)]
        self._q, self._p = q, p
        self._t += self.dt
        self._last_u = u
        v = sysm.velocity(q, p, SCALAR)
        err = 0.0
        for qi, ti, ang in zip(q, self.target, self._angle):
            e = qi - ti
            if ang:
                e = (e + math.pi) % _TWO_PI - math.pi
            err += e * e
        reward = regulation_reward(err, sum(vi * vi for vi in v), sum(ui * ui for ui in u))
        info = self._info()
        info["action_clipped"] = clipped
        return self._obs(), float(reward), False, False, info

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        from .render import render_frame

        return render_frame(self.system, np.array(self._q), u=np.array(self._last_u), actuated_dofs=self.actuated_dofs,
                            p=np.array(self._p))
