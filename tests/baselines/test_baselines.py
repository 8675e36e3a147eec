"""Baselines: shapes, causality, rollout = autoregressive definition, parameter counts, learning."""

from __future__ import annotations

import pytest
import torch

from phast_model.baselines import BASELINES, DHNNBaseline, TransformerBaseline, make_baseline
from phast_model.baselines.ssm import scan_2x2, scan_complex_diag, scan_diag
from phast_model.baselines.transformer import sinusoidal_encoding
from phast_model.world.interfaces import ForecastModel, coordinate_error

SEQ = [k for k in BASELINES if k != "dhnn"]
torch.set_num_threads(1)


def _data(n: int, m: int, B: int = 3, T: int = 24, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(B, T, n, generator=g), torch.randn(B, T - 1, m, generator=g)


def _model(name: str, n: int = 2, m: int = 1, angle_dims: tuple[int, ...] = (0,)) -> ForecastModel:
    torch.manual_seed(0)
    model = make_baseline(name, n, m, angle_dims)
    model.eval()  # dropout off (Transformer) so outputs are deterministic
    return model


@pytest.mark.parametrize("name", SEQ)
def test_shapes_and_wrapping(name: str) -> None:
    model = _model(name)
    q, u = _data(2, 1)
    out = model(q, u)
    assert out.shape == q.shape and torch.isfinite(out).all()
    assert out[..., 0].abs().max() <= torch.pi + 1e-6  # angular output wrapped
    assert model(q, None).shape == q.shape  # no input: zeros
    assert model(q, torch.cat([u, u[:, :1]], 1)).shape == q.shape  # u of length T
    with pytest.raises(ValueError, match="q must have shape"):
        model(q[..., :1], u)


@pytest.mark.parametrize("name", SEQ)
def test_causal(name: str) -> None:
    """Changing q or u after time t never changes the predictions at times <= t."""
    model = _model(name)
    q, u = _data(2, 1)
    t = 13
    q2, u2 = q.clone(), u.clone()
    q2[:, t + 1:] += torch.randn_like(q2[:, t + 1:])
    u2[:, t + 1:] += 3.0
    a, b = model(q, u), model(q2, u2)
    assert torch.equal(a[:, : t + 1], b[:, : t + 1])
    assert not torch.allclose(a[:, t + 1:], b[:, t + 1:])


@pytest.mark.parametrize("name", SEQ)
def test_rollout_matches_autoregressive_definition(name: str) -> None:
    model = _model(name)
    q, u = _data(2, 1, T=30)
    fast = model.rollout(q[:, :8], u, 12)
    slow = ForecastModel.rollout(model, q[:, :8], u, 12)  # the interface's step-by-step definition
    assert fast.shape == (3, 12, 2)
    assert torch.allclose(fast, slow, atol=2e-4, rtol=1e-3)
    assert torch.allclose(model.rollout(q[:, :8], None, 5), ForecastModel.rollout(model, q[:, :8], None, 5), atol=2e-4)


@pytest.mark.parametrize("name", SEQ)
def test_cached_rollout_equals_definition_float64(name: str) -> None:
    """O(H) rollouts (recurrent state, KV cache, VPT input cache) = re-running the prefix, to 1e-10 in float64."""
    model = _model(name).double()
    q, u = (t.double() for t in _data(2, 1, T=40))
    for uu in (u, None):
        fast = model.rollout(q[:, :9], uu, 30)
        slow = ForecastModel.rollout(model, q[:, :9], uu, 30)
        assert (fast - slow).abs().max() <= 1e-10


def _torch_encoder(model: TransformerBaseline, x: torch.Tensor) -> torch.Tensor:
    """Reference hidden states: torch's nn.TransformerEncoder on the model's own weights."""
    T = x.shape[1]
    h = model.embed(x) + sinusoidal_encoding(T, model.d_model, x.device, x.dtype)
    mask = torch.triu(torch.ones(T, T, dtype=torch.bool), diagonal=1)
    return model.encoder(h, mask=mask, is_causal=True)


@pytest.mark.parametrize("train", [False, True])
def test_transformer_fused_attention_matches_torch_encoder(train: bool) -> None:
    """Fused causal attention = torch's encoder (outputs and parameter gradients to 1e-10, float64); train mode
    with dropout 0 exercises torch's training path (the one that also drops attention weights)."""
    torch.manual_seed(0)
    model = make_baseline("transformer", 2, 1, (0,), dropout=0.0).double().train(train)
    x = torch.randn(3, 23, model.in_dim, dtype=torch.float64)
    w = torch.randn(3, 23, model.d_model, dtype=torch.float64)
    params = [*model.embed.parameters(), *model.encoder.parameters()]
    fast, ref = model.encode(x), _torch_encoder(model, x)
    assert (fast - ref).abs().max() <= 1e-10
    for a, b in zip(torch.autograd.grad((fast * w).sum(), params), torch.autograd.grad((ref * w).sum(), params)):
        assert (a - b).abs().max() <= 1e-10 * max(1.0, float(b.abs().max()))


def test_transformer_dropout_is_active_in_training() -> None:
    model = _model("transformer").train()
    q, u = _data(2, 1)
    assert not torch.equal(model(q, u), model(q, u))


def _rnn_params(gate: int, f: int, n: int, d: int = 64) -> int:
    layer1 = gate * (f * d + d * d + 2 * d)
    layer2 = gate * (2 * d * d + 2 * d)
    return layer1 + layer2 + d * n + n


def test_parameter_counts() -> None:
    """Closed-form counts for the d = 64, depth-2 architectures (features = sin/cos angles + u)."""
    n, m, f = 2, 1, 2 + 1 + 1  # q = (angle, x): sin, cos, x, u
    assert _model("gru", n, m).n_parameters() == _rnn_params(3, f, n)
    assert _model("lstm", n, m).n_parameters() == _rnn_params(4, f, n)
    d = 64
    enc = f * d + d + d * n + n
    per_layer = (3 * d * d + 3 * d) + (d * d + d) + (d * 4 * d + 4 * d) + (4 * d * d + d) + 4 * d
    assert _model("transformer", n, m).n_parameters() == enc + 2 * per_layer
    P = 32  # S5: d_state 64 as 32 conjugate pairs; Lambda (2P) + B, C complex + D + LayerNorm
    assert _model("s5", n, m).n_parameters() == enc + 2 * (2 * P + 2 * P * d * 2 + d + 2 * d)
    assert _model("linoss", n, m).n_parameters() == enc + 2 * (2 * P + 2 * P * d * 2 + d + 2 * d)
    assert _model("dlinoss", n, m).n_parameters() == enc + 2 * (3 * P + 2 * P * d * 2 + d + 2 * d + d * 2 * d + 2 * d)
    tri = d * (d - 1) // 2
    assert _model("vpt", n, m).n_parameters() == enc + 2 * (tri + 4 * (tri + d))
    # buffers (normalization) are not parameters
    assert all(not b.requires_grad for b in _model("gru").buffers())


@pytest.mark.parametrize("name", SEQ)
def test_a_few_steps_lower_the_loss(name: str) -> None:
    torch.manual_seed(1)
    t = torch.arange(40) * 0.1
    phase = torch.rand(16, 1) * 6
    q = torch.stack([torch.remainder(torch.sin(t + phase) * 2 + torch.pi, 2 * torch.pi) - torch.pi, torch.cos(t + phase)], -1)
    u = torch.zeros(16, 39, 1)
    model = make_baseline(name, 2, 1, (0,))
    model.fit_normalizer(q, u)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)

    def loss() -> torch.Tensor:
        e = coordinate_error(model(q, u)[:, :-1], q[:, 1:], (0,))
        return (e * e).mean()

    model.train()
    first = float(loss().detach())
    for _ in range(15):
        opt.zero_grad()
        ell = loss()
        ell.backward()
        opt.step()
    assert float(loss().detach()) < first


