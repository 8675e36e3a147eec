"""Attention baselines: a causal Transformer and a volume-preserving transformer (VPT).

* **Transformer** (Vaswani et al., 2017): linear embedding, sinusoidal positional
  encoding (Sec. 3.5), 2 post-norm encoder layers of multi-head self-attention
  ``softmax(Q K^T / sqrt(d_k) + mask) V`` (Eq. 1) with a causal mask, 4 heads,
  feed-forward 4d, dropout 0.1 (paper Table 14).  The parameters live in
  ``nn.TransformerEncoderLayer`` modules; attention runs as one fused causal
  ``scaled_dot_product_attention``.  Dropout 0.1 is applied where Vaswani et al.
  (Sec. 5.4) put it, on each sublayer's output before the residual add, and inside
  the feed-forward (as torch's layer does), but **not** on the attention weights:
  torch's ``nn.MultiheadAttention`` also drops attention weights, which forces
  the unfused attention path (a 2.5x slower training step).  Open-loop rollouts reuse
  each layer's cached keys and values (one new position per step).
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
    only use inputs before t, so ``dz'_t/dz_t = I``.  Rollouts cache each attention
    layer's past inputs z_s (one new position per step).
"""

from __future__ import annotations

import math
from typing import cast

import torch
import torch.nn.functional as F
from torch import nn

from .common import SeqBaseline

#: per layer, the attention keys and values (B, heads, t, d_head) of the positions seen so far
KVCache = list[tuple[torch.Tensor, torch.Tensor]]


