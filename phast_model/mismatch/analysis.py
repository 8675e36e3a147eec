"""The mismatch pipeline of docs/mismatch.md: calibrate, explain, locate, show the fit.

Everything that decides (calibration, term selection, coefficients and their
95% intervals, the held-out comparison) is a *fit by simulation*: multiple
shooting of the nominal / augmented simulator on windows of the recordings
(:mod:`phast_model.identify.shooting`).  Smoothed derivatives are used only to seed window states
and to draw the residual map, so the answer does not move with the filter.

Stages (this module composes them, the only one that imports them all; their order is the package docstring's):
:mod:`.fitting.problem` (noise, scales, windows), :mod:`.calibrate`,
:mod:`.selection` (screening, shooting selection, two-fold validation, the longer look at laws),
:mod:`.explainers` (the answer's strategies: the shooting selection's, then :mod:`.friction.systematic`'s weak form and
:mod:`.friction` when model error dominates, adopted only when it predicts the held-out recordings better),
:mod:`.evaluate` (the fit on the held-out recordings) and :mod:`.energy`,
:mod:`.locate`, :mod:`.report` (and :mod:`.report.mjcf_answer` for a MuJoCo model file).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from phast_gym.systems.base import System

from ..identify.mujoco_sim import StepProbe, engine_threads
from ..identify.recordings import Recordings, load_raw, validate
from ..identify.shooting import Heartbeat, odd, time_scale
from ..identify.simulators import Simulator, load_simulator
from ..identify.split import check_holdout_indices, check_holdout_range, split
from .calibrate import (
    ParameterScreen,
    calibration,
    drives_screen,
    explained_share,
    fit_nominal,
    nominal_sample,
    screen_parameters,
)
from .energy import energy_check
from .evaluate import FitTable, HeldOut, check_rollout_window, held_out
from .explainers import Context, Explained, Explainer, ShootingExplainer, explain_in_turn
from .fitting.problem import Problem, at_file_step, prepare
from .friction.engine_refit import FAR
from .friction.systematic import WeakFormExplainer, drive_share, drives_trial, parameter_share
from .locate import locate
from .options import Options, Progress
from .report.document import Report, summary_text
from .report.mjcf_answer import answer_in_model_terms
from .rows import ParamRow, TermRow
from .selection import candidates, select
from .vocabulary.registry import ACTUATOR_GAIN, mujoco_vocabulary
from .vocabulary.terms import VOCABULARY
from .written import fits_in_mujoco, in_mujoco, is_model_file_system, with_coarse_step

__all__ = ["EXPLAINERS", "InternalError", "Options", "Report", "analyze", "held_out_scores"]

#: the explainers :func:`analyze` runs, in order (:func:`.explainers.explain_in_turn`): a later answer challenges the
#: standing one and is adopted only when it predicts the held-out recordings better.  A new explainer is added here.
EXPLAINERS: tuple[Explainer, ...] = (ShootingExplainer(), WeakFormExplainer())


def _options(options: Options | None, overrides: Mapping[str, object]) -> Options:
    opts = options or Options()
    bad = sorted(k for k in overrides if k not in Options.flat_names())
    if bad:
        raise ValueError(f"unknown option(s) {bad}; valid: {sorted(Options.flat_names())}")
    opts = opts.with_(**overrides)
    if isinstance(opts.free, str):
        opts = replace(opts, free=(opts.free,))
    unknown = sorted(set(opts.terms or ()) - set(VOCABULARY))
    if unknown:
        raise ValueError(f"unknown term(s) {unknown}; the vocabulary is {sorted(VOCABULARY)}")
    return opts


def _simulator(sim: str | type[System] | Simulator,
               sim_kwargs: Mapping[str, object] | None) -> tuple[Simulator, System]:
    try:
        simulator = load_simulator(sim, sim_kwargs)
    except ValueError as exc:
        if sim_kwargs and "failed to build" in str(exc):
            raise ValueError(f"bad --sim-kwargs: {exc}") from None
        raise
    return simulator, simulator.build()


def _recordings(recordings: str | Path | Mapping[str, object] | Recordings, sys0: System, name: str) -> Recordings:
    if isinstance(recordings, Recordings):
        if recordings.n != sys0.n:
            raise ValueError(f"recordings have n={recordings.n} coordinates but {name} has n={sys0.n}")
        return recordings
    raw, src = load_raw(recordings)
    return validate(raw, sys0.n, tuple(sys0.angle_dims), src, actuated_dofs=getattr(sys0, "actuated_dofs", None))


def _decimate(rec: Recordings, opts: Options) -> tuple[Recordings, int]:
    """Every k-th sample, k ~ a twentieth of the time scale, and k.  Never with u (held per recorded interval): then
    shooting simulates every interval and compares every k-th sample instead
    (:func:`.fitting.problem.comparison_stride`)."""
    dec = opts.decimate
    if dec is None:
        dec = 1 if rec.u is not None else max(1, int(time_scale(rec.resampled().q, rec.dt) / (20 * rec.dt)))
        dec = min(dec, max(1, rec.T // 200))
    return (rec.decimate(dec) if dec > 1 else rec), dec


def _compared(compare: Mapping[str, System] | None, sys0: System, name: str) -> dict[str, System]:
    """The user's comparison models, checked to be systems of the same coordinates (names must not shadow ours)."""
    out = dict(compare or {})
    for key, system in out.items():
        if key in ("nominal", "calibrated", "augmented"):
            raise ValueError(f"compare: the name {key!r} is taken by the report's own rows; choose another")
        if not isinstance(system, System) or system.n != sys0.n:
            raise ValueError(f"compare[{key!r}] must be a phast_gym System with n={sys0.n} coordinates like {name}, "
                             f"got {system!r}")
    return out


