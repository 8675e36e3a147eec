"""Plots of a trained run on its test split (what ``phast-train`` draws into the run directory).

Wrapped angles are drawn with a break where they wrap (:func:`phast_gym.systems.break_at_wraps`), not with a
vertical line across ``[-pi, pi)``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.systems import break_at_wraps, fd_velocity


def _save(plt: Any, fig: Any, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _angle_series(y: np.ndarray, is_angle: bool) -> np.ndarray:
    return break_at_wraps(y) if is_angle else y


def make_plots(model: Any, test: Any, out: Path, burn_in: int = 10, H: int = 100, n_show: int = 4) -> list[Path]:
    """rollout.png (rollout vs truth), phase.png, damping.png (learned vs true), energy.png; returns the paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .metrics import env_energy
    from .rollout import batched_rollout

    q = np.asarray(test.q[:n_show])
    H = min(H, q.shape[1] - burn_in)
    roll = batched_rollout(model, q, test.u[:n_show], burn_in, H)
    t = np.arange(q.shape[1]) * test.dt
    ang = tuple(model.angle_dims)
    paths = []
    n = q.shape[-1]
    fig, axes = plt.subplots(n, 1, figsize=(8, 2.2 * n), squeeze=False)
    for i in range(n):
        ax = axes[i, 0]
        for b in range(n_show):
            ln, = ax.plot(t[: burn_in + H], _angle_series(q[b, : burn_in + H, i], i in ang), lw=1)
            ax.plot(t[burn_in:burn_in + H], _angle_series(roll[b, :, i], i in ang), "--", color=ln.get_color(), lw=1)
        ax.axvline(t[burn_in - 1], color="k", lw=0.5)
        ax.set_ylabel(f"q{i}")
    axes[-1, 0].set_xlabel("t [s] (solid: truth, dashed: PHAST rollout after burn-in)")
    paths.append(_save(plt, fig, out / "rollout.png"))

    def truth_and_rollout(b: int) -> tuple[np.ndarray, np.ndarray]:
        """Trajectory b from the last burn-in sample on, and its rollout behind the same first sample (1, H+1, n)."""
        truth = q[b:b + 1, burn_in - 1:burn_in + H]
        return truth, np.concatenate([truth[:, :1], roll[b:b + 1]], 1)

    fig, ax = plt.subplots(figsize=(5, 4))
    for b in range(n_show):
        truth, pred = truth_and_rollout(b)
        ln, = ax.plot(_angle_series(truth[0, 1:, 0], 0 in ang), fd_velocity(truth, test.dt, ang)[0, :, 0], lw=1)
        ax.plot(_angle_series(pred[0, 1:, 0], 0 in ang), fd_velocity(pred, test.dt, ang)[0, :, 0], "--", color=ln.get_color(), lw=1)
    ax.set_xlabel("q0")
    ax.set_ylabel("finite-difference qdot0")
    ax.set_title("phase portrait (solid truth, dashed rollout)")
    paths.append(_save(plt, fig, out / "phase.png"))

    if getattr(model, "damping", None) is not None:
        import torch

        qa = np.asarray(test.q[: min(64, len(test.q))]).reshape(-1, n)
        with torch.no_grad():
            dh = model.damping_diag(torch.as_tensor(qa, dtype=next(model.parameters()).dtype)).numpy()
        d = np.asarray(test.damping[: min(64, len(test.q))]).reshape(-1, n)
        fig, axes = plt.subplots(1, n, figsize=(4 * n, 3.2), squeeze=False)
        for i in range(n):
            ax = axes[0, i]
            ax.scatter(qa[:, i], d[:, i], s=2, label="true D_ii(q)")
            ax.scatter(qa[:, i], dh[:, i], s=2, label="learned D_ii(q)")
            ax.set_xlabel(f"q{i}")
            ax.legend(markerscale=4, fontsize=7)
        paths.append(_save(plt, fig, out / "damping.png"))

    from phast_gym import make_env_system

    if make_env_system(test.env_id).hamiltonian_system:
        fig, ax = plt.subplots(figsize=(6, 3.5))
        for b in range(n_show):
            truth, pred = truth_and_rollout(b)
            ln, = ax.plot(t[burn_in:burn_in + H], env_energy(test.env_id, truth, test.dt, ang)[0], lw=1)
            ax.plot(t[burn_in:burn_in + H], env_energy(test.env_id, pred, test.dt, ang)[0], "--", color=ln.get_color(), lw=1)
        ax.set_xlabel("t [s]")
        ax.set_ylabel("env H (FD velocities)")
        ax.set_title("energy along the rollout (solid truth, dashed PHAST)")
        paths.append(_save(plt, fig, out / "energy.png"))
    return paths