def test_registry_and_errors() -> None:
    assert isinstance(make_baseline("D-LinOSS", 1, 0), BASELINES["dlinoss"])
    with pytest.raises(ValueError, match="unknown baseline"):
        make_baseline("mamba", 1, 1)
    with pytest.raises(ValueError, match="angle_dims"):
        make_baseline("gru", 1, 1, (3,))
    m = make_baseline("gru", 1, 0, (0,))  # unactuated system
    assert m(torch.zeros(2, 5, 1), None).shape == (2, 5, 1)
    with pytest.raises(ValueError, match="shape"):
        m.fit_normalizer(torch.zeros(5, 1))


def test_fit_normalizer_sets_scales() -> None:
    m = make_baseline("s5", 2, 1, (0,))
    q = torch.stack([torch.zeros(4, 10), 5 + 3 * torch.randn(4, 10)], -1)
    m.fit_normalizer(q, torch.randn(4, 9, 1) * 7)
    assert abs(float(m.q_mean[1]) - float(q[..., 1].mean())) < 1e-5
    assert 4 < float(m.u_std[0]) < 10
    state = m.state_dict()
    assert "q_std" in state and "dq_scale" in state  # scales travel with the checkpoint


def test_scan_diag_matches_recurrence() -> None:
    g = torch.Generator().manual_seed(0)
    a = torch.complex(torch.rand(5, generator=g) * 0.9, torch.rand(5, generator=g) * 0.3)
    b = torch.randn(2, 37, 5, dtype=torch.complex64, generator=g)
    x, ref = torch.zeros(2, 5, dtype=torch.complex64), []
    for t in range(37):
        x = a * x + b[:, t]
        ref.append(x)
    assert torch.allclose(scan_diag(a, b), torch.stack(ref, 1), atol=1e-5)


