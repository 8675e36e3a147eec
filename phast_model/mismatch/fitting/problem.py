"""What every stage of the pipeline shares: the training recordings, their noise and scales, the windows, the nominal
family."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from phast_gym.systems.base import System

from ...identify.mujoco_sim import StepCheck
from ...identify.recordings import Recordings
from ...identify.shooting import (
    Heartbeat,
    Shooter,
    Windows,
    estimate_noise,
    odd,
    smooth,
    substeps_for,
    time_scale,
)
from ...identify.simulators import Simulator
from ...identify.weakform import rms_speed, sign_smoothing, smoothing_window
from ..options import Options, Progress
from ..vocabulary.candidates import Family


@dataclass(frozen=True)
class Noise:
    """Measurement noise of the training recordings, per coordinate."""

    sigma_raw: np.ndarray  # (n,) estimated measurement noise std
    sigma: np.ndarray  # (n,) noise std used to standardize residuals (floored)
    q_std: np.ndarray  # (n,) std of q


@dataclass(frozen=True)
class Smoothing:
    """The smoothed training recordings and the smoothing behind them."""

    window: int  # Savitzky-Golay window [samples] (seeds, residual map, weak form)
    qs: np.ndarray  # smoothed q of the training recordings
    vs: np.ndarray  # smoothed qdot
    x_scale: np.ndarray  # (2n,) typical |q|, |qdot|
    eps: float  # tanh smoothing of sign(qdot) in the weak form and the residual map (one for all coordinates)
    eps_coord: tuple[float, ...]  # tanh smoothing of each coordinate's Coulomb edge in the fits by simulation


@dataclass(frozen=True)
class ShootingSetup:
    """The shooting windows (before outlier rejection) and their smoothed initial states."""

    window: int  # shooting window [samples]
    windows: Windows
    substeps: int
    X0: np.ndarray  # smoothed window initial states
    engine_substeps: int | None = None  # MuJoCo's steps an interval in the fits (None: the file's; written.py)


@dataclass(frozen=True)
class Problem:
    """The fitting problem on the training recordings (read-only once built by :func:`prepare`)."""

    sim: Simulator
    sys0: System  # the nominal system
    train: Recordings
    opts: Options
    log: Progress
    noise: Noise
    smoothing: Smoothing
    shooting: ShootingSetup
    nominal_family: Family  # the nominal family (no parameters, no terms)
    step_check: StepCheck = field(default_factory=StepCheck)  # every fit's departure at the coarser MuJoCo step

    @property
    def has_u(self) -> list[bool]:
        """Per coordinate: a non-zero port input acts on it."""
        u = self.train.u
        return [bool(u is not None and np.any(u[..., i] != 0)) for i in range(self.n)]

    # the groups' fields by the names the stages use
    @property
    def sigma(self) -> np.ndarray:
        return self.noise.sigma

    @property
    def sigma_raw(self) -> np.ndarray:
        return self.noise.sigma_raw

    @property
    def q_std(self) -> np.ndarray:
        return self.noise.q_std

    @property
    def smoothing_window(self) -> int:
        return self.smoothing.window

    @property
    def qs(self) -> np.ndarray:
        return self.smoothing.qs

    @property
    def vs(self) -> np.ndarray:
        return self.smoothing.vs

    @property
    def x_scale(self) -> np.ndarray:
        return self.smoothing.x_scale

    @property
    def eps(self) -> float:
        return self.smoothing.eps

    @property
    def eps_coord(self) -> tuple[float, ...]:
        return self.smoothing.eps_coord

    @property
    def shoot_window(self) -> int:
        return self.shooting.window

    @property
    def n(self) -> int:
        return self.train.n

    def shooter(self, windows: Windows) -> Shooter:
        """A shooter on ``windows`` whose long fits report their progress in the analysis' log, and simulate a model
        file at the analysis' coarser step where one holds (:func:`~phast_model.mismatch.written.with_coarse_step`)."""
        shooter = Shooter(windows, self.sigma, self.shooting.substeps, self.x_scale)
        shooter.heartbeat = Heartbeat(self.log)
        shooter.engine_substeps = self.shooting.engine_substeps
        shooter.step_check = self.step_check
        return shooter

    def q_sample(self) -> np.ndarray:
        """About 200 recorded configurations (parameter-structure probes)."""
        train = self.train
        return train.q.reshape(-1, train.n)[:: max(1, train.q.shape[0] * train.T // 200)]


def _windows(train: Recordings, length: int, stride: int, opts: Options) -> Windows:
    """Shooting windows of ``length`` samples (every ``stride``-th compared), subsampled evenly to the caps of
    ``opts``."""
    win = Windows.cut(train, length, stride=stride)
    max_w = int(min(opts.max_windows, max(40, opts.max_residuals // (len(win.obs) * train.n))))
    if win.count > max_w:
        win = win.select(np.unique(np.linspace(0, win.count - 1, max_w).round().astype(int)))
    return win


def smoothed_states(qs: np.ndarray, vs: np.ndarray, win: Windows) -> np.ndarray:
    """(W, 2n) each window's starting state from the smoothed recordings (a fit's initial window states)."""
    return np.concatenate([qs[win.traj, win.start], vs[win.traj, win.start]], axis=1)


def longer_windows(problem: Problem, length: int) -> Windows:
    """Shooting windows of ``length`` samples (at most the recordings') on the training recordings, compared at the
    selection's stride and under the same caps (fewer, longer windows)."""
    return _windows(problem.train, min(length, problem.train.T), problem.shooting.windows.stride, problem.opts)


def comparison_stride(train: Recordings, period: float) -> int:
    """Compare every k-th sample in shooting when u forbids decimation: ~20 samples per time scale (1 when not
    oversampled)."""
    if train.u is None:
        return 1
    return max(1, int(period / (2 * math.pi) / (20 * train.dt)))


def at_file_step(problem: Problem) -> Problem:
    """``problem`` with MuJoCo at the file's own step in every fit."""
    return replace(problem, shooting=replace(problem.shooting, engine_substeps=None), step_check=StepCheck())


def prepare(sim: Simulator, sys0: System, train: Recordings, opts: Options, log: Progress) -> Problem:
    """Noise, time scales (smoothing and shooting windows: fractions of one oscillation period), seeds."""
    n, dt = train.n, train.dt
    sigma_raw = estimate_noise(train.q, train.t)
    q_std = train.q.reshape(-1, n).std(0) + 1e-12
    noise = Noise(sigma_raw, np.maximum(sigma_raw, 1e-6 * q_std), q_std)
    period = 2 * math.pi * time_scale(train.resampled().q, dt)
    window = odd(opts.smoothing_window) if opts.smoothing_window else smoothing_window(period, dt)
    window = min(window, odd(train.T // 2 - 1))
    shoot_window = int(opts.shoot_window or int(np.clip(round(0.5 * period / dt), 20, train.T)))
    shoot_window = min(shoot_window, train.T)
    qs, vs = smooth(train.q, dt, window, train.t)
    v_rms = rms_speed(vs)
    x_scale = np.concatenate([np.sqrt(np.mean(qs**2, axis=(0, 1))) + 1e-9, v_rms])
    eps = sign_smoothing(v_rms, opts.coulomb_eps_rel)
    # per coordinate: 0.005 x its own rms speed (a slow cart's edge is not set by a fast pole), never below eps / 5
    eps_coord = tuple(float(e) for e in np.maximum(opts.coulomb_eps_rel * v_rms, 0.2 * eps))
    win = _windows(train, shoot_window, comparison_stride(train, period), opts)
    X0 = smoothed_states(qs, vs, win)
    u = train.u
    u_med = float(np.median(np.abs(u[u != 0]))) if u is not None and np.any(u != 0) else 1.0
    nominal = Family(sim, {}, [], [], eps_coord, 0.05 * u_med)
    return Problem(sim, sys0, train, opts, log, noise, Smoothing(window, qs, vs, x_scale, eps, eps_coord),
                   ShootingSetup(shoot_window, win, int(substeps_for(sys0, dt)), X0), nominal)
