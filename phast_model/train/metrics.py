"""Test metrics with the paper's Table 16 keys (Appendix F, Eq. 89-96).

Per-coordinate squared errors are averaged over coordinates, steps and trajectories;
angular coordinates use wrapped differences.  Rollout metrics at horizon H average the
first H open-loop steps after a burn-in of K = 10 true samples.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import torch

from phast_gym import make_env_system, resolve_env_id
from phast_gym.systems import NUMPY, System, angle_diff, fd_velocity, split

from ..world.envinfo import ENV_INFO
from ..world.interfaces import DampingModel, ForecastModel, TimedTrajectories, Trajectories
from ..world.rollout import batched_predict, batched_rollout


def benchmark_metric(env_id: str) -> str:
    """Key of the paper's Table 4 metric for ``env_id`` (angular envs: wrapped rollout MSE at H = 100)."""
    env_id = resolve_env_id(env_id)
    return ENV_INFO[env_id].metric


def squared_error(pred: np.ndarray, target: np.ndarray, angle_dims: tuple[int, ...]) -> np.ndarray:
    """Elementwise squared error, wrapped on the angle coordinates."""
    e = angle_diff(pred, target, angle_dims)
    return e * e


def error_keys(prefix: str, se: np.ndarray, angle_dims: tuple[int, ...], suffix: str = "") -> dict[str, float]:
    """theta_wrap_mse / mse / mixed_mse from squared errors (..., n)."""
    n = se.shape[-1]
    eu = [i for i in range(n) if i not in angle_dims]
    out = {f"{prefix}mse{suffix}": float(se.mean())}
    if angle_dims:
        out[f"{prefix}theta_wrap_mse{suffix}"] = float(se[..., list(angle_dims)].mean())
    if angle_dims and eu:
        out[f"{prefix}mixed_mse{suffix}"] = 0.5 * (float(se[..., eu].mean()) + float(se[..., list(angle_dims)].mean()))
    return out


