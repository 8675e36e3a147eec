"""Full-state PHAST (paper Table 25 ablation): the core on observed (q, p)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from phast_gym.datasets import make_dataset
from phast_model.world.fullstate import FullStatePHAST
from phast_model.world.regimes import build_model


@pytest.fixture(scope="module")
def data():
    ds = make_dataset("PHAST/WindyPendulum-v0", 6, T=40, seed=3)
    x = torch.as_tensor(np.concatenate([ds.q, ds.p], -1), dtype=torch.float32)
    return ds, x


def test_forward_is_one_core_step_and_rollout_iterates_it(data):
    torch.manual_seed(0)
    _, x = data
    inner = build_model("PHAST/WindyPendulum-v0", "partial")
    m = FullStatePHAST(inner)
    out = m(x)
    assert out.shape == x.shape
    q1, p1 = inner.step(x[..., :1], x[..., 1:])
    torch.testing.assert_close(out[..., 1:], p1)
    torch.testing.assert_close(torch.remainder(out[..., :1] - q1 + np.pi, 2 * np.pi) - np.pi, torch.zeros_like(q1), atol=1e-6, rtol=0)
    roll = m.rollout(x[:, :5], None, 3)
    step = x[:, 4:5]
    for h in range(3):
        step = m(step)
        torch.testing.assert_close(roll[:, h], step[:, 0])
    # the observer is frozen and not counted; damping is read at the positions of (q, p)
    assert m.n_parameters() == sum(p.numel() for n, p in inner.named_parameters() if not n.startswith("observer."))
    assert m.damping_diag(x).shape == x[..., :1].shape


def test_bad_input_width_is_a_clear_error(data):
    _, x = data
    m = FullStatePHAST(build_model("PHAST/WindyPendulum-v0", "unknown"))
    with pytest.raises(ValueError, match="2n = 2"):
        m(x[..., :1])


def test_training_on_full_state_lowers_the_loss(data):
    from phast_model.train.fit import TrainConfig, fit

    torch.manual_seed(0)
    ds = make_dataset("PHAST/WindyPendulum-v0", 24, T=40, seed=4)
    from phast_model.bench.runner import full_state_view

    tr, va = full_state_view(ds.subset(slice(0, 16))), full_state_view(ds.subset(slice(16, 24)))
    m = FullStatePHAST(build_model("PHAST/WindyPendulum-v0", "unknown"))
    xv = torch.as_tensor(va.q, dtype=torch.float32)

    def val_mse() -> float:
        with torch.no_grad():
            e = m(xv)[:, :-1] - xv[:, 1:]
            e[..., 0] = torch.remainder(e[..., 0] + np.pi, 2 * np.pi) - np.pi
            return float((e**2).mean())

    before = val_mse()
    res = fit(m, tr, va, TrainConfig(epochs=10, batch_size=4, lr=3e-3, seed=0, progress=False))
    after = val_mse()
    assert np.isfinite(after) and after < 0.5 * before, (before, after, res.best_val)
