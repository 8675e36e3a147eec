"""The friction stage's weak-form answer (the systematic regime): when model error, not noise, dominates the shooting
residual.

With chi^2/dof >> 1 (a real encoder's noise is tiny next to any model error) the
shooting chi^2 gains and |t| values measure misfit, not evidence, and a law
chosen by them (or by how well a model follows the training recordings open
loop, which large swings' phase drift dominates) need not predict anything.
So the answer is built from time-resolved, local evidence instead, every choice
made by prediction on recordings not used for the fit:

* the weak-form momentum balance (one filter on both sides, :mod:`phast_model.identify.weakform`)
  under the simulator at the user's values (a shooting calibration made before
  any friction term may have absorbed friction);
* which parameters to calibrate (:func:`.weakid.check_parameters`): those whose
  fit predicts the left-out recordings' weak-form force better;
* parameters, armature (where u drives) and a provisional friction law in one
  least squares (:func:`.weakid.identify`);
* a non-parametric friction curve (total dissipative force by speed band, with
  block-bootstrap intervals) from the training recordings;
* per coordinate, the candidate laws (up to 3 dissipative vocabulary terms,
  coefficients sign free) fitted on all training recordings but one and scored
  by how well they predict the left-out recording's friction curve; passivity
  is required of the total force at every observed speed, every coefficient's
  95% interval must exclude zero and the law must lie inside the training
  curve's intervals; the fewest parameters not significantly worse than the
  best win;
* the chosen law refitted jointly with the parameters and armature;
* on a MuJoCo model file, that answer refitted on the shooting windows as MuJoCo simulates it
  (:mod:`.engine_refit`): the coefficients mean what the written file means, a rotor inertia is refitted on every
  driven joint, and a term whose interval then reaches zero is dropped;
* a delay the shooting selection chose (``input_delay``, ``sensor_delay``: no force the weak form can fit) competes
  with that law by held-out prediction (:func:`with_shooting_delays`): the law with the delays added is adopted only
  when it predicts the held-out recordings better than the law alone.

:class:`WeakFormExplainer` is this regime as an :class:`~..explainers.Explainer`: its answer challenges the shooting
answer and is adopted only when it predicts the held-out recordings better (:func:`..explainers.explain_in_turn`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from phast_gym.systems.base import ParameterError, System
from phast_gym.systems.mjcf import is_body_value

from ...identify.frictioncurve import FrictionCurve, friction_curve
from ...identify.shooting import Heartbeat, Shooter, ShootFit
from ...identify.simulators import known_params
from ..calibrate import Calibration
from ..evaluate import HeldOut
from ..explainers import Answer, Context, Declined
from ..fitting.problem import Problem
from ..rows import Alternative, ParamRow, TermRow, param_value
from ..vocabulary.candidates import Candidate
from ..vocabulary.registry import ARMATURE, COULOMB, VISCOUS, law_terms
from ..vocabulary.terms import VOCABULARY, AugmentedSystem, Term
from ..written import in_mujoco, is_model_file_system
from .engine_refit import EngineRefit, engine_refit
from .laws import FrictionLaw, spec_of
from .lawselect import LawSelection, select_friction
from .passivity import check_against_curve, is_passive
from .weakid import (
    WeakFit,
    WeakModel,
    beyond_drives,
    check_parameters,
    explained_force,
    identify,
    parameter_force,
)


@dataclass
class SystematicContext:
    """What :func:`systematic` reads (it changes none of it)."""

    problem: Problem
    cal: Calibration
    chosen: list[Candidate]  # the shooting selection (reported, not adopted)
    chi2_aug: float  # chi^2/dof of the shooting-augmented model
    calibrated: dict[str, ParamRow]  # rows of the shooting answer (parameters the weak form does not fit)
    params: list[str]  # the parameters the weak form may calibrate (a full-rank set spanning the identifiable ones)


@dataclass(frozen=True)
class SystematicResult:
    """The answer of the model-error regime: :meth:`to_dict` is details.friction of the report; ``evidence`` (what the
    weak form found, as report objects) and the models and rows are set only when the regime applies."""

    reason: str
    evidence: dict[str, Any] = field(default_factory=dict)
    system: System | None = None
    fit: ShootFit | None = None
    calibrated: dict[str, ParamRow] = field(default_factory=dict)
    missing: tuple[TermRow, ...] = ()
    curve: FrictionCurve | None = None
    laws: dict[str, FrictionLaw] = field(default_factory=dict)  # for the friction-curve plot

    @property
    def replaces(self) -> bool:
        """The regime applied: its answer challenges the shooting one."""
        return self.system is not None

    @property
    def intervals(self) -> str:
        """How the answer's 95% intervals were computed (the weak-form least squares of its law)."""
        return "from the weak-form least squares: " + "; ".join(sorted({law.interval for law in self.laws.values()}))

    def to_dict(self) -> dict[str, Any]:
        """report.details.friction."""
        return {"used": self.replaces, "reason": self.reason, **self.evidence}


