"""Plots of a trained run on its test split (what ``phast-train`` draws into the run directory).

Wrapped angles are drawn with a break where they wrap (:func:`phast_gym.systems.break_at_wraps`), not with a
vertical line across ``[-pi, pi)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

import numpy as np

from phast_gym.systems import System, break_at_wraps, fd_velocity

from ..world.interfaces import ForecastModel

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from phast_gym.datasets import Dataset


def _save(plt: ModuleType, fig: Figure, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _angle_series(y: np.ndarray, is_angle: bool) -> np.ndarray:
    return break_at_wraps(y) if is_angle else y


@dataclass(frozen=True)
class RolloutView:
    """The test trajectories a run's plots show, their open-loop rollouts after the burn-in, and how to draw them."""

    q: np.ndarray  # (n_show, T, n) true positions
    roll: np.ndarray  # (n_show, H, n) rollout after the burn-in
    dt: float
    burn_in: int
    angles: tuple[int, ...]  # wrapped coordinates

    @property
    def H(self) -> int:
        return self.roll.shape[1]

    @property
    def t(self) -> np.ndarray:
        return np.arange(self.q.shape[1]) * self.dt

    def series(self, y: np.ndarray, i: int) -> np.ndarray:
        return _angle_series(y, i in self.angles)

    def truth_and_rollout(self, b: int) -> tuple[np.ndarray, np.ndarray]:
        """Trajectory b from the last burn-in sample on, and its rollout behind the same first sample (1, H+1, n)."""
        truth = self.q[b:b + 1, self.burn_in - 1:self.burn_in + self.H]
        return truth, np.concatenate([truth[:, :1], self.roll[b:b + 1]], 1)


def make_plots(model: ForecastModel, test: Dataset, out: Path, burn_in: int = 10, H: int = 100,
               n_show: int = 4) -> list[Path]:
    """rollout.png (rollout vs truth), phase.png, damping.png (learned vs true), energy.png; returns the paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..world.rollout import batched_rollout
    from .metrics import data_system

    q = np.asarray(test.q[:n_show])
    H = min(H, q.shape[1] - burn_in)
    view = RolloutView(q, batched_rollout(model, q, test.u[:n_show], burn_in, H), test.dt, burn_in,
                       tuple(model.angle_dims))
    paths = [_save(plt, plot_rollout(plt, view), out / "rollout.png"),
             _save(plt, plot_phase(plt, view), out / "phase.png")]
    if getattr(model, "damping", None) is not None:
        paths.append(_save(plt, plot_damping(plt, model, test), out / "damping.png"))
    system = data_system(test)  # the data's own physics (its kwargs), built once by make_dataset
    if system is not None and system.hamiltonian_system:
        paths.append(_save(plt, plot_energy(plt, view, system), out / "energy.png"))
    return paths


def plot_rollout(plt: ModuleType, view: RolloutView) -> Figure:
    """Each coordinate over time: truth (solid) and the rollout after the burn-in (dashed)."""
    n, end = view.q.shape[-1], view.burn_in + view.H
    fig, axes = plt.subplots(n, 1, figsize=(8, 2.2 * n), squeeze=False)
    for i in range(n):
        ax = axes[i, 0]
        for b in range(len(view.q)):
            ln, = ax.plot(view.t[:end], view.series(view.q[b, :end, i], i), lw=1)
            ax.plot(view.t[view.burn_in:end], view.series(view.roll[b, :, i], i), "--", color=ln.get_color(), lw=1)
        ax.axvline(view.t[view.burn_in - 1], color="k", lw=0.5)
        ax.set_ylabel(f"q{i}")
    axes[-1, 0].set_xlabel("t [s] (solid: truth, dashed: PHAST rollout after burn-in)")
    return fig


def plot_phase(plt: ModuleType, view: RolloutView) -> Figure:
    """Phase portrait of coordinate 0 (finite-difference velocity), truth against rollout."""
    fig, ax = plt.subplots(figsize=(5, 4))
    for b in range(len(view.q)):
        truth, pred = view.truth_and_rollout(b)
        ln, = ax.plot(view.series(truth[0, 1:, 0], 0), fd_velocity(truth, view.dt, view.angles)[0, :, 0], lw=1)
        ax.plot(view.series(pred[0, 1:, 0], 0), fd_velocity(pred, view.dt, view.angles)[0, :, 0], "--",
                color=ln.get_color(), lw=1)
    ax.set_xlabel("q0")
    ax.set_ylabel("finite-difference qdot0")
    ax.set_title("phase portrait (solid truth, dashed rollout)")
    return fig


def plot_damping(plt: ModuleType, model: Any, test: Dataset, n_traj: int = 64) -> Figure:
    """The learned damping diagonal D_ii(q) against the env's true one along the test trajectories."""
    import torch

    n = test.q.shape[-1]
    qa = np.asarray(test.q[: min(n_traj, len(test.q))]).reshape(-1, n)
    with torch.no_grad():
        dh = model.damping_diag(torch.as_tensor(qa, dtype=next(model.parameters()).dtype)).numpy()
    d = np.asarray(test.damping[: min(n_traj, len(test.q))]).reshape(-1, n)
    fig, axes = plt.subplots(1, n, figsize=(4 * n, 3.2), squeeze=False)
    for i in range(n):
        ax = axes[0, i]
        ax.scatter(qa[:, i], d[:, i], s=2, label="true D_ii(q)")
        ax.scatter(qa[:, i], dh[:, i], s=2, label="learned D_ii(q)")
        ax.set_xlabel(f"q{i}")
        ax.legend(markerscale=4, fontsize=7)
    return fig


def plot_energy(plt: ModuleType, view: RolloutView, system: System) -> Figure:
    """The energy of the data's ``system`` (finite-difference velocities) along truth and rollout."""
    from .metrics import env_energy

    fig, ax = plt.subplots(figsize=(6, 3.5))
    t = view.t[view.burn_in:view.burn_in + view.H]
    for b in range(len(view.q)):
        truth, pred = view.truth_and_rollout(b)
        ln, = ax.plot(t, env_energy(system, truth, view.dt, view.angles)[0], lw=1)
        ax.plot(t, env_energy(system, pred, view.dt, view.angles)[0], "--", color=ln.get_color(), lw=1)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("env H (FD velocities)")
    ax.set_title("energy along the rollout (solid truth, dashed PHAST)")
    return fig
