"""The env path's training configuration (paper Appendix E, Table 13), torch-free so that the regime recipes
(:func:`phast_model.world.regimes.recipe`) can return one beside the model config."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class TrainConfig:
    """Training hyper-parameters (paper Appendix E, Table 13 defaults).

    ``adam_eps`` and ``warmup_epochs`` are the settings a regime may ask for (KNOWN's identification settings:
    eps 1e-15 and a 1-epoch warm-up); None leaves them to the regime recipe (:func:`phast_model.world.regimes.recipe`
    fills them in), and a config that reaches the trainer with None uses AdamW's 1e-8 and no warm-up."""

    epochs: int = 50
    batch_size: int = 64
    lr: float = 1e-3
    weight_decay: float = 1e-5
    val_every: int = 10
    seed: int = 0
    progress: bool = True
    lambda_data: float = 1.0  # weight of L_data (Eq. 85); PHAST's other weights live in its config
    skip_first: int | None = None  # predictions t < skip_first left out of the loss (None: model.loss_skip or 0)
    grad_clip: float | None = 10.0  # max grad norm (None: off)
    warmup_epochs: float | None = None  # linear lr warm-up before the cosine decay (None: the recipe's, else 0)
    adam_eps: float | None = None  # AdamW eps (None: the recipe's, else 1e-8)
    max_nan_events: int = 5  # rollbacks allowed before training stops (the NaN guard)
    nan_lr_factor: float = 0.5  # lr multiplier after a rollback
    checkpoint_every: int = 1  # epochs between checkpoint writes (run_dir given)
    val_batch_size: int = 256
    dtype: str = "float32"

    def __post_init__(self) -> None:
        for name in ("epochs", "batch_size", "val_every", "checkpoint_every", "val_batch_size"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"TrainConfig.{name} must be a positive integer, got {v!r}")
        if not (self.lr > 0 and math.isfinite(self.lr)):
            raise ValueError(f"TrainConfig.lr must be positive and finite, got {self.lr!r}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"TrainConfig.dtype must be float32 or float64, got {self.dtype!r}")
