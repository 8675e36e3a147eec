"""Open-loop rollouts in batches (paper Sec. 4.1.1, Appendix F).

* autoregressive: ``model.rollout`` (the observer re-infers velocity from the model's own
  predictions; the primary mode, shared with the baselines);
* takeover (PHAST only): infer one state at the end of the burn-in, then integrate the core.
"""

from __future__ import annotations

import numpy as np
import torch

from .interfaces import ForecastModel, TakeoverModel


def _u(u: np.ndarray | torch.Tensor | None, sl: slice | tuple[slice, ...], dtype: torch.dtype) -> torch.Tensor | None:
    if u is None or np.size(u) == 0:
        return None
    return torch.as_tensor(np.asarray(u[sl]), dtype=dtype)


@torch.no_grad()
def batched_rollout(model: ForecastModel, q: np.ndarray | torch.Tensor, u: np.ndarray | torch.Tensor | None,
                    burn_in: int, H: int, mode: str = "autoregressive", batch_size: int = 256) -> np.ndarray:
    """Rollouts of every trajectory of ``q`` (N, T, n) after ``burn_in`` true samples -> (N, H, n) numpy.

    ``u`` (N, T-1, m) is the logged port input (sliced to the window); ``mode`` is
    ``"autoregressive"`` or ``"takeover"``."""
    if mode not in ("autoregressive", "takeover"):
        raise ValueError(f"mode must be 'autoregressive' or 'takeover', got {mode!r}")
    if mode == "takeover" and not hasattr(model, "rollout_takeover"):
        raise ValueError(f"{type(model).__name__} has no takeover rollout")
    q = np.asarray(q)
    if burn_in < 1 or burn_in + H > q.shape[1]:
        raise ValueError(f"burn_in={burn_in} + H={H} must fit in T={q.shape[1]} (burn_in >= 1)")
    dtype = next(model.parameters()).dtype
    was = model.training
    model.eval()
    outs = []
    for i in range(0, q.shape[0], batch_size):
        qb = torch.as_tensor(q[i:i + batch_size, :burn_in], dtype=dtype)
        ub = _u(u, np.s_[i:i + batch_size, : burn_in - 1 + H], dtype) if u is not None else None
        if mode == "autoregressive":
            roll = model.rollout(qb, ub, H)
        else:
            assert isinstance(model, TakeoverModel)  # checked above
            roll = model.rollout_takeover(qb, ub, H)
        outs.append(roll.cpu().numpy())
    model.train(was)
    return np.concatenate(outs, 0)


@torch.no_grad()
def batched_predict(model: ForecastModel, q: np.ndarray, u: np.ndarray | None, batch_size: int = 256) -> np.ndarray:
    """Teacher-forced next-step predictions (N, T, n) in batches."""
    dtype = next(model.parameters()).dtype
    was = model.training
    model.eval()
    outs = []
    for i in range(0, q.shape[0], batch_size):
        qb = torch.as_tensor(np.asarray(q[i:i + batch_size]), dtype=dtype)
        outs.append(model(qb, _u(u, np.s_[i:i + batch_size], dtype) if u is not None else None).cpu().numpy())
    model.train(was)
    return np.concatenate(outs, 0)