#: the nominal simulator must explain at least this share of the recordings beyond a line per window (explained_share)
MIN_DESCRIBED = 0.5
#: a motor-driven model file whose drives alone (rotor inertia, joint friction) follow a sample of the windows to
#: this chi^2/dof (noise: 1) is answered with its drives, its body values kept (:func:`_screen`)
DRIVES_CHI2 = 2.0
#: drives that remove at least this share of the file's misfit beyond the noise on the sample, (chi2_file -
#: chi2_drives) / (chi2_file - 1), without being far from following it (chi^2/dof <= FAR), explain nearly all of it with
#: a few values per joint: the rest is for body values, fitted after the drives and only where they cannot stand in for
#: one (a CAD model a few per cent off that also lacks its drives: 90-99% on the bench's 6-joint arm, against 6-13%
#: where only body values or a gear are off); the file's 42 body values would otherwise be bent to mimic the drives
DRIVES_NEAR_SHARE = 0.8


def drives_nearly_follow(drives_chi2: float | None, file_chi2: float | None) -> bool:
    """The drives alone nearly follow the sample (:data:`DRIVES_NEAR_SHARE`)."""
    return (drives_chi2 is not None and file_chi2 is not None and file_chi2 > 1.0 and drives_chi2 <= FAR
            and file_chi2 - drives_chi2 >= DRIVES_NEAR_SHARE * (file_chi2 - 1.0))


def _backed(row: TermRow) -> bool:
    """The term's own 95% interval excludes zero: the data back a term of its sign."""
    lo, hi = row.ci95
    return not lo <= 0.0 <= hi


def _confirmed(missing: list[TermRow], fitres: FitTable) -> tuple[list[TermRow], list[TermRow]]:
    """What is reported as missing physics, and what is set aside (details.unconfirmed_terms): a term whose own
    interval includes zero is not backed by the data, and terms that do not improve the prediction of the held-out
    recordings are not a discovery."""
    unbacked = [m for m in missing if not _backed(m)]
    backed = [m for m in missing if _backed(m)]
    if backed and fitres.rmse("augmented") >= fitres.rmse("calibrated"):
        return [], missing
    return backed, unbacked


#: an input scale the model does not share: every driven coordinate asks for a gain this far from 1 (or its inverse) ...
INPUT_SCALE_OFF = 2.0
#: ... and the same one, within this ratio of the largest to the smallest
INPUT_SCALE_SPREAD = 1.5


def input_scale(missing: Sequence[TermRow], driven: Sequence[bool]) -> float | None:
    """The common gain when an ``actuator_gain`` on every driven coordinate (two or more) asks for the same large
    factor: the recorded input is in other units than the model's (a motor current for a torque, a missing gear or
    drive gain), not a weak motor on each joint.  None otherwise."""
    gains = {m.coordinate: m.coefficient for m in missing if m.term == ACTUATOR_GAIN.name}
    want = {i for i, d in enumerate(driven) if d}
    if len(want) < 2 or set(gains) != want or min(gains.values()) <= 0:
        return None
    lo, hi = min(gains.values()), max(gains.values())
    mid = math.exp(float(np.mean(np.log(list(gains.values())))))
    off = max(mid, 1.0 / mid) >= INPUT_SCALE_OFF
    return mid if off and hi / lo <= INPUT_SCALE_SPREAD else None