def _fd_energy(system: System, q: np.ndarray, dt: float, angle_dims: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(H(q_{h+1}, M(q_{h+1}) v_h) (..., T-1), v (..., T-1, n)) with v_h = wrapped (q_{h+1} - q_h) / dt."""
    v = fd_velocity(q, dt, angle_dims)
    qs = split(q[..., 1:, :])
    H = np.asarray(system.hamiltonian(qs, system.momentum(qs, split(v), NUMPY), NUMPY))
    return H * np.ones(v.shape[:-1]), v


def env_energy(env: System | str, q: np.ndarray, dt: float, angle_dims: tuple[int, ...],
               env_kwargs: Mapping[str, object] | None = None) -> np.ndarray:
    """The env's energy H(q, M(q) qdot_fd) along trajectories (..., T, n) -> (..., T-1), through the system's own
    functions (finite-difference velocities, wrapped on angles); ``env`` is the system (e.g. a dataset's
    ``system``) or an env id built with ``env_kwargs``.  ValueError for a system with no mechanical energy."""
    system = make_env_system(env, **(env_kwargs or {})) if isinstance(env, str) else env
    if not system.hamiltonian_system:  # e.g. predator-prey: no M(q), its invariant needs the unobserved latent
        raise ValueError(f"{env if isinstance(env, str) else system.name} is not port-Hamiltonian: "
                         "no energy H(q, M(q) qdot)")
    return _fd_energy(system, q, dt, angle_dims)[0]


def energy_diagnostics(system: System, q_roll: np.ndarray, dt: float, angle_dims: tuple[int, ...],
                       tol: float = 1e-6) -> tuple[float, float]:
    """(energy-budget residual Eq. 96, passivity-violation rate Eq. 94) of rollouts q_roll (N, H+1, n),
    from finite-difference velocities and ``system``'s analytic H and D (the data's physics: ``Dataset.system``)."""
    Hh, v = _fd_energy(system, q_roll, dt, angle_dims)  # H_env(q_{h+1}, v_h), (N, H)
    dH = Hh[:, 1:] - Hh[:, :-1]
    d = np.stack(np.broadcast_arrays(*system.damping(split(q_roll[:, 1:-1]), NUMPY)), -1)
    diss = (d * v[:, 1:] ** 2).sum(-1)
    rho = dH / dt + diss  # Eq. 96
    return float(np.abs(rho).mean()), float((dH > tol).mean())


def data_system(ds: Trajectories) -> System | None:
    """The physics that generated dataset ``ds``: its ``system`` (built once by :func:`phast_gym.make_dataset`),
    else one built from its ``env_id`` and the parameters in its ``config``; None without an env id."""
    system = getattr(ds, "system", None)
    if system is not None:
        return system
    env_id = getattr(ds, "env_id", None)
    return make_env_system(env_id, **_env_kwargs(ds)) if env_id else None


def forecast_metrics(model: ForecastModel, test: TimedTrajectories, horizons: tuple[int, ...] = (10, 50, 100),
                     burn_in: int = 10,
                     batch_size: int = 256, takeover: bool = True, energy: bool = True) -> dict[str, float]:
    """Table 16 metrics of ``model`` on ``test`` (a Dataset): one-step, autoregressive and takeover
    rollouts at each H, damping R^2 / MAE (models with a damping field), energy-budget residual and
    passivity violations from the data's H and D (:func:`data_system`; ``energy=False`` switches them off, e.g. for
    full-state inputs whose q are not positions), and the trainable parameter count."""
    q = np.asarray(test.q)
    u = getattr(test, "u", None)
    T = q.shape[1]
    horizons = tuple(int(h) for h in horizons if burn_in + int(h) <= T)
    if not horizons:
        raise ValueError(f"no horizon fits T={T} after burn_in={burn_in}")
    ang = tuple(model.angle_dims)
    out: dict[str, float] = {"n_parameters": float(model.n_parameters())}
    pred = batched_predict(model, q, u, batch_size)
    se1 = squared_error(pred[:, :-1], q[:, 1:], ang)
    out.update(error_keys("", se1, ang))  # Eq. 90: every next-step prediction
    # the same after the K = burn_in context (targets q_t, t >= K): free of the first steps' unobservable velocity
    out.update(error_keys("", se1[:, burn_in - 1:], ang, "_after_burnin"))
    Hmax = max(horizons)
    modes = [("rollout_", "autoregressive")]
    if takeover and hasattr(model, "rollout_takeover"):
        modes.append(("rollout_takeover_", "takeover"))
    system = data_system(test) if energy else None
    for prefix, mode in modes:
        roll = batched_rollout(model, q, u, burn_in, Hmax, mode, batch_size)
        se = squared_error(roll, q[:, burn_in:burn_in + Hmax], ang)
        for H in horizons:
            out.update(error_keys(prefix, se[:, :H], ang, f"_h{H}"))
            if mode == "autoregressive" and system is not None and system.hamiltonian_system and H >= 3:
                full = np.concatenate([q[:, burn_in - 1:burn_in], roll[:, :H]], 1)
                full = np.where(np.isfinite(full), full, np.nan)
                res, viol = energy_diagnostics(system, full, float(test.dt), ang)
                out[f"rollout_energy_budget_resid_h{H}"] = res
                out[f"rollout_passivity_violations_h{H}"] = viol
    if getattr(model, "damping", None) is not None and isinstance(model, DampingModel) and hasattr(test, "damping"):
        with torch.no_grad():
            dtype = next(model.parameters()).dtype
            d_hat = np.concatenate([model.damping_diag(torch.as_tensor(q[i:i + batch_size], dtype=dtype)).numpy()
                                    for i in range(0, q.shape[0], batch_size)], 0)
        out.update(damping_scores(d_hat, np.asarray(test.damping)))
    return {k: (float(v) if math.isfinite(v) else float("nan")) for k, v in out.items()}


def damping_scores(d_hat: np.ndarray, d: np.ndarray) -> dict[str, float]:
    """``damping_mae`` (Eq. 92) and ``damping_r2`` (Eq. 93) of the learned diag D against the truth along the test
    trajectories.  R^2 is NaN where the true D does not vary (a constant or zero damping): its denominator is then
    round-off, and the ratio would say nothing about the fit (the MAE does)."""
    spread = float(((d - d.mean()) ** 2).sum())
    sse = float(((d_hat - d) ** 2).sum())
    varies = spread > 1e-12 * max(float((d * d).sum()), 1e-300)
    return {"damping_r2": 1.0 - sse / spread if varies else float("nan"),
            "damping_mae": float(np.abs(d_hat - d).mean())}


def _env_kwargs(ds: Trajectories) -> dict[str, object]:
    """Physical parameters a dataset was generated with (non-default envs)."""
    cfg = getattr(ds, "config", {}) or {}
    params = cfg.get("params") or {}
    return {k: v for k, v in params.items() if v is not None}