def sinusoidal_encoding(T: int, d: int, device: torch.device, dtype: torch.dtype, start: int = 0) -> torch.Tensor:
    """(T, d) positional encoding of Vaswani et al. (Sec. 3.5) for positions ``start .. start + T - 1``."""
    pos = torch.arange(start, start + T, device=device, dtype=dtype)[:, None]
    freq = torch.exp(torch.arange(0, d, 2, device=device, dtype=dtype) * (-math.log(10000.0) / d))
    pe = torch.zeros(T, d, device=device, dtype=dtype)
    pe[:, 0::2] = torch.sin(pos * freq)
    pe[:, 1::2] = torch.cos(pos * freq[: d // 2])
    return pe


def _self_attention(attn: nn.MultiheadAttention, x: torch.Tensor, past: tuple[torch.Tensor, torch.Tensor] | None
                    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
    """Causal multi-head self-attention of ``x`` (B, T, d) with ``attn``'s weights; ``past`` = cached (keys, values).

    Without a cache the T positions attend causally to each other; with one, ``x``
    is a single new position (T = 1) that attends to the cache and itself.  Returns the output and the keys
    and values of every position seen so far.
    """
    B, T, d = x.shape
    heads = attn.num_heads
    q, k, v = (F.linear(x, attn.in_proj_weight, attn.in_proj_bias).view(B, T, 3, heads, d // heads)
               .permute(2, 0, 3, 1, 4))
    if past is not None:
        k, v = torch.cat([past[0], k], 2), torch.cat([past[1], v], 2)
    out = F.scaled_dot_product_attention(q, k, v, is_causal=past is None)
    return attn.out_proj(out.transpose(1, 2).reshape(B, T, d)), (k, v)


def _encoder_layer(layer: nn.TransformerEncoderLayer, x: torch.Tensor, past: tuple[torch.Tensor, torch.Tensor] | None
                   ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
    """Post-norm encoder layer (torch's ``norm_first=False`` layer) with fused causal attention."""
    a, kv = _self_attention(layer.self_attn, x, past)
    x = layer.norm1(x + layer.dropout1(a))
    ff = layer.linear2(layer.dropout(layer.activation(layer.linear1(x))))
    return layer.norm2(x + layer.dropout2(ff)), kv


class TransformerBaseline(SeqBaseline):
    """Causal Transformer encoder (d = 64, 2 layers, 4 heads, FF 4d, dropout 0.1 off the attention weights)."""

    stateful = True

    def __init__(self, n: int, m: int, angle_dims: tuple[int, ...] = (), d_model: int = 64, depth: int = 2,
                 n_heads: int = 4, ff_mult: int = 4, dropout: float = 0.1) -> None:
        super().__init__(n, m, angle_dims, d_model)
        self.embed = nn.Linear(self.in_dim, d_model)
        layer = nn.TransformerEncoderLayer(d_model, n_heads, ff_mult * d_model, dropout, batch_first=True)
        self.encoder = nn.TransformerEncoder(layer, depth, enable_nested_tensor=False)

    def _run(self, x: torch.Tensor, start: int, cache: KVCache | None) -> tuple[torch.Tensor, KVCache]:
        h = self.embed(x) + sinusoidal_encoding(x.shape[1], self.d_model, x.device, x.dtype, start)
        new: KVCache = []
        for i, layer in enumerate(self.encoder.layers):
            h, kv = _encoder_layer(layer, h, None if cache is None else cache[i])
            new.append(kv)
        return h, new

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        return self._run(x, 0, None)[0]

    def encode_state(self, x: torch.Tensor) -> tuple[torch.Tensor, tuple[int, KVCache]]:
        h, cache = self._run(x, 0, None)
        return h, (x.shape[1], cache)

    def step(self, x: torch.Tensor, state: tuple[int, KVCache]) -> tuple[torch.Tensor, tuple[int, KVCache]]:
        t, cache = state
        h, cache = self._run(x[:, None], t, cache)
        return h[:, 0], (t + 1, cache)


class _TriangularResidual(nn.Module):
    """``x + tanh(W x + b)`` with W strictly lower (or upper) triangular: Jacobian determinant 1."""

    idx: torch.Tensor  # buffer: the (2, K) indices of W's free entries

    def __init__(self, d: int, upper: bool) -> None:
        super().__init__()
        self.upper = upper
        self.register_buffer("idx", torch.triu_indices(d, d, 1) if upper else torch.tril_indices(d, d, -1),
                             persistent=False)
        self.w = nn.Parameter(torch.randn(self.idx.shape[1]) / math.sqrt(d))
        self.b = nn.Parameter(torch.zeros(d))
        self.d = d

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        W = x.new_zeros(self.d, self.d)
        W[self.idx[0], self.idx[1]] = self.w
        return x + torch.tanh(x @ W.T + self.b)


class _SkewCausalAttention(nn.Module):
    """Causal unit-lower-triangular time mixing with weights from a skew-symmetric form."""

    idx: torch.Tensor  # buffer: the (2, K) indices of A's upper triangle

    def __init__(self, d: int) -> None:
        super().__init__()
        self.register_buffer("idx", torch.triu_indices(d, d, 1), persistent=False)
        self.a = nn.Parameter(torch.randn(self.idx.shape[1]) / d)
        self.d = d

    def skew(self, like: torch.Tensor) -> torch.Tensor:
        """The skew-symmetric (d, d) matrix A."""
        A = like.new_zeros(self.d, self.d)
        A[self.idx[0], self.idx[1]] = self.a
        return A - A.T

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        T = z.shape[1]
        z_prev = torch.cat([torch.zeros_like(z[:, :1]), z[:, :-1]], dim=1)
        C = torch.tanh(z_prev @ self.skew(z) @ z.transpose(1, 2))  # (B, T, T): row t uses z_{t-1}, column s uses z_s
        # strictly causal mean: weight 1/t on the columns s < t of row t (one (T, T) factor, one multiply)
        count = torch.arange(T, device=z.device, dtype=z.dtype).clamp_min(1.0)[:, None]
        mean_mask = torch.tril(torch.ones(T, T, dtype=z.dtype, device=z.device), diagonal=-1) / count
        return z + (C * mean_mask) @ z

    def step(self, z: torch.Tensor, past: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Output at the next position t = len(past) for its input z (B, d); ``past`` (B, t, d) holds z_0 .. z_{t-1}."""
        t = past.shape[1]
        out = z
        if t:
            c = torch.tanh(past[:, -1:] @ self.skew(z) @ past.transpose(1, 2))  # (B, 1, t)
            out = z + (c @ past)[:, 0] / t
        return out, torch.cat([past, z[:, None]], 1)


class VPTBaseline(SeqBaseline):
    """Volume-preserving transformer: 2 blocks of skew causal attention + 2 lower/upper VP feed-forwards."""

    stateful = True

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

    def encode_state(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        """Hidden states and, per attention layer, its inputs so far (the rollout cache)."""
        h, cache = self.embed(x), []
        for block in self.blocks:
            cache.append(h)
            h = block(h)
        return h, cache

    def step(self, x: torch.Tensor, state: list[torch.Tensor]) -> tuple[torch.Tensor, list[torch.Tensor]]:
        h, new = self.embed(x), []
        for block, past in zip(self.blocks, state):
            attention, *ffs = cast(nn.Sequential, block)  # _SkewCausalAttention, then the feed-forwards
            h, past = cast(_SkewCausalAttention, attention).step(h, past)
            for ff in ffs:
                h = ff(h)
            new.append(past)
        return h, new