def _verdicts(described: Described, unconfirmed: list[TermRow], fitres: FitTable,
              scale: float | None = None) -> list[str]:
    """Sentences for the summary when the simulator does not describe the recordings or the found terms do not
    predict."""
    out = []
    if not described.ok:
        share = described.share
        out.append("The simulator does not describe these recordings: nominal or calibrated, it explains "
                   f"{max(share, 0.0):.0%} "
                   "of their variation beyond a straight line per window (a model of the recorded system explains "
                   "nearly all of it), so no parameter was calibrated and no term is named; check the simulator, the "
                   "coordinates and the units (angle_offset, angle_dims).")
    unbacked = [m for m in unconfirmed if not _backed(m)]
    if unbacked:
        named = ", ".join(f"{m.label} ({m.coefficient:.3g} [{m.ci95[0]:.3g}, {m.ci95[1]:.3g}])" for m in unbacked)
        out.append(f"The 95% interval of {named} includes zero: the data do not back it, so it is not reported as "
                   "missing physics (details.unconfirmed_terms).")
    if scale is not None:
        out.append(f"The input's scale does not match the model: every driven coordinate asks for the same gain, about "
                   f"{scale:.3g}x the recorded input. The recorded u is probably in other units than the model's "
                   "(a motor current where a torque is expected, or a missing gear or drive gain): convert it (drive "
                   "gain x current) or set the actuators' gear; the gains are not reported as missing physics "
                   "(details.unconfirmed_terms).")
    held_out = [m for m in unconfirmed if _backed(m) and not (scale is not None and m.term == ACTUATOR_GAIN.name)]
    if held_out:
        names = ", ".join(m.label for m in held_out)
        out.append(f"Terms that fit the training recordings ({names}) do not improve the prediction of the held-out "
                   f"recordings (rollout RMSE calibrated {fitres.rmse('calibrated'):.4g}, with them "
                   f"{fitres.rmse('augmented'):.4g}), so they are not reported as missing physics "
                   "(details.unconfirmed_terms).")
    return out


def _data(rec: Recordings, dec: int, sigma_raw: np.ndarray) -> dict[str, Any]:
    """report.data (sizes of the recordings as given, before decimation; a log set's logs, pieces and dropped rows)."""
    from ..identify.logs import report_facts

    return {"n_traj": rec.n_traj, "T": rec.T, "dt": rec.dt, "decimated_by": dec,
            "noise_std": float(np.sqrt(np.mean(sigma_raw**2))),
            "noise_std_per_coordinate": [float(s) for s in sigma_raw], "source": rec.source,
            "angle_dims": list(rec.angle_dims), "has_input": rec.u is not None, **report_facts(rec.meta)}


def _details(ctx: Context, explained: Explained, augmented: System) -> dict[str, Any]:
    """report.details: method, windows, chi^2/dof of each stage, what was set aside, cost."""
    problem, cal, sel, answer = ctx.problem, ctx.cal, ctx.selection, explained.answer
    opts, win = problem.opts, cal.shooter.w
    return {"method": explained.method, "shoot_window_samples": int(win.length), "n_windows": int(win.count),
            "n_windows_dropped_as_outliers": cal.n_dropped, "smoothing_window_samples": int(problem.smoothing_window),
            "coulomb_sign_smoothing": f"tanh(qdot/{problem.eps:.3g})",
            "coulomb_sign_smoothing_per_coordinate": np.broadcast_to(sel.family.eps, (problem.train.n,)).tolist(),
            "threshold": opts.threshold,
            "intervals": explained.intervals,
            "chi2_per_dof": {"nominal": cal.fit_nominal.chi2_red, "calibrated": cal.fit.chi2_red,
                             "augmented": answer.fit.chi2_red},
            "identifiability": cal.screen.identifiability.to_dict(),
            "held_out_check": sel.validation,  # the two-fold validation (select.py); the key's name is kept for readers
            "equivalent_swap": sel.equivalent_swap,
            "chi2_per_dof_every_pivot_fitted": cal.screen.fit_full.chi2_red, **explained.details(),
            "n_simulations": cal.shooter.n_sims,
            "wall_time_s": problem.log.elapsed(), "calibrated_kwargs": dict(augmented.params)}


