"""State-space baselines: S5, LinOSS and D-LinOSS, each a stack of residual SSM layers.

All three are linear time-invariant recurrences ``x_t = A_bar x_{t-1} + B_bar u_t``
evaluated over a whole sequence in a few vectorized steps (S5: a parallel
Hillis-Steele prefix scan; LinOSS / D-LinOSS: a chunked scan with an adjoint
backward, :func:`scan_2x2`); the open-loop rollout steps the same recurrence.

* **S5** (Smith, Warrington & Linderman, ICLR 2023): diagonal complex state
  ``x' = Lambda x + B u``, ``y = 2 Re(C x) + D u`` (conjugate-symmetric, P = d_state/2
  complex modes), zero-order hold ``Lambda_bar = exp(Lambda dt)``,
  ``B_bar = Lambda^-1 (Lambda_bar - I) B`` (S5 Eq. 6-7); Lambda initialized S4D-Lin
  (``-1/2 + i pi k``); internal dt_ssm = 0.01 fixed (paper Table 14).
* **LinOSS-IM** (Rusch & Rus, ICLR 2025): forced harmonic oscillators
  ``y'' = -A y + B u``, ``A = ReLU(A_hat) >= 0`` diagonal, implicit discretization
  (LinOSS Eq. 4-5): ``S = (I + dt^2 A)^-1``,
  ``[z; y]_t = [[S, -dt A S], [dt S, S]] [z; y]_{t-1} + [dt S B u; dt^2 S B u]``;
  ``|eig| = sqrt(S) <= 1`` for any parameters.  ``x = Re(C y) + D u``.  Deviation: A is
  floored at 0.2 (``A = ReLU(A_hat) + 0.2``); with ReLU alone, modes pushed to A = 0
  become double integrators whose outputs grow without bound over T = 200 steps.
* **D-LinOSS** (Boyer, Rusch & Rus, 2025): damped oscillators
  ``y'' = -A y - G y' + B u``, implicit-explicit discretization with
  ``S = (I + dt G)^-1``: ``[z; y]_t = [[S, -dt S A], [dt S, I - dt^2 S A]] [z; y]_{t-1}
  + [dt S B u; dt^2 S B u]``; ``det = S``, and A is clamped to the Jury region
  ``dt^2 S A < 2 (1 + S)`` so every mode is stable; learnable per-oscillator dt;
  a GLU after the SSM (paper Table 14: P = floor(d/2) oscillators).

Each layer is pre-norm residual: ``h <- h + post(SSM(LayerNorm(h)))`` with GELU
(and a GLU for D-LinOSS).
"""

from __future__ import annotations

import math
from typing import Any, cast

import torch
import torch.nn.functional as F
from torch import nn
from torch.autograd.function import FunctionCtx, once_differentiable

from .common import SeqBaseline


# --------------------------------------------------------------------------- diagonal scan
def scan_diag(a: torch.Tensor, b: torch.Tensor, x0: torch.Tensor | None = None) -> torch.Tensor:
    """All states of ``x_t = a * x_{t-1} + b_t`` (a (P,), b (B, T, P), x_{-1} = x0 or 0) by a prefix scan."""
    if x0 is not None:
        b = torch.cat([(a * x0)[:, None] + b[:, :1], b[:, 1:]], dim=1)
    T, k, ak, x = b.shape[1], 1, a, b
    while k < T:
        x = torch.cat([x[:, :k], x[:, k:] + ak * x[:, :-k]], dim=1)
        ak, k = ak * ak, 2 * k
    return x


# --------------------------------------------------------------------------- 2x2 oscillator scan
#: a batch of 2x2 blocks as four coefficient vectors (a, b; c, d), each (Q,) or broadcastable
Coef = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]


def _mul_add_(out0: torch.Tensor, out1: torch.Tensor, m: Coef, x0: torch.Tensor, x1: torch.Tensor) -> None:
    """``(out0, out1) += M (x0, x1)`` in place (fused multiply-adds, broadcasting)."""
    a, b, c, d = m
    out0.addcmul_(a, x0).addcmul_(b, x1)
    out1.addcmul_(c, x0).addcmul_(d, x1)


def _powers(m: Coef, n: int) -> Coef:
    """Coefficients of ``M^1 .. M^n``, each stacked to (n, Q)."""
    a, b, c, d = m
    out = [m]
    for _ in range(n - 1):
        A, B, C, D = out[-1]
        out.append((A * a + B * c, A * b + B * d, C * a + D * c, C * b + D * d))
    pa, pb, pc, pd = (torch.stack(p) for p in zip(*out))
    return pa, pb, pc, pd


