"""What limits the damping R^2 of the windy cart-pole KNOWN model (issue 39 item 1): the oracle fit of D.

    .venv/bin/python benchmarks/cartpole_damping_floor.py --n-traj 1000 --fd-orders 3 4 5 6 [--out FILE.json]
    .venv/bin/python benchmarks/cartpole_damping_floor.py --fd-orders 4 --central-orders 2 4 6 8

With the TRUE mass M(q) and potential V(q) of the env (what the KNOWN regime is given), it fits ONLY the damping
D(q), linear in a basis, by Gauss-Newton on the model's own objective: the teacher-forced next-step MSE of
``phast-train`` (Strang splitting, implicit midpoint, L = 4 substeps), from the same q-only training data.  That
is the best any learner of this model class can do from these data; its damping R^2 on the test split (Eq. 93,
``damping_scores``) is the floor.  Velocity sources:

* ``fd<k>``: the KNOWN observer (fixed backward-difference formula of order k; the default is k = 4);
* ``exact``: the simulator's own velocity M(q)^-1 p (not available to a q-only model: shows what the observer costs);
* ``central<k>``: the non-causal central difference of accuracy k (:class:`CentralDifference`, one-sided at the
  trajectory ends), what ``PHASTConfig.train_velocity="central"`` puts in the training loss.

Bases (the true D is diag(0.3, 0.3 + 0.5 |sin theta|)):

* ``form``: D = diag(a, b + c |sin theta|), the true functional form (3 coefficients);
* ``free``: every entry of a symmetric D (xx, theta-theta, x-theta) on [1, |sin theta|, cos theta, sin theta,
  cos 2 theta, sin 2 theta] (18 coefficients, off-diagonal allowed as in the Householder damping);
* ``freediag``: the same basis on the two diagonal entries only (12 coefficients, D diagonal).

Measured at 341aa8f (docs/phast_model.md, "KNOWN, windy cart-pole"): order 4, 1000 trajectories: form 0.9990,
freediag 0.9889, free 0.9868; exact velocities >= 0.9997 with every basis.  Central differences (at 41c5271, the
second command, docs/results/cartpole_damping_floor_central.json): order 2 0.83-0.87 (its O(dt^2) error is larger
than the backward difference's O(dt^4)), order 4, 6, 8 >= 0.9996 with every basis, true-D loss 4.4e-12 / 3.4e-12 /
3.4e-12 (fd4 1.8e-10, exact 2.9e-12).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import torch

from phast_gym import make_splits
from phast_model.components.damping import Damping, KnownDamping
from phast_model.components.observer import CentralDifference
from phast_model.train.metrics import damping_scores
from phast_model.world.regimes import build_model

ENV = "PHAST/WindyCartPole-v0"


def basis(q: torch.Tensor, kind: str) -> torch.Tensor:
    th = q[..., 1]
    one = torch.ones_like(th)
    if kind == "form":
        return torch.stack([one, th.sin().abs()], -1)
    # "free" / "freediag"
    return torch.stack([one, th.sin().abs(), th.cos(), th.sin(), (2 * th).cos(), (2 * th).sin()], -1)


class BasisDamping(Damping):
    """D(q) linear in coefficients w: ``form``: diag(w0, w1 + w2 |sin|); ``free``: xx, tt, xt entries on a basis."""

    def __init__(self, kind: str, w: torch.Tensor) -> None:
        super().__init__()
        self.kind, self.w = kind, w

    def entries(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        phi = basis(q, self.kind).to(self.w.dtype)
        if self.kind == "form":
            w = self.w
            return w[0] * phi[..., 0], phi @ w[1:3], torch.zeros_like(phi[..., 0])
        k = phi.shape[-1]
        off = phi @ self.w[2 * k:] if self.kind == "free" else torch.zeros_like(phi[..., 0])
        return phi @ self.w[:k], phi @ self.w[k:2 * k], off

    def force(self, q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        dxx, dtt, dxt = self.entries(q)
        return torch.stack([dxx * v[..., 0] + dxt * v[..., 1], dxt * v[..., 0] + dtt * v[..., 1]], -1)

    def diag(self, q: torch.Tensor) -> torch.Tensor:
        dxx, dtt, _ = self.entries(q)
        return torch.stack([dxx, dtt], -1)

    def bound(self, q: torch.Tensor) -> torch.Tensor:
        return self.diag(q).abs().max(-1).values


def known_model(fd_order: int):  # noqa: ANN201
    """The KNOWN model of ``phast-train``'s defaults (true M, V; fixed FD observer of order ``fd_order``), float64."""
    return build_model(ENV, "known", observer_fd_order=fd_order).double().eval()