def analyze(sim: str | type[System] | Simulator, recordings: str | Path | Mapping[str, object] | Recordings,
            sim_kwargs: Mapping[str, object] | None = None, holdout_fraction: float = 0.3,
            options: Options | None = None,
            holdout_trajectories: Sequence[int] | None = None, compare: Mapping[str, System] | None = None,
            explainers: Sequence[Explainer] | None = None, **option_overrides: Any) -> Report:
    """Find what the nominal simulator ``sim`` leaves out of ``recordings``.

    ``sim``: an env id, ``my_pkg.mod:MyRig``, ``path/to/rig.py:MyRig`` or a System subclass
    (:func:`.simulators.load_simulator`); ``sim_kwargs`` override its physical parameters.
    ``recordings``: an .npz / .csv path, a dict with the keys of docs/mismatch.md, or a :class:`Recordings`.
    ``holdout_trajectories`` (0-based indices) overrides ``holdout_fraction``.  ``compare``: more models (e.g. a
    published identified model) scored on the held-out recordings by the same code, as extra rows of ``fit``.
    ``explainers`` replaces :data:`EXPLAINERS` (the strategies that answer, in order; :mod:`.explainers`).
    Returns a :class:`Report`.
    """
    opts = _options(options, option_overrides)
    holdout = check_holdout_indices(holdout_trajectories)
    log = Progress(opts.progress)
    simulator, sys0 = _simulator(sim, sim_kwargs)
    if opts.terms is None and is_model_file_system(sys0):  # the friction MuJoCo simulates: the answer is the file
        opts = replace(opts, terms=mujoco_vocabulary())
    given = _recordings(recordings, sys0, simulator.name)
    if holdout is not None:
        check_holdout_range(holdout, given.n_traj)
    rec, dec = _decimate(given, opts)
    train, hold, evaluated_on = split(rec, holdout_fraction, holdout)
    check_rollout_window(opts.rollout_window, rec.dt)
    check_free(opts.free, simulator.numeric_params(sys0))
    comparison = _compared(compare, sys0, simulator.name)
    log(f"{simulator.name}: {rec.n_traj} recordings x {rec.T} samples, dt={rec.dt}")
    if opts.threads < 1:
        raise ValueError(f"threads must be at least 1, got {opts.threads}")
    with engine_threads(opts.threads):
        try:  # the input was checked above: anything raised from here on is the tool's own failure
            problem = with_coarse_step(fits_in_mujoco(prepare(simulator, sys0, train, opts, log)))
            held = replace(held_out(hold, evaluated_on, problem.sigma, problem.x_scale, problem.shoot_window,
                                    problem.smoothing_window, held_out_window(problem, hold)),
                           heartbeat=Heartbeat(log), engine_substeps=problem.shooting.engine_substeps)
            inputs = _Inputs(simulator, given, dec, train, hold, held, comparison,
                             tuple(EXPLAINERS if explainers is None else explainers))
            if not is_model_file_system(sys0):
                return _second_look(problem, inputs, _explain(problem, inputs))
            problem, inputs, report = _checked_step(problem, inputs)
            return answer_in_model_terms(report, sys0, inputs.held, given)
        except ValueError as exc:
            raise InternalError(f"internal failure of the analysis: {type(exc).__name__}: {exc}") from exc


#: RMS departure of the answer (and of every fit) at the fits' coarser MuJoCo step from the file's step, in units of
#: the larger of the noise and that model's own residual RMS, above which the fits are redone at the file's step
ANSWER_STEP_TOL = 0.2


class _StepDeparts(Exception):
    """A fit at the coarser MuJoCo step departed from the file's step (:class:`~phast_model.identify.mujoco_sim.
    StepCheck`) early in the analysis (the drives trial, whose friction the nominal model lacked)."""


def _at_file_step(problem: Problem, inputs: _Inputs, dep: float, k: int | None) -> tuple[Problem, _Inputs]:
    problem.log(f"a fit at {k} MuJoCo steps a sample departs from the file's step by {dep:.3g} RMS (noise units, or "
                "the residual's own RMS where larger): the fits at the file's step")
    return at_file_step(problem), replace(inputs, held=replace(inputs.held, engine_substeps=None))


def _checked_step(problem: Problem, inputs: _Inputs) -> tuple[Problem, _Inputs, Report]:
    """A model file's answer from fits at a coarser MuJoCo step (:func:`.written.coarse_substeps`), kept when
    every fit's final model and the answer itself follow the file's step within :data:`ANSWER_STEP_TOL` on the
    shooting windows (noise units, or the model's own residual RMS where model error leaves more;
    :class:`~phast_model.identify.mujoco_sim.StepCheck`); else the analysis again at the file's step (MuJoCo's
    frictionloss sticks with a time constant of a few ms: a step that held for the frictionless nominal model can
    depart with a fitted friction).  A departure of the drives trial, the first fit with friction, switches to the
    file's step at once (:class:`_StepDeparts`).  ``details.engine_step`` says which."""
    k, s = problem.shooting.engine_substeps, problem.shooting
    dep, when = 0.0, None
    try:
        report = _second_look(problem, inputs, _explain(problem, inputs))
        if k is not None:
            answer = StepProbe(in_mujoco(report.augmented_system()), s.windows, s.X0, s.substeps, problem.sigma,
                               problem.x_scale)
            dep = max(answer.departure(k, relative=True), problem.step_check.worst)
            when = "the answer" if not dep <= ANSWER_STEP_TOL else None
    except _StepDeparts:
        dep, when = problem.step_check.worst, "the drives trial"
    if when is not None:
        problem, inputs = _at_file_step(problem, inputs, dep, k)
        report = _second_look(problem, inputs, _explain(problem, inputs))
    info = {"fit_steps_per_sample": k, "departure_rms": dep, "redone_at_file_step": when is not None,
            "departed": when,
            "note": "MuJoCo steps a sample in the fits (None: the file's own step) and the largest RMS departure of a "
                    "fit's final model or the answer from the file's step on the shooting windows, in units of the "
                    "larger of the noise and that model's own residual RMS; the held-out rollouts and calibrated.xml "
                    "are at the file's step"}
    return problem, inputs, replace(report, diagnostics={**report.diagnostics, "engine_step": info})