def _law_rows(law: FrictionLaw, sels: list[LawSelection], passive: dict[str, Any],
              own: dict[int, float], refitted: bool = False) -> list[TermRow]:
    """report.missing_physics rows of the chosen law: coefficient, 95% interval, the evidence, near alternatives
    (``refitted``: the coefficients and the terms kept come from the refit in MuJoCo)."""
    rows = []
    for t in law.terms:
        sel = sels[t.coordinate]
        term = Term(t.term, t.coordinate, t.coefficient, t.velocity)
        near = [s.law for s in sel.scores if s.law != sel.chosen_name and s.not_worse]
        note = ""
        if t.coefficient < 0:
            total = own.get(t.coordinate, 0.0) + t.coefficient if t.term == VISCOUS.name else None
            note = ("negative coefficient: the *total* friction force stays passive at every observed speed "
                    f"(min {passive['per_coordinate'][t.coordinate]['min_force']:.3g} >= 0)"
                    + (f"; total viscous coefficient with the model's own damping {total:.4g}" if total is not None
                       else ""))
        alternatives = tuple(Alternative(law=n,
                                         note="as good at predicting left-out friction curves") for n in near[:3])
        rows.append(TermRow(t.term, t.coordinate, term.component, t.coefficient, (t.ci95[0], t.ci95[1]),
                            term.expression(),
                            None, alternatives, t.velocity if term.kind.has_velocity else None,
                            f"weak-form force balance; law chosen by {sel.folds}, score: left-out friction curve; "
                            + (REFITTED if refitted else "") + f"|t| = {abs(t.t):.3g}" + (f"; {note}" if note else "")))
    return rows


def _own_viscous(system: System, rec_q: np.ndarray) -> dict[int, float]:
    """The model's own damping D_ii at the recorded states (mean), per coordinate."""
    base = system.base if isinstance(system, AugmentedSystem) else system
    d = base.damping(tuple(rec_q[:, i] for i in range(rec_q.shape[1])))
    return {i: float(np.mean(np.asarray(d[i], dtype=float))) for i in range(rec_q.shape[1])}


@dataclass(frozen=True)
class _EngineStates:
    """The refit in MuJoCo where it stands (None: it does not), and the window states its closest model was fitted
    with (None: no refit ran), from which the answer's own state fit starts."""

    refit: EngineRefit | None
    X: np.ndarray | None


def _in_engine(ctx: SystematicContext, model: WeakModel, final: WeakFit,
               more_params: Sequence[str] = ()) -> _EngineStates:
    """A model file's weak-form answer refitted on the shooting windows as MuJoCo simulates it (:mod:`.engine_refit`),
    with both of MuJoCo's friction kinds (``damping``, ``frictionloss``) on every joint as candidates: the weak form's
    law choice per joint starts the refit, and the windows, whose backward elimination keeps only what they back,
    decide it; no refit for another simulator, or when the refit follows the windows worse than its start or leaves
    model error."""
    problem = ctx.problem
    if not is_model_file_system(problem.sys0):
        return _EngineStates(None, None)
    if ctx.cal.screen.far:
        problem.log("no refit in MuJoCo: the drives alone were far from following the windows (model error)")
        return _EngineStates(None, None)
    refit = engine_refit(ctx.cal.shooter, ctx.cal.fit.X, model, final, model.armature, problem.opts.max_iter,
                         ctx.cal.screen.starts, more_params, _law_on(problem))
    if refit is None:
        return _EngineStates(None, None)
    chi2 = f"chi2/dof {refit.cost_before / refit.fit.dof:.3g} -> {refit.fit.chi2_red:.3g}"
    if not refit.at_noise:
        problem.log(f"refitted in MuJoCo on the windows: {chi2}, model error left: the weak form's answer stands")
        return _EngineStates(None, refit.fit.X)
    problem.log(f"refitted in MuJoCo on the windows: {chi2}"
                + (f"; dropped {refit.dropped} (not backed by the data)" if refit.dropped else ""))
    return _EngineStates(refit, refit.fit.X)