@pytest.mark.parametrize("T", [1, 2, 37, 200])
def test_complex_scan_equals_the_log_depth_scan_with_gradients(T: int) -> None:
    """S5's scan as 2x2 rotation-scalings: the values and the gradients of scan_diag (float64, to 1e-10)."""
    g = torch.Generator().manual_seed(T)
    lam = torch.polar(0.5 + 0.5 * torch.rand(6, generator=g, dtype=torch.float64),
                      3 * torch.rand(6, generator=g, dtype=torch.float64)).requires_grad_(True)
    b = torch.randn(3, T, 6, dtype=torch.complex128, generator=g).requires_grad_(True)
    w = torch.randn(3, T, 6, dtype=torch.complex128, generator=g)
    x1, x2 = scan_diag(lam, b), scan_complex_diag(lam, b)
    assert torch.allclose(x1, x2, atol=1e-10)
    g1 = torch.autograd.grad((x1 * w).real.sum(), (lam, b), allow_unused=True)  # T = 1: lam is not used
    g2 = torch.autograd.grad((x2 * w).real.sum(), (lam, b), allow_unused=True)
    for a, c, ref in zip(g1, g2, (lam, b)):
        zero = torch.zeros_like(ref)
        assert torch.allclose(zero if a is None else a, zero if c is None else c, atol=1e-10)


def test_s5_outputs_are_those_of_the_log_depth_scan(monkeypatch) -> None:
    """The S5 baseline with the 2x2 scan gives the outputs of the earlier log-depth scan to 1e-6 (float32)."""
    import phast_model.baselines.ssm as ssm

    torch.manual_seed(0)
    m = make_baseline("s5", 2, 1, (0,))
    q, u = torch.randn(4, 50, 2), torch.randn(4, 50, 1)
    fast = m(q, u)
    monkeypatch.setattr(ssm, "scan_complex_diag", ssm.scan_diag)
    assert torch.allclose(fast, m(q, u), atol=1e-6)


def test_vpt_attention_is_the_causal_mean_of_its_definition() -> None:
    """VPT's skew attention, row by row: out_t = z_t + (1/t) sum_{s<t} tanh(z_{t-1}^T A z_s) z_s (out_0 = z_0)."""
    from phast_model.baselines.transformer import _SkewCausalAttention

    torch.manual_seed(0)
    att = _SkewCausalAttention(8).double()
    z = torch.randn(3, 11, 8, dtype=torch.float64)
    A = att.skew(z)
    ref = [z[:, 0]]
    for t in range(1, 11):
        c = torch.tanh(torch.einsum("bi,ij,bsj->bs", z[:, t - 1], A, z[:, :t]))
        ref.append(z[:, t] + (c[..., None] * z[:, :t]).sum(1) / t)
    assert torch.allclose(att(z), torch.stack(ref, 1), atol=1e-12)


