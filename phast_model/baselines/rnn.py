"""Recurrent baselines: GRU (Cho et al., 2014) and LSTM (Hochreiter & Schmidhuber, 1997).

Paper Table 14: hidden d = 64, depth 2, GRU dropout 0.  The gate equations are
torch's ``nn.GRU`` / ``nn.LSTM`` (the papers' equations: GRU reset/update gates,
LSTM input/forget/output gates with a cell state); the features go straight into
the first recurrent layer and a linear head reads the increment out.
"""

from __future__ import annotations

from typing import TypeAlias

import torch
from torch import nn

from .common import SeqBaseline

#: the recurrent state: a GRU's hidden tensor or an LSTM's (h, c), (depth, B, d) each
RNNState: TypeAlias = torch.Tensor | tuple[torch.Tensor, torch.Tensor]


class _RNNBaseline(SeqBaseline):
    stateful = True
    cell: type[nn.GRU] | type[nn.LSTM] = nn.GRU

    def __init__(self, n: int, m: int, angle_dims: tuple[int, ...] = (), d_model: int = 64, depth: int = 2,
                 dropout: float = 0.0) -> None:
        super().__init__(n, m, angle_dims, d_model)
        self.rnn = self.cell(self.in_dim, self.d_model, num_layers=depth, batch_first=True,
                             dropout=dropout if depth > 1 else 0.0)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        return self.rnn(x)[0]

    def encode_state(self, x: torch.Tensor) -> tuple[torch.Tensor, RNNState]:
        return self.rnn(x)

    def step(self, x: torch.Tensor, state: RNNState) -> tuple[torch.Tensor, RNNState]:
        h, state = self.rnn(x[:, None], state)
        return h[:, 0], state


class GRUBaseline(_RNNBaseline):
    """2-layer GRU next-step predictor (paper Table 14: d = 64, dropout 0)."""

    cell = nn.GRU


class LSTMBaseline(_RNNBaseline):
    """2-layer LSTM next-step predictor (d = 64)."""

    cell = nn.LSTM