def held_out_window(problem: Problem, hold: Recordings) -> float | None:
    """The held-out open-loop window [s]: the user's; else, for a driven robot's model file, :data:`LONG_LOOK` shooting
    windows (a robot's recordings are usually closed loop: replayed open loop for their whole length, every model
    drifts away and the score measures the missing controller, not the model); else None (whole trajectories)."""
    if problem.opts.rollout_window is not None or not any(problem.has_u) or not is_model_file_system(problem.sys0):
        return problem.opts.rollout_window
    samples = LONG_LOOK * problem.shoot_window
    return (samples - 1) * hold.dt if samples < hold.T else None


def held_out_scores(sim: str | type[System] | Simulator, recordings: str | Path | Mapping[str, object] | Recordings,
                    models: Mapping[str, System], *, sim_kwargs: Mapping[str, object] | None = None,
                    holdout_trajectories: Sequence[int] | None = None, holdout_fraction: float = 0.3,
                    rollout_window: float | None = None) -> dict[str, dict[str, float]]:
    """The held-out one-step MSE and rollout RMSE of the nominal simulator and ``models`` exactly as :func:`analyze`
    scores them (the same split, decimation, noise and windows), without the analysis: for scoring another tool's
    fitted models (e.g. ``mujoco.sysid``'s) on the same footing."""
    opts = _options(None, {"rollout_window": rollout_window})
    holdout = check_holdout_indices(holdout_trajectories)
    simulator, sys0 = _simulator(sim, sim_kwargs)
    rec, _ = _decimate(_recordings(recordings, sys0, simulator.name), opts)
    train, hold, evaluated_on = split(rec, holdout_fraction, holdout)
    problem = with_coarse_step(prepare(simulator, sys0, train, opts, Progress(False)))
    held = replace(held_out(hold, evaluated_on, problem.sigma, problem.x_scale, problem.shoot_window,
                            problem.smoothing_window, held_out_window(problem, hold)),
                   engine_substeps=problem.shooting.engine_substeps)
    metrics, _ = held.evaluate({"nominal": sys0, **models})
    return metrics


#: shooting windows of the second look, as a multiple of the first (capped at the recordings' length)
LONG_LOOK = 4
#: a fit within the noise: chi^2/dof at most this
AT_NOISE_CHI2 = 1.5
#: windows a model cannot follow open loop (e.g. a closed-loop recording replayed on an unstable arm): chi^2/dof above
CANNOT_FOLLOW_CHI2 = 100.0
#: the second look is taken when the calibrated model's held-out rollout RMSE exceeds this multiple of the noise
SECOND_LOOK_RATIO = 3.0


