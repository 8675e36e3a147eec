"""Figures shaped like the paper's Figures 5-6, drawn from finished runs (matplotlib, Agg).

For each env of the grid, the best PHAST regime and the best baseline (lowest mean
row metric over seeds; their lowest seed is drawn) are reloaded from their saved
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
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.systems import break_at_wraps, fd_velocity

from .runner import BENCH_MODEL_FILE, build_run_model, load_result, load_splits, work_dir
from .spec import RunSpec
from .summary import DISPLAY, aggregate, env_metric


def load_model(out_dir: str | Path, spec: RunSpec, train: Any) -> Any:
    """Rebuild a finished run's model and load its saved weights (weights_only)."""
    import torch

    model = build_run_model(spec, train)
    state = torch.load(work_dir(out_dir, spec) / BENCH_MODEL_FILE, weights_only=True, map_location="cpu")
    model.to(next(iter(state.values())).dtype)
    model.load_state_dict(state)
    return model.eval()


def _pick(records: list[dict], env: str, phast: bool) -> dict | None:
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
        return None
    runs = [r for r in records if r["env"] == env and r["model"] == best[0] and not r["config"].get("full_state")]
    return min(runs, key=lambda r: r["seed"])


def make_figures(out_dir: str | Path, specs: list[RunSpec], n_traj: int = 3, H: int = 100) -> list[Path]:
    """Draw the rollout and damping/energy figures of every env in ``specs`` with finished runs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import torch

    from ..metrics import env_energy

    out_dir = Path(out_dir)
    fig_dir = out_dir / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    records = [r for s in specs if not s.full_state and (r := load_result(out_dir, s)) is not None]
    written: list[Path] = []
    for env in dict.fromkeys(s.env_id for s in specs if not s.full_state):
        chosen = [r for r in (_pick(records, env, True), _pick(records, env, False)) if r is not None]
        if not chosen:
            continue
        spec0 = RunSpec.from_config(chosen[0]["config"])
        splits = load_splits(spec0)
        test, train = splits["test"], splits["train"]
        K = spec0.burn_in
        Hh = min(H, test.T - K)
        idx = slice(0, min(n_traj, test.n_traj))
        q = np.asarray(test.q[idx])
        u = np.asarray(test.u[idx])
        ang = tuple(test.angle_dims)
        preds, models = {}, {}
        for rec in chosen:
            spec = RunSpec.from_config(rec["config"])
            try:
                model = load_model(out_dir, spec, train)
            except (RuntimeError, OSError, KeyError) as exc:  # weights from another version of the model code
                warnings.warn(f"figures: skipping {env} {rec['model']} seed {rec['seed']}: saved weights do not load "
                              f"into the current code ({str(exc).splitlines()[0]}); rerun that run to draw it", stacklevel=2)
                continue
            dtype = next(model.parameters()).dtype
            with torch.no_grad():
                roll = model.rollout(torch.as_tensor(q[:, :K], dtype=dtype), torch.as_tensor(u, dtype=dtype), Hh).numpy()
            preds[rec["model"]] = roll
            models[rec["model"]] = model
        if not preds:
            continue
        t = np.arange(q.shape[1]) * test.dt
        tr = t[K:K + Hh]
        n = q.shape[-1]
        # ---- Fig. 5 shape: rollouts + phase portraits
        fig, axes = plt.subplots(n, 2, figsize=(10, 3 * n), squeeze=False)
        for i in range(n):
            ax = axes[i, 0]
            brk = break_at_wraps if i in ang else np.asarray
            ax.plot(t[:K + Hh], brk(q[0, :K + Hh, i]), "k-", lw=2, label="truth")
            ax.axvline(t[K - 1], color="grey", ls=":", lw=1)
            for name, roll in preds.items():
                ax.plot(tr, brk(roll[0, :, i]), "--", label=DISPLAY.get(name, name))
            ax.set_xlabel("t")
            ax.set_ylabel(f"q[{i}]" + (" (wrapped)" if i in ang else ""))
            ax.legend(fontsize=7)
            ax = axes[i, 1]
            full_true = q[0, K - 1:K + Hh]
            ax.plot(brk(full_true[1:, i]), fd_velocity(full_true, test.dt, ang)[:, i], "k-", lw=2, label="truth")
            for name, roll in preds.items():
                full = np.concatenate([q[0, K - 1:K], roll[0]], 0)
                ax.plot(brk(full[1:, i]), fd_velocity(full, test.dt, ang)[:, i], "--", label=DISPLAY.get(name, name))
            ax.set_xlabel(f"q[{i}]")
            ax.set_ylabel(f"finite-difference qdot[{i}]")
        fig.suptitle(f"{env}: open-loop rollout after {K} burn-in steps (test trajectory 0)")
        fig.tight_layout()
        path = fig_dir / f"{env.replace('PHAST/', '').replace('/', '_')}_rollout.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
        # ---- Fig. 6 shape: damping field + energy traces
        fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
        ax = axes[0]
        phast = next((m for name, m in models.items() if name.startswith("phast-")), None)
        if phast is not None and getattr(phast, "damping", None) is not None and hasattr(phast, "damping_diag"):
            qa = np.asarray(test.q)
            with torch.no_grad():
                d_hat = phast.damping_diag(torch.as_tensor(qa, dtype=next(phast.parameters()).dtype)).numpy()
            d = np.asarray(test.damping)
            x = qa[..., 0].ravel()
            order = np.argsort(x)
            ax.plot(x[order], d[..., 0].ravel()[order], "k.", ms=2, label="true D(q)[0]")
            ax.plot(x[order], d_hat[..., 0].ravel()[order], "r.", ms=2, label="learned (PHAST)")
            ax.set_xlabel("q[0]")
            ax.set_ylabel("damping diagonal [0]")
            ax.legend(fontsize=7)
        else:
            ax.text(0.5, 0.5, "no learned damping field", ha="center", va="center", transform=ax.transAxes)
        ax = axes[1]
        try:
            e_true = env_energy(env, q[0:1, K - 1:K + Hh], test.dt, ang)[0]
            ax.plot(tr, e_true, "k-", lw=2, label="truth")
            for name, roll in preds.items():
                full = np.concatenate([q[0:1, K - 1:K], roll[0:1]], 1)
                ax.plot(tr, env_energy(env, full, test.dt, ang)[0], "--", label=DISPLAY.get(name, name))
            ax.set_xlabel("t")
            ax.set_ylabel("env energy H(q, M(q) qdot_fd)")
            ax.legend(fontsize=7)
        except (ValueError, TypeError, IndexError) as exc:  # systems without a mechanical energy
            ax.text(0.5, 0.5, f"energy n/a: {exc}", ha="center", va="center", transform=ax.transAxes, fontsize=7)
        fig.suptitle(f"{env}: damping field and energy along the rollout")
        fig.tight_layout()
        path = fig_dir / f"{env.replace('PHAST/', '').replace('/', '_')}_damping_energy.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written