def residual_fn(model, q: torch.Tensor, v: torch.Tensor, skip: int):  # noqa: ANN001, ANN201
    """w -> flattened next-step errors (wrapped angle) of ``model`` with D = BasisDamping(w)."""
    p = model.canonicalize(q, v)

    def r(kind: str, w: torch.Tensor) -> torch.Tensor:
        model.core.damping = BasisDamping(kind, w)
        with torch.no_grad():
            q1, _ = model.core.strang_step(q, p, None, need_p=False)
        d = q1[:, skip:-1] - q[:, skip + 1:]
        d[..., 1] = torch.remainder(d[..., 1] + math.pi, 2 * math.pi) - math.pi
        return d.reshape(-1)

    return r


def gauss_newton(r, kind: str, n_w: int, iters: int = 3) -> tuple[torch.Tensor, float]:  # noqa: ANN001
    w = torch.zeros(n_w, dtype=torch.float64)
    for _ in range(iters):
        r0 = r(kind, w)
        eps = 1e-2
        J = torch.stack([(r(kind, w + eps * torch.eye(n_w, dtype=torch.float64)[k]) - r0) / eps for k in range(n_w)], 1)
        dw = torch.linalg.lstsq(J, -r0.unsqueeze(1)).solution.squeeze(1)
        w = w + dw
    return w, float(r(kind, w).pow(2).mean())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n-traj", type=int, default=1000, help="training trajectories used by the fit (of 1000)")
    ap.add_argument("--n-train", type=int, default=1000, help="size of the training split generated")
    ap.add_argument("--fd-orders", type=int, nargs="+", default=[3, 4, 5, 6])
    ap.add_argument("--central-orders", type=int, nargs="*", default=[], help="central-difference accuracies (even)")
    ap.add_argument("--bases", nargs="+", default=["form", "freediag", "free"])
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    sp = make_splits(ENV, n_train=args.n_train)
    tr, te = sp["train"], sp["test"]
    q = torch.as_tensor(np.asarray(tr.q[: args.n_traj]), dtype=torch.float64)
    p_true = torch.as_tensor(np.asarray(tr.p[: args.n_traj]), dtype=torch.float64)
    q_te = torch.as_tensor(np.asarray(te.q), dtype=torch.float64)
    d_te = np.asarray(te.damping)
    skip = 8  # the same steps for every observer order (>= any fd_order's start-up)
    rows = []
    sources = ([("exact", 4)] + [(f"fd{k}", k) for k in args.fd_orders]
               + [(f"central{k}", k) for k in args.central_orders])
    for src, k in sources:
        model = known_model(4 if src.startswith("central") else k)
        v_true = model.mass.velocity(q, p_true)
        if src.startswith("central"):
            v = CentralDifference(model.n, model.dt, model.angle_dims, k).double()(q)
        else:
            v = v_true if src == "exact" else model.observer(q).detach()
        v_rms = [float(x) for x in (v - v_true)[:, skip:-1].pow(2).mean((0, 1)).sqrt()]
        print(f"velocity {src}: rms error vs M^-1 p {v_rms[0]:.2e} / {v_rms[1]:.2e}", flush=True)
        r = residual_fn(model, q, v, skip)
        model.core.damping = KnownDamping(tr.system)
        with torch.no_grad():
            q1, _ = model.core.strang_step(q, model.canonicalize(q, v), None, need_p=False)
        dd = q1[:, skip:-1] - q[:, skip + 1:]
        dd[..., 1] = torch.remainder(dd[..., 1] + math.pi, 2 * math.pi) - math.pi
        loss_true = float(dd.pow(2).mean())
        for kind in args.bases:
            n_w = {"form": 3, "freediag": 12, "free": 18}[kind]
            w, loss = gauss_newton(r, kind, n_w)
            d_hat = BasisDamping(kind, w).diag(q_te).detach().numpy()
            sc = damping_scores(d_hat, d_te)
            rows.append({"velocity": src, "basis": kind, "v_rms": v_rms, "loss_fit": loss, "loss_true_D": loss_true,
                         "damping_r2": sc["damping_r2"], "damping_mae": sc["damping_mae"],
                         "cart_mean": float(d_hat[..., 0].mean()), "w": [round(float(x), 4) for x in w]})
            print(f"velocity {src:6s} basis {kind:5s}: next-step loss fit {loss:.3e} (true D {loss_true:.3e})  "
                  f"test damping R^2 {sc['damping_r2']:.4f}  MAE {sc['damping_mae']:.4f}  cart D mean "
                  f"{d_hat[..., 0].mean():.4f}" + (f"  w {rows[-1]['w']}" if kind == "form" else ""), flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps({"n_traj": args.n_traj, "n_train": args.n_train, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
