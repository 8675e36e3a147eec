"""KNOWN's least-squares damping floor (phast_model.world.data_init.damping_floor) with its basis against plain
harmonics, on the windy and damped envs (256 training trajectories, dataset seed 42).

    .venv/bin/python benchmarks/damping_floor_basis.py
"""

from __future__ import annotations

import numpy as np
import torch

from phast_gym.datasets import make_dataset
from phast_model.world import data_init
from phast_model.world.regimes import build_model

ENVS = ("PHAST/WindyPendulum-v0", "PHAST/WindyCartPole-v0", "PHAST/WindyDoublePendulum-v0", "PHAST/DampedPendulum-v0")


def harmonics(q: torch.Tensor, angle_dims: tuple[int, ...], K: int = 4) -> torch.Tensor:
    """1, cos kq and sin kq (k <= K) per angle, (q, q^2) scaled by their RMS otherwise."""
    parts = [torch.ones_like(q[:, 0])]
    for i in range(q.shape[-1]):
        x = q[:, i]
        if i in angle_dims:
            parts += [f(k * x) for k in range(1, K + 1) for f in (torch.cos, torch.sin)]
        else:
            z = x / x.pow(2).mean().sqrt().clamp_min(1e-9)
            parts += [z, z * z]
    return torch.stack(parts, -1)


def main() -> int:
    torch.set_num_threads(1)
    default = data_init._fourier
    for env in ENVS:
        ds = make_dataset(env, 256, T=200, seed=42)
        model = build_model(env, "known")
        kin = data_init.kinematics(torch.as_tensor(ds.q, dtype=torch.float32), None, model.dt, tuple(model.angle_dims))
        row = {}
        for name, basis in (("default basis", default), ("harmonics <= 4q", harmonics)):
            data_init._fourier = basis
            try:
                row[name] = round(data_init.damping_floor(model, kin), 4)
            finally:
                data_init._fourier = default
        print(f"{env:<32} true min D {float(np.min(ds.damping)):.3f}  {row}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
