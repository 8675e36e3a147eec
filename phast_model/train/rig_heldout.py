"""The held-out score of a rig's world model (``phast-train --recordings``): every model (PHAST, the nominal rig as a
KNOWN model, a compared phast_gym system, a sequence baseline) on the same held-out windows, each after a burn-in (its
state fitted to it, or a sequence model's warm-up of observed positions), then open loop with the recorded u; RMSE of
q, wrapped on angles."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypedDict

import numpy as np
import torch

from phast_gym.systems import System

from ..identify.recordings import Recordings
from ..identify.shooting import Shooter, Windows, estimate_noise, simulate_qv, smooth, substeps_for
from ..identify.simulators import is_model_file
from ..world.interfaces import ForecastModel, coordinate_error, wrap_angles
from ..world.model import PHAST
from .rig_fit import BURN_IN_S, SMOOTH_S, STATE_FIT_ITERS, check_window_room, fit_states, odd_samples, simulate


@dataclass(frozen=True)
class HeldoutWindows:
    """Held-out windows: ``burn`` samples to fit the state to, then ``H`` samples scored open loop."""

    q: torch.Tensor  # (W, burn + H, n)
    u: torch.Tensor | None
    burn: int
    H: int
    trajectory: np.ndarray  # (W,) held-out trajectory of each window
    start: np.ndarray  # (W,) first (burn-in) sample


def heldout_windows(rec: Recordings, window_s: float | None, burn_s: float = BURN_IN_S) -> HeldoutWindows:
    """Windows of ``window_s`` seconds (None: each whole recording after its burn-in), each after a burn-in."""
    burn = max(5, int(round(burn_s / rec.dt)))
    H = rec.T - burn if window_s is None else int(round(window_s / rec.dt))
    check_window_room(rec, burn + H, f"a {burn_s:g} s burn-in plus one {window_s if window_s else 'whole'} s window")
    starts = np.arange(0, rec.T - (burn + H) + 1, H)
    idx = starts[:, None] + np.arange(burn + H)[None, :]
    q = rec.q[:, idx].reshape(-1, burn + H, rec.n)
    u = None if rec.u is None else rec.u[:, idx[:, :-1]].reshape(-1, burn + H - 1, rec.n)
    traj = np.repeat(np.arange(rec.n_traj), len(starts))
    return HeldoutWindows(torch.as_tensor(q), None if u is None else torch.as_tensor(u), burn, H, traj,
                          np.tile(starts, rec.n_traj))


def smoothed(q: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Savitzky-Golay q and qdot of ``q`` (N, T, n) over about ``SMOOTH_S`` (at most the recordings' length)."""
    T = q.shape[1]
    return smooth(q, dt, min(odd_samples(SMOOTH_S, dt), T - (1 - T % 2)))


