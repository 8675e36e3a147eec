"""Friction-law selection by leave-one-out prediction.

*Leave-one-out*: each training recording (one recording: each contiguous time block) is left out of the fit in turn
and predicted; the held-out recordings of the split (:mod:`..evaluate`) are never used here, and the selection's
two-fold validation (:mod:`..selection.forward`) is a different check.

:func:`select_law`: candidate laws (subsets of up to 3 terms per coordinate), each fitted on all training recordings
but one and scored on the left-out one (default: by how well it predicts the left-out recording's friction curve;
rollout criteria are available), with a paired one-sided t-test parsimony rule over the folds.  Laws that are not
passive over the observed speeds, or with a coefficient not distinguishable from zero, are not chosen.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.stats import t as student_t

from phast_gym.systems import angle_diff
from phast_gym.systems.base import System

from ...identify.frictioncurve import FrictionCurve, friction_curve, speed_edges
from ...identify.recordings import Recordings
from ...identify.shooting import Heartbeat, estimate_noise, odd, smooth, time_scale
from ...identify.weakform import WeakForm, weak_form
from ..vocabulary.registry import law_terms
from ..vocabulary.terms import Term
from .laws import FrictionLaw, Spec, design, fit_law_specs, own_samples, own_terms, parse_terms, spec_of
from .passivity import check_against_curve, is_passive


def coordinate_laws(i: int, max_terms: int = 3, terms: Sequence[str] | None = None) -> list[list[Spec]]:
    """Every subset of up to ``max_terms`` of ``terms`` (default: every dissipative kind registered) on coordinate
    ``i`` (Stribeck v_s profiled), including none."""
    terms = law_terms() if terms is None else terms
    subsets = [()] + [c for k in range(1, max_terms + 1) for c in itertools.combinations(terms, k)]
    return [[spec_of(nm, i, None) for nm in sub] for sub in subsets]


def candidate_laws(n: int, max_terms: int = 3, terms: Sequence[str] | None = None) -> list[list[Spec]]:
    """Per coordinate, every subset of up to ``max_terms`` of ``terms`` (default: every dissipative kind registered;
    Stribeck v_s profiled), including none; for n > 1 the per-coordinate subsets are combined (the product grows fast:
    pass ``terms`` to narrow it)."""
    terms = law_terms() if terms is None else terms
    per = [[()]] + [list(c) for k in range(1, max_terms + 1) for c in itertools.combinations(terms, k)]
    out = []
    for combo in itertools.product(per, repeat=n):
        spec: list[Spec] = []
        for i, sub in enumerate(combo):
            spec += [spec_of(nm, i, None) for nm in sub if nm]
        out.append(spec)
    return out


def rollout_score(system: System, rec: Recordings, window: int | None, init_samples: int, smoothing: int,
                  sigma: np.ndarray | None = None, relative: bool = True) -> tuple[float, np.ndarray]:
    """Open-loop rollout error of ``system`` on ``rec`` cut into windows of ``window`` samples (None: whole recordings),
    initial state re-fitted on each window's first ``init_samples`` samples (:func:`..evaluate.evaluate_models`).
    ``relative``: each window's RMSE divided by that window's rms |q - mean| (so small swings count as much as large
    ones); returns (mean over windows, per-window values)."""
    from ..evaluate import evaluate_models

    recw = rec.windows(window) if window else rec
    sigma = estimate_noise(rec.q) if sigma is None else sigma
    sigma = np.maximum(sigma, 1e-6 * (rec.q.reshape(-1, rec.n).std(0) + 1e-12))
    smoothing = min(smoothing, odd(recw.T // 2 - 1))
    qs, vs = smooth(recw.q, recw.dt, smoothing)
    x_scale = np.concatenate([np.sqrt(np.mean(qs**2, axis=(0, 1))) + 1e-9,
                              np.sqrt(np.mean(vs**2, axis=(0, 1))) + 1e-12])
    _, rolls = evaluate_models({"m": system}, recw, sigma, x_scale, min(init_samples, recw.T), smoothing,
                               np.ones(rec.n))
    d = angle_diff(rolls["m"], recw.q, recw.angle_dims)
    d = np.where(np.isfinite(d), d, 1e3)
    per = np.sqrt(np.mean(d**2, axis=(1, 2)))
    if relative:
        amp = np.sqrt(np.mean((recw.q - recw.q.mean(1, keepdims=True)) ** 2, axis=(1, 2))) + 1e-12
        per = per / amp
    return float(np.mean(per)), per


def _curve_score(law: FrictionLaw, wf: WeakForm, edges: list[np.ndarray], min_count: int, ref: list[np.ndarray],
                 coords: Sequence[int] | None = None) -> float:
    """rms over speed bands of (law - curve) / ref on a left-out weak form: how well the law predicts the left-out
    recording's friction curve.  ``ref`` per coordinate and band: |curve| of all training recordings pooled (a
    denominator that is the same for every candidate and fold); bands with fewer than ``min_count`` samples skipped;
    every band weighs the same."""
    errs = []
    for i in range(wf.n) if coords is None else coords:
        s = np.sign(wf.vs[..., i])
        sp = np.abs(wf.vs[..., i])
        f_law = wf.filt(law.force(i, wf.q_raw[..., i], wf.v_raw[..., i])) + wf.own[..., i]
        for k, (a, b) in enumerate(zip(edges[i][:-1], edges[i][1:])):
            m = (sp >= a) & (sp < b)
            if m.sum() < min_count:
                continue
            cv = float(np.mean((wf.total[..., i] * s)[m]))
            lv = float(np.mean((f_law * s)[m]))
            errs.append((lv - cv) / ref[i][k])
    return float(np.sqrt(np.mean(np.square(errs)))) if errs else float("nan")


@dataclass
class FoldStats:
    """A candidate law's criterion scores over the folds (fitted without the fold, scored on it)."""

    scores: list[float]
    mean: float
    se: float
    weak_form_loro: float  # mean over folds of the left-out weak-form force RMSE
    diff_se: float = 0.0  # paired standard error of (fold scores - the best candidate's fold scores)


