"""Figures shaped like the paper's Figures 5-6, drawn from finished runs (matplotlib, Agg).

For each env of the grid, the best PHAST regime and the best baseline (lowest mean
row metric over seeds; their lowest seed whose saved weights load is drawn) are reloaded from their saved
weights and rolled out open loop on test trajectories:

* ``<env>_rollout.png`` (Fig. 5 shape): q(t) truth vs both models after the burn-in,
  and the phase portrait (q, finite-difference qdot) of truth and predictions;
* ``<env>_damping_energy.png`` (Fig. 6 shape): the learned damping diagonal of
  PHAST against the env's true D(q) on test states, and the env energy H(q, M(q) qdot)
  along the true and predicted trajectories (all physics from ``phast_gym.systems``).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from phast_gym.systems import break_at_wraps, fd_velocity

from .runner import BENCH_MODEL_FILE, build_run_model, load_result, load_splits, work_dir
from .spec import RunSpec
from .summary import DISPLAY, aggregate, env_metric

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from phast_gym.datasets import Dataset

    from ..world.interfaces import ForecastModel


def load_run_model(out_dir: str | Path, spec: RunSpec, train: Dataset) -> ForecastModel:
    """Rebuild a finished run's model and load its saved weights (``checkpoint.torch_load``: weights_only, and a
    ValueError naming the problem when the file is missing or damaged)."""
    from phast_model.train.checkpoint import torch_load

    model = build_run_model(spec, train)
    state = torch_load(work_dir(out_dir, spec) / BENCH_MODEL_FILE, "benchmark weights")
    model.to(next(iter(state.values())).dtype)
    model.load_state_dict(state)
    return model.eval()


def _pick(records: Sequence[Mapping[str, Any]], env: str, phast: bool) -> list[Mapping[str, Any]]:
    """The runs of ``env``'s best PHAST regime (or best baseline), lowest seed first (empty: none finished)."""
    agg = aggregate(records)
    metric = env_metric(agg, env)
    best = None
    for (e, m), g in agg.items():
        if e != env or m.startswith("phast-") != phast or metric not in g["metrics"]:
            continue
        if not math.isfinite(g["metrics"][metric][0]):
            continue
        if best is None or g["metrics"][metric][0] < best[1]:
            best = (m, g["metrics"][metric][0])
    if best is None:
        return []
    runs = [r for r in records if r["env"] == env and r["model"] == best[0] and not r["config"].get("full_state")]
    return sorted(runs, key=lambda r: r["seed"])


@dataclass
class EnvRollouts:
    """One env's test trajectories and the chosen models' open-loop rollouts from its burn-in."""

    env: str
    test: Dataset
    q: np.ndarray  # (n_traj, T, n) observed test trajectories
    K: int  # burn-in
    H: int  # rollout horizon
    preds: dict[str, np.ndarray] = field(default_factory=dict)  # model name -> (n_traj, H, n)
    models: dict[str, Any] = field(default_factory=dict)

    @property
    def angle_dims(self) -> tuple[int, ...]:
        return tuple(self.test.angle_dims)

    def label(self, name: str) -> str:
        return DISPLAY.get(name, name)


def _rollouts(out_dir: Path, env: str, chosen: list[list[Mapping[str, Any]]], n_traj: int,
              H: int) -> EnvRollouts | None:
    """Reload each chosen model (its lowest seed whose saved weights load) and roll it out open loop on the first
    ``n_traj`` test trajectories."""
    import torch

    spec0 = RunSpec.from_config(chosen[0][0]["config"])
    splits = load_splits(spec0)
    test, K = splits["test"], spec0.burn_in
    idx = slice(0, min(n_traj, test.n_traj))
    ro = EnvRollouts(env, test, np.asarray(test.q[idx]), K, min(H, test.T - K))
    u = np.asarray(test.u[idx])
    for runs in chosen:
        model, skipped = None, []
        for rec in runs:
            try:
                model = load_run_model(out_dir, RunSpec.from_config(rec["config"]), splits["train"])
                break
            except (ValueError, RuntimeError, KeyError) as exc:  # weights missing, or from another version of the code
                skipped.append(f"seed {rec['seed']} ({str(exc).splitlines()[0]})")
        if model is None:
            warnings.warn(f"figures: skipping {env} {runs[0]['model']}: no saved weights load into the current code: "
                          f"{'; '.join(skipped)}; rerun a run to draw it", stacklevel=2)
            continue
        dtype = next(model.parameters()).dtype
        with torch.no_grad():
            ro.preds[runs[0]["model"]] = model.rollout(torch.as_tensor(ro.q[:, :K], dtype=dtype),
                                                       torch.as_tensor(u, dtype=dtype), ro.H).numpy()
        ro.models[runs[0]["model"]] = model
    return ro if ro.preds else None