def _refitted(ctx: SystematicContext, model: WeakModel, final: WeakFit) -> tuple[WeakFit, _EngineStates]:
    """The weak-form answer refitted in MuJoCo (:func:`_in_engine`), with every body value where they come after the
    drives (under the file's prior, :func:`.engine_refit.body_prior`: the windows pin more of them than the weak
    form's balance can tell from a drive, and those left at the file's bend the drives).  Where the drives alone
    follow the windows the file's body values stay: refitted there too, the exact ones of a drives-only file drifted
    along what the short windows cannot tell (held-out 0.0022 -> 0.019 rad on the 7-joint arm)."""
    bodies = [k for k in body_values(ctx.problem) if k not in model.params] if ctx.cal.screen.bodies_after else []
    engine = _in_engine(ctx, model, final, bodies)
    return (final, engine) if engine.refit is None else (engine.refit.applied(final), engine)


def _law_on(problem: Problem) -> list[tuple[str, int]]:
    """Both of MuJoCo's friction kinds on every joint (of the vocabulary's): the refit's friction candidates."""
    kinds = [k for k in PROVISIONAL_LAW if k in law_terms(problem.opts.terms)]
    return [(k, i) for i in range(problem.n) for k in kinds]


def _weak_model(ctx: SystematicContext, window: int) -> WeakModel:
    """Start at the user's nominal values (a shooting calibration made before any friction term may have absorbed
    friction); armature estimated where u drives.  The shooting selection's terms are not carried over: in this regime
    their chi^2 gains measure misfit, and its terms bend the parameters (docs/mismatch.md, design notes)."""
    problem = ctx.problem
    vocab = problem.opts.terms or tuple(VOCABULARY)
    arm = [i for i in range(problem.n) if problem.has_u[i]] if ARMATURE.name in vocab else []
    return WeakModel(problem.sim, {}, list(ctx.params), [], arm, problem.eps, problem.nominal_family.deadzone_width,
                     window)


def _calibrated_rows(ctx: SystematicContext, fit: WeakFit, held: list[str],
                     no_signal: list[str], drive_like: Sequence[str] = ()) -> dict[str, ParamRow]:
    rows = dict(ctx.calibrated)
    for k in drive_like:
        rows[k] = ParamRow.held(param_value(ctx.problem.sys0.params[k]),
                                "held at the file's value: the drives come first, and on these recordings it acts "
                                "like a rotor inertia, a friction or other body values (weak form)")
    nominal = {k: param_value(ctx.problem.sys0.params[k]) for k in [*held, *no_signal]}
    for k in held:
        rows[k] = ParamRow.held(nominal[k], "held at nominal: fitting it does not predict left-out recordings better "
                                            "(details.friction.parameter_check)")
    for k, row in fit.params.items():
        rows[k] = replace(row, note="weak-form fit jointly with the friction law (and the armature where u drives)"
                          if row.data_share is None else "refitted in MuJoCo under the file's prior: "
                          f"{row.data_share:.0%} of what is known of it from the recordings")
    for k in no_signal:  # a row the shooting answer or the fit above made keeps its other fields
        note = "held at nominal: the friction law (added to the model's own dissipation) covers it"
        rows[k] = (replace(rows[k], fitted=nominal[k], ci95=None, note=note) if k in rows
                   else ParamRow.held(nominal[k], note))
    return rows


#: the evidence of a row whose value the refit in MuJoCo gave (:mod:`.engine_refit`)
REFITTED = ("refitted on the shooting windows as MuJoCo simulates the written model, with the drives trial's terms, "
            "kept by backward elimination; ")