def _chunked_scan(m: Coef, f: torch.Tensor, reverse: bool = False) -> torch.Tensor:
    """States of ``x_t = M x_{t-1} + f_t`` (``x_{-1} = 0``) for state-major ``f`` (2, N, T, Q); no autograd.

    Exact sequential steps inside chunks of length ``L = ceil(sqrt(T))``, vectorized over
    the chunks; then each chunk's end state is carried into the next chunk
    (``s_c = end_c + M^L s_{c-1}``) and added to its steps as ``M^(i+1) s_{c-1}``.
    O(T) work in O(sqrt(T)) vectorized steps, in place in one buffer (a parallel
    prefix scan does O(T log T) work and, under autograd, allocates a full-size
    gradient per level).  ``reverse`` scans from the end (the adjoint pass).
    """
    _, N, T, Q = f.shape
    L = math.isqrt(max(T - 1, 0)) + 1
    C = -(-T // L)
    x = f.new_empty(2, N, C * L, Q)
    x[:, :, :T] = f.flip(2) if reverse else f
    x[:, :, T:] = 0.0
    xc = x.view(2, N, C, L, Q)
    for i in range(1, L):
        _mul_add_(xc[0, :, :, i], xc[1, :, :, i], m, xc[0, :, :, i - 1], xc[1, :, :, i - 1])
    if C > 1:
        pa, pb, pc, pd = _powers(m, L)
        m_L = (pa[-1], pb[-1], pc[-1], pd[-1])
        for c in range(1, C):
            _mul_add_(xc[0, :, c, -1], xc[1, :, c, -1], m_L, xc[0, :, c - 1, -1], xc[1, :, c - 1, -1])
        ends = xc[0, :, :-1, -1:], xc[1, :, :-1, -1:]  # true end states of chunks 0 .. C-2
        _mul_add_(xc[0, :, 1:, :-1], xc[1, :, 1:, :-1], (pa[:-1], pb[:-1], pc[:-1], pd[:-1]), *ends)
    x = x[:, :, :T]
    return x.flip(2) if reverse else x


class _Scan2x2(torch.autograd.Function):
    """:func:`_chunked_scan` with its adjoint as the backward: ``g_t + M^T g_{t+1}`` scanned in reverse."""

    @staticmethod
    def forward(ctx: FunctionCtx, a: torch.Tensor, b: torch.Tensor, c: torch.Tensor, d: torch.Tensor,
                f: torch.Tensor) -> torch.Tensor:
        x = _chunked_scan((a, b, c, d), f)
        ctx.save_for_backward(a, b, c, d, x)
        return x

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, g: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        a, b, c, d, x = ctx.saved_tensors
        gf = _chunked_scan((a, c, b, d), g.contiguous(), reverse=True)
        if not any(ctx.needs_input_grad[:4]):
            return None, None, None, None, gf
        # dL/dM_ij = sum_{n,t} gf_i[n, t] x_j[n, t-1]: a broadcast product and a sum (an einsum here permuted both
        # operands into a batched matmul, two full-size copies that cost more than the scan)
        dm = (gf[:, None, :, 1:] * x[None, :, :, :-1]).sum((2, 3))
        return dm[0, 0], dm[0, 1], dm[1, 0], dm[1, 1], gf


def scan_2x2(M: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
    """All states of ``x_t = M x_{t-1} + f_t`` for Q independent real 2x2 blocks.

    ``M`` (Q, 2, 2); ``f`` (2, N, T, Q), state-major: ``f[0]``, ``f[1]`` are the two
    state components, so every update runs on contiguous rows.  Returns x in the
    same layout.  Differentiable in M and f (an adjoint scan, not autograd through
    the steps).
    """
    if f.ndim != 4 or f.shape[0] != 2 or M.shape != (f.shape[-1], 2, 2):
        raise ValueError(f"need M (Q, 2, 2) and f (2, N, T, Q), got {tuple(M.shape)} and {tuple(f.shape)}")
    return _Scan2x2.apply(M[:, 0, 0], M[:, 0, 1], M[:, 1, 0], M[:, 1, 1], f)


def scan_complex_diag(lam: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """All states of ``x_t = lam * x_{t-1} + b_t`` (complex lam (P,), b (B, T, P), x_{-1} = 0): the same recurrence
    as :func:`scan_diag`, run as P real 2x2 rotation-scalings ``[[Re, -Im], [Im, Re]]`` by :func:`scan_2x2`
    (O(T) work and an adjoint backward instead of a log-depth scan under autograd)."""
    re, im = lam.real, lam.imag
    M = torch.stack([torch.stack([re, -im], -1), torch.stack([im, re], -1)], -2)
    x = scan_2x2(M, torch.stack([b.real, b.imag]))
    return torch.complex(x[0], x[1])


def _complex_param(*shape: int, scale: float) -> nn.Parameter:
    return nn.Parameter(torch.randn(*shape, 2) * scale)


def _c(p: torch.Tensor) -> torch.Tensor:
    return torch.complex(p[..., 0], p[..., 1])


# --------------------------------------------------------------------------- layers
class _SSMLayer(nn.Module):
    """Residual pre-norm SSM layer; subclasses define the recurrence (:meth:`sequence`, :meth:`recur`)."""

    def __init__(self, d: int) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(d)
        self.D = nn.Parameter(torch.randn(d) * 0.1)

    def post(self, y: torch.Tensor) -> torch.Tensor:
        return F.gelu(y)

    def sequence(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # pragma: no cover - abstract
        """SSM outputs (B, T, d) of normalized inputs z (B, T, d) and the state after the last step."""
        raise NotImplementedError

    def recur(self, z: torch.Tensor, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # pragma: no cover
        """One step: SSM output (B, d) of z (B, d) and the new state."""
        raise NotImplementedError

    def forward(self, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        y, state = self.sequence(self.norm(h))
        return h + self.post(y), state

    def step(self, h: torch.Tensor, state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        y, state = self.recur(self.norm(h), state)
        return h + self.post(y), state


class S5Layer(_SSMLayer):
    def __init__(self, d: int, d_state: int = 64, dt: float = 0.01) -> None:
        super().__init__(d)
        P = d_state // 2
        self.dt = float(dt)
        self.log_neg_re = nn.Parameter(torch.full((P,), math.log(0.5)))
        self.im = nn.Parameter(math.pi * torch.arange(P, dtype=torch.float32))
        self.B = _complex_param(P, d, scale=1.0 / math.sqrt(2 * d))
        self.C = _complex_param(d, P, scale=1.0 / math.sqrt(2 * P))

    def _disc(self) -> tuple[torch.Tensor, torch.Tensor]:
        lam = torch.complex(-torch.exp(self.log_neg_re), self.im)
        lam_bar = torch.exp(lam * self.dt)  # ZOH, S5 Eq. 6
        b_bar = ((lam_bar - 1) / lam)[:, None] * _c(self.B)  # S5 Eq. 7
        return lam_bar, b_bar

    def out(self, x: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return 2 * (x @ _c(self.C).T).real + self.D * z

    def sequence(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        lam_bar, b_bar = self._disc()
        x = scan_complex_diag(lam_bar, z.to(b_bar.dtype) @ b_bar.T)
        return self.out(x, z), x[:, -1]

    def recur(self, z: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        lam_bar, b_bar = self._disc()
        x = lam_bar * x + z.to(b_bar.dtype) @ b_bar.T
        return self.out(x, z), x


class _OscLayer(_SSMLayer):
    """Shared parts of LinOSS / D-LinOSS: P oscillators, complex B, C, per-oscillator dt.

    The inputs z are real, so ``B z`` splits into ``(Re B) z`` and ``(Im B) z``: the
    layer runs Q = 2P real oscillators (the real parts, then the imaginary parts)
    sharing M, with real matrices throughout; ``Re(C y) = (Re C) Re y - (Im C) Im y``.
    The state is (2, B, Q) in the layout of :func:`scan_2x2`.
    """

    def __init__(self, d: int, P: int) -> None:
        super().__init__(d)
        self.A_hat = nn.Parameter(torch.rand(P))
        self.steps = nn.Parameter(torch.zeros(P))
        self.B = _complex_param(P, d, scale=1.0 / math.sqrt(2 * d))
        self.C = _complex_param(d, P, scale=1.0 / math.sqrt(P))

    def transition(self) -> tuple[torch.Tensor, torch.Tensor]:  # pragma: no cover - abstract
        """(M (P, 2, 2), f-weights (P, 2)) of the discretized oscillators."""
        raise NotImplementedError

    def _real_system(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """M (Q, 2, 2), forcing weights (2, Q), input map (Q, d), output map (d, Q) of the Q = 2P real oscillators."""
        M, w = self.transition()
        B_in = torch.cat([self.B[..., 0], self.B[..., 1]], 0)
        C_out = torch.cat([self.C[..., 0], -self.C[..., 1]], 1)
        return M.repeat(2, 1, 1), w.T.repeat(1, 2), B_in, C_out

    def sequence(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        M, w, B_in, C_out = self._real_system()
        x = scan_2x2(M, w[:, None, None] * (z @ B_in.T))
        return x[1] @ C_out.T + self.D * z, x[:, :, -1]

    def recur(self, z: torch.Tensor, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        M, w, B_in, C_out = self._real_system()
        x = torch.einsum("qij,jbq->ibq", M, x) + w[:, None] * (z @ B_in.T)
        return x[1] @ C_out.T + self.D * z, x


class LinOSSLayer(_OscLayer):
    #: floor on the frequencies: A = 0 is a double integrator (|eig| = 1, polynomial growth of y over
    #: 200 steps) and a small A has a DC gain 1/A; the floor keeps the teacher-forced outputs bounded
    a_min: float = 0.2

    def transition(self) -> tuple[torch.Tensor, torch.Tensor]:
        A = F.relu(self.A_hat) + self.a_min
        dt = torch.sigmoid(self.steps)
        S = 1.0 / (1.0 + dt * dt * A)  # LinOSS-IM, Eq. 5
        M = torch.stack([torch.stack([S, -dt * A * S], -1), torch.stack([dt * S, S], -1)], -2)
        return M, torch.stack([dt * S, dt * dt * S], -1)


class DLinOSSLayer(_OscLayer):
    def __init__(self, d: int, P: int) -> None:
        super().__init__(d, P)
        self.G_hat = nn.Parameter(torch.rand(P))
        self.glu = nn.Linear(d, 2 * d)

    def transition(self) -> tuple[torch.Tensor, torch.Tensor]:
        dt = torch.sigmoid(self.steps)
        G = F.relu(self.G_hat)
        S = 1.0 / (1.0 + dt * G)  # D-LinOSS IMEX
        a_max = 2.0 * (1.0 + S) / (S * dt * dt) * 0.999  # Jury stability bound
        A = torch.minimum(F.relu(self.A_hat), a_max)
        M = torch.stack([torch.stack([S, -dt * S * A], -1), torch.stack([dt * S, 1.0 - dt * dt * S * A], -1)], -2)
        return M, torch.stack([dt * S, dt * dt * S], -1)

    def post(self, y: torch.Tensor) -> torch.Tensor:
        return F.glu(self.glu(F.gelu(y)), dim=-1)


# --------------------------------------------------------------------------- models
class _SSMModel(SeqBaseline):
    stateful = True

    def __init__(self, n: int, m: int, angle_dims: tuple[int, ...], d_model: int, layers: list[_SSMLayer]) -> None:
        super().__init__(n, m, angle_dims, d_model)
        self.encoder = nn.Linear(self.in_dim, self.d_model)
        self.layers = nn.ModuleList(layers)

    def encode(self, x: torch.Tensor) -> torch.Tensor:
        return self.encode_state(x)[0]

    def encode_state(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        h, states = self.encoder(x), []
        for layer in self.layers:
            h, s = layer(h)
            states.append(s)
        return h, states

    def step(self, x: torch.Tensor, state: list[torch.Tensor]) -> tuple[torch.Tensor, list[torch.Tensor]]:
        h, new = self.encoder(x), []
        for layer, s in zip(self.layers, state):
            h, s = cast(_SSMLayer, layer).step(h, s)  # self.layers holds the _SSMLayers given
            new.append(s)
        return h, new


class S5Baseline(_SSMModel):
    """S5: 2 residual layers of a diagonal complex SSM (d_state 64, dt_ssm 0.01)."""

    def __init__(self, n: int, m: int, angle_dims: tuple[int, ...] = (), d_model: int = 64, depth: int = 2,
                 d_state: int = 64, dt: float = 0.01) -> None:
        super().__init__(n, m, angle_dims, d_model, [S5Layer(d_model, d_state, dt) for _ in range(depth)])


class LinOSSBaseline(_SSMModel):
    """LinOSS-IM: 2 residual layers of P = d/2 implicit forced oscillators."""

    def __init__(self, n: int, m: int, angle_dims: tuple[int, ...] = (), d_model: int = 64, depth: int = 2,
                 n_osc: int | None = None) -> None:
        P = n_osc or d_model // 2
        super().__init__(n, m, angle_dims, d_model, [LinOSSLayer(d_model, P) for _ in range(depth)])


class DLinOSSBaseline(_SSMModel):
    """D-LinOSS (IMEX): 2 residual layers of P = d/2 damped oscillators with learned damping and dt, + GLU."""

    def __init__(self, n: int, m: int, angle_dims: tuple[int, ...] = (), d_model: int = 64, depth: int = 2,
                 n_osc: int | None = None) -> None:
        P = n_osc or d_model // 2
        super().__init__(n, m, angle_dims, d_model, [DLinOSSLayer(d_model, P) for _ in range(depth)])
