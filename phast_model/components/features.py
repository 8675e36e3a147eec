"""Helpers shared by the components: the neural components' input features (angles enter as (sin, cos)), and the
inverse of the softplus that keeps positive coefficients positive."""

from __future__ import annotations

import torch


def inv_softplus(x: torch.Tensor | float) -> torch.Tensor:
    """softplus^-1(x) = log(expm1(x)) for x > 0, written as x + log(-expm1(-x)) so that a large x does not overflow."""
    x = torch.as_tensor(x, dtype=torch.float64)
    return x + torch.log(-torch.expm1(-x))


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