@dataclass(frozen=True)
class Eligibility:
    """What the law fitted on all training recordings must show to be chosen."""

    passive: bool
    every_ci_excludes_zero: bool
    curve_agreement: float = 1.0  # share of the training curve's speed bands whose 95% interval holds the law


@dataclass
class CandidateScore:
    """One candidate law: its fold scores, its eligibility and the fit on all training recordings."""

    law: str
    n_params: int
    folds: FoldStats
    eligibility: Eligibility
    not_worse: bool = False  # eligible and not significantly worse than the best (one-sided paired t-test, 5%)
    fitted: FrictionLaw | None = field(default=None, repr=False)  # fitted on all training recordings

    @property
    def fold_scores(self) -> list[float]:
        return self.folds.scores

    @property
    def mean(self) -> float:
        return self.folds.mean

    @property
    def se(self) -> float:
        return self.folds.se

    @property
    def passive(self) -> bool:
        return self.eligibility.passive

    @property
    def every_ci_excludes_zero(self) -> bool:
        return self.eligibility.every_ci_excludes_zero

    @property
    def curve_agreement(self) -> float:
        return self.eligibility.curve_agreement

    def to_dict(self) -> dict[str, Any]:
        f, e = self.folds, self.eligibility
        return {"law": self.law, "n_params": self.n_params, "fold_scores": list(f.scores), "mean": f.mean, "se": f.se,
                "passive": e.passive, "every_ci_excludes_zero": e.every_ci_excludes_zero,
                "weak_form_loro": f.weak_form_loro,
                "diff_se": f.diff_se, "curve_agreement": e.curve_agreement, "not_worse": self.not_worse,
                "fitted": self.fitted.to_dict() if self.fitted else None}


