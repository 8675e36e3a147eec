"""The traced model step of the controllers (phast_model.control.traced): the same numbers as eager, eager where a
trace would be unsafe, and the planner and the learned-model UKF on it."""

from __future__ import annotations

import numpy as np
import torch

from phast_model.control.traced import Traced


class _Scale(torch.nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.w = torch.nn.Parameter(torch.tensor([2.0, -1.0], dtype=torch.float64))

    def step(self, x: torch.Tensor) -> tuple[torch.Tensor]:
        return (torch.tanh(x * self.w) + x,)

    def branchy(self, x: torch.Tensor) -> tuple[torch.Tensor]:
        return (x * self.w if bool(x.sum() > 0) else -x,)  # the data's value picks a branch


def test_trace_gives_the_eager_numbers_for_every_input_of_its_shape() -> None:
    m = _Scale()
    t = Traced(m, lambda x: m.step(x))  # a function (torch.jit.trace takes no nn.Module method)
    for seed in range(3):
        x = torch.randn(5, 2, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)
        assert torch.equal(t(x)[0], m.step(x)[0])
    assert len(t._calls) == 1 and isinstance(t._calls[((5, 2),)], torch.jit.ScriptFunction)
    assert all(p.requires_grad for p in m.parameters())  # frozen only while tracing
    t(torch.zeros(3, 2, dtype=torch.float64))
    assert len(t._calls) == 2  # one trace per shape


def test_a_branch_on_the_data_stays_eager() -> None:
    """The tracer's warning that a tensor's value steered Python control flow keeps the eager function: a trace at
    a positive sum would apply the positive branch to a negative input."""
    m = _Scale()
    t = Traced(m, lambda x: m.branchy(x))
    t.warm(torch.ones(4, 2, dtype=torch.float64))
    x = -torch.ones(4, 2, dtype=torch.float64)
    assert not isinstance(t._calls[((4, 2),)], torch.jit.ScriptFunction)
    assert torch.equal(t(x)[0], -x)


def test_disabled_is_the_function_itself() -> None:
    m = _Scale()
    t = Traced(m, m.step, enabled=False)
    t.warm(torch.ones(2, 2, dtype=torch.float64))
    assert not t._calls
    x = torch.randn(2, 2, dtype=torch.float64)
    assert torch.equal(t(x)[0], m.step(x)[0])


def test_planner_and_filter_traced_equal_eager() -> None:
    """MPPI's rollout step and the UKF's process step of a PHAST model: traced and eager agree to the bit."""
    from phast_model.control.mppi import MPPI, MPPISpec
    from phast_model.control.phast_estimators import PHASTProcess
    from phast_model.world.regimes import build_model

    model = build_model("PHAST/WindyCartPole-v0", "partial").double()
    g = torch.Generator().manual_seed(1)
    q, p = torch.randn(32, 2, generator=g, dtype=torch.float64), torch.randn(32, 2, generator=g, dtype=torch.float64)
    u = torch.randn(32, 1, generator=g, dtype=torch.float64)
    planners = [MPPI(model, MPPISpec(samples=32, traced=tr), np.array([0.0, np.pi]), 10.0, [0]) for tr in (True, False)]
    assert isinstance(planners[0]._rollout_step._calls[((32, 2), (32, 2), (32, 1))], torch.jit.ScriptFunction)
    out = [mppi._rollout_step(q, p, u) for mppi in planners]
    assert all(torch.equal(a, b) for a, b in zip(*out, strict=True))
    X = np.random.default_rng(0).normal(size=(9, 4))
    filters = [PHASTProcess(model, 0.01, tr) for tr in (True, False)]
    assert isinstance(filters[0]._step._calls[((9, 4), (9, 2))], torch.jit.ScriptFunction)  # warm for the UKF's 9
    np.testing.assert_array_equal(*(f.propagate(X, np.ones(2)) for f in filters))
