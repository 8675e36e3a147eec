"""The training-only velocity estimate: :class:`CentralDifference` (``PHASTConfig.train_velocity="central"``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from phast_model.components import CentralDifference, FDTCNObserver
from phast_model.components.observer import derivative_weights

DT = 0.02


def _trajectory(T: int, w: float = 1.3, omega: float = 3.0) -> tuple[torch.Tensor, torch.Tensor]:
    """A smooth (1, T, 2) trajectory (x, wrapped angle theta) and its exact velocity."""
    t = torch.arange(T, dtype=torch.float64) * DT
    x, th = torch.sin(w * t) + 0.2 * t, omega * t + 0.5 * torch.sin(2 * t)
    q = torch.stack([x, torch.remainder(th + math.pi, 2 * math.pi) - math.pi], -1)[None]
    v = torch.stack([w * torch.cos(w * t) + 0.2, omega + torch.cos(2 * t)], -1)[None]
    return q, v


def test_weights_are_the_classical_formulas() -> None:
    assert np.allclose(derivative_weights(np.arange(-1, 2)), [-0.5, 0.0, 0.5])
    assert np.allclose(derivative_weights(np.arange(-2, 3)), np.array([1, -8, 0, 8, -1]) / 12)


@pytest.mark.parametrize("order", [2, 4, 6])
def test_shapes_and_more_accurate_than_the_causal_observer(order: int) -> None:
    q, v = _trajectory(200)
    est = CentralDifference(2, DT, (1,), order)(q)
    assert est.shape == q.shape and est.dtype == q.dtype
    err = (est - v).abs()
    assert err[:, order // 2:-(order // 2)].max() < 1e-3 * DT ** (order - 2)  # interior: O(dt^order)
    # the KNOWN observer (4th-order backward difference): the same-order central difference is ~ 4x as accurate
    causal = (FDTCNObserver(2, DT, (1,)).double()(q) - v)[:, 4:].abs()
    if order >= 4:
        assert err[:, 2:-2].max() < causal.max() / 3


@given(T=st.integers(1, 12), order=st.sampled_from([2, 4, 6, 8]))
@settings(max_examples=30, deadline=None)
def test_ends_and_short_trajectories_exact_on_polynomials(T: int, order: int) -> None:
    """Every row (ends one-sided, short trajectories on all samples) differentiates polynomials of degree
    min(order, T - 1) exactly, so no sample is left without an estimate."""
    t = torch.arange(T, dtype=torch.float64) * DT
    deg = min(order, T - 1)
    q = torch.stack([(1 + t) ** deg, 0.3 * t], -1)[None]
    v = torch.stack([deg * (1 + t) ** (deg - 1) if deg else 0 * t, 0.3 + 0 * t], -1)[None]
    est = CentralDifference(2, DT, (), order)(q)
    assert est.shape == (1, T, 2)
    if T >= 2:
        assert torch.allclose(est, v, rtol=1e-6, atol=1e-6)


def test_long_path_matches_the_dense_matrix_and_rejects_odd_orders() -> None:
    q, _ = _trajectory(40)
    est = CentralDifference(2, DT, (), 4)  # the unfold/one-sided path of T >= 2 (order + 1)
    dense = torch.einsum("st,btn->bsn", torch.as_tensor(est.weights(40)), q)
    assert torch.allclose(est(q), dense)
    with pytest.raises(ValueError):
        CentralDifference(2, DT, (), 3)


def test_phast_uses_it_in_the_loss_only() -> None:
    """``train_velocity="central"`` (the cart-pole KNOWN default): the loss's predictions start from the central
    difference, ``forward`` (rollouts, metrics) keeps the causal observer, the saved weights are the same, and a
    trainable observer is refused."""
    from phast_model.train.fit import next_step_loss
    from phast_model.world.regimes import build_model

    env = "PHAST/WindyCartPole-v0"
    causal, central = build_model(env, "known", train_velocity="observer"), build_model(env, "known")
    assert central.state_dict().keys() == causal.state_dict().keys()
    q = torch.as_tensor(_trajectory(30)[0], dtype=torch.float32) * 0.1
    assert torch.equal(central(q), causal(q))
    assert torch.equal(causal.loss_forward(q), causal(q))
    expected = central._teacher_forced(q, None, CentralDifference(2, central.dt, (1,), 4))
    assert torch.allclose(central.loss_forward(q), expected)
    assert next_step_loss(central, q, None)[0] != next_step_loss(causal, q, None)[0]
    with pytest.raises(ValueError, match="observer_trainable"):
        build_model(env, "known", train_velocity="central", observer_trainable=True)