def _armature_rows(fit: WeakFit, refitted: bool = False) -> list[TermRow]:
    return [TermRow(ARMATURE.name, t.coordinate, ARMATURE.component, t.coefficient, (t.ci95[0], t.ci95[1]),
                    t.to_term().expression(), None, (),
                    evidence="weak-form fit jointly with the parameters and the friction law; "
                             + (REFITTED if refitted else "") + f"|t| = {abs(t.t):.3g}")
            for t in fit.armature if t.coefficient > 0 and t.excludes_zero]


#: a generous law for the first joint fit, so that parameters cannot absorb friction while the law is not yet chosen
PROVISIONAL_LAW = (VISCOUS.name, COULOMB.name)


def drive_share(problem: Problem) -> float:
    """How much of the force the simulator leaves unexplained in the weak-form momentum balance a rotor inertia and a
    viscous + Coulomb friction on each driven coordinate account for: 1 - rss / |f~ - own|^2 of one linear least
    squares (the simulator at the user's values, nothing else fitted).  Near 1 for a motor-driven model whose file
    leaves out its drives (a CAD model without gears); near 0 when the force it leaves is of another kind."""
    driven = [i for i in range(problem.n) if problem.has_u[i]]
    if not driven:
        return 0.0
    window = problem.smoothing_window
    model = WeakModel(problem.sim, {}, [], [], driven, problem.eps, problem.nominal_family.deadzone_width, window)
    return explained_force(model, problem.train.resampled(), [(nm, i) for i in driven for nm in PROVISIONAL_LAW])


#: iterations of a drives trial's refit: from the weak form's values it reaches the noise in fewer, or not at all
TRIAL_ITER = 10


def drives_trial(problem: Problem, shooter: Shooter, X: np.ndarray) -> EngineRefit | None:
    """The drives alone (a rotor inertia on each driven joint, viscous + Coulomb friction on every joint, the file's
    body values kept) from the weak form, refitted on ``shooter``'s windows as MuJoCo simulates them
    (:mod:`.engine_refit`): how well a model file's missing drives explain the recordings, before any body value is
    examined.  None without a driven joint, or when the refit follows the windows worse than the weak form's values."""
    driven = [i for i in range(problem.n) if problem.has_u[i]]
    if not driven:
        return None
    model = WeakModel(problem.sim, {}, [], [], driven, problem.eps, problem.nominal_family.deadzone_width,
                      problem.smoothing_window)
    first = identify(model, problem.train.resampled(), [(nm, i) for i in range(problem.n) for nm in PROVISIONAL_LAW])
    return engine_refit(shooter, X, model, first, driven, min(TRIAL_ITER, problem.opts.max_iter))


def body_values(problem: Problem) -> list[str]:
    """A model file's non-zero body values (masses, centres of mass, principal moments) but the known constants: what
    the weak form may fit after the drives."""
    known = known_params(problem.sys0) - set(problem.opts.free)
    return [k for k, v in problem.sim.numeric_params(problem.sys0).items()
            if v != 0 and k not in known and is_body_value(k)]


def parameter_share(problem: Problem) -> float:
    """The share of the same balance (:func:`drive_share`) that a change of the simulator's own parameters accounts
    for, linearized at the user's values: every non-zero numeric one but the known constants (body values, gears).
    A model whose parameters explain the recordings at least as well as drives do is calibrated, not given drives."""
    known = known_params(problem.sys0) - set(problem.opts.free)
    params = [k for k, v in problem.sim.numeric_params(problem.sys0).items() if v != 0 and k not in known]
    model = WeakModel(problem.sim, {}, params, [], [], problem.eps, problem.nominal_family.deadzone_width,
                      problem.smoothing_window)
    return parameter_force(model, problem.train.resampled(), Heartbeat(problem.log))