def _second_look(problem: Problem, inputs: _Inputs, report: Report) -> Report:
    """When the half-period shooting windows name no term, look again with windows :data:`LONG_LOOK` times longer.

    A slow effect (a small viscous damping under a large noise) can stay below the threshold in short windows and
    still decide an open-loop rollout of the whole recording: a pendulum's viscous 0.01 under 0.02 rad of noise gave
    a chi^2 gain of 18.5 (< 25) in 1.1-s windows, while the true model predicted the held-out recordings 37x better
    than the calibrated one.  The longer look's answer replaces the first only when it names a term that passed the
    same held-out confirmation; a window length the user gave is kept.  It is only taken when the held-out
    recordings say the calibrated model leaves something (rollout RMSE above :data:`SECOND_LOOK_RATIO` x the noise,
    in the same units): a simulator that already predicts them at the noise level has no slow effect to find.  And it
    starts from the first pass's answer: when that answer fits the longer windows within the noise there is nothing
    left to find, and when it cannot follow them open loop (a closed-loop recording replayed on an arm that drifts
    away) a longer window measures the drift, not missing physics; in both cases the first answer stands."""
    longer = min(LONG_LOOK * problem.shoot_window, inputs.train.T)
    noise = float(np.sqrt(np.mean((problem.sigma_raw / inputs.held.scale) ** 2)))
    done = (report.terms or problem.opts.shoot_window or longer < 2 * problem.shoot_window
            or report.diagnostics.get("explained_share", 1.0) < MIN_DESCRIBED
            or report.fit["calibrated"]["rollout_rmse"] <= SECOND_LOOK_RATIO * noise)
    if done:
        return report
    long_problem = prepare(inputs.simulator, problem.sys0, inputs.train, problem.opts.with_(shoot_window=longer),
                           problem.log)
    if problem.shooting.engine_substeps is not None:  # the same engine step, its fits checked with the first pass's
        long_problem = replace(with_coarse_step(long_problem), step_check=problem.step_check)
    followed = _followed_on(long_problem, inputs.simulator.build(**report.diagnostics["calibrated_kwargs"]))
    look: dict[str, Any] = {"shoot_window_samples": longer, "calibrated_chi2_per_dof": followed}
    if not AT_NOISE_CHI2 < followed <= CANNOT_FOLLOW_CHI2:
        problem.log(f"no term in {problem.shoot_window}-sample shooting windows; no second look: the calibrated model "
                    f"{'fits' if followed <= AT_NOISE_CHI2 else 'cannot follow'} {longer}-sample windows "
                    f"(chi2/dof {followed:.3g})")
        return replace(report, diagnostics={**report.diagnostics, "second_look": {**look, "taken": False}})
    problem.log(f"no term in {problem.shoot_window}-sample shooting windows: a second look with {longer}-sample "
                f"windows (the calibrated model leaves chi2/dof {followed:.3g} there)")
    second = _explain(long_problem, inputs)
    look.update({"taken": True, "found": [m.label for m in second.terms], "adopted": bool(second.terms)})
    chosen = second if second.terms else report
    return replace(chosen, diagnostics={**chosen.diagnostics, "second_look": look})


def _followed_on(problem: Problem, calibrated: System) -> float:
    """chi^2/dof of the first pass's answer (window states fitted, parameters as calibrated) on ``problem``'s
    windows."""
    fit = problem.shooter(problem.shooting.windows).fit_states(calibrated, problem.shooting.X0,
                                                               max_iter=problem.opts.max_iter)
    return float(fit.chi2_red)


def check_free(free: Sequence[str], numeric: Mapping[str, float]) -> None:
    """``Options.free`` names numeric parameters of the simulator (a typo must not silently free nothing)."""
    bad = sorted(set(free) - set(numeric))
    if bad:
        raise ValueError(f"--free {bad}: not a numeric parameter of the simulator; its parameters are "
                         f"{sorted(numeric)}")


class InternalError(RuntimeError):
    """A failure of the tool itself on valid input (a bug: the CLI exits 1 and writes the traceback)."""


@dataclass(frozen=True)
class _Inputs:
    """The checked inputs of one analysis (besides the fitting problem)."""

    simulator: Simulator
    given: Recordings  # as loaded, before decimation
    dec: int
    train: Recordings
    hold: Recordings
    held: HeldOut
    compare: dict[str, System]
    explainers: tuple[Explainer, ...] = EXPLAINERS


@dataclass(frozen=True)
class Described:
    """How much of the recordings the simulator describes: the shooting share (:func:`.calibrate.explained_share`) and,
    when that is low, the share of the weak-form force a drive (rotor inertia + viscous + Coulomb per driven
    coordinate) accounts for (:func:`.friction.systematic.drive_share`; None when not computed); on a motor-driven
    model file, the chi^2/dof its drives alone reach on a sample of the windows (:func:`.friction.systematic.
    drives_trial`; None when not tried)."""

    share: float
    drive_share: float | None = None
    drives_chi2: float | None = None
    file_chi2: float | None = None  # the file's own chi^2/dof on the drives trial's sample

    @property
    def drives_follow(self) -> bool:
        """The drives alone follow the sampled windows to the noise."""
        return self.drives_chi2 is not None and self.drives_chi2 <= DRIVES_CHI2

    @property
    def drives_near(self) -> bool:
        """The drives alone nearly follow the sampled windows (:func:`drives_nearly_follow`): body values come after
        them."""
        return self.drives_follow or drives_nearly_follow(self.drives_chi2, self.file_chi2)

    @property
    def ok(self) -> bool:
        return (self.share >= MIN_DESCRIBED or self.drives_near
                or (self.drive_share is not None and self.drive_share >= MIN_DESCRIBED))

    @property
    def drives_first(self) -> bool:
        """Described up to its drives: the weak form answers with the drives (and, where they only nearly follow, the
        body values after them), no body value examined before."""
        return self.ok and (self.share < MIN_DESCRIBED or self.drives_near)

    def to_dict(self) -> dict[str, float]:
        return {"explained_share": self.share,
                **({} if self.drive_share is None else {"drive_share": self.drive_share}),
                **({} if self.drives_chi2 is None else {"drives_alone_chi2_per_dof": self.drives_chi2})}


