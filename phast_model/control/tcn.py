"""FD+TCN velocity observer trained offline with noise augmentation (paper Sec. 4.2, Tables 7-11).

``qdot_hat_t = FIR(qdot_fd)_t + TCN(sin q, cos q, qdot_fd [, sigma])_t`` where ``qdot_fd`` is the
wrap-aware backward difference (paper Eq. 6-7) and both parts are causal.  Training data are
closed-loop runs of the control plant (the Energy-Casimir loop with true velocity plus a random
excitation ``v_ext``), simulated batched with :func:`phast_gym.integrate.step`; labels are the true
``qdot``.  Measurement noise is added per trajectory during training:

* ``fixed``:       sigma_train = ``sigma`` (noise-matched, paper Table 10 'matched');
* ``uniform``:     sigma_train ~ U[0, sigma_max] (paper 'anchored range');
* ``conditioned``: sigma_train ~ U[0, sigma_max] and sigma is an input channel (paper Table 11).
"""

from __future__ import annotations

import hashlib
import json
import time
from collections import deque
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import cast

import numpy as np
import torch
from torch import nn

from phast_gym import integrate
from phast_gym.control.estimators import PortEstimator
from phast_gym.control.evaluation import START_REGIMES, ControlProtocol, control_system, sample_start_states
from phast_gym.systems.base import NUMPY, System, split, stack, wrap

from ..components.observer import CausalConv1d, finite_difference
from ..train.checkpoint import atomic_torch_save, atomic_write_json

NOISE_MODES = ("fixed", "uniform", "conditioned")


@dataclass
class TCNObserverConfig:
    """Architecture, noise augmentation and (small, CPU) training budget of the observer."""

    noise_mode: str = "fixed"
    sigma: float = 0.01
    sigma_max: float = 0.05
    hidden: int = 24
    layers: int = 4
    kernel_size: int = 3
    fir_taps: int = 24
    n_traj: int = 96
    traj_steps: int = 1200
    crop: int = 160
    iters: int = 600
    batch_size: int = 32
    lr: float = 3e-3
    seed: int = 0

    def __post_init__(self) -> None:
        if self.noise_mode not in NOISE_MODES:
            raise ValueError(f"noise_mode must be one of {NOISE_MODES}, got {self.noise_mode!r}")
        if self.sigma < 0 or self.sigma_max < 0:
            raise ValueError(f"sigma and sigma_max must be >= 0, got {self.sigma}, {self.sigma_max}")


