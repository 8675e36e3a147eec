"""Baseline forecasters of the paper (Sec. 4.1.1, Table 14) behind one registry.

>>> from phast_model.baselines import make_baseline
>>> model = make_baseline("gru", n=1, m=1, angle_dims=(0,))

All are :class:`phast_model.world.interfaces.ForecastModel` subclasses: causal
seq2seq next-step predictors with d = 64, depth 2 unless overridden by ``**kw``.
"""

from __future__ import annotations

from typing import Any

from ..world.interfaces import ForecastModel
from .common import SeqBaseline
from .dhnn import DHNNBaseline
from .rnn import GRUBaseline, LSTMBaseline
from .ssm import DLinOSSBaseline, LinOSSBaseline, S5Baseline
from .transformer import TransformerBaseline, VPTBaseline

#: registry name -> class (names as used on the phast-bench command line)
BASELINES: dict[str, type[ForecastModel]] = {
    "gru": GRUBaseline,
    "lstm": LSTMBaseline,
    "transformer": TransformerBaseline,
    "s5": S5Baseline,
    "linoss": LinOSSBaseline,
    "dlinoss": DLinOSSBaseline,
    "vpt": VPTBaseline,
    "dhnn": DHNNBaseline,
}

#: display names used in tables (paper spelling)
DISPLAY_NAMES = {"gru": "GRU", "lstm": "LSTM", "transformer": "Transformer", "s5": "S5", "linoss": "LinOSS",
                 "dlinoss": "D-LinOSS", "vpt": "VPT", "dhnn": "DHNN"}

#: baselines that need the full state (q, p) as input rather than q only
FULL_STATE = frozenset({"dhnn"})


def make_baseline(name: str, n: int, m: int, angle_dims: tuple[int, ...] = (), **kw: Any) -> ForecastModel:
    """Build baseline ``name`` (see :data:`BASELINES`) for n coordinates and m inputs."""
    key = name.lower().replace("-", "").replace("_", "")
    if key not in BASELINES:
        raise ValueError(f"unknown baseline {name!r}; known: {sorted(BASELINES)}")
    return BASELINES[key](n, m, tuple(angle_dims), **kw)


__all__ = ["BASELINES", "DISPLAY_NAMES", "FULL_STATE", "SeqBaseline", "make_baseline", "GRUBaseline", "LSTMBaseline",
           "TransformerBaseline", "S5Baseline", "LinOSSBaseline", "DLinOSSBaseline", "VPTBaseline", "DHNNBaseline"]