@dataclass
class LawSelection:
    """The friction law :func:`select_law` chose, how, and every candidate's score."""

    chosen: FrictionLaw
    chosen_name: str
    criterion: str
    scores: list[CandidateScore]  # sorted by mean score
    folds: str
    rule: str

    def to_dict(self) -> dict[str, Any]:
        return {"chosen": self.chosen.to_dict(), "criterion": self.criterion, "folds": self.folds, "rule": self.rule,
                "candidates": [s.to_dict() for s in self.scores]}


def _leave_one_out_folds(rec: Recordings, n_blocks: int) -> tuple[list[tuple[Recordings, Recordings]], str]:
    """(training, left-out) recordings of each leave-one-out fold, and the folds in words."""
    if rec.n_traj >= 2:
        out = [(rec.subset(np.array([j for j in range(rec.n_traj) if j != k])),
                rec.subset(slice(k, k + 1))) for k in range(rec.n_traj)]
        return out, f"leave-one-recording-out ({rec.n_traj} folds)"
    # one recording: contiguous time blocks, each left out in turn (fit on the rest, concatenated as separate
    # recordings)
    e = np.linspace(0, rec.T, n_blocks + 1).round().astype(int)
    out = []
    for k in range(n_blocks):
        parts = [rec.time_slice(e[j], e[j + 1]) for j in range(n_blocks) if j != k]
        length = min(p.T for p in parts)
        q = np.concatenate([p.q[:, :length] for p in parts])
        u = None if rec.u is None else np.concatenate([p.u[:, : length - 1] for p in parts if p.u is not None])
        out.append((Recordings(q, rec.dt, u, rec.angle_dims, rec.source, rec.meta), rec.time_slice(e[k], e[k + 1])))
    return out, f"one recording: {n_blocks} contiguous time blocks, each held out in turn"


@dataclass(frozen=True)
class RolloutCriterion:
    """The rollout criteria's knobs."""

    rollout_window: float | None = None  # [s] for "window_rollout" (default 3 periods)
    init_samples: int | None = None  # samples each rollout's initial state is fitted to
    relative: bool | None = None  # RMSE relative to each window's amplitude (default: for "window_rollout")


@dataclass(frozen=True)
class EligibilityRules:
    """What a law fitted on all training recordings must show to be chosen."""

    require_significant: bool = True
    min_t: float = 3.0
    min_share: float = 0.01  # rms force of a term / rms total friction force
    min_agreement: float = 0.75  # share of the training curve's bands whose interval holds the law


@dataclass(frozen=True)
class LawSelectionOptions:
    """Knobs of :func:`select_law` (criterion and eligibility rules).  :meth:`with_` takes the flat names of every
    group (``min_t=2``, ``rollout_window=1.0``, ...)."""

    criterion: str = "curve"  # "curve", "window_rollout", "rollout" or "weak_form"
    rollout: RolloutCriterion = RolloutCriterion()
    rules: EligibilityRules = EligibilityRules()
    n_time_blocks: int = 4  # folds when there is one recording
    max_terms: int = 3
    terms: tuple[str, ...] | None = None  # the dissipative terms laws are built from (None: every one registered)
    bands: str = "quantile"
    n_bands: int = 8
    progress: bool = False

    def with_(self, **flat: Any) -> LawSelectionOptions:
        """These options with the given fields (of this class or of its groups) changed."""
        groups: dict[str, Any] = {"rollout": self.rollout, "rules": self.rules}
        top: dict[str, Any] = {}
        sub: dict[str, dict[str, Any]] = {g: {} for g in groups}
        for key, value in flat.items():
            group = next((g for g, obj in groups.items() if key in obj.__dataclass_fields__), None)
            if group is not None:
                sub[group][key] = value
            elif key in self.__dataclass_fields__:
                top[key] = value
            else:
                raise TypeError(f"unknown law-selection option {key!r}")
        return replace(self, **top, **{g: replace(groups[g], **kw) for g, kw in sub.items() if kw})


@dataclass(frozen=True)
class _Folds:
    """The folds of a selection: (training weak form, left-out weak form, left-out recordings) each, and in words."""

    weak: list[tuple[WeakForm, WeakForm, Recordings]]
    text: str


