"""State-space baselines: S5, LinOSS and D-LinOSS, each a stack of residual SSM layers.

All three are linear time-invariant recurrences ``x_t = A_bar x_{t-1} + B_bar u_t``
evaluated over a whole sequence with a parallel (Hillis-Steele) prefix scan in
ceil(log2 T) vectorized steps; the open-loop rollout steps the same recurrence.

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
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from .common import SeqBaseline


# --------------------------------------------------------------------------- parallel scans
def scan_diag(a: torch.Tensor, b: torch.Tensor, x0: torch.Tensor | None = None) -> torch.Tensor:
    """All states of ``x_t = a * x_{t-1} + b_t`` (a (P,), b (B, T, P), x_{-1} = x0 or 0) by a prefix scan."""
    if x0 is not None:
        b = torch.cat([(a * x0)[:, None] + b[:, :1], b[:, 1:]], dim=1)
    T, k, ak, x = b.shape[1], 1, a, b
    while k < T:
        x = torch.cat([x[:, :k], x[:, k:] + ak * x[:, :-k]], dim=1)
        ak, k = ak * ak, 2 * k
    return x


def scan_2x2(M: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
    """All states of ``x_t = M x_{t-1} + f_t`` for P independent 2x2 blocks (M (P, 2, 2) real, f (B, T, P, 2)).

    A complex ``f`` is scanned as its real and imaginary parts (M is real), with the
    2x2 products written out elementwise: much cheaper than a complex einsum on CPU.
    """
    if f.is_complex():
        return torch.view_as_complex(scan_2x2(M, torch.view_as_real(f).movedim(-1, 0)).movedim(0, -1).contiguous())
    lead = f.shape[:-3]
    x = f.reshape(-1, *f.shape[-3:])
    T, k = x.shape[1], 1
    a, b, c, d = M[:, 0, 0], M[:, 0, 1], M[:, 1, 0], M[:, 1, 1]
    while k < T:
        x0, x1 = x[:, :-k, :, 0], x[:, :-k, :, 1]
        upd = torch.stack([a * x0 + b * x1, c * x0 + d * x1], -1)
        x = torch.cat([x[:, :k], x[:, k:] + upd], dim=1)
        a, b, c, d = a * a + b * c, a * b + b * d, c * a + d * c, c * b + d * d  # M^k -> M^2k
        k *= 2
    return x.reshape(*lead, *x.shape[1:])


def _complex_param(*shape: int, scale: float) -> nn.Parameter:
    return nn.Parameter(torch.randn(*shape, 2) * scale)


def _c(p: torch.Tensor) -> torch.Tensor:
    return torch.complex(p[..., 0], p[..., 1])


# --------------------------------------------------------------------------- layers
class _SSMLayer(nn.Module):
    """Residual pre-norm SSM layer; subclasses define the recurrence."""

    def __init__(self, d: int) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(d)
        self.D = nn.Parameter(torch.randn(d) * 0.1)

    def post(self, y: torch.Tensor) -> torch.Tensor:
        return F.gelu(y)

    def forward(self, h: torch.Tensor) -> tuple[torch.Tensor, Any]:
        z = self.norm(h)
        states = self.scan(z)
        return h + self.post(self.out(states, z)), states[:, -1]

    def step(self, h: torch.Tensor, state: Any) -> tuple[torch.Tensor, Any]:
        z = self.norm(h)
        state = self.recur(z, state)
        return h + self.post(self.out(state[:, None], z[:, None])[:, 0]), state


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

    def scan(self, z: torch.Tensor) -> torch.Tensor:
        lam_bar, b_bar = self._disc()
        return scan_diag(lam_bar, z.to(b_bar.dtype) @ b_bar.T)

    def recur(self, z: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        lam_bar, b_bar = self._disc()
        return lam_bar * x + z.to(b_bar.dtype) @ b_bar.T

    def out(self, x: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return 2 * (x @ _c(self.C).T).real + self.D * z


class _OscLayer(_SSMLayer):
    """Shared parts of LinOSS / D-LinOSS: P oscillators, complex B, C, per-oscillator dt."""

    def __init__(self, d: int, P: int) -> None:
        super().__init__(d)
        self.A_hat = nn.Parameter(torch.rand(P))
        self.steps = nn.Parameter(torch.zeros(P))
        self.B = _complex_param(P, d, scale=1.0 / math.sqrt(2 * d))
        self.C = _complex_param(d, P, scale=1.0 / math.sqrt(P))

    def transition(self) -> tuple[torch.Tensor, torch.Tensor]:  # pragma: no cover - abstract
        """(M (P, 2, 2), f-weights (P, 2)) of the discretized oscillators."""
        raise NotImplementedError

    def _forcing(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        M, w = self.transition()
        bu = z.to(torch.complex64 if z.dtype == torch.float32 else torch.complex128) @ _c(self.B).T
        return M, bu[..., None] * w.to(bu.dtype)

    def scan(self, z: torch.Tensor) -> torch.Tensor:
        M, f = self._forcing(z)
        return scan_2x2(M, f)

    def recur(self, z: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        M, f = self._forcing(z)
        return torch.einsum("pij,bpj->bpi", M.to(x.dtype), x) + f

    def out(self, x: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return (x[..., 1] @ _c(self.C).T).real + self.D * z


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

    def __init__(self, n: int, m: int, angle_dims: tuple[int, ...], d_model: int, layers: list[nn.Module]) -> None:
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
            h, s = layer.step(h, s)
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
