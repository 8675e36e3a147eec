"""Causal velocity observer: finite differences plus a dilated causal TCN correction.

``qdot_fd_t = wrap(q_t - q_{t-1}) / dt`` (0 at t = 0), then
``qdot_hat_t = qdot_fd_t + delta_t`` with ``delta = TCN(q_{0:t}, qdot_fd_{0:t})``
(paper Eq. 6-7).  Causal by construction: left-padded convolutions only, so the
estimate at t never sees q after t.  Its receptive field is finite, which lets
rollouts re-run the observer on a short window only (:attr:`window`).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from phast_gym.systems import wrap

from .features import coordinate_features, n_features


def finite_difference(q: torch.Tensor, dt: float, angle_dims: tuple[int, ...]) -> torch.Tensor:
    """Backward difference along time of (B, T, n), wrapped on angles; 0 at t = 0 (Eq. 6)."""
    d = q[:, 1:] - q[:, :-1]
    if angle_dims:
        idx = list(angle_dims)
        d = d.clone()
        d[..., idx] = wrap(d[..., idx])
    return torch.cat([torch.zeros_like(q[:, :1]), d / dt], dim=1)


def backward_difference_weights(order: int) -> np.ndarray:
    """Weights w_k with qdot_t ~= sum_k w_k qdot_fd_{t-k} (k = 0..order-1): the backward-difference
    formula of the given order, rewritten on first differences."""
    c = derivative_weights(-np.arange(order + 1))  # qdot_t ~= sum_j c_j q_{t-j} / dt
    return -np.array([c[k + 1:].sum() for k in range(order)])


class CausalConv1d(nn.Conv1d):
    """Conv1d over (B, C, T) with left padding only (output t sees inputs <= t)."""

    def __init__(self, c_in: int, c_out: int, kernel_size: int, dilation: int = 1, groups: int = 1,
                 bias: bool = True) -> None:
        super().__init__(c_in, c_out, kernel_size, dilation=dilation, groups=groups, bias=bias)
        self.left = (kernel_size - 1) * dilation

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward(nn.functional.pad(x, (self.left, 0)))


class FDTCNObserver(nn.Module):
    """q history (B, T, n) -> velocity estimates (B, T, n), causal (FD + TCN)."""

    q_scale: torch.Tensor  # buffers: input scales and the start-up rows (below)
    v_scale: torch.Tensor
    startup: torch.Tensor

    def __init__(self, n: int, dt: float, angle_dims: tuple[int, ...] = (), hidden: int = 32, layers: int = 2,
                 kernel_size: int = 3, q_scale: torch.Tensor | float = 1.0, v_scale: torch.Tensor | float = 1.0,
                 use_tcn: bool = True, fd_order: int = 4) -> None:
        super().__init__()
        self.n, self.dt, self.angle_dims = n, float(dt), tuple(angle_dims)
        n_eu = n - len(self.angle_dims)
        self.register_buffer("q_scale", torch.as_tensor(q_scale, dtype=torch.float32).expand(n_eu).clone())
        self.register_buffer("v_scale", torch.as_tensor(v_scale, dtype=torch.float32).expand(n).clone())
        self.use_tcn = bool(use_tcn)
        c_in = n_features(n, self.angle_dims) + n
        convs = []
        for i in range(layers):
            convs.append(CausalConv1d(c_in if i == 0 else hidden, hidden, kernel_size, dilation=2**i))
        self.convs = nn.ModuleList(convs)
        #: receptive field of the TCN in samples; the FD needs one more sample before it
        self.receptive_field = 1 + sum((kernel_size - 1) * 2**i for i in range(layers))
        #: the estimate at t depends on q_{t-window+1 .. t} only
        self.window = self.receptive_field + 1
        self.head = nn.Conv1d(hidden, n, 1)
        nn.init.zeros_(self.head.weight)  # start as the plain finite-difference observer
        assert self.head.bias is not None  # a Conv1d has one by default
        nn.init.zeros_(self.head.bias)
        # linear skip path of the TCN over qdot_fd (a learnable causal FIR filter), initialized so that
        # qdot_fd + skip is the backward-difference formula of order ``fd_order`` (order 2:
        # (3 q_t - 4 q_{t-1} + q_{t-2}) / (2 dt)); order 1 = plain FD
        self.fd_order = int(fd_order)
        if not 1 <= self.fd_order <= self.receptive_field:
            raise ValueError(f"fd_order must be in [1, {self.receptive_field}], got {fd_order!r}")
        self.skip = CausalConv1d(n, n, self.fd_order, groups=n, bias=False)
        with torch.no_grad():
            w = torch.as_tensor(backward_difference_weights(self.fd_order), dtype=torch.float32)
            w[0] -= 1.0  # the plain FD is already added
            self.skip.weight.copy_(w.flip(0).expand(n, 1, self.fd_order))
        # start-up rows: at t < fd_order only t first differences exist (the zero-padded FIR above would weight
        # missing ones as zero velocity: with order 4 that is a 108 % / 83 % / 25 % velocity error at t = 1 / 2 / 3),
        # so those steps use the backward-difference formula of order t instead; t = 0 has no velocity information (0)
        start = np.zeros((self.fd_order, self.fd_order))
        for t in range(1, self.fd_order):
            start[t, 1:t + 1] = backward_difference_weights(t)[::-1]  # weight of qdot_fd_j, j = 1..t
        self.register_buffer("startup", torch.as_tensor(start, dtype=torch.float32), persistent=False)

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        """(B, T, n) positions -> (B, T, n) velocity estimates qdot_hat (Eq. 7)."""
        v_fd = finite_difference(q, self.dt, self.angle_dims)
        if not self.use_tcn:
            return v_fd
        x = torch.cat([coordinate_features(q, self.angle_dims, self.q_scale), v_fd / self.v_scale], -1).transpose(1, 2)
        skip = self.skip(v_fd.transpose(1, 2))
        for conv in self.convs:
            x = nn.functional.silu(conv(x))
        delta = (self.head(x) * self.v_scale.unsqueeze(-1) + skip).transpose(1, 2)
        v = v_fd + delta
        # start-up steps t < fd_order: plain backward difference of the order the history supports (0 at t = 0)
        k = min(self.fd_order, q.shape[1])
        v0 = torch.einsum("tj,bjn->btn", self.startup[:k, :k].to(v_fd.dtype), v_fd[:, :k])
        return torch.cat([v0, v[:, k:]], 1)


def derivative_weights(offsets: np.ndarray) -> np.ndarray:
    """Weights c_j with qdot(0) ~= sum_j c_j q(offsets_j) / dt: the finite-difference formula of order
    ``len(offsets) - 1`` on the given (integer) sample offsets (Vandermonde solve)."""
    nodes = np.asarray(offsets, dtype=np.float64)
    V = np.stack([nodes**m for m in range(len(nodes))])
    rhs = np.zeros(len(nodes))
    rhs[1] = 1.0
    return np.linalg.solve(V, rhs)


def unwrap_angles(q: torch.Tensor, angle_dims: tuple[int, ...]) -> torch.Tensor:
    """(B, T, n) with the angular coordinates made continuous along time (first sample + cumulative wrapped
    differences); Euclidean coordinates unchanged."""
    if not angle_dims or q.shape[1] < 2:
        return q
    idx = list(angle_dims)
    a = q[..., idx]
    steps = wrap(a[:, 1:] - a[:, :-1])
    out = q.clone()
    out[..., idx] = torch.cat([a[:, :1], a[:, :1] + torch.cumsum(steps, 1)], 1)
    return out


class CentralDifference(nn.Module):
    """NON-causal velocity estimate for training only: the central finite difference of accuracy ``order`` (even;
    ``order + 1`` samples, ``order / 2`` either side; order 4: (q_{t-2} - 8 q_{t-1} + 8 q_{t+1} - q_{t+2}) / (12 dt)),
    on angles unwrapped along time.  The first and last ``order / 2`` samples, where the centred stencil would leave
    the trajectory, use the ``order + 1`` samples nearest to them (a one-sided formula of the same order); a
    trajectory shorter than the stencil uses all its samples.

    Same interface as :class:`FDTCNObserver` (q (B, T, n) -> velocities (B, T, n)) but it reads q after t, so it
    never infers a state for a rollout: ``PHASTConfig.train_velocity="central"`` puts it in the training loss only
    (:meth:`phast_model.world.model.PHAST.loss_forward`).  No parameters."""

    causal = False

    def __init__(self, n: int, dt: float, angle_dims: tuple[int, ...] = (), order: int = 4) -> None:
        super().__init__()
        if int(order) != order or order < 2 or order % 2:
            raise ValueError(f"central-difference order must be an even integer >= 2, got {order!r}")
        self.n, self.dt, self.angle_dims, self.order = n, float(dt), tuple(angle_dims), int(order)
        self.reach = self.order // 2  # samples either side of a centred stencil

    def weights(self, T: int) -> np.ndarray:
        """(T, T) differentiation matrix of a trajectory of length T (rows: times, columns: samples), / dt."""
        w = min(self.order + 1, T)
        D = np.zeros((T, T))
        for t in range(T):
            start = min(max(t - w // 2, 0), T - w)  # centred where the trajectory allows it
            D[t, start:start + w] = derivative_weights(np.arange(start, start + w) - t)
        return D / self.dt

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        """(B, T, n) positions -> (B, T, n) velocity estimates (0 for a single sample)."""
        T = q.shape[1]
        if T < 2:
            return torch.zeros_like(q)
        qu = unwrap_angles(q, self.angle_dims)
        w, k = min(self.order + 1, T), self.reach
        if T < 2 * w:  # short: the dense matrix
            return torch.einsum("st,btn->bsn", torch.as_tensor(self.weights(T), dtype=q.dtype, device=q.device), qu)
        ends = torch.as_tensor(self.weights(2 * w), dtype=q.dtype, device=q.device)  # first/last rows of any T
        head = torch.einsum("st,btn->bsn", ends[:k, :w], qu[:, :w])
        tail = torch.einsum("st,btn->bsn", ends[-k:, -w:], qu[:, -w:])
        c = torch.as_tensor(derivative_weights(np.arange(-k, k + 1)) / self.dt, dtype=q.dtype, device=q.device)
        mid = qu.unfold(1, w, 1) @ c  # (B, T - 2k, n): windows q_{t-k .. t+k}
        return torch.cat([head, mid, tail], 1)


#: ``PHASTConfig.train_velocity`` -> the class of the training loss's velocity estimate (None: the causal observer)
TRAIN_VELOCITIES: dict[str, type[CentralDifference] | None] = {"observer": None, "central": CentralDifference}


def training_velocity(name: str, n: int, dt: float, angle_dims: tuple[int, ...], order: int) -> nn.Module | None:
    """The training velocity estimate ``name`` of :data:`TRAIN_VELOCITIES` (None: the observer); ValueError for an
    unknown name."""
    if name not in TRAIN_VELOCITIES:
        raise ValueError(f"train_velocity must be one of {sorted(TRAIN_VELOCITIES)}, got {name!r}")
    cls = TRAIN_VELOCITIES[name]
    return None if cls is None else cls(n, dt, angle_dims, order)
