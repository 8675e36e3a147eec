"""``phast-train``: train a PHAST model on a registered env and write a run directory.

    phast-train --env PHAST/WindyPendulum-v0 --regime partial --epochs 50 --seed 0 \\
        --n-train 1000 --out runs/windy_partial [--resume]

Writes ``model.pt``, ``config.json``, ``metrics.json`` (Table 16 keys on the test split
plus the training wall time), ``history.json``, ``checkpoint.pt`` and plots
(``rollout.png``, ``phase.png``, ``damping.png``, ``energy.png``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym import env_ids, make_splits, resolve_env_id
from phast_gym.systems import wrap


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="phast-train", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--env", required=True, help=f"env id, one of {env_ids()}")
    ap.add_argument("--regime", default="partial", choices=("known", "partial", "unknown"))
    ap.add_argument("--epochs", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0, help="model / training seed")
    ap.add_argument("--data-seed", type=int, default=42, help="dataset seed (paper: 42)")
    ap.add_argument("--n-train", type=int, default=1000)
    ap.add_argument("--n-val", type=int, default=200)
    ap.add_argument("--n-test", type=int, default=200)
    ap.add_argument("--T", type=int, default=200, help="trajectory length")
    ap.add_argument("--batch-size", type=int, default=64)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--obs-noise-std", type=float, default=0.0)
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=JSON",
                    help="override a PHASTConfig field, e.g. --set damping_cap=1.0 --set substeps=4")
    ap.add_argument("--out", required=True, help="run directory")
    ap.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    ap.add_argument("--no-plots", action="store_true")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    ap.add_argument("--no-progress", action="store_true")
    return ap.parse_args(argv)


def _overrides(items: list[str]) -> dict[str, Any]:
    out = {}
    for it in items:
        if "=" not in it:
            raise ValueError(f"--set expects FIELD=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def train_run(env: str, regime: str, out: str | Path, epochs: int = 50, seed: int = 0, n_train: int = 1000,
              n_val: int = 200, n_test: int = 200, T: int = 200, data_seed: int = 42, batch_size: int = 64,
              lr: float = 1e-3, obs_noise_std: float = 0.0, overrides: dict[str, Any] | None = None,
              resume: bool = False, plots: bool = True, progress: bool = True) -> dict[str, Any]:
    """Python entry point of ``phast-train``: returns the metrics dict it writes to ``metrics.json``."""
    import torch

    from phast_gym.datasets import _check_noise
    from phast_gym.fileio import dir_lock, ensure_writable_dir

    from ..regimes import build_model
    from ..training import CHECKPOINT, TrainConfig, check_resume, fit

    # every check before any work (no dataset generated, nothing written): a bad run leaves nothing half-done
    env = resolve_env_id(env)
    for name, v in (("n_train", n_train), ("n_val", n_val), ("n_test", n_test)):
        if isinstance(v, bool) or int(v) != v or v < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be a positive integer (the {name[2:]} split cannot be "
                             f"empty), got {v!r}")
    if int(T) != T or T < 2:
        raise ValueError(f"--T must be an integer >= 2, got {T!r}")
    noise = _check_noise(obs_noise_std)
    cfg = TrainConfig(epochs=epochs, batch_size=batch_size, lr=lr, seed=seed, progress=progress)
    model = build_model(env, regime, seed=seed, **(overrides or {}))
    data = {"n_train": n_train, "n_val": n_val, "n_test": n_test, "T": T, "seed": data_seed, "obs_noise_std": noise}
    identity = {"env_id": env, "regime": regime, "data": data, "overrides": overrides or {}}
    out = ensure_writable_dir(out, "--out")
    with dir_lock(out):  # one writer per run directory
        if resume:
            check_resume(out / CHECKPOINT, cfg, identity)
        kw = {"obs_noise_std": noise} if noise > 0 else {}
        splits = make_splits(env, n_train, n_val, n_test, T=T, seed=data_seed, **kw)
        res = fit(model, splits["train"], splits["val"], cfg, run_dir=out, resume=resume, identity=identity)
        if not all(bool(torch.isfinite(p).all()) for p in res.model.parameters()):
            raise RuntimeError("training produced non-finite parameters; nothing saved")
        return _finish(res, splits, cfg, identity, out, plots)


def _finish(res: Any, splits: dict[str, Any], cfg: Any, identity: dict[str, Any], out: Path, plots: bool) -> dict[str, Any]:
    """Score on the test split, then save model.pt + config.json, metrics.json / history.json and the plots."""
    from ..checkpoint import atomic_write_json, save_run
    from ..metrics import benchmark_metric, forecast_metrics

    env, regime, seed, epochs = identity["env_id"], identity["regime"], cfg.seed, cfg.epochs
    metrics = forecast_metrics(res.model, splits["test"])
    save_run(res.model, out, {"train": cfg.__dict__, "data": identity["data"], "overrides": identity["overrides"]})
    metrics.update({"train_wall_time_s": res.wall_time_s, "best_val": res.best_val, "best_epoch": res.best_epoch,
                    "nan_events": res.nan_events, "benchmark_metric": benchmark_metric(env)})
    metrics["benchmark_value"] = metrics.get(metrics["benchmark_metric"], float("nan"))
    atomic_write_json(out / "metrics.json", {"env_id": env, "regime": regime, "seed": seed, "epochs": epochs, **metrics})
    atomic_write_json(out / "history.json", res.history)
    if plots:
        make_plots(res.model, splits["test"], out)
    return metrics


def make_plots(model: Any, test: Any, out: Path, burn_in: int = 10, H: int = 100, n_show: int = 4) -> list[Path]:
    """rollout.png (rollout vs truth), phase.png, damping.png (learned vs true), energy.png."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..metrics import energy_diagnostics  # noqa: F401  (same conventions)
    from ..rollout import batched_rollout

    q = np.asarray(test.q[:n_show])
    H = min(H, q.shape[1] - burn_in)
    roll = batched_rollout(model, q, test.u[:n_show], burn_in, H)
    t = np.arange(q.shape[1]) * test.dt
    paths = []
    n = q.shape[-1]
    fig, axes = plt.subplots(n, 1, figsize=(8, 2.2 * n), squeeze=False)
    for i in range(n):
        ax = axes[i, 0]
        for b in range(n_show):
            ln, = ax.plot(t[: burn_in + H], q[b, : burn_in + H, i], lw=1)
            ax.plot(t[burn_in:burn_in + H], roll[b, :, i], "--", color=ln.get_color(), lw=1)
        ax.axvline(t[burn_in - 1], color="k", lw=0.5)
        ax.set_ylabel(f"q{i}")
    axes[-1, 0].set_xlabel("t [s] (solid: truth, dashed: PHAST rollout after burn-in)")
    fig.tight_layout()
    paths.append(out / "rollout.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)

    def fd(x: np.ndarray) -> np.ndarray:
        d = np.diff(x, axis=1)
        for a in model.angle_dims:
            d[..., a] = wrap(d[..., a])
        return d / test.dt

    fig, ax = plt.subplots(figsize=(5, 4))
    for b in range(n_show):
        truth = q[b:b + 1, burn_in - 1:burn_in + H]
        pred = np.concatenate([truth[:, :1], roll[b:b + 1]], 1)
        ln, = ax.plot(truth[0, 1:, 0], fd(truth)[0, :, 0], lw=1)
        ax.plot(pred[0, 1:, 0], fd(pred)[0, :, 0], "--", color=ln.get_color(), lw=1)
    ax.set_xlabel("q0")
    ax.set_ylabel("finite-difference qdot0")
    ax.set_title("phase portrait (solid truth, dashed rollout)")
    fig.tight_layout()
    paths.append(out / "phase.png")
    fig.savefig(paths[-1], dpi=100)
    plt.close(fig)

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
        fig.tight_layout()
        paths.append(out / "damping.png")
        fig.savefig(paths[-1], dpi=100)
        plt.close(fig)

    from phast_gym import make_env_system
    from phast_gym.systems import NUMPY, split

    system = make_env_system(test.env_id)
    if system.hamiltonian_system:
        def energy(x: np.ndarray) -> np.ndarray:
            v = fd(x)
            qs = split(x[:, 1:])
            rows = system.mass_matrix(qs, NUMPY)
            vs = split(v)
            p = tuple(sum(np.asarray(rows[i][j]) * vs[j] for j in range(n)) for i in range(n))
            return np.asarray(system.hamiltonian(qs, p, NUMPY))

        fig, ax = plt.subplots(figsize=(6, 3.5))
        for b in range(n_show):
            truth = q[b:b + 1, burn_in - 1:burn_in + H]
            pred = np.concatenate([truth[:, :1], roll[b:b + 1]], 1)
            ln, = ax.plot(t[burn_in:burn_in + H], energy(truth)[0], lw=1)
            ax.plot(t[burn_in:burn_in + H], energy(pred)[0], "--", color=ln.get_color(), lw=1)
        ax.set_xlabel("t [s]")
        ax.set_ylabel("env H (FD velocities)")
        ax.set_title("energy along the rollout (solid truth, dashed PHAST)")
        fig.tight_layout()
        paths.append(out / "energy.png")
        fig.savefig(paths[-1], dpi=100)
        plt.close(fig)
    return paths


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    import torch

    torch.set_num_threads(max(1, args.threads))
    try:
        metrics = train_run(args.env, args.regime, args.out, args.epochs, args.seed, args.n_train, args.n_val, args.n_test,
                            args.T, args.data_seed, args.batch_size, args.lr, args.obs_noise_std, _overrides(args.set),
                            resume=args.resume, plots=not args.no_plots, progress=not args.no_progress)
    except ValueError as exc:
        print(f"phast-train: error: {exc}", file=sys.stderr)
        return 2
    keys = [metrics["benchmark_metric"], "damping_r2", "train_wall_time_s"]
    print(json.dumps({k: metrics.get(k) for k in keys if k in metrics}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
