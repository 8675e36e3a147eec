"""Input features shared by the neural components: angles enter as (sin, cos)."""

from __future__ import annotations

import torch


def n_features(n: int, angle_dims: tuple[int, ...]) -> int:
    """Width of :func:`coordinate_features` for ``n`` coordinates."""
    return n + len(angle_dims)


def coordinate_features(q: torch.Tensor, angle_dims: tuple[int, ...],
                        scale: torch.Tensor | None = None) -> torch.Tensor:
    """(..., n) -> (..., n + len(angle_dims)): Euclidean coordinates (optionally divided by ``scale``), then sin/cos of
    angles."""
    n = q.shape[-1]
    eu = [i for i in range(n) if i not in angle_dims]
    parts = []
    if eu:
        x = q[..., eu]
        if scale is not None:
            x = x / scale
        parts.append(x)
    if angle_dims:
        a = q[..., list(angle_dims)]
        parts += [torch.sin(a), torch.cos(a)]
    return torch.cat(parts, -1)
