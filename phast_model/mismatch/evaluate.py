"""Held-out evaluation (docs/mismatch.md, "Show the fit"): rollout windows, one-step MSE and open-loop rollout RMSE.

*Held-out* means one thing in the tool: the recordings the split (:mod:`phast_model.identify.split`) sets aside before
any stage runs, which nothing is fitted to.  The other two checks on recordings left out of a fit are named apart:
the selection's *two-fold validation* on the training recordings (:mod:`.selection.forward`) and the *leave-one-out* of
the
friction-law selection and the weak-form parameter check (:mod:`.friction`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from phast_gym.systems.base import System

from ..identify.recordings import Recordings
from ..identify.shooting import Heartbeat, Shooter, Windows, angle_diff, odd, simulate_qv, smooth, substeps_for
from .written import in_mujoco

#: fewest samples of a held-out rollout window
MIN_ROLLOUT_SAMPLES = 20
#: largest rollout spread (noise units, linearized) an initial state's uncertainty may leave before it is fitted to more
#: samples
MAX_INIT_SPREAD = 1.0
#: largest spread (noise units, linearized) over the samples of the next fit length that the current fitted state may
#: leave for the homotopy on the length to jump there directly
MAX_JUMP_SPREAD = 3.0


# --------------------------------------------------------------------------- metrics
def _ladder(K0: int, K_max: int) -> list[int]:
    """Initial-state fit lengths: K0, doubled up to K_max."""
    out = [K0]
    while out[-1] < K_max:
        out.append(min(2 * out[-1], K_max))
    return out


def _fit_states(system: System, rec: Recordings, K: int, sigma: np.ndarray, x_scale: np.ndarray,
                X0: np.ndarray, heartbeat: Heartbeat | None = None, engine_substeps: int | None = None) -> np.ndarray:
    """Each trajectory's initial (q, qdot) fitted to its first K samples with ``system`` (a model file's MuJoCo at
    ``engine_substeps``, the analysis' coarser step where one holds: the rollouts scored from these states run at the
    file's)."""
    sub = int(substeps_for(system, rec.dt))
    shooter = Shooter(Windows.cut(rec.time_slice(0, K), K), sigma, sub, x_scale)
    shooter.heartbeat = heartbeat
    shooter.engine_substeps = engine_substeps
    shooter.scaled_stop = False  # a score's initial state: converged in noise units, whatever the model error
    return shooter.fit(lambda g: system, X0, np.zeros(0), max_iter=15, stats=False).X


@dataclass(frozen=True)
class _Linearization:
    """A model's full held-out rollouts linearized in their initial states: J (W, T n, 2n), in noise units."""

    J: np.ndarray
    n: int

    @classmethod
    def at(cls, system: System, rec: Recordings, sigma: np.ndarray, x_scale: np.ndarray,
           X: np.ndarray, engine_substeps: int | None = None) -> _Linearization:
        shooter = Shooter(Windows.cut(rec, rec.T), sigma, int(substeps_for(system, rec.dt)), x_scale)
        shooter.engine_substeps = engine_substeps  # a linearization for the fit lengths, not a score
        return cls(shooter.residual_and_jac_X(system, X)[1], rec.n)

    def spread(self, fitted: int, over: int) -> np.ndarray:
        """(W,) the RMS over the first ``over`` samples of the linearized std of q (noise units) that the state of a
        fit to the first ``fitted`` samples leaves: sqrt(trace(J_o C J_o^T) / (over n)), C = (J_f^T J_f)^+."""
        Jf, Jo = self.J[:, : fitted * self.n], self.J[:, : over * self.n]
        cov = np.linalg.pinv(np.einsum("wla,wlb->wab", Jf, Jf))
        out = np.sqrt(np.einsum("wla,wab,wlb->w", Jo, cov, Jo) / Jo.shape[1])
        return np.where(np.isfinite(out), out, np.inf)

    def needed(self, ladder: list[int]) -> np.ndarray:
        """Per trajectory, the shortest fit length of ``ladder`` whose state spreads the whole rollout by at most
        :data:`MAX_INIT_SPREAD` (else the longest)."""
        need = np.full(self.J.shape[0], ladder[-1])
        T = self.J.shape[1] // self.n
        for K in reversed(ladder):
            need[self.spread(K, T) <= MAX_INIT_SPREAD] = K
        return need

    def next_lengths(self, ladder: list[int], current: np.ndarray, final: np.ndarray) -> np.ndarray:
        """Per trajectory, the next fit length on its way to ``final``: the longest whose samples the current state
        already predicts within :data:`MAX_JUMP_SPREAD` (the fit then starts in its basin), else the next one of the
        ladder (every spread computed once for all trajectories)."""
        nxt = np.array([min((K for K in ladder if K > c), default=c) for c in current])
        for c in np.unique(current):
            at = current == c
            for K in (K for K in ladder if K > c):
                jump = at & (K <= final) & (K > nxt) & (self.spread(int(c), K) <= MAX_JUMP_SPREAD)
                nxt[jump] = K
        return nxt


