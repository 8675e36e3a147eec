"""Attention baselines: a causal Transformer and a volume-preserving transformer (VPT).

* **Transformer** (Vaswani et al., 2017): linear embedding, sinusoidal positional
  encoding (Sec. 3.5), 2 post-norm encoder layers of multi-head self-attention
  ``softmax(Q K^T / sqrt(d_k) + mask) V`` (Eq. 1) with a causal mask, 4 heads,
  feed-forward 4d, dropout 0.1 (paper Table 14).
* **VPT** (Brantner, de Romemont, Kraus & Li, "Volume-preserving transformers for
  learning time series data with structure", 2023): every sublayer has a
  unit-triangular Jacobian, so its determinant is 1.
  - volume-preserving feed-forward (their Eq. for the "lower/upper" layers, as in
    SympNets): ``x <- x + tanh(L x + b)`` with L strictly lower triangular, then the
    same with a strictly upper-triangular U; Jacobian ``I + diag(tanh') L`` is unit
    triangular.  ``n_ff = 2`` such lower/upper pairs per block (paper Table 14).
  - skew-symmetric attention: their attention forms ``C = Z^T A Z`` with A
    skew-symmetric and maps it to an orthogonal matrix (Cayley), which mixes *all*
    time steps and is therefore not causal.  The causal adaptation used here keeps
    the skew-symmetric bilinear form but makes the time-mixing matrix unit lower
    triangular (determinant 1, so still volume preserving):
    ``z'_t = z_t + (1/t) sum_{s<t} tanh(z_{t-1}^T A z_s) z_s``; the weights of step t
    only use inputs before t, so ``dz'_t/dz_t = I``.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .common import SeqBaseline


def sinusoidal_encoding(T: int, d: int, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """(T, d) positional encoding of Vaswani et al. (Sec. 3.5)."""
    pos = torch.arange(T, device=device, dtype=dtype)[:, None]
    freq = torch.exp(torch.arange(0, d, 2, device=device, dtype=dtype) * (-math.log(10000.0) / d))
    pe = torch.zeros(T, d, device=device, dtype=dtype)
    pe[:, 0::2] = torch.sin(pos * freq)
    pe[:, 1::2] = torch.cos(pos * freq[: d // 2])
    return pe


def causal_mask(T: int, device: torch.device) -> torch.Tensor:
    """(T, T) boolean mask, True where attention is forbidden (the future)."""
    return torch.triu(torch.ones(T, T, dtype=torch.bool, device=device), diagonal=1)


class TransformerBaseline(SeqBaseline):
    """Causal Transformer encoder (d = 64, 2 layers, 4 heads, FF 4d, dropout 0.1)."""

    def __init__(self, n: int, m: int, angle_dims: tuple[int, ...] = (), d_model: int = 64, depth: int = 2,
                 n_heads: int = 4, ff_mult: int = 4, dropout: float = 0.1) -> None:
        super().__init__(n, m, angle_dims, d_model)
        self.embed = nn.Linear(self.in_dim, d_model)
        layer = nn.TransformerEncoderLayer(d_model, n_heads, ff_mult * d_model, dropout, batch_first=True)
        self.encoder = nn.TransformerEncoder(layer, depth, enable_nested_tensor=False)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        T = x.shape[1]
        h = self.embed(x) + sinusoidal_encoding(T, self.d_model, x.device, x.dtype)
        return self.encoder(h, mask=causal_mask(T, x.device), is_causal=True)


class _TriangularResidual(nn.Module):
    """``x + tanh(W x + b)`` with W strictly lower (or upper) triangular: Jacobian determinant 1."""

    def __init__(self, d: int, upper: bool) -> None:
        super().__init__()
        self.upper = upper
        self.register_buffer("idx", torch.triu_indices(d, d, 1) if upper else torch.tril_indices(d, d, -1), persistent=False)
        self.w = nn.Parameter(torch.randn(self.idx.shape[1]) / math.sqrt(d))
        self.b = nn.Parameter(torch.zeros(d))
        self.d = d

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        W = x.new_zeros(self.d, self.d)
        W[self.idx[0], self.idx[1]] = self.w
        return x + torch.tanh(x @ W.T + self.b)


class _SkewCausalAttention(nn.Module):
    """Causal unit-lower-triangular time mixing with weights from a skew-symmetric form."""

    def __init__(self, d: int) -> None:
        super().__init__()
        self.register_buffer("idx", torch.triu_indices(d, d, 1), persistent=False)
        self.a = nn.Parameter(torch.randn(self.idx.shape[1]) / d)
        self.d = d

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        A = z.new_zeros(self.d, self.d)
        A[self.idx[0], self.idx[1]] = self.a
        A = A - A.T  # skew-symmetric
        T = z.shape[1]
        z_prev = torch.cat([torch.zeros_like(z[:, :1]), z[:, :-1]], dim=1)
        C = torch.tanh(z_prev @ A @ z.transpose(1, 2))  # (B, T, T): row t uses z_{t-1}, column s uses z_s
        strict = torch.tril(torch.ones(T, T, dtype=torch.bool, device=z.device), diagonal=-1)
        count = torch.arange(T, device=z.device, dtype=z.dtype).clamp_min(1.0)[:, None]
        W = torch.where(strict, C, torch.zeros_like(C)) / count
        return z + W @ z


class VPTBaseline(SeqBaseline):
    """Volume-preserving transformer: 2 blocks of skew causal attention + 2 lower/upper VP feed-forwards."""

    def __init__(self, n: int, m: int, angle_dims: tuple[int, ...] = (), d_model: int = 64, depth: int = 2,
                 n_ff: int = 2) -> None:
        super().__init__(n, m, angle_dims, d_model)
        self.embed = nn.Linear(self.in_dim, d_model)
        blocks = []
        for _ in range(depth):
            ff = [_TriangularResidual(d_model, upper) for _ in range(n_ff) for upper in (False, True)]
            blocks.append(nn.Sequential(_SkewCausalAttention(d_model), *ff))
        self.blocks = nn.Sequential(*blocks)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        return self.blocks(self.embed(x))