def _described(problem: Problem, share: float, drives: float | None = None,
               drives_chi2: float | None = None, file_chi2: float | None = None) -> Described:
    """A simulator whose windows its model cannot follow may still describe the recordings up to its drives (a CAD
    model of a motor-driven arm without rotor inertia and gear friction): the weak form checks that before the
    recordings are called undescribed (``drives``: that share, when already computed); ``drives_chi2``: the drives
    trial's chi^2/dof, when tried."""
    if share >= MIN_DESCRIBED:
        return Described(share, None, drives_chi2, file_chi2)
    if drives is None:
        drives = drive_share(problem)
    problem.log(f"the nominal model follows the windows no better than a line (share {share:.2f}); rotor inertia and "
                f"friction per driven joint account for {drives:.0%} of the force it leaves (weak form)")
    return Described(share, drives, drives_chi2, file_chi2)


def _screen(problem: Problem) -> tuple[ParameterScreen, Described]:
    """The parameter screen and how much the simulator describes.  A motor-driven model file is first fitted on a
    sample of the windows, as MuJoCo simulates it (:func:`.calibrate.nominal_sample`), and its drives are tried
    before any body value: when a rotor inertia per driven joint and friction per joint follow the sample to the noise
    (:func:`.friction.systematic.drives_trial`), or the model follows the windows no better than a line and the drives
    account for more of the force it leaves than a change of its own parameters does (weak form), it goes to its
    drives without a screen of every window: with the file's body values in the first case, and in the second with
    those body values fitted after the drives that cannot stand in for them (:func:`.friction.weakid.beyond_drives`)."""
    drives, chi2 = None, None
    if any(problem.has_u) and is_model_file_system(problem.sys0):
        shooter, fit = nominal_sample(problem, in_mujoco(problem.nominal_family.build(np.zeros(0))))
        share = explained_share(shooter, fit)
        trial = drives_trial(problem, shooter, fit.X)
        if problem.shooting.engine_substeps is not None and not problem.step_check.worst <= ANSWER_STEP_TOL:
            raise _StepDeparts
        chi2 = math.inf if trial is None else float(trial.fit.chi2_red)
        problem.log(f"the drives alone (rotor inertia per driven joint, friction per joint) follow {len(fit.X)} of the "
                    f"windows to chi2/dof {chi2:.3g} (the file's model: {fit.chi2_red:.3g})")
        starts = () if trial is None else trial.terms()
        if trial is not None and chi2 <= DRIVES_CHI2:
            return drives_screen(problem, (shooter, fit, 0), starts), _described(problem, share, None, chi2)
        if trial is not None and drives_nearly_follow(chi2, fit.chi2_red):
            problem.log(f"the drives nearly follow the sample (chi2/dof {fit.chi2_red:.3g} -> {chi2:.3g}): drives "
                        "first, then the body values they cannot stand in for")
            return (drives_screen(problem, (shooter, fit, 0), starts, bodies_after=True),
                    _described(problem, share, None, chi2, fit.chi2_red))
        if share < MIN_DESCRIBED:
            n_rec = problem.train.n_traj
            problem.log(f"weak form on {n_rec} recordings: how much of the force rotor inertia and friction per driven "
                        "joint account for")
            drives = drive_share(problem)
            problem.log(f"weak form on {n_rec} recordings: how much of it a change of the file's own parameters "
                        "accounts for")
            params = parameter_share(problem)
            problem.log(f"on {len(fit.X)} of the {len(problem.shooting.windows.traj)} windows the model follows no "
                        f"better than a line (share {share:.3g}); its own parameters account for {params:.0%} of "
                        "the force it leaves (weak form)")
            if drives >= MIN_DESCRIBED and drives > params:
                screen = drives_screen(problem, (shooter, fit, 0), starts, far=chi2 > FAR, bodies_after=True)
                return screen, _described(problem, share, drives, chi2)
    nominal = fit_nominal(problem)
    share = explained_share(nominal[0], nominal[1])
    screen = screen_parameters(problem, nominal)
    return screen, _described(problem, max(share, explained_share(screen.shooter, screen.fit_full)), drives, chi2)