def _say(heartbeat: Heartbeat | None, text: str) -> None:
    """A progress line at a stage's start (the held-out scoring of a UR10e takes minutes)."""
    if heartbeat is not None:
        heartbeat.mark(text)


def _initial_states(models: dict[str, System], rec: Recordings, K: int, sigma: np.ndarray, x_scale: np.ndarray,
                    qs: np.ndarray, vs: np.ndarray, heartbeat: Heartbeat | None = None,
                    engine_substeps: int | None = None) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Every model's initial states of the held-out trajectories, and the samples each was fitted to.

    A trajectory whose state fitted to K samples leaves a rollout spread above :data:`MAX_INIT_SPREAD` under any model
    (a pendulum creeping past its upright: the open-loop error then measures the luck of the initial state, the true
    model's included) is fitted to more samples: the shortest of K, 2K, 4K, ... (up to half the recording) whose state
    is predicted to leave a small spread (one linearization at the K-sample fit, :class:`_Linearization`), for every
    model alike, reached by a homotopy on the length."""
    ladder = _ladder(min(K, rec.T), max(min(K, rec.T), rec.T // 2))
    X = {}
    for k, (name, s) in enumerate(models.items()):
        _say(heartbeat, f"  held-out: {name}: initial states of {rec.n_traj} windows ({k + 1} of {len(models)})")
        X[name] = _fit_states(s, rec, ladder[0], sigma, x_scale,
                              np.concatenate([getattr(s, "unmeasure", lambda y: y)(qs[:, 0]), vs[:, 0]], axis=1),
                              heartbeat, engine_substeps)
    Ks = np.full(rec.n_traj, ladder[0])
    if len(ladder) == 1:
        return X, Ks
    _say(heartbeat, "  held-out: how far each initial state's uncertainty spreads the rollouts")
    lin = {name: _Linearization.at(s, rec, sigma, x_scale, X[name], engine_substeps) for name, s in models.items()}
    Ks = np.max([m.needed(ladder) for m in lin.values()], axis=0)
    for name, system in models.items():
        current = np.full(rec.n_traj, ladder[0])
        if np.any(current < Ks):
            longer = int(np.sum(current < Ks))
            _say(heartbeat, f"  held-out: {name}: initial states of {longer} windows on longer spans")
        while np.any(current < Ks):
            todo = np.flatnonzero(current < Ks)
            nxt = lin[name].next_lengths(ladder, current, Ks)[todo]
            for k in np.unique(nxt):
                idx = todo[nxt == k]
                X[name][idx] = _fit_states(system, rec.subset(idx), int(k), sigma, x_scale, X[name][idx], heartbeat,
                                           engine_substeps)
                current[idx] = k
    return X, Ks


def evaluate_models(models: dict[str, System], rec: Recordings, sigma: np.ndarray, x_scale: np.ndarray, K: int,
                    smoothing_window: int, scale: np.ndarray, heartbeat: Heartbeat | None = None,
                    engine_substeps: int | None = None) -> tuple[dict[str, dict[str, float]], dict[str, np.ndarray]]:
    """one_step_mse and rollout_rmse (docs/mismatch.md) of each model on held-out recordings; a system listed under
    several names (the calibrated model when no parameter changed) is scored once.  ``engine_substeps``: MuJoCo's
    steps an interval in the initial-state fits (None: the file's; the scored rollouts are always at the file's)."""
    first = {id(s): name for name, s in reversed(list(models.items()))}  # each system's first name
    if len(first) < len(models):
        distinct = {name: s for name, s in models.items() if first[id(s)] == name}
        out, rolls = _evaluate(distinct, rec, sigma, x_scale, K, smoothing_window, scale, heartbeat, engine_substeps)
        return ({name: out[first[id(s)]] for name, s in models.items()},
                {name: rolls[first[id(s)]] for name, s in models.items()})
    return _evaluate(models, rec, sigma, x_scale, K, smoothing_window, scale, heartbeat, engine_substeps)


def _evaluate(models: dict[str, System], rec: Recordings, sigma: np.ndarray, x_scale: np.ndarray, K: int,
              smoothing_window: int, scale: np.ndarray, heartbeat: Heartbeat | None = None,
              engine_substeps: int | None = None) -> tuple[dict[str, dict[str, float]], dict[str, np.ndarray]]:
    """:func:`evaluate_models` of distinct systems."""
    n, dt = rec.n, rec.dt
    qs, vs = smooth(rec.q, dt, smoothing_window, rec.t)
    out: dict[str, dict[str, float]] = {}
    rollouts: dict[str, np.ndarray] = {}
    states, _ = _initial_states(models, rec, K, sigma, x_scale, qs, vs, heartbeat, engine_substeps)
    for name, system in models.items():
        _say(heartbeat, f"  held-out: {name}: rollouts and one-step predictions")
        X = states[name]
        q_roll = simulate_qv(system, X[:, :n], X[:, n:], rec.T - 1, rec.u, rec.sim_dt, substeps_for(system, rec.sim_dt))
        d = angle_diff(q_roll, rec.q, rec.angle_dims) / scale
        rollout_rmse = float(np.sqrt(np.mean(np.where(np.isfinite(d), d, 1e6) ** 2)))
        # one step from every smoothed state
        unmeasure = getattr(system, "unmeasure", lambda y: y)
        q0 = unmeasure(qs[:, :-1]).reshape(-1, n)
        v0 = vs[:, :-1].reshape(-1, n)
        u1 = None if rec.u is None else rec.u.reshape(-1, 1, n)
        d1 = dt if rec.uniform else rec.steps.reshape(-1, 1)
        q1 = simulate_qv(system, q0, v0, 1, u1, d1, substeps_for(system, d1))[:, 1]
        e = angle_diff(q1, rec.q[:, 1:].reshape(-1, n), rec.angle_dims) / scale
        out[name] = {"one_step_mse": float(np.mean(np.where(np.isfinite(e), e, 1e6) ** 2)),
                     "rollout_rmse": rollout_rmse}
        rollouts[name] = q_roll
    return out, rollouts


# --------------------------------------------------------------------------- the held-out comparison
@dataclass(frozen=True)
class ModelScore:
    """One model's metrics on the held-out recordings (docs/mismatch.md)."""

    one_step_mse: float
    rollout_rmse: float


@dataclass(frozen=True)
class RolloutSetup:
    """How the held-out rollouts were made (the same for all models)."""

    window_samples: int  # open-loop window
    n_windows: int
    window_s: float
    init_samples: int
    text: str


@dataclass
class FitTable:
    """report.fit: the metrics of each model (ours, then any compared ones) and what they were computed on."""

    models: dict[str, ModelScore]
    evaluated_on: str
    rollout: RolloutSetup
    energy_check: dict[str, Any] | None = None  # set by the analysis when the augmented model adds dissipation

    def rmse(self, name: str) -> float:
        return self.models[name].rollout_rmse

    def to_dict(self) -> dict[str, Any]:
        """The report.json ``fit`` object."""
        out: dict[str, Any] = {k: {"one_step_mse": m.one_step_mse, "rollout_rmse": m.rollout_rmse}
                               for k, m in self.models.items()}
        ro = self.rollout
        out.update({"evaluated_on": self.evaluated_on, "rollout_window_samples": ro.window_samples,
                    "rollout_n_windows": ro.n_windows,
                    "rollout_window_s": ro.window_s, "rollout_init_samples": ro.init_samples, "rollout": ro.text})
        if self.energy_check is not None:
            out["energy_check"] = self.energy_check
        return out


@dataclass
class HeldOut:
    """How models are compared on the held-out recordings (the split's, never fitted; the systematic regime also
    scores the training recordings with the same setup)."""

    rec: Recordings  # what rollouts are scored on: the held-out trajectories, or their consecutive windows
    full: Recordings  # the held-out trajectories whole
    evaluated_on: str
    sigma: np.ndarray
    x_scale: np.ndarray
    scale: np.ndarray  # per-coordinate RMSE scale (std of q when angles and lengths mix, else 1)
    init_samples: int  # samples each initial state is fitted to
    smoothing_window: int  # smoothing window of the one-step seeds
    mixed: bool
    windowed: bool
    heartbeat: Heartbeat | None = None  # progress lines while the models' initial states are fitted (minutes)
    engine_substeps: int | None = None  # MuJoCo's steps an interval in the initial-state fits (None: the file's)

    def evaluate(self, models: dict[str, System],
                 rec: Recordings | None = None) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """The metrics and rollouts of ``models``; a model file's models are simulated as MuJoCo simulates them
        written back (:func:`.written.in_mujoco`), each distinct system once."""
        simulated: dict[int, System] = {}
        for s in models.values():
            if id(s) not in simulated:
                simulated[id(s)] = in_mujoco(s)
        if self.heartbeat is not None:
            self.heartbeat.say(f"  held-out: scoring {', '.join(models)}")
        return evaluate_models({k: simulated[id(s)] for k, s in models.items()}, self.rec if rec is None else rec,
                               self.sigma, self.x_scale, self.init_samples, self.smoothing_window, self.scale,
                               self.heartbeat, self.engine_substeps)

    def rollout_rmse(self, system: System, rec: Recordings) -> float:
        return self.evaluate({"m": system}, rec)[0]["m"]["rollout_rmse"]

    def fit_table(self, models: dict[str, System]) -> tuple[FitTable, dict[str, np.ndarray]]:
        """report.fit: the metrics of each model plus what they were computed on; and the rollouts (plots)."""
        hold, init_samples = self.rec, self.init_samples
        metrics, rollouts = self.evaluate(models)
        win_txt = (f"held-out recordings cut into {hold.n_traj} consecutive windows of {hold.T} samples; "
                   if self.windowed else "")
        text = (win_txt
                + f"per held-out trajectory / window: initial state fitted to its first {init_samples} samples (2, 4, "
                  "... "
                "times as many, up to half the window, where that state's uncertainty alone, linearized, would spread "
                "the rollout by more than the noise), open-loop "
                f"simulation over all {hold.T} samples with the recorded u; RMSE of q"
                + (" scaled per coordinate by its std" if self.mixed else "")
                + (" (angles wrapped)" if hold.angle_dims else ""))
        setup = RolloutSetup(int(hold.T), int(hold.n_traj), float(np.median(hold.times()[:, -1] - hold.times()[:, 0])),
                             init_samples, text)
        scores = {k: ModelScore(m["one_step_mse"], m["rollout_rmse"]) for k, m in metrics.items()}
        return FitTable(scores, self.evaluated_on, setup), rollouts


def check_rollout_window(rollout_window: float | None, dt: float) -> None:
    """ValueError (the user's input) when a rollout window of ``rollout_window`` seconds holds too few samples."""
    if rollout_window is not None and int(round(rollout_window / dt)) + 1 < MIN_ROLLOUT_SAMPLES:
        raise ValueError(f"rollout_window {rollout_window} s is shorter than {MIN_ROLLOUT_SAMPLES} samples (dt={dt})")


def held_out(hold: Recordings, evaluated_on: str, sigma: np.ndarray, x_scale: np.ndarray, shoot_window: int,
             smoothing_window: int,
             rollout_window: float | None) -> HeldOut:
    """The held-out comparison: rollout windows of ``rollout_window`` seconds (default: whole trajectories), initial
    states fitted to a quarter shooting window."""
    n, dt = hold.n, hold.dt
    mixed = len(set(hold.angle_dims)) not in (0, n)
    scale = hold.q.reshape(-1, n).std(0) if mixed else np.ones(n)
    rec = hold
    if rollout_window is not None:
        check_rollout_window(rollout_window, dt)
        rec = hold.windows(int(round(rollout_window / dt)) + 1)
    init_samples = int(min(rec.T, max(10, shoot_window // 4)))
    return HeldOut(rec, hold, evaluated_on, sigma, x_scale, scale, init_samples,
                   min(smoothing_window, odd(rec.T // 2 - 1)), mixed,
                   rollout_window is not None)
