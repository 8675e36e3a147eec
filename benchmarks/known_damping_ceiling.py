"""Diagnostics of KNOWN damping identification on the windy pendulum (CPU, about a minute).

    .venv/bin/python benchmarks/known_damping_ceiling.py --substeps 4 8

1. Gradient scale: one-step loss and mean |grad| of the damping parameters at init on one batch of 64
   trajectories (compare with AdamW's default eps = 1e-8: why KNOWN uses eps = 1e-15).
2. Ceiling: the KNOWN model (env V, M, frozen BDF4 observer, L substeps) with D(q) replaced by a linear
   Fourier series c0 + sum_k a_k cos kq + b_k sin kq (K terms), fitted by full-batch L-BFGS on the
   same one-step loss (``--n-traj`` training trajectories): the damping R^2 on the test split that the
   loss itself can deliver (observer and splitting biases included), and the loss of the true D.
Prints one JSON line per L.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch
from torch import nn

from phast_gym import make_env_system, make_splits
from phast_model.components.damping import Damping, KnownDamping
from phast_model.train.fit import next_step_loss
from phast_model.world.regimes import build_model

ENV = "PHAST/WindyPendulum-v0"


class FourierDamping(Damping):
    """Diagonal D(q) = c0 + sum_k a_k cos(k q) + b_k sin(k q) (1-D angle; diagnostics only, not PSD-constrained)."""

    def __init__(self, K: int, c0: float = 0.5) -> None:
        super().__init__()
        self.K = K
        self.c = nn.Parameter(torch.zeros(2 * K + 1))
        with torch.no_grad():
            self.c[0] = c0

    def diag(self, q: torch.Tensor) -> torch.Tensor:
        a = q[..., :1] * torch.arange(1, self.K + 1, dtype=q.dtype)
        return (torch.cat([torch.ones_like(q[..., :1]), torch.cos(a), torch.sin(a)], -1) * self.c).sum(-1, keepdim=True)

    def force(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        return self.diag(q) * v

    def bound(self, q: torch.Tensor) -> torch.Tensor:
        return self.diag(q).abs().max(-1).values


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--substeps", type=int, nargs="+", default=[4, 8])
    ap.add_argument("--K", type=int, default=12, help="Fourier terms of the ceiling fit")
    ap.add_argument("--n-traj", type=int, default=400, help="training trajectories in the full-batch fit")
    args = ap.parse_args(argv)
    if args.K < 1 or args.n_traj < 1 or min(args.substeps) < 1:
        raise SystemExit("--K, --n-traj and --substeps must be >= 1")
    torch.set_num_threads(1)
    sp = make_splits(ENV, 1000, 200, 200, T=200, seed=42)
    q = torch.as_tensor(sp["train"].q[: args.n_traj], dtype=torch.float32)
    qt, d = sp["test"].q, sp["test"].damping
    for L in args.substeps:
        model = build_model(ENV, "known", substeps=L)
        loss0, _ = next_step_loss(model, q[:64], None, model.loss_skip)
        loss0.backward()
        grads = {n: float(p.grad.abs().mean()) for n, p in model.named_parameters() if p.grad is not None}
        model.core.damping = FourierDamping(args.K)
        opt = torch.optim.LBFGS(model.core.damping.parameters(), lr=1, max_iter=200, line_search_fn="strong_wolfe",
                                tolerance_grad=1e-14, tolerance_change=1e-16)

        def closure(opt: torch.optim.Optimizer = opt, model: nn.Module = model) -> torch.Tensor:
            opt.zero_grad()
            loss = next_step_loss(model, q, None, model.loss_skip)[0] * 1e6  # scaled for L-BFGS tolerances
            loss.backward()
            return loss

        for _ in range(3):
            opt.step(closure)
        with torch.no_grad():
            fit_loss = float(next_step_loss(model, q, None, model.loss_skip)[0])
            dh = model.core.damping.diag(torch.as_tensor(qt, dtype=torch.float32)).numpy()
            model.core.damping = KnownDamping(make_env_system(ENV))
            true_loss = float(next_step_loss(model, q, None, model.loss_skip)[0])
        r2 = float(1 - ((dh - d) ** 2).sum() / ((d - d.mean()) ** 2).sum())
        print(json.dumps({"substeps": L, "init_loss": float(loss0.detach()), "init_mean_abs_grad": grads, "K": args.K,
                          "ceiling_damping_r2": r2, "ceiling_damping_mae": float(np.abs(dh - d).mean()),
                          "fourier_fit_loss": fit_loss, "true_D_loss": true_loss}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