class TCNObserver(nn.Module):
    """Causal (B, T, n) noisy q -> (B, T, n) velocity; optional noise-level channel."""

    v_scale: torch.Tensor  # buffer

    def __init__(self, n: int, dt: float, angle_dims: tuple[int, ...], cfg: TCNObserverConfig,
                 v_scale: float = 1.0) -> None:
        super().__init__()
        self.n, self.dt, self.angle_dims, self.cfg = n, float(dt), tuple(angle_dims), cfg
        self.conditioned = cfg.noise_mode == "conditioned"
        c_in = 2 * len(self.angle_dims) + (n - len(self.angle_dims)) + n + (1 if self.conditioned else 0)
        self.convs = nn.ModuleList(
            CausalConv1d(c_in if i == 0 else cfg.hidden, cfg.hidden, cfg.kernel_size, dilation=2**i)
            for i in range(cfg.layers))
        self.head = nn.Conv1d(cfg.hidden, n, 1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(cast(torch.Tensor, self.head.bias))  # a Conv1d with the default bias=True: never None
        # linear causal smoother of qdot_fd, initialised to the identity (plain finite differences)
        self.fir = CausalConv1d(n, n, cfg.fir_taps, groups=n, bias=False)
        with torch.no_grad():
            self.fir.weight.zero_()
            self.fir.weight[:, 0, -1] = 1.0
        self.register_buffer("v_scale", torch.tensor(float(v_scale)))
        rf = 1 + sum((cfg.kernel_size - 1) * 2**i for i in range(cfg.layers))
        #: samples of history the estimate at t depends on (+1 for the difference)
        self.window = max(rf, cfg.fir_taps) + 1

    def forward(self, q: torch.Tensor, sigma: torch.Tensor | None = None) -> torch.Tensor:
        v_fd = finite_difference(q, self.dt, self.angle_dims)
        feats = []
        for i in range(self.n):
            if i in self.angle_dims:
                feats += [torch.sin(q[..., i]), torch.cos(q[..., i])]
            else:
                feats.append(q[..., i])
        x = torch.cat([torch.stack(feats, -1), v_fd / self.v_scale], -1)
        if self.conditioned:
            if sigma is None:
                raise ValueError("a noise-conditioned observer needs sigma")
            x = torch.cat([x, (sigma / max(self.cfg.sigma_max, 1e-6)).reshape(-1, 1, 1)
                           .expand(q.shape[0], q.shape[1], 1).to(x)], -1)
        x = x.transpose(1, 2)
        for conv in self.convs:
            x = nn.functional.silu(conv(x))
        return (self.fir(v_fd.transpose(1, 2)) + self.head(x) * self.v_scale).transpose(1, 2)


def closed_loop_data(protocol: ControlProtocol, n_traj: int, steps: int,
                     seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Batched closed-loop trajectories of the control plant: true q (N, T, n) and qdot (N, T, n).

    The loop is the Energy-Casimir law with exact velocity and ``k_xi`` tracking (same gains as the
    protocol) plus a random piecewise-constant excitation, so the data cover the transients and the
    near-target regime the observer meets in closed loop.  Physics comes from the plant's System.
    """
    system = control_system(protocol)
    rng = np.random.default_rng(seed)
    names = list(START_REGIMES)
    x0 = np.concatenate([sample_start_states(system, names[i % len(names)], rng, 1) for i in range(n_traj)])
    n = system.n
    q, p = list(split(x0[:, :n])), list(split(x0[:, n:]))
    xi = x0[:, :n].copy()
    qs, vs = np.empty((n_traj, steps, n)), np.empty((n_traj, steps, n))
    hold = max(1, int(round(0.5 / protocol.dt)))
    amp = rng.uniform(0.0, 1.0, size=(n_traj, 1))
    v_ext = np.zeros((n_traj, n))
    angle = np.array([i in system.angle_dims for i in range(n)])
    for t in range(steps):
        v = stack(system.velocity(q, p, NUMPY))
        qa = stack(q)
        qs[:, t], vs[:, t] = qa, v
        if t % hold == 0:
            v_ext = amp * rng.normal(size=(n_traj, n))
        err = xi - protocol.q_star
        err = np.where(angle, wrap(err), err)
        u = -protocol.k_c * err + v_ext - protocol.d_inj * v
        xi = xi + protocol.dt * (v + protocol.k_xi * np.where(angle, wrap(qa - xi), qa - xi))
        q, p = integrate.step(system, q, p, list(split(u)), NUMPY, dt=protocol.dt, substeps=system.substeps)
    return qs, vs


def train_tcn_observer(protocol: ControlProtocol, cfg: TCNObserverConfig,
                       progress: bool = False) -> tuple[TCNObserver, dict[str, float]]:
    """Train an observer on noisy closed-loop data; returns the model and a small report."""
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed + 1)
    system = control_system(protocol)
    t0 = time.time()
    q, v = closed_loop_data(protocol, cfg.n_traj, cfg.traj_steps, seed=cfg.seed)
    v_scale = float(np.sqrt(np.mean(v**2)) + 1e-3)
    model = TCNObserver(system.n, protocol.dt, system.angle_dims, cfg, v_scale=v_scale).double()
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=1e-5)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.iters)
    qt, vt = torch.as_tensor(q), torch.as_tensor(v)
    angle = list(system.angle_dims)
    from tqdm.auto import tqdm

    losses = []
    for _ in tqdm(range(cfg.iters), desc=f"tcn observer ({cfg.noise_mode})", disable=not progress):
        idx = torch.as_tensor(rng.integers(0, cfg.n_traj, cfg.batch_size))
        start = torch.as_tensor(rng.integers(0, cfg.traj_steps - cfg.crop, cfg.batch_size))
        ar = start[:, None] + torch.arange(cfg.crop)[None]
        qb, vb = qt[idx[:, None], ar], vt[idx[:, None], ar]
        if cfg.noise_mode == "fixed":
            sig = torch.full((cfg.batch_size,), cfg.sigma, dtype=qb.dtype)
        else:
            sig = torch.as_tensor(rng.uniform(0.0, cfg.sigma_max, cfg.batch_size))
        qn = qb + sig[:, None, None] * torch.randn_like(qb)
        if angle:
            qn[..., angle] = wrap(qn[..., angle])
        pred = model(qn, sig)
        w = model.window
        loss = ((pred[:, w:] - vb[:, w:]) / v_scale).pow(2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        losses.append(float(loss.detach()))
    model.eval()
    return model, {"final_loss": float(np.mean(losses[-50:])), "train_seconds": time.time() - t0, "v_scale": v_scale}


def save_tcn_observer(model: TCNObserver, path: str | Path, protocol: ControlProtocol,
                      report: dict[str, float]) -> None:
    """``path`` (.pt state dict) + ``path.json`` (config), both written atomically."""
    path = Path(path)
    atomic_torch_save(model.state_dict(), path)
    atomic_write_json(path.with_suffix(".json"), {"format": "phast-tcn-observer", "cfg": asdict(model.cfg),
                                                   "dt": model.dt, "protocol": protocol.to_dict(), "report": report})


def load_tcn_observer(path: str | Path, system: System) -> TCNObserver:
    """Load an observer saved by :func:`save_tcn_observer` (``weights_only=True``)."""
    path = Path(path)
    meta_path = path.with_suffix(".json")
    if not path.is_file() or not meta_path.is_file():
        raise ValueError(f"no TCN observer at {path} (need {path.name} and {meta_path.name})")
    try:
        meta = json.loads(meta_path.read_text())
        if meta.get("format") != "phast-tcn-observer":
            raise ValueError(f"{meta_path} is not a TCN observer file")
        cfg = TCNObserverConfig(**meta["cfg"])
        state = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, json.JSONDecodeError, KeyError, TypeError, RuntimeError) as exc:
        raise ValueError(f"cannot read TCN observer {path}: {exc}") from None
    model = TCNObserver(system.n, float(meta["dt"]), system.angle_dims, cfg).double()
    model.load_state_dict(state)
    model.eval()
    return model


def get_tcn_observer(protocol: ControlProtocol, cfg: TCNObserverConfig, cache_dir: str | Path | None,
                     progress: bool = False) -> TCNObserver:
    """Load the observer for (protocol, cfg) from ``cache_dir`` or train and cache it."""
    system = control_system(protocol)
    if cache_dir is not None:
        digest = hashlib.sha1(json.dumps([asdict(cfg), protocol.to_dict()], sort_keys=True).encode()).hexdigest()[:10]
        key = f"tcn_{cfg.noise_mode}_s{cfg.sigma:g}_m{cfg.sigma_max:g}_{protocol.env_id.replace('/', '_')}_{digest}"
        path = Path(cache_dir) / f"{key}.pt"
        if path.is_file():
            meta = json.loads(path.with_suffix(".json").read_text())
            if meta.get("cfg") == asdict(cfg) and meta.get("protocol") == protocol.to_dict():
                return load_tcn_observer(path, system)
    model, report = train_tcn_observer(protocol, cfg, progress=progress)
    if cache_dir is not None:
        save_tcn_observer(model, path, protocol, report)
    return model


class TCNEstimator(PortEstimator):
    """Online FD+TCN estimator: runs the observer on the last ``window`` measurements each step."""

    name = "tcn"

    def __init__(self, system: System, dt: float, model: TCNObserver, sigma: float = 0.0) -> None:
        super().__init__(system, dt)
        if abs(model.dt - self.dt) > 1e-12:
            raise ValueError(f"the TCN observer was trained at dt = {model.dt}, the plant runs at dt = {self.dt}")
        self.model = model
        self.sigma = float(sigma)
        # numpy copy of the weights: one closed-loop step is a few tiny matmuls (torch per-call overhead dominates)
        sd = {k: v.detach().double().numpy() for k, v in model.state_dict().items()}
        self._convs = [(sd[f"convs.{i}.weight"], sd[f"convs.{i}.bias"], 2**i) for i in range(len(model.convs))]
        self._head_w, self._head_b = sd["head.weight"][:, :, 0], sd["head.bias"]
        self._fir = sd["fir.weight"][:, 0, :]  # (n, taps)
        self._v_scale = float(sd["v_scale"])
        self.reset()

    def reset(self) -> None:
        self._hist: deque[np.ndarray] = deque(maxlen=self.model.window)

    def update(self, q_meas: np.ndarray, info: dict | None = None, u_prev: np.ndarray | None = None) -> np.ndarray:
        q_meas = np.asarray(q_meas, dtype=np.float64).reshape(self.n)
        if not self._hist:  # episode start: pad with the first sample (zero finite differences)
            self._hist.extend([q_meas] * (self.model.window - 1))
        self._hist.append(q_meas)
        return self._forward_last(np.stack(self._hist))

    def _forward_last(self, q: np.ndarray) -> np.ndarray:
        """Numpy replica of :meth:`TCNObserver.forward` on one window (W, n), last output only."""
        m = self.model
        v_fd = np.concatenate([np.zeros((1, self.n)), self._wrap_diff(np.diff(q, axis=0)) / self.dt])
        feats = []
        for i in range(self.n):
            feats += [np.sin(q[:, i]), np.cos(q[:, i])] if i in m.angle_dims else [q[:, i]]
        x = np.concatenate([np.stack(feats, -1), v_fd / self._v_scale], -1)
        if m.conditioned:
            x = np.concatenate([x, np.full((len(q), 1), self.sigma / max(m.cfg.sigma_max, 1e-6))], -1)
        x = x.T  # (C, W)
        W = x.shape[1]
        for w, b, d in self._convs:
            k = w.shape[-1]
            xp = np.concatenate([np.zeros((x.shape[0], (k - 1) * d)), x], 1)
            y = b[:, None] + sum(w[:, :, j] @ xp[:, j * d : j * d + W] for j in range(k))
            x = y / (1.0 + np.exp(-y))  # silu
        taps = self._fir.shape[1]
        fir = np.sum(self._fir * v_fd[-taps:].T, axis=1) if W >= taps else np.sum(self._fir[:, -W:] * v_fd.T, axis=1)
        return fir + (self._head_w @ x[:, -1] + self._head_b) * self._v_scale
