"""Python API over PHAST runs (what the CLIs, control and mismatch code call): train one
(:func:`train_run`, what ``phast-train`` runs), load it, forecast with it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from .train.checkpoint import load_model
from .train.runs import train_run
from .world.model import PHAST

__all__ = ["load_run", "predict", "train_run"]


def load_run(run_dir: str | Path) -> PHAST:
    """The PHAST model of a ``phast-train`` run directory (``model.pt`` + ``config.json``), in eval mode.

    Raises ValueError for a missing, corrupted or foreign run."""
    return load_model(run_dir)


def predict(run: PHAST | str | Path, q_history: np.ndarray, u_seq: np.ndarray | None = None, H: int | None = None,
            mode: str = "autoregressive") -> np.ndarray:
    """Open-loop forecast after an observed history.

    q_history: (K, n) or (B, K, n) observed positions (angles wrapped);
    u_seq: (H, m) / (B, H, m) port inputs applied from the last observed sample on (u_seq[0] acts over
    [K-1, K]); H defaults to len(u_seq) (required without u_seq). Returns (H, n) or (B, H, n)."""
    model = run if isinstance(run, torch.nn.Module) else load_run(run)
    q = np.asarray(q_history, dtype=np.float64)
    single = q.ndim == 2
    if single:
        q = q[None]
    if q.ndim != 3 or q.shape[-1] != model.n:
        raise ValueError(f"q_history must be (K, {model.n}) or (B, K, {model.n}), got {np.shape(q_history)}")
    if not np.isfinite(q).all():
        raise ValueError("q_history contains NaN/inf")
    K = q.shape[1]
    u_full = None
    if u_seq is not None:
        u = np.asarray(u_seq, dtype=np.float64)
        if u.ndim == 2:
            u = np.broadcast_to(u[None], (q.shape[0], *u.shape))
        if u.ndim != 3 or u.shape[-1] != model.m:
            raise ValueError(f"u_seq must be (H, {model.m}) or (B, H, {model.m}), got {np.shape(u_seq)}")
        H = u.shape[1] if H is None else H
        u_full = np.concatenate([np.zeros((q.shape[0], K - 1, model.m)), u], 1)
    if H is None or H < 1:
        raise ValueError("H must be a positive integer (or pass u_seq)")
    dtype = next(model.parameters()).dtype
    qt, ut = torch.as_tensor(q, dtype=dtype), None if u_full is None else torch.as_tensor(u_full, dtype=dtype)
    with torch.no_grad():
        roll = model.rollout(qt, ut, int(H)) if mode == "autoregressive" else model.rollout_takeover(qt, ut, int(H))
    assert isinstance(roll, torch.Tensor)  # positions only (return_p=False)
    out = roll.cpu().numpy().astype(np.float64)
    return out[0] if single else out