def _naive_2x2(M: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
    """x_t = M x_{t-1} + f_t step by step; M (Q, 2, 2), f (2, N, T, Q) state-major."""
    x, out = torch.zeros_like(f[:, :, 0]), []
    for t in range(f.shape[2]):
        x = torch.einsum("qij,jnq->inq", M, x) + f[:, :, t]
        out.append(x)
    return torch.stack(out, 2)


@pytest.mark.parametrize("T", [1, 2, 9, 19, 37, 200])
def test_scan_2x2_matches_recurrence_and_its_gradients(T: int) -> None:
    """Chunked scan = the step-by-step recurrence to 1e-12 (float64), values and gradients in M and f."""
    g = torch.Generator().manual_seed(T)
    M = (torch.randn(5, 2, 2, generator=g, dtype=torch.float64) * 0.5).requires_grad_()
    f = torch.randn(2, 3, T, 5, generator=g, dtype=torch.float64, requires_grad=True)
    w = torch.randn(2, 3, T, 5, generator=g, dtype=torch.float64)
    fast, ref = scan_2x2(M, f), _naive_2x2(M, f)
    scale = ref.abs().max()
    assert (fast - ref).abs().max() <= 1e-12 * scale
    for a, b in zip(torch.autograd.grad((fast * w).sum(), (M, f)), torch.autograd.grad((ref * w).sum(), (M, f))):
        assert (a - b).abs().max() <= 1e-12 * b.abs().max()
    with pytest.raises(ValueError, match="need M"):
        scan_2x2(M, f[0])


def test_scan_2x2_gradcheck() -> None:
    g = torch.Generator().manual_seed(1)
    M = (torch.randn(3, 2, 2, generator=g, dtype=torch.float64) * 0.5).requires_grad_()
    f = torch.randn(2, 2, 11, 3, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(scan_2x2, (M, f))


@pytest.mark.parametrize("name", ["linoss", "dlinoss"])
def test_oscillator_layer_matches_complex_recurrence(name: str) -> None:
    """The real-arithmetic layer = the paper's complex recurrence x_t = M x_{t-1} + (B z_t) w, y = Re(C x_t[1]) + D z."""
    torch.manual_seed(0)
    layer = make_baseline(name, 2, 1, (0,)).double().layers[0]
    z = torch.randn(3, 29, 64, dtype=torch.float64)
    M, w = layer.transition()
    B, C = torch.complex(layer.B[..., 0], layer.B[..., 1]), torch.complex(layer.C[..., 0], layer.C[..., 1])
    x, ys = torch.zeros(3, M.shape[0], 2, dtype=torch.complex128), []
    for t in range(z.shape[1]):
        x = torch.einsum("pij,bpj->bpi", M.to(x.dtype), x) + (z[:, t].to(x.dtype) @ B.T)[..., None] * w
        ys.append((x[..., 1] @ C.T).real + layer.D * z[:, t])
    y, _ = layer.sequence(z)
    assert (y - torch.stack(ys, 1)).abs().max() <= 1e-12


def test_oscillator_ssms_are_stable() -> None:
    """LinOSS-IM (|eig| = sqrt(S)) and clamped D-LinOSS modes stay in the unit disk for any parameters."""
    for name in ("linoss", "dlinoss"):
        model = make_baseline(name, 1, 0)
        with torch.no_grad():
            for p in model.parameters():
                p.mul_(50.0)
        for layer in model.layers:
            M, _ = layer.transition()
            assert torch.linalg.eigvals(M).abs().max() <= 1.0 + 1e-5


def test_dhnn_full_state() -> None:
    torch.manual_seed(0)
    model = make_baseline("dhnn", 2, 1, (0,), dt=0.05, hidden=32)
    assert isinstance(model, DHNNBaseline)
    q, u = _data(2, 1, T=12)
    out = model(q, u)
    assert out.shape == q.shape and torch.isfinite(out).all()
    a, b = model(q, u), model(torch.cat([q[:, :6], q[:, 6:] + 1], 1), u)
    assert torch.equal(a[:, :6], b[:, :6])  # Markov: causal
    fast = model.rollout(q[:, :5], u, 6)
    slow = ForecastModel.rollout(model, q[:, :5], u, 6)
    assert torch.allclose(fast, slow, atol=1e-5)
    with pytest.raises(ValueError, match="full state"):
        make_baseline("dhnn", 3, 1)
    # zero dissipation net, zero port: H is (nearly) conserved by RK4 over one step
    model.eval()
    with torch.no_grad():
        for p in model.D.parameters():
            p.zero_()
    x0 = torch.tensor([[[0.3, 0.1]]])
    f = model._feat
    h0 = model.H(f(x0)).item()
    h1 = model.H(f(model(x0))).item()
    assert abs(h1 - h0) < 1e-3 * max(1.0, abs(h0))
