"""How robust is one PHAST run's identified D to rounding-level perturbations of its weights?
(``benchmarks/identification_fragility.py`` runs :func:`main`.)

Trains the same run (paper protocol: 1000 / 200 / 200 trajectories, T = 200, 50 epochs) once as is and once per
perturbation k = 1..P, where every weight is multiplied by ``1 + eps N(0, 1)`` (generator seed k) right after the
data start (``initialize_from_data``).  ``eps = 1e-7`` is float32 rounding, the size of the change a reordered sum
makes.  A run whose result moves far under such a change is an accident of its trajectory, not a property of the
method.  Per run: the selected (best-validation) epoch, damping R^2, the benchmark metric and the epochs where the
training loss jumped above ``--spike-ratio`` times its running minimum (a training instability).

To measure an older checkout's code, add a git worktree at that commit and run the study there, with that
checkout's own ``benchmarks/identification_fragility.py`` (``git worktree add /tmp/old <commit>``); the commit
recorded is that of the phast_model imported.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from phast_gym import make_splits, resolve_env_id
from phast_model.train.checkpoint import atomic_write_json
from phast_model.train.fit import TrainConfig
from phast_model.train.metrics import benchmark_metric
from phast_model.train.provenance import code_commit
from phast_model.train.runs import train_and_score
from phast_model.world import regimes
from phast_model.world.regimes import build_model


@dataclass
class Outcome:
    """One training run of the study."""

    perturbation: int  # 0 = unperturbed
    best_epoch: int
    damping_r2: float
    benchmark_value: float
    spike_epochs: list[int]
    max_loss_jump: float
    wall_s: float


def model_commit() -> str:
    """Commit of the checkout whose phast_model is imported (``+dirty`` when its code differs from it)."""
    return code_commit(short=True, dirty=True) or "unknown"


def perturb_(model: torch.nn.Module, eps: float, seed: int) -> None:
    """Multiply every weight by ``1 + eps N(0, 1)`` (in place; the generator is seeded by ``seed``)."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.mul_(1 + eps * torch.randn(p.shape, generator=gen, dtype=p.dtype))


def loss_spikes(history: list[dict[str, Any]], ratio: float) -> tuple[list[int], float]:
    """Epochs whose training loss exceeds ``ratio`` x the lowest loss of the epochs before it, and the largest
    such jump."""
    losses = np.array([h["train_loss"] for h in history], dtype=float)
    if losses.size < 2:
        return [], 1.0
    jumps = losses[1:] / np.minimum.accumulate(losses[:-1])
    epochs = [int(h["epoch"]) for h, j in zip(history[1:], jumps) if j > ratio]
    return epochs, float(jumps.max())


def train_once(env: str, regime: str, seed: int, splits: dict[str, Any], cfg: TrainConfig, k: int, eps: float,
               spike_ratio: float, run_dir: Path) -> Outcome:
    """One run; perturbation ``k`` > 0 perturbs the weights right after the data start."""
    model = build_model(env, regime, seed=seed)
    if k > 0:
        init = getattr(model, "initialize_from_data", None)
        if init is None:
            perturb_(model, eps, k)
        else:
            def initialize_then_perturb(*a: Any, **kw: Any) -> None:
                init(*a, **kw)
                perturb_(model, eps, k)
            model.initialize_from_data = initialize_then_perturb
    recipe = getattr(regimes, "recipe", None)  # None on older checkouts, whose models carried their trainer settings
    if recipe is not None:  # the regime's trainer settings (KNOWN: eps 1e-15, a warm-up)
        cfg = recipe(env, regime, cfg, seed=seed).train
    res, metrics = train_and_score(model, splits, cfg, run_dir, {"study": "identification_fragility", "k": k})
    spikes, jump = loss_spikes(res.history, spike_ratio)
    return Outcome(perturbation=k, best_epoch=int(res.best_epoch), damping_r2=float(metrics.get("damping_r2", np.nan)),
                   benchmark_value=float(metrics[benchmark_metric(env)]), spike_epochs=spikes, max_loss_jump=jump,
                   wall_s=float(res.wall_time_s))


def summarize(outcomes: list[Outcome], epochs: int) -> dict[str, Any]:
    r2 = np.array([o.damping_r2 for o in outcomes])
    return {"runs": len(outcomes), "damping_r2_min": float(r2.min()), "damping_r2_median": float(np.median(r2)),
            "damping_r2_max": float(r2.max()), "runs_with_spikes": sum(bool(o.spike_epochs) for o in outcomes),
            "runs_selecting_an_earlier_epoch": sum(o.best_epoch < epochs for o in outcomes)}


def markdown(outcomes: list[Outcome]) -> str:
    lines = ["| perturbation | best epoch | damping R^2 | benchmark metric | loss spikes (epochs) | max jump |",
             "|---|---|---|---|---|---|"]
    for o in outcomes:
        lines.append(f"| {o.perturbation or 'none'} | {o.best_epoch} | {o.damping_r2:.4f} | {o.benchmark_value:.4g} | "
                     f"{', '.join(map(str, o.spike_epochs)) or '-'} | {o.max_loss_jump:.3g} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--env", default="WindyPendulum-v0")
    ap.add_argument("--regime", default="known", choices=["known", "partial", "unknown"])
    ap.add_argument("--seed", type=int, default=0, help="the run's seed (model init and batch order)")
    ap.add_argument("--perturbations", type=int, default=8, help="perturbed runs besides the unperturbed one")
    ap.add_argument("--eps", type=float, default=1e-7, help="relative size of the weight perturbation")
    ap.add_argument("--epochs", type=int, default=50)
    ap.add_argument("--n-train", type=int, default=1000)
    ap.add_argument("--spike-ratio", type=float, default=3.0)
    ap.add_argument("--out", help="JSON written after every run")
    args = ap.parse_args(argv)
    if args.perturbations < 0 or not args.eps > 0:
        ap.error("--perturbations must be >= 0 and --eps > 0")
    torch.set_num_threads(1)
    env = resolve_env_id(args.env if args.env.startswith("PHAST/") else f"PHAST/{args.env}")
    splits = make_splits(env, args.n_train, 200, 200, T=200, seed=42)
    cfg = TrainConfig(epochs=args.epochs, batch_size=64, lr=1e-3, seed=args.seed, progress=False)
    header = {"env_id": env, "regime": args.regime, "seed": args.seed, "eps": args.eps, "epochs": args.epochs,
              "n_train": args.n_train, "spike_ratio": args.spike_ratio, "commit": model_commit()}
    outcomes: list[Outcome] = []
    with tempfile.TemporaryDirectory(prefix="phast_fragility_") as tmp:
        for k in tqdm(range(args.perturbations + 1), desc="identification_fragility"):
            outcomes.append(train_once(env, args.regime, args.seed, splits, cfg, k, args.eps, args.spike_ratio,
                                       Path(tmp) / f"k{k}"))
            if args.out:
                atomic_write_json(Path(args.out), {**header, "summary": summarize(outcomes, args.epochs),
                                                   "outcomes": [asdict(o) for o in outcomes]})
    print(markdown(outcomes))
    print(json.dumps({**header, **summarize(outcomes, args.epochs)}))
    return 0