@dataclass(frozen=True)
class _CurveReference:
    """The training friction curve, the speed-band edges per coordinate and the pooled |curve| per band (the common
    denominator of the curve score)."""

    curve: FrictionCurve
    edges: list[np.ndarray]
    ref: list[np.ndarray]


@dataclass(frozen=True)
class _RolloutSetup:
    window: int  # rollout window [samples]
    init_samples: int  # rollout initial-state samples
    sigma: np.ndarray


@dataclass
class _Caches:
    """Filtered basis columns already computed: per fold (training, left-out), and on all recordings."""

    folds: list[tuple[dict, dict]] = field(default_factory=list)
    all: dict = field(default_factory=dict)


@dataclass
class _Scoring:
    """What every candidate is scored against: the weak forms of all recordings and of each fold, the curve."""

    system: System
    rec: Recordings
    opts: LawSelectionOptions
    wf_all: WeakForm
    folds: _Folds
    reference: _CurveReference
    scored: list[int] | None  # coordinates the score looks at (None: all)
    own: list
    rollout: _RolloutSetup
    caches: _Caches


def _pooled_reference(wf: WeakForm, edges: list[np.ndarray]) -> list[np.ndarray]:
    """|curve| of all recordings per coordinate and band (floored at 5% of the largest band)."""
    ref = []
    for i in range(wf.n):
        sp, sign = np.abs(wf.vs[..., i]), np.sign(wf.vs[..., i])
        vals = [abs(float(np.mean((wf.total[..., i] * sign)[(sp >= a) & (sp < b)])))
                if np.any((sp >= a) & (sp < b)) else 0.0
                for a, b in zip(edges[i][:-1], edges[i][1:])]
        ref.append(np.maximum(np.asarray(vals), 0.05 * max(vals + [1e-300])))
    return ref


