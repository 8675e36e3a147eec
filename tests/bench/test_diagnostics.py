"""phast_model.bench.diagnostics (benchmarks/regime_diagnostics.py): the error decomposition re-scores the row metric
and isolates its parts."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from phast_gym.datasets import make_splits
from phast_model.bench import diagnostics
from phast_model.bench.spec import RunSpec
from phast_model.train.metrics import forecast_metrics
from phast_model.world.regimes import build_model

ENV = "PHAST/DampedPendulum-v0"


@pytest.fixture(scope="module")
def rd():  # noqa: ANN201
    return diagnostics


@pytest.fixture(scope="module")
def test_split():  # noqa: ANN201
    return make_splits(ENV, 8, 4, 6, T=120, seed=3, cache=False)["test"]


def _known_with(d_floor: float, env: str = ENV) -> torch.nn.Module:
    """The KNOWN model untrained, its damping the constant floor ``d_floor`` (the Householder terms switched off)."""
    model = build_model(env, "known", seed=0)
    damping = model.core.damping
    with torch.no_grad():
        damping.set_d0(d_floor)
        last, n_dir = damping.net[-1], damping.rank * damping.n
        last.weight[n_dir:] = 0.0
        last.bias[n_dir:] = -60.0  # softplus(-60) ~ 1e-26
    return model.eval()


def test_scored_is_the_row_metric(rd, test_split) -> None:
    model = _known_with(0.2)
    spec = RunSpec(env_id=ENV, model="phast-known", seed=0, T=120)
    metric = forecast_metrics(model, test_split, horizons=(100,), energy=False)["rollout_theta_wrap_mse_h100"]
    d = rd.diagnose(model, spec, test_split, recorded=metric)
    assert d.scored == pytest.approx(metric, rel=1e-9)
    assert 0.0 < d.worst5_share <= 1.0
    assert d.startup_share is None and d.floor_ratio is None  # next-step rows only


def test_true_damping_from_the_true_state_reproduces_the_data(rd, test_split) -> None:
    """KNOWN has the env's V and M: with the env's D and the true state, only the time step is left (~0), while the
    wrong learned floor (0.2 against 0.5) shows up in oracle_state and in the dissipation rate."""
    model = _known_with(0.2)
    spec = RunSpec(env_id=ENV, model="phast-known", seed=0, T=120)
    d = rd.diagnose(model, spec, test_split, recorded=float("nan"))
    assert d.oracle_state_true_D < 1e-6 < d.oracle_state_fine
    assert d.true_rate == pytest.approx(0.5 / 1.0, rel=0.2)  # D / (m l^2) of the env
    assert d.learned_rate == pytest.approx(d.true_rate * 0.2 / 0.5, rel=0.05)
    assert np.isfinite(d.velocity_rel_err)


def test_missing_weights_name_the_file(rd, tmp_path, test_split) -> None:
    spec = RunSpec(env_id=ENV, model="phast-known", seed=0)
    with pytest.raises(FileNotFoundError, match="bench_model.pt"):
        rd.load_trained(tmp_path, spec, {"train": test_split})


def test_next_step_rows_are_decomposed_too(rd) -> None:
    """RLC's row metric is the next-step MSE (Eq. 90): scored equals it, and the true D from the true state is exact."""
    env = "PHAST/RLCCircuit-v0"
    test = make_splits(env, 8, 4, 6, T=60, seed=3, cache=False)["test"]
    model = _known_with(0.1, env)
    spec = RunSpec(env_id=env, model="phast-known", seed=0, T=60)
    metric = forecast_metrics(model, test, horizons=(10,), energy=False)["mse"]
    d = rd.diagnose(model, spec, test, recorded=metric, floor=0.5 * metric)
    assert d.metric == "mse" and d.takeover is None
    assert d.scored == pytest.approx(metric, rel=1e-9)
    assert d.oracle_state_true_D < 1e-3 * d.oracle_state_fine
    assert d.floor_ratio == pytest.approx(2.0, rel=1e-9)
    # the start-up share: the per-step errors of the first loss_skip predictions over all of them
    with torch.no_grad():
        se = ((model(torch.as_tensor(test.q, dtype=torch.float32)).numpy()[:, :-1] - test.q[:, 1:]) ** 2).mean(axis=(0, 2))
    assert 0.0 < d.startup_share < 1.0
    assert d.startup_share == pytest.approx(se[:model.loss_skip].sum() / se.sum(), rel=1e-4)


def test_merge_keeps_other_blocks_and_retires_stale_keys(rd) -> None:
    """The grid refreshes one block at a time: other blocks stay, entries of a bumped revision are dropped."""
    def diag(env: str, model: str, seed: int, key: str | None = None) -> object:
        spec = RunSpec(env_id=env, model=model, seed=seed)
        return rd.Diagnosis(env=env, model=model, seed=seed, key=key or rd.run_key(spec), metric="mse", recorded=1.0,
                            scored=1.0, takeover=None, oracle_state=None, oracle_state_fine=None,
                            oracle_state_true_D=None, velocity_rel_err=None, learned_rate=None, true_rate=0.0,
                            worst5_share=1.0)

    import dataclasses

    old = [dataclasses.asdict(d) for d in (diag(ENV, "phast-known", 0), diag(ENV, "phast-partial", 0),
                                            diag("PHAST/Pendulum-v0", "phast-known", 1, key="0" * 16))]
    new = [diag(ENV, "phast-partial", 1)]
    merged = rd.merge(old, new, {(ENV, "phast-partial")})
    assert [(d.env, d.model, d.seed) for d in merged] == [(ENV, "phast-known", 0), (ENV, "phast-partial", 1)]
    assert "| DampedPendulum-v0 | phast-known | 1 |" in rd.diagnoses_markdown(merged)