def systematic(ctx: SystematicContext) -> SystematicResult:
    """Parameters (those that predict left-out recordings better when fitted), armature and the friction law from the
    weak form, as the module docstring says."""
    problem = ctx.problem
    train = problem.train.resampled()  # the filters need uniform samples; shooting keeps the recorded times
    window = problem.smoothing_window
    problem.log(f"model error dominates (chi2/dof {ctx.chi2_aug:.3g}): weak-form identification, window {window} "
                "samples")
    model = _weak_model(ctx, window)
    provisional = [(nm, i) for i in range(problem.n) for nm in PROVISIONAL_LAW]
    drive_like: list[str] = []
    beyond: list[str] = []
    if ctx.cal.screen.bodies_after:
        beyond = beyond_drives(model, train, provisional)
        drive_like = [k for k in model.params if k not in beyond]
        model = replace(model, params=beyond)
        problem.log(f"after the drives, {len(beyond)} of {len(ctx.params)} body values can be told from them and "
                    f"from each other (weak form): {beyond}")
    pcheck = check_parameters(model, train, provisional, Heartbeat(problem.log))
    model = replace(model, params=pcheck.kept)
    problem.log(f"parameters that predict left-out recordings better when fitted: {pcheck.kept}")
    problem.log(f"weak-form fit of {len(model.params)} parameters, rotor inertia and the provisional friction law "
                f"({train.n_traj} recordings)")
    first = identify(model, train, provisional, heartbeat=Heartbeat(problem.log))
    problem.log(f"weak-form fit with the provisional law done; choosing each coordinate's friction law by left-out "
                f"prediction ({train.n_traj} recordings)")
    base = model.build(first.kwargs, first.armature_terms())
    law, sels = select_friction(base, train, Heartbeat(problem.log), window=window, eps=problem.eps,
                                terms=law_terms(problem.opts.terms))
    problem.log(f"friction law: {law.name}; parameters {first.kwargs}")
    specs = [spec_of(t.term, t.coordinate, t.velocity) for t in law.terms]
    final = identify(replace(model, kwargs=first.kwargs), train, specs)
    final, engine = _refitted(ctx, model, final)
    refit = engine.refit
    augmented = final.system(model)
    curve = friction_curve(model.build(final.kwargs, final.armature_terms()), train, window=window, eps=problem.eps)
    passive = is_passive(final.law, curve).to_dict()
    # its training chi^2 as held-out scores simulate it (a model file's: MuJoCo, whose frictionloss stays stable)
    # (from the states of the refit's closest model where one ran)
    fit = ctx.cal.shooter.fit_states(in_mujoco(augmented), ctx.cal.fit.X if engine.X is None else engine.X,
                                     max_iter=problem.opts.max_iter, in_basin=engine.X is not None)
    own = _own_viscous(augmented, problem.q_sample())
    missing = _law_rows(final.law, sels, passive, own, refit is not None) + _armature_rows(final, refit is not None)
    reason = (f"shooting-augmented chi^2/dof {ctx.chi2_aug:.3g} > {problem.opts.systematic_chi2}: the residual is "
              "model error, not noise, so parameters, armature and the dissipation law were identified from local "
              "evidence (weak form; the law chosen by left-out friction curves)")
    evidence = {"shooting_selection": [c.label for c in ctx.chosen],
                "shooting_selection_note": "chosen by chi^2 gains that measure misfit in this regime; not adopted",
                "window_samples": int(window),
                "law": final.law.to_dict(), "passivity": passive, "selection": [s.to_dict() for s in sels],
                ARMATURE.name: [{"coordinate": a.coordinate, "coefficient": a.coefficient, "ci95": list(a.ci95)}
                                for a in final.armature],
                "parameter_check": pcheck.to_dict(),
                "armature_absorbed_by_parameters": [int(k.split(":")[1]) for k in final.no_signal
                                                    if k.startswith("armature:")],
                "curve": curve.to_dict(), "law_vs_curve": check_against_curve(final.law, curve),
                "chi2_per_dof_augmented": fit.chi2_red,
                "engine_refit": None if refit is None else refit.to_dict()}
    held_params = [k for k in ctx.params if k not in {*pcheck.kept, *pcheck.no_signal, *drive_like}]
    rows = _calibrated_rows(ctx, final, held_params, pcheck.no_signal, drive_like)
    return SystematicResult(reason, evidence, augmented, fit, rows, tuple(missing), curve,
                            {f"chosen: {law.name}": final.law})


