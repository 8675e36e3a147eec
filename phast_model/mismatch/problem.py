"""What every stage of the pipeline shares: the training recordings, their noise and scales, the windows, the nominal family."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from phast_gym.systems.base import System

from .candidates import Family
from .options import Options, Progress
from .recordings import Recordings
from .shooting import Shooter, Windows, _odd, estimate_noise, smooth, substeps_for, time_scale
from .simulators import Simulator


@dataclass
class Problem:
    """The fitting problem on the training recordings (read-only once built by :func:`prepare`)."""

    sim: Simulator
    sys0: System  # the nominal system
    train: Recordings
    opts: Options
    log: Progress
    sigma_raw: np.ndarray  # (n,) estimated measurement noise std
    sigma: np.ndarray  # (n,) noise std used to standardize residuals (floored)
    q_std: np.ndarray  # (n,) std of q
    sg: int  # Savitzky-Golay window [samples] (seeds, residual map)
    L: int  # shooting window [samples]
    qs: np.ndarray  # smoothed q of the training recordings
    vs: np.ndarray  # smoothed qdot
    x_scale: np.ndarray  # (2n,) typical |q|, |qdot|
    eps: float  # tanh smoothing of sign(qdot) in the weak form and the residual map (one for all coordinates)
    eps_coord: tuple[float, ...]  # tanh smoothing of each coordinate's Coulomb edge in the fits by simulation
    windows: Windows  # shooting windows (before outlier rejection)
    substeps: int
    X0: np.ndarray  # smoothed window initial states
    fam0: Family  # the nominal family (no parameters, no terms)
    has_u: list[bool]  # per coordinate: a non-zero port input acts on it

    @property
    def n(self) -> int:
        return self.train.n

    def shooter(self, windows: Windows) -> Shooter:
        return Shooter(windows, self.sigma, self.substeps, self.x_scale)

    def q_sample(self) -> np.ndarray:
        """About 200 recorded configurations (parameter-structure probes)."""
        train = self.train
        return train.q.reshape(-1, train.n)[:: max(1, train.q.shape[0] * train.T // 200)]


def _windows(train: Recordings, L: int, stride: int, opts: Options) -> Windows:
    """Shooting windows of L samples (every ``stride``-th compared), subsampled evenly to the caps of ``opts``."""
    win = Windows.cut(train, L, stride=stride)
    max_w = int(min(opts.max_windows, max(40, opts.max_residuals // (len(win.obs) * train.n))))
    if win.count > max_w:
        win = win.select(np.unique(np.linspace(0, win.count - 1, max_w).round().astype(int)))
    return win


def comparison_stride(train: Recordings, period: float) -> int:
    """Compare every k-th sample in shooting when u forbids decimation: ~20 samples per time scale (1 when not oversampled)."""
    if train.u is None:
        return 1
    return max(1, int(period / (2 * math.pi) / (20 * train.dt)))


def prepare(sim: Simulator, sys0: System, train: Recordings, opts: Options, log: Progress) -> Problem:
    """Noise, time scales (smoothing and shooting windows: fractions of one oscillation period), seeds."""
    n, dt = train.n, train.dt
    sigma_raw = estimate_noise(train.q, train.t)
    q_std = train.q.reshape(-1, n).std(0) + 1e-12
    sigma = np.maximum(sigma_raw, 1e-6 * q_std)
    period = 2 * math.pi * time_scale(train.resampled().q, dt)
    sg = _odd(opts.smoothing_window or max(7, int(round(0.15 * period / dt))))
    sg = min(sg, _odd(train.T // 2 - 1))
    L = int(opts.shoot_window or int(np.clip(round(0.5 * period / dt), 20, train.T)))
    L = min(L, train.T)
    qs, vs = smooth(train.q, dt, sg, train.t)
    v_rms = np.sqrt(np.mean(vs**2, axis=(0, 1))) + 1e-12
    x_scale = np.concatenate([np.sqrt(np.mean(qs**2, axis=(0, 1))) + 1e-9, v_rms])
    eps = float(opts.coulomb_eps_rel * np.median(v_rms))
    # per coordinate: 0.005 x its own rms speed (a slow cart's edge is not set by a fast pole), never below eps / 5
    eps_coord = tuple(float(e) for e in np.maximum(opts.coulomb_eps_rel * v_rms, 0.2 * eps))
    win = _windows(train, L, comparison_stride(train, period), opts)
    X0 = np.concatenate([qs[win.traj, win.start], vs[win.traj, win.start]], axis=1)
    u = train.u
    u_med = float(np.median(np.abs(u[u != 0]))) if u is not None and np.any(u != 0) else 1.0
    has_u = [bool(u is not None and np.any(u[..., i] != 0)) for i in range(n)]
    fam0 = Family(sim, {}, [], [], eps_coord, 0.05 * u_med)
    return Problem(sim, sys0, train, opts, log, sigma_raw, sigma, q_std, sg, L, qs, vs, x_scale, eps, eps_coord, win,
                   substeps_for(sys0, dt), X0, fam0, has_u)