def _scoring(system: System, rec: Recordings, window: int | None, eps: float | None, block: int | None,
             coordinate: int | None, opts: LawSelectionOptions) -> _Scoring:
    wf_all = weak_form(system, rec, window, eps, block)
    window, eps = wf_all.window, wf_all.eps
    folds, fold_txt = _leave_one_out_folds(rec, opts.n_time_blocks)
    period = 2 * math.pi * time_scale(rec.q, rec.dt)
    rollout_window = int(round((opts.rollout.rollout_window or 3 * period) / rec.dt)) + 1
    init_samples = int(opts.rollout.init_samples or max(10, int(round(0.5 * period / rec.dt)) // 4))
    if rec.n_traj >= 2:  # leave one recording out: each fold's weak forms are slices of the whole one (the filters
        # run along each recording), not N recomputations of N - 1 recordings
        every = np.arange(rec.n_traj)
        fold_wf = [(wf_all.subset(every[every != k]), wf_all.subset(every[k: k + 1]), te)
                   for k, (_, te) in enumerate(folds)]
    else:
        fold_wf = [(weak_form(system, tr, window, eps, block), weak_form(system, te, window, eps, block), te)
                   for tr, te in folds]
    curve = friction_curve(system, rec, window, bands=opts.bands, n_bands=opts.n_bands, eps=eps, block=block)
    edges = [speed_edges(np.abs(wf_all.vs[..., i]).reshape(-1), opts.bands, opts.n_bands) for i in range(rec.n)]
    return _Scoring(system, rec, opts, wf_all, _Folds(fold_wf, fold_txt),
                    _CurveReference(curve, edges, _pooled_reference(wf_all, edges)),
                    None if coordinate is None else [coordinate], own_samples(system, wf_all),
                    _RolloutSetup(rollout_window, init_samples, estimate_noise(rec.q)),
                    _Caches([({}, {}) for _ in folds]))


def _fold_score(sc: _Scoring, specs: Sequence[Spec], k: int) -> tuple[float, float]:
    """(criterion score, left-out weak-form rms) of the law ``specs`` fitted without fold k."""
    wtr, wte, te = sc.folds.weak[k]
    ctr, cte = sc.caches.folds[k]
    opts, n = sc.opts, sc.rec.n
    law = fit_law_specs(wtr, specs, cache=ctr, own=sc.own, own_terms=own_terms(sc.system))
    fixed = [spec_of(t.term, t.coordinate, t.velocity) for t in law.terms]  # the fold's v_s
    X = design(wte, fixed, cte)
    res = []
    for i in range(n):
        idx = [j for j, t in enumerate(law.terms) if t.coordinate == i]
        pi = np.einsum("ntk,k->nt", X[..., idx], np.array([law.terms[j].coefficient for j in idx])) if idx else 0.0
        res.append((wte.total[..., i] - wte.own[..., i] - pi).reshape(-1))
    wfs = float(np.sqrt(np.mean(np.concatenate(res) ** 2)))
    if opts.criterion == "weak_form":
        return wfs, wfs
    if opts.criterion in ("window_rollout", "rollout"):
        rel = (opts.criterion == "window_rollout") if opts.rollout.relative is None else opts.rollout.relative
        ro = sc.rollout
        window = ro.window if opts.criterion == "window_rollout" else None
        return (rollout_score(law.augmented(sc.system), te, window, ro.init_samples, wtr.window, ro.sigma,
                              relative=rel)[0], wfs)
    if opts.criterion == "curve":
        ref = sc.reference
        return _curve_score(law, wte, ref.edges, max(10, 2 * wtr.window), ref.ref, sc.scored), wfs
    raise ValueError(f"unknown criterion {opts.criterion!r}")


def fold_stats(scores: list[float], weak_form: list[float]) -> FoldStats:
    """A law's fold scores and their mean and standard error.  A left-out recording on which the score is undefined
    for every law (a joint that does not move there: no speed band holds its samples) is no evidence: the mean and its
    standard error are over the folds that scored."""
    scored = np.asarray(scores, dtype=float)[np.isfinite(scores)]
    mean = float(np.mean(scored)) if scored.size else math.nan
    se = float(np.std(scored, ddof=1) / math.sqrt(scored.size)) if scored.size > 1 else 0.0
    return FoldStats([float(x) for x in scores], mean, se, float(np.mean(weak_form)))


def _score(sc: _Scoring, specs: Sequence[Spec]) -> CandidateScore:
    """Fit on all recordings (passivity, significance, curve agreement) and on each fold (the scores)."""
    rules, wf = sc.opts.rules, sc.wf_all
    full = fit_law_specs(wf, specs, cache=sc.caches.all, own=sc.own, own_terms=own_terms(sc.system))
    passive = is_passive(full, [float(np.max(np.abs(wf.vs[..., i]))) for i in range(sc.rec.n)]).passive
    tot_rms = [float(np.sqrt(np.mean(wf.total[..., i] ** 2))) + 1e-300 for i in range(sc.rec.n)]
    share = [float(np.sqrt(np.mean((t.coefficient
                                    * design(wf, [(t.term, t.coordinate, t.velocity)], sc.caches.all)) ** 2)))
             / tot_rms[t.coordinate] for t in full.terms]
    sig = all(t.excludes_zero and abs(t.t) >= rules.min_t and sh >= rules.min_share for t, sh in zip(full.terms, share))
    fs, wfs = zip(*[_fold_score(sc, specs, k) for k in range(len(sc.folds.weak))])
    inside = [r["inside"] for r in check_against_curve(full, sc.reference.curve)
              if sc.scored is None or r["coordinate"] in sc.scored]
    folds = fold_stats(list(fs), list(wfs))
    return CandidateScore(full.name, full.n_params, folds,
                          Eligibility(passive, sig, float(np.mean(inside)) if inside else 1.0),
                          fitted=full)


def _choose(scores: list[CandidateScore], opts: EligibilityRules) -> tuple[CandidateScore, str]:
    """The eligible law with the fewest parameters not significantly worse than the best; and the rule in words."""
    sig_ok = [s for s in scores if s.passive and (s.every_ci_excludes_zero or not opts.require_significant)]
    ok = ([s for s in sig_ok if s.curve_agreement >= opts.min_agreement] or sig_ok
          or [s for s in scores if s.passive] or scores)
    scored = [s for s in ok if math.isfinite(s.mean)]
    if not scored:  # e.g. a few short recordings: no fold could score any law
        for s in scores:
            s.not_worse = False
        pick = min(ok, key=lambda s: s.n_params)
        return pick, ("not enough data to decide: no candidate law could be scored on left-out recordings, so the one "
                      "with the fewest parameters is kept")
    ok = scored
    best = min(ok, key=lambda s: s.mean)
    for s in scores:  # paired standard error of the fold-wise difference to the best candidate (folds both scored)
        d = np.asarray(s.fold_scores) - np.asarray(best.fold_scores)
        d = d[np.isfinite(d)]
        s.folds.diff_se = float(np.std(d, ddof=1) / math.sqrt(len(d))) if len(d) > 1 else 0.0
    # not significantly worse than the best: one-sided paired t-test at 5% over the folds
    t_margin = float(student_t.ppf(0.95, max(int(np.isfinite(best.fold_scores).sum()) - 1, 1)))
    for s in ok:
        s.not_worse = s is best or s.mean - best.mean <= t_margin * s.folds.diff_se
    pick = min([s for s in ok if s.not_worse], key=lambda s: (s.n_params, s.mean))
    sig_txt = (f", every coefficient |t| >= {opts.min_t:g} (95% interval excludes zero) and its rms force >= "
               f"{opts.min_share:g} "
               "of the rms total friction force" if opts.require_significant else "")
    rule = ("passive over observed speeds" + sig_txt + f", inside the training friction curve's 95% interval in >= "
            f"{opts.min_agreement:.0%} of its speed bands; fewest parameters (a Stribeck term counts 2) among those "
            f"not significantly worse than the best (one-sided paired t-test over the folds at 5%: mean difference <= "
            f"{t_margin:.3g} x its standard error); ties: lower mean")
    return pick, rule


def select_law(system: System, rec: Recordings, candidates: Sequence[Sequence[Term | str | Spec]] | None = None,
               window: int | None = None, eps: float | None = None, block: int | None = None,
               coordinate: int | None = None,
               options: LawSelectionOptions | None = None, **overrides: Any) -> LawSelection:
    """Choose a friction law by prediction on data not used for its fit.

    Each candidate (a list of terms as in :func:`fit_law`; default :func:`candidate_laws`) is fitted by the weak form on
    all training recordings but one and scored on the left-out one (one recording: ``n_time_blocks`` time blocks).
    ``criterion``:

    * ``"curve"`` (default): how well the law predicts the left-out recording's friction curve: rms over speed bands
      (quantile bands of the pooled |qdot|, or ``bands="log"``) of (law - curve) / |pooled curve|, law and curve through
      the same filter.  Every speed range weighs the same; no simulation, so phase drift cannot enter (why it is the
      default: docs/mismatch.md, design notes);
    * ``"window_rollout"``: open-loop rollouts over consecutive windows of ``rollout_window`` seconds (default 3
      periods) of the left-out recording, initial state re-fitted per window (:func:`..evaluate.evaluate_models`), RMSE
      relative to each window's amplitude.  Short windows barely see the friction law (they favour the shooting-
      calibrated model);
    * ``"rollout"``: each left-out recording whole, absolute RMSE (the tool's held-out metric): dominated by the phase
      drift of large swings, noisy with few recordings;
    * ``"weak_form"``: rms of the left-out filtered force residual: dominated by non-dissipative model error.

    Rule: among laws that are passive over the observed speeds (:func:`is_passive` of the total force, fitted on all
    training recordings), inside the training friction curve's 95% interval in at least ``min_agreement`` of its
    speed bands (:func:`check_against_curve`: a law the curve rejects is not chosen) and, with
    ``require_significant``, whose every coefficient has |t| >= ``min_t`` (its 95% interval excludes zero) and an rms
    force >= ``min_share`` of the rms total friction force: the one with the fewest parameters (a Stribeck term counts
    2) that is not significantly worse than the best (one-sided paired t-test of the fold-wise differences at 5%);
    ties: lower mean.  (A plain one-standard-error rule lets a noisy candidate through while excluding one that tracks
    the best closely.)"""
    opts = (options or LawSelectionOptions()).with_(**overrides)
    if candidates is not None:
        specs_list = [parse_terms(c, rec.n) for c in candidates]
    elif coordinate is not None:
        specs_list = coordinate_laws(coordinate, opts.max_terms, opts.terms)
    else:
        specs_list = candidate_laws(rec.n, opts.max_terms, opts.terms)
    return _select(_scoring(system, rec, window, eps, block, coordinate, opts), specs_list)


@dataclass
class _Progress:
    """Where a per-coordinate selection stands, for a progress line at least every 30 s (:class:`Heartbeat`)."""

    heartbeat: Heartbeat
    total: int  # candidate laws over every coordinate
    done: int = 0
    start: float = field(default_factory=time.monotonic)

    def step(self, coordinate: int, n: int) -> None:
        self.done += 1
        if self.heartbeat.due():
            left = (time.monotonic() - self.start) / self.done * (self.total - self.done)
            self.heartbeat.say(f"  friction laws: coordinate {coordinate + 1} of {n}, {self.done} of {self.total} "
                               f"candidate laws scored (about {left:.0f} s left)")


def _select(sc: _Scoring, specs_list: list[list[Spec]], progress: _Progress | None = None) -> LawSelection:
    """Score every candidate law against ``sc`` and choose."""
    opts = sc.opts
    scores = []
    for c_idx, specs in enumerate(specs_list):
        scores.append(_score(sc, specs))
        if progress is not None and sc.scored:
            progress.step(sc.scored[0], sc.rec.n)
        if opts.progress:
            s = scores[-1]
            print(f"[select_law {c_idx + 1}/{len(specs_list)}] {s.law}: {s.mean:.4g} +- {s.se:.2g} passive={s.passive} "
                  f"sig={s.every_ci_excludes_zero}", flush=True)
    scores.sort(key=lambda s: s.mean)
    pick, rule = _choose(scores, opts.rules)
    assert pick.fitted is not None
    return LawSelection(pick.fitted, pick.law, opts.criterion, scores, sc.folds.text, rule)


def select_friction(system: System, rec: Recordings, heartbeat: Heartbeat | None = None,
                    **kwargs: Any) -> tuple[FrictionLaw, list[LawSelection]]:
    """:func:`select_law` coordinate by coordinate (friction is diagonal: the weak-form balance of coordinate i holds
    only the terms on i, so the choices are independent and the candidate count stays linear in n).  Returns the
    merged law and the per-coordinate selections.  ``heartbeat``: progress lines while the candidates are scored
    (minutes on a 6-joint arm with many recordings)."""
    opts = LawSelectionOptions().with_(**{k: v for k, v in kwargs.items() if k not in ("window", "eps", "block")})
    # weak forms, folds
    sc = _scoring(system, rec, kwargs.get("window"), kwargs.get("eps"), kwargs.get("block"), None, opts)
    # and curve computed once, shared by the coordinates
    laws = [coordinate_laws(i, opts.max_terms, opts.terms) for i in range(rec.n)]
    progress = None if heartbeat is None else _Progress(heartbeat, sum(len(c) for c in laws))
    sels = [_select(replace(sc, scored=[i]), laws[i], progress) for i in range(rec.n)]
    first = sels[0].chosen
    merged = FrictionLaw([t for s in sels for t in s.chosen.terms], first.eps, first.n,
                         float(sum(s.chosen.rss for s in sels)),
                         first.n_obs, first.interval, first.own_samples, first.own_terms)
    return merged, sels