def with_shooting_delays(result: SystematicResult, shooting_rows: list[TermRow], held: HeldOut, shooter: Shooter,
                         max_iter: int) -> SystematicResult:
    """The model-error regime's answer with the delays of the shooting answer (``shooting_rows``) added, when that
    predicts the held-out recordings better than the friction law alone (rollout RMSE); the comparison is written to
    details.friction.delays_vs_law either way.  Unchanged when the regime did not apply or the shooting chose no
    delay."""
    delayed_rows = [r for r in shooting_rows if VOCABULARY[r.term].delay]
    law = result.system
    if not delayed_rows or not isinstance(law, AugmentedSystem) or result.fit is None:
        return result
    terms = [*law.terms, *(Term(r.term, r.coordinate, r.coefficient) for r in delayed_rows)]
    delayed = AugmentedSystem(law.base, terms, law.coulomb_eps_per_coordinate, law.deadzone_width)
    scores = held.evaluate({"law": law, "law_and_delays": delayed})[0]
    a, b = scores["law"]["rollout_rmse"], scores["law_and_delays"]["rollout_rmse"]
    note = {"delays": [r.label for r in delayed_rows], "held_out_rollout_rmse": {"law": a, "law_and_delays": b},
            "adopted": b < a}
    evidence = {**result.evidence, "delays_vs_law": note}
    if not b < a:
        return replace(result, evidence=evidence)
    fit = shooter.fit_states(delayed, result.fit.X, max_iter=max_iter)
    return replace(result, evidence=evidence, system=delayed, fit=fit, missing=(*result.missing, *delayed_rows))


#: details.method appended when the weak-form answer was computed
METHOD_SYSTEMATIC = ("; model error >> noise, so the dissipation law was chosen per coordinate from the weak-form "
                     "force balance (one filter on both sides): candidate laws fitted on all training recordings but "
                     "one, scored by how well they predict the left-out recording's friction curve, passive total "
                     "force at every observed speed, every 95% interval excluding zero, fewest parameters within one "
                     "paired standard error; the shooting selection's other terms held fixed")


class WeakFormExplainer:
    """Stage 2b as an explainer: when the shooting-augmented chi^2/dof exceeds ``Options.systematic_chi2`` (model
    error, not noise, dominates), the weak-form answer of :func:`systematic` with the standing answer's delays
    (:func:`with_shooting_delays`); otherwise :class:`~..explainers.Declined` with the reason (details.friction)."""

    def explain(self, ctx: Context) -> Answer | Declined:
        problem, cal, sel = ctx.problem, ctx.cal, ctx.selection
        if not sel.fit.chi2_red > problem.opts.systematic_chi2:
            reason = (f"shooting-augmented chi^2/dof {sel.fit.chi2_red:.3g} <= {problem.opts.systematic_chi2}: "
                      "the shooting selection stands")
            return Declined({"friction": SystematicResult(reason).to_dict()})
        calibrated, standing = (ctx.current.calibrated, list(ctx.current.missing)) if ctx.current else ({}, [])
        params = body_values(problem) if cal.screen.bodies_after else list(cal.screen.identifiability.basis)
        try:
            result = systematic(SystematicContext(problem, cal, sel.terms, sel.fit.chi2_red, calibrated, params))
        except ParameterError as exc:  # the weak form's least squares left the simulator's valid parameters
            problem.log(f"weak form: {exc}")
            reason = (f"shooting-augmented chi^2/dof {sel.fit.chi2_red:.3g} > {problem.opts.systematic_chi2}, but the "
                      f"weak-form identification reached parameters the simulator refuses ({exc}): the shooting "
                      "selection stands")
            return Declined({"friction": SystematicResult(reason).to_dict()})
        # a delay the standing answer chose competes with the friction law by held-out prediction
        result = with_shooting_delays(result, standing, ctx.held, cal.shooter, problem.opts.max_iter)
        assert result.system is not None and result.fit is not None
        return Answer("weak-form answer", result.system, result.fit, result.calibrated, result.missing,
                      METHOD_SYSTEMATIC,
                      result.intervals, "friction", result.to_dict(), result.curve, result.laws)