def burn_in_states(w: HeldoutWindows, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(W, n) q and qdot at every window's first sample, from Savitzky-Golay smoothing of its burn-in: where every
    model's state fit starts."""
    qs, vs = smoothed(w.q[:, : w.burn].numpy(), dt)
    return qs[:, 0], vs[:, 0]


@torch.no_grad()
def rollout_windows(model: PHAST, w: HeldoutWindows, dt: float) -> torch.Tensor:
    """(W, burn + H, n) open-loop q of ``model`` on the windows: the state fitted to the burn-in (started from
    Savitzky-Golay smoothing of it), then the recorded u."""
    model = model.double()
    qs, vs = burn_in_states(w, dt)
    X = torch.as_tensor(np.concatenate([qs, vs], -1))
    ub = None if w.u is None else w.u[:, : w.burn - 1]
    X = fit_states(model, X, w.q[:, : w.burn], ub, iters=4)
    return simulate(model, X, w.u, w.burn + w.H - 1)


def system_rollouts(system: System, w: HeldoutWindows, dt: float, angle_dims: tuple[int, ...]) -> torch.Tensor:
    """(W, burn + H, n) open-loop q of a phast_gym ``System`` (a compared model: the phast-mismatch augmented
    model, an identified model written as a rig) on the windows: the state started like PHAST's
    (:func:`burn_in_states`), fitted to the burn-in by the mismatch tool's window-state Gauss-Newton with the
    system's own simulation, then the recorded u."""
    qs, vs = burn_in_states(w, dt)
    unmeasure = getattr(system, "unmeasure", lambda y: y)
    X0 = np.concatenate([unmeasure(qs), vs], axis=-1)
    x_scale = np.concatenate([np.sqrt(np.mean(qs**2, 0)), np.sqrt(np.mean(vs**2, 0))]) + 1e-9
    sigma = np.maximum(estimate_noise(w.q.numpy()), 1e-6)
    sub = int(substeps_for(system, dt))
    q, u = w.q.numpy(), None if w.u is None else w.u.numpy()
    count = q.shape[0]
    burn = Windows(np.arange(count), np.zeros(count, dtype=int), w.burn, q[:, : w.burn],
                   None if u is None else u[:, : w.burn - 1], angle_dims, dt)
    X = Shooter(burn, sigma, sub, x_scale).fit_states(system, X0, STATE_FIT_ITERS).X
    n = qs.shape[-1]
    return torch.as_tensor(simulate_qv(system, X[:, :n], X[:, n:], w.burn + w.H - 1, u, dt, sub))


@torch.no_grad()
def forecast_rollouts(model: ForecastModel, w: HeldoutWindows) -> torch.Tensor:
    """(W, burn + H, n) open-loop q of a sequence model (a :class:`ForecastModel`: the baselines) on the windows: the
    burn-in's measured q is its warm-up (the samples PHAST's state is fitted to), then ``model.rollout`` with the
    recorded u over the window; the burn-in part of the result is the measured q (not scored)."""
    dtype = next(iter(model.parameters())).dtype
    u = None if w.u is None or model.m == 0 else w.u.to(dtype)
    pred = model.rollout(w.q[:, : w.burn].to(dtype), u, w.H).to(w.q.dtype)
    return torch.cat([w.q[:, : w.burn], pred], 1)


def nominal_source(sim: str) -> str:
    """How :func:`nominal_entries` scores the nominal rig: ``"mujoco"`` (a model file) or ``"phast_known"``."""
    return "mujoco" if is_model_file(sim) else "phast_known"


def nominal_entries(nominal: PHAST, sim: str, compare: Mapping[str, System] | None
                    ) -> tuple[dict[str, PHAST], Mapping[str, System] | None]:
    """The nominal rig's entry for :func:`heldout_rollouts`, as (PHAST models, compared systems): the rig as a KNOWN
    PHAST model, or, for a MuJoCo model file, the file as MuJoCo simulates it (what the file means: on a geared arm
    whose file leaves out the motors the recorded torques spin the light links up, and a 10-ms step of PHAST's
    integrator overflows where MuJoCo's own step does not; the UR10e's nominal score was inf)."""
    if nominal_source(sim) == "phast_known":
        return {"nominal": nominal}, compare
    from ..identify.mujoco_sim import mujoco_simulated

    if "nominal" in (compare or {}):
        raise ValueError("compare: 'nominal' is the rig's own score; name the compared model otherwise")
    return {}, {"nominal": mujoco_simulated(sim), **(compare or {})}


class HeldoutScore(TypedDict):
    """One model's score on the held-out windows."""

    rollout_rmse: float
    per_window_rmse: list[float]


def _score(sim: torch.Tensor, w: HeldoutWindows, angle_dims: tuple[int, ...]) -> HeldoutScore:
    err = coordinate_error(sim[:, w.burn:], w.q[:, w.burn:], angle_dims)
    rmse = float(torch.sqrt((err ** 2).mean()))
    return {"rollout_rmse": rmse if math.isfinite(rmse) else float("inf"),
            "per_window_rmse": [float(x) for x in torch.sqrt((err ** 2).mean((1, 2)))]}


def heldout_rollouts(models: dict[str, PHAST], rec: Recordings, window_s: float | None, burn_s: float = BURN_IN_S,
                     compare: Mapping[str, System] | None = None,
                     forecasters: Mapping[str, ForecastModel] | None = None
                     ) -> tuple[dict[str, Any], dict[str, np.ndarray], HeldoutWindows]:
    """``{name: {"rollout_rmse", "per_window_rmse"}}`` of every model on the held-out windows (the same windows,
    the same burn-in, the same error), plus the rollouts themselves (plots) and the windows.  ``compare``: phast_gym
    systems scored beside the PHAST models (:func:`system_rollouts`); ``forecasters``: sequence models, the burn-in
    their warm-up (:func:`forecast_rollouts`)."""
    w = heldout_windows(rec, window_s, burn_s)
    sims = {name: (rollout_windows(model, w, rec.dt), tuple(model.angle_dims)) for name, model in models.items()}
    for name, forecaster in (forecasters or {}).items():
        if name in sims:
            raise ValueError(f"forecasters: {name!r} is already a scored model's name ({sorted(sims)})")
        sims[name] = (forecast_rollouts(forecaster, w), tuple(rec.angle_dims))
    for name, system in (compare or {}).items():
        if name in sims:
            raise ValueError(f"compare: {name!r} is already a scored model's name ({sorted(sims)})")
        if not isinstance(system, System):
            raise TypeError(f"compare: {name!r} must be a phast_gym System (built), got {type(system).__name__}")
        sims[name] = (system_rollouts(system, w, rec.dt, tuple(rec.angle_dims)), tuple(rec.angle_dims))
    out = {name: _score(sim, w, dims) for name, (sim, dims) in sims.items()}
    rolls = {name: wrap_angles(sim, dims).numpy() for name, (sim, dims) in sims.items()}
    meta = {"n_windows": int(w.q.shape[0]), "window_s": None if window_s is None else float(window_s),
            "burn_in_s": float(burn_s), "window_samples": int(w.H), "burn_in_samples": int(w.burn),
            "dt": float(rec.dt)}
    return {**out, **meta}, rolls, w