def _context(problem: Problem, inputs: _Inputs) -> tuple[Context, Described]:
    """The shooting selection, the calibration fitted with its terms, and how much of the recordings the simulator
    describes (not enough: no parameter change, no terms, no model-error regime).  A simulator described only up to its
    drives goes to the model-error regime directly and the weak form answers with the drives (rotor inertia and a
    friction law per joint; body values only where they cannot stand in for a drive): no shooting selection or
    calibration on windows its model cannot follow, and no body parameter bent to absorb a drive."""
    screen, described = _screen(problem)
    if not described.ok:
        problem = replace(problem, opts=replace(problem.opts, max_terms=0, systematic_chi2=math.inf))
        screen = replace(screen, identifiability=replace(screen.identifiability, basis=(), independence=()))
    elif described.drives_first:  # described up to its drives: the drives first, by the weak form alone
        problem = replace(problem, opts=replace(problem.opts, max_terms=0, systematic_chi2=0.0))
        screen = replace(screen, candidates=[],
                         identifiability=replace(screen.identifiability, basis=(), independence=()))
    # no term can be selected with max_terms 0: their shooting columns (the alternatives of a selected one) are spared
    terms = candidates(problem, problem.nominal_family.build(np.zeros(0))) if problem.opts.max_terms else []
    sel = select(problem, screen, [*screen.candidates, *terms])
    cal = calibration(problem, screen, sel.params, sel.fit, len(sel.terms))
    nominal = problem.nominal_family.build(np.zeros(0))
    # no parameter changed: the calibrated model is the nominal one (the held-out table then scores it once)
    models = {"nominal": nominal, "calibrated": cal.system if cal.fit.g.size else nominal}
    return Context(problem, cal, sel, inputs.held, models, inputs.compare), described


def _scored(ctx: Context, explained: Explained, undescribed: bool
            ) -> tuple[dict[str, System], dict[str, ParamRow], tuple[FitTable, dict[str, np.ndarray]]]:
    """The models of report.fit, the calibrated rows and the held-out table of the adopted answer (computed here unless
    a challenge already did); a simulator that does not describe the recordings keeps its nominal values."""
    models, calibrated = {**ctx.models, "augmented": explained.answer.system}, explained.answer.calibrated
    if undescribed:
        calibrated = {k: ParamRow.held(v.nominal, "not calibrated: the simulator does not describe these recordings")
                      for k, v in calibrated.items()}
        models["calibrated"] = models["augmented"] = models["nominal"]
    if explained.table is not None and not undescribed:
        return models, calibrated, explained.table
    table = ctx.held.fit_table({**models, **ctx.compare})
    ctx.problem.log(f"held-out: {table[0].to_dict()}")
    return models, calibrated, table


def _explain(problem: Problem, inputs: _Inputs) -> Report:
    """The explainers' answer (:func:`.explainers.explain_in_turn`), the held-out fit, the residual map, the report."""
    ctx, described = _context(problem, inputs)
    problem, train, hold, held = ctx.problem, inputs.train, inputs.hold, inputs.held
    explained = explain_in_turn(inputs.explainers, ctx)
    answer = explained.answer
    models, calibrated, (fitres, rollouts) = _scored(ctx, explained, not described.ok)
    missing, unconfirmed = _confirmed(list(answer.missing), fitres)
    scale = input_scale(missing, problem.has_u)
    if scale is not None:  # a unit mismatch of the input, not a weak motor on every joint
        unconfirmed = [*unconfirmed, *(m for m in missing if m.term == ACTUATOR_GAIN.name)]
        missing = [m for m in missing if m.term != ACTUATOR_GAIN.name]
    if train.u is None and any(VOCABULARY[m.term].component == "dissipation" for m in missing):  # a check, no fitting
        fitres = replace(fitres, energy_check={
            "model": "augmented", "training": energy_check(models["augmented"], train, problem.smoothing_window),
            "held_out": energy_check(models["augmented"], hold, min(problem.smoothing_window, odd(hold.T // 2 - 1)))})
    located, resid_map = locate(models["calibrated"], train.resampled(), problem.smoothing_window, problem.eps)
    if not missing and ctx.cal.fit.chi2_red < AT_NOISE_CHI2:
        located = []
    summary = summary_text(inputs.simulator.name, calibrated, missing, located, fitres, ctx.cal.fit.chi2_red,
                           answer.fit.chi2_red, problem.sigma_raw, _verdicts(described, unconfirmed, fitres, scale))
    if not described.ok:
        located = []
    return Report(
        simulator={"env_id": inputs.simulator.name, "kwargs": dict(inputs.simulator.kwargs)}, calibrated=calibrated,
        data=_data(inputs.given, inputs.dec, problem.sigma_raw),
        located=located, terms=missing, unconfirmed=unconfirmed, fit=fitres.to_dict(), summary=summary,
        diagnostics={**_details(ctx, explained, models["augmented"]), **described.to_dict()},
        plot_data={"hold": held.rec, "rollouts": rollouts, "resid_map": resid_map, "train": train,
                   "augmented_system": models["augmented"], "calibrated_system": models["calibrated"],
                   "nominal_system": models["nominal"], "friction_curve": explained.curve,
                   "friction_laws": explained.laws},
    )