def _save(fig: Figure, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _rollout_figure(ro: EnvRollouts, path: Path) -> Path:
    """Fig. 5 shape: q(t) of truth and predictions, and the phase portraits (q, finite-difference qdot)."""
    import matplotlib.pyplot as plt

    q, K, Hh, ang, dt = ro.q, ro.K, ro.H, ro.angle_dims, ro.test.dt
    t = np.arange(q.shape[1]) * dt
    tr = t[K:K + Hh]
    n = q.shape[-1]
    fig, axes = plt.subplots(n, 2, figsize=(10, 3 * n), squeeze=False)
    for i in range(n):
        ax = axes[i, 0]
        brk = break_at_wraps if i in ang else np.asarray
        ax.plot(t[:K + Hh], brk(q[0, :K + Hh, i]), "k-", lw=2, label="truth")
        ax.axvline(t[K - 1], color="grey", ls=":", lw=1)
        for name, roll in ro.preds.items():
            ax.plot(tr, brk(roll[0, :, i]), "--", label=ro.label(name))
        ax.set_xlabel("t")
        ax.set_ylabel(f"q[{i}]" + (" (wrapped)" if i in ang else ""))
        ax.legend(fontsize=7)
        ax = axes[i, 1]
        full_true = q[0, K - 1:K + Hh]
        ax.plot(brk(full_true[1:, i]), fd_velocity(full_true, dt, ang)[:, i], "k-", lw=2, label="truth")
        for name, roll in ro.preds.items():
            full = np.concatenate([q[0, K - 1:K], roll[0]], 0)
            ax.plot(brk(full[1:, i]), fd_velocity(full, dt, ang)[:, i], "--", label=ro.label(name))
        ax.set_xlabel(f"q[{i}]")
        ax.set_ylabel(f"finite-difference qdot[{i}]")
    fig.suptitle(f"{ro.env}: open-loop rollout after {K} burn-in steps (test trajectory 0)")
    return _save(fig, path)


def _damping_panel(ax: Axes, ro: EnvRollouts) -> None:
    """The first PHAST model's learned damping diagonal against the env's D(q) on the test states."""
    import torch

    phast = next((m for name, m in ro.models.items() if name.startswith("phast-")), None)
    if phast is None or getattr(phast, "damping", None) is None or not hasattr(phast, "damping_diag"):
        ax.text(0.5, 0.5, "no learned damping field", ha="center", va="center", transform=ax.transAxes)
        return
    qa = np.asarray(ro.test.q)
    with torch.no_grad():
        d_hat = phast.damping_diag(torch.as_tensor(qa, dtype=next(phast.parameters()).dtype)).numpy()
    d = np.asarray(ro.test.damping)
    x = qa[..., 0].ravel()
    order = np.argsort(x)
    ax.plot(x[order], d[..., 0].ravel()[order], "k.", ms=2, label="true D(q)[0]")
    ax.plot(x[order], d_hat[..., 0].ravel()[order], "r.", ms=2, label="learned (PHAST)")
    ax.set_xlabel("q[0]")
    ax.set_ylabel("damping diagonal [0]")
    ax.legend(fontsize=7)


def _energy_panel(ax: Axes, ro: EnvRollouts) -> None:
    """The env's energy along the true and the predicted trajectories (n/a for systems without one)."""
    from ..train.metrics import data_system, env_energy

    q, K, Hh, ang, dt = ro.q, ro.K, ro.H, ro.angle_dims, ro.test.dt
    tr = (np.arange(q.shape[1]) * dt)[K:K + Hh]
    system = data_system(ro.test)  # the data's physics, built once
    env = ro.env if system is None else system
    try:
        ax.plot(tr, env_energy(env, q[0:1, K - 1:K + Hh], dt, ang)[0], "k-", lw=2, label="truth")
        for name, roll in ro.preds.items():
            full = np.concatenate([q[0:1, K - 1:K], roll[0:1]], 1)
            ax.plot(tr, env_energy(env, full, dt, ang)[0], "--", label=ro.label(name))
        ax.set_xlabel("t")
        ax.set_ylabel("env energy H(q, M(q) qdot_fd)")
        ax.legend(fontsize=7)
    except (ValueError, TypeError, IndexError) as exc:  # systems without a mechanical energy
        ax.text(0.5, 0.5, f"energy n/a: {exc}", ha="center", va="center", transform=ax.transAxes, fontsize=7)


def _damping_energy_figure(ro: EnvRollouts, path: Path) -> Path:
    """Fig. 6 shape: the damping field and the energy along the rollout."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    _damping_panel(axes[0], ro)
    _energy_panel(axes[1], ro)
    fig.suptitle(f"{ro.env}: damping field and energy along the rollout")
    return _save(fig, path)


def make_figures(out_dir: str | Path, specs: list[RunSpec], n_traj: int = 3, H: int = 100) -> list[Path]:
    """Draw the rollout and damping/energy figures of every env in ``specs`` with finished runs."""
    import matplotlib

    matplotlib.use("Agg")
    out_dir = Path(out_dir)
    fig_dir = out_dir / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    records = [r for s in specs if not s.full_state and (r := load_result(out_dir, s)) is not None]
    written: list[Path] = []
    for env in dict.fromkeys(s.env_id for s in specs if not s.full_state):
        chosen = [runs for runs in (_pick(records, env, True), _pick(records, env, False)) if runs]
        ro = _rollouts(out_dir, env, chosen, n_traj, H) if chosen else None
        if ro is None:
            continue
        stem = env.replace("PHAST/", "").replace("/", "_")
        written.append(_rollout_figure(ro, fig_dir / f"{stem}_rollout.png"))
        written.append(_damping_energy_figure(ro, fig_dir / f"{stem}_damping_energy.png"))
    return written
