"""Weak-form identification: the simulator's parameters, the reflected rotor inertia and a friction law in one
least-squares problem.

The filtered momentum balance of :mod:`phast_model.identify.weakform` (one Savitzky-Golay filter S on both sides),

    f~(theta) = S * (F_cons(theta) + u) - d/dt S * (M(q; theta) qdot),

is the total dissipative force the data ask of a model with parameters theta.  With the missing physics added,
d/dt ((M + A) qdot) = F_cons + u - f_law, so

    f~(theta0) - J dz = sum_k c_k S * basis_k + A_ii d/dt S * qdot_i,    J = d f~ / dz,  theta = theta0 exp(z),

which is linear in (dz, c, A) once J is taken by finite differences (Gauss-Newton: re-linearized a few times).
This is the classic linear-in-parameters identification of robot dynamics, in weak form so that no noisy
acceleration enters alone.  It keeps a wrong parameter from absorbing unmodelled friction (and the reverse),
which a shooting calibration made before any friction term is considered cannot.  Intervals are cluster-robust
over time blocks within recordings (every coordinate of a block in one cluster).
"""

from __future__ import annotations

import math
import numbers
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.stats import t as student_t

from phast_gym.systems.base import System

from ...identify.recordings import Recordings
from ...identify.shooting import Heartbeat
from ...identify.signals import SAVGOL, Differentiator
from ...identify.simulators import Simulator
from ...identify.weakform import WeakForm, weak_form
from ..fitting.linear import cluster_cov, orth_against, rel_resid
from ..rows import ParamRow
from ..vocabulary.registry import ARMATURE
from ..vocabulary.terms import AugmentedSystem, Term
from .laws import FrictionLaw, LawTerm, Spec, filtered_basis, own_samples, own_terms

#: log-relative finite-difference step of a parameter column
PARAM_STEP = 1e-3
#: a parameter whose column is below this fraction of the largest one has no weak-form signal (e.g. the model's own
#: damping, which the total dissipative force f~ does not depend on)
NO_SIGNAL = 1e-9
#: an armature column whose part independent of the parameter columns is below this share is absorbed by them
ABSORBED = 0.05


@dataclass
class WeakModel:
    """What is identified: start values, the parameters to fit, fixed terms, the coordinates with an armature column."""

    sim: Simulator
    kwargs: dict[str, Any]  # start values (overrides of the simulator's kwargs)
    params: list[str]  # parameter names fitted (log-relative)
    fixed_terms: list[Term]  # non-dissipative terms held at their values (sensor map, potential, port)
    armature: list[int]  # coordinates whose reflected inertia is estimated
    eps: float  # tanh smoothing of sign(qdot)
    deadzone_width: float
    window: int  # weak-form filter window [samples]
    differentiator: Differentiator = SAVGOL  # the weak-form filter and its derivative

    def build(self, kwargs: dict[str, Any], extra: Sequence[Term] = ()) -> System:
        terms = list(self.fixed_terms) + list(extra)
        base = self.sim.build(**kwargs)
        return AugmentedSystem(base, terms, self.eps, self.deadzone_width) if terms else base


@dataclass
class WeakFit:
    """The identified model: parameter values with intervals, armature and friction terms."""

    kwargs: dict[str, Any]
    params: dict[str, ParamRow]  # name -> nominal, fitted, ci95, relative_change
    armature: list[LawTerm]
    law: FrictionLaw
    # parameters the weak form cannot see (held); "armature:i" absorbed
    no_signal: list[str] = field(default_factory=list)
    interval: str = ""

    def armature_terms(self, significant_only: bool = True) -> list[Term]:
        """Positive armature terms (whose interval excludes zero, by default)."""
        return [Term(ARMATURE.name, a.coordinate, a.coefficient) for a in self.armature
                if a.coefficient > 0 and (a.excludes_zero or not significant_only)]

    def system(self, model: WeakModel) -> System:
        """The identified simulator: parameters, fixed terms, armature and the friction law."""
        return self.law.augmented(model.build(self.kwargs, self.armature_terms()))


def _number(value: object) -> float:
    """A parameter's value as a float (a fitted parameter is numeric)."""
    if not isinstance(value, numbers.Real):
        raise ValueError(f"parameter value {value!r} is not a number")
    return float(value)


def _exp(x: float) -> float:
    """exp(x) capped at exp(700): the bound of an interval the data leave open stays a (huge) number."""
    return math.exp(min(x, 700.0))


def _accel(wf: WeakForm, i: int) -> np.ndarray:
    """d/dt S * qdot_i (the armature column: the force a missing inertia A_ii needs), trimmed like the weak form."""
    a = wf.filter.differentiator.derivative(wf.v_raw[..., i], wf.window, wf.dt, 1)
    return a[:, wf.trim: wf.v_raw.shape[1] - wf.trim]


def _on(i: int, col: np.ndarray, n: int) -> np.ndarray:
    """(N, T', n) with ``col`` on coordinate i and zero elsewhere."""
    out = np.zeros(col.shape + (n,))
    out[..., i] = col
    return out


def _columns(model: WeakModel, kwargs: dict[str, Any], rec: Recordings, law: list[Spec],
             absorb: bool = True, heartbeat: Heartbeat | None = None
             ) -> tuple[WeakForm, list[str], list[np.ndarray], list[str]]:
    """The weak form at ``kwargs`` and the design columns: -d f~/dz per parameter, each law term, each armature
    (``absorb``: without the armature columns the parameters can represent); ``heartbeat``: progress lines over the
    parameters' columns (a weak form of every recording each: a minute for a UR10e's 30 body values)."""
    system = model.build(kwargs)
    wf = weak_form(system, rec, model.window, model.eps, differentiator=model.differentiator)
    names, cols, none = [], [], []
    t0 = time.monotonic()
    for j, k in enumerate(model.params):
        if heartbeat is not None and j and heartbeat.due():
            left = (time.monotonic() - t0) / j * (len(model.params) - j)
            heartbeat.say(f"  weak form: column {j + 1} of {len(model.params)} parameters ({rec.n_traj} recordings; "
                          f"about {left:.0f} s left)")
        kw = dict(kwargs)
        kw[k] = _number(system.params[k]) * math.exp(PARAM_STEP)
        col = -(weak_form(model.build(kw), rec, model.window, model.eps, differentiator=model.differentiator).total
                - wf.total) / PARAM_STEP
        names.append(f"param:{k}")
        cols.append(col)
    for s in law:
        names.append(f"law:{s[0]}:{s[1]}")
        cols.append(_on(s[1], filtered_basis(wf, s[0], s[1], s[2] if len(s) > 2 and s[2] is not None else 0.0), rec.n))
    for i in model.armature:
        names.append(f"armature:{i}")
        cols.append(_on(i, _accel(wf, i), rec.n))
    norms = np.array([float(np.linalg.norm(c)) for c in cols]) if cols else np.zeros(0)
    big = float(norms.max()) if norms.size else 0.0
    keep = [j for j in range(len(cols)) if norms[j] > NO_SIGNAL * big]
    none = [names[j].split(":", 1)[1] for j in range(len(cols)) if j not in keep and names[j].startswith("param:")]
    P = [j for j in keep if names[j].startswith("param:")]
    # an armature the fitted parameters can represent exactly (e.g. inertia1 on joint 1) is theirs, not a new term
    if P and absorb:
        basis = np.stack([cols[j].reshape(-1) for j in P], 1)
        absorbed = [j for j in keep
                    if names[j].startswith("armature:") and rel_resid(cols[j].reshape(-1), basis) < ABSORBED]
        none += [names[j] for j in absorbed]
        keep = [j for j in keep if j not in absorbed]
    return wf, [names[j] for j in keep], [cols[j] for j in keep], none


#: a body value is fitted after the drives only where at least this share of its weak-form column lies outside the
#: span of the drives' columns and of the values picked before it (pivoted QR): the rest would take a rotor inertia's
#: or a friction's place, or repeat other body values (a centre of mass against a mass)
BEYOND_DRIVES = 0.2
#: recordings (evenly spread) the test of :func:`beyond_drives` reads: it asks which columns are independent, not
#: how large any coefficient is, and a 6-joint arm's 168 recordings cost a weak form per body value
BEYOND_DRIVES_RECORDINGS = 32


def beyond_drives(model: WeakModel, rec: Recordings, law: list[Spec]) -> list[str]:
    """The parameters of ``model.params`` the weak form can tell from the drives (``law`` and the armature columns)
    and from each other, linearized at ``model.kwargs``: the greedy pivoted QR of their columns with the drives'
    span projected out, each column measured against its own norm, kept while the new share is >=
    :data:`BEYOND_DRIVES`, on at most :data:`BEYOND_DRIVES_RECORDINGS` of the recordings.  The drives come first: no
    body value is fitted that could stand in for them."""
    from scipy.linalg import qr

    if rec.n_traj > BEYOND_DRIVES_RECORDINGS:
        rec = rec.subset(np.unique(np.linspace(0, rec.n_traj - 1, BEYOND_DRIVES_RECORDINGS).round().astype(int)))
    _, names, cols, _ = _columns(model, dict(model.kwargs), rec, law, absorb=False)
    P = [j for j, nm in enumerate(names) if nm.startswith("param:")]
    if not P:
        return []
    D = [cols[j].reshape(-1) for j in range(len(names)) if j not in P]
    B = np.stack([cols[j].reshape(-1) for j in P], 1)
    B = orth_against(B, np.stack(D, 1) if D else None) / np.linalg.norm(B, axis=0)
    _, R, pivots = qr(B, mode="economic", pivoting=True)
    share = np.abs(np.diag(R))
    picked = {names[P[j]].split(":", 1)[1] for j, r in zip(pivots, share) if r >= BEYOND_DRIVES}
    return [k for k in model.params if k in picked]


def _solve(wf: WeakForm, cols: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, int, float]:
    """Least squares of f~ - own on the columns (stacked over coordinates): coefficients, cluster covariance, clusters,
    residual sum of squares."""
    y = (wf.total - wf.own).reshape(-1)
    X = np.stack([c.reshape(-1) for c in cols], 1) if cols else np.zeros((y.size, 0))
    g = np.repeat(wf.blocks.reshape(-1), wf.n)
    sc = np.linalg.norm(X, axis=0) + 1e-300
    coef = np.linalg.lstsq(X / sc, y, rcond=None)[0] / sc
    r = y - X @ coef
    V, G = cluster_cov(X, r, g)
    return coef, V, G, float(r @ r)


def explained_force(model: WeakModel, rec: Recordings, law: list[Spec]) -> float:
    """1 - rss / |S (conservative + port force)|^2 of a non-negative least squares of the force the model leaves (at
    ``model.kwargs``) on the columns of ``law``, ``model.armature`` and ``model.params``: the share of the forces the
    balance carries (gravity, springs, the recorded input) that the model with those columns accounts for.
    Non-negative coefficients (physical inertia and friction), so that a negative inertia cannot absorb a balance of
    another kind."""
    from scipy.optimize import nnls

    wf, _, cols, _ = _columns(model, dict(model.kwargs), rec, law)
    y = (wf.total - wf.own).reshape(-1)
    scale = max(float(np.sum(wf.carried**2)), 1e-300)
    if not cols:
        return 1.0 - float(y @ y) / scale
    X = np.stack([c.reshape(-1) for c in cols], 1)
    sc = np.linalg.norm(X, axis=0) + 1e-300
    _, r = nnls(X / sc, y, maxiter=50 * X.shape[1])
    return 1.0 - float(r) ** 2 / scale


def parameter_force(model: WeakModel, rec: Recordings, heartbeat: Heartbeat | None = None) -> float:
    """1 - rss / |S (conservative + port force)|^2 of a least squares (signs free) of the force the model leaves on the
    columns of ``model.params``: the share of the forces the balance carries that a change of those parameters
    (linearized at ``model.kwargs``) accounts for."""
    wf, _, cols, _ = _columns(model, dict(model.kwargs), rec, [], heartbeat=heartbeat)
    y = (wf.total - wf.own).reshape(-1)
    scale = max(float(np.sum(wf.carried**2)), 1e-300)
    if cols:
        X = np.stack([c.reshape(-1) for c in cols], 1)
        X = X / (np.linalg.norm(X, axis=0) + 1e-300)
        y = y - X @ np.linalg.lstsq(X, y, rcond=None)[0]
    return 1.0 - float(y @ y) / scale


def identify(model: WeakModel, rec: Recordings, law: list[Spec], iterations: int = 3,
             heartbeat: Heartbeat | None = None) -> WeakFit:
    """Parameters, armature and the friction law ``law`` (specs with Stribeck velocities fixed) by Gauss-Newton on the
    weak form, starting at ``model.kwargs`` (reported against the simulator's own values); ``rec`` must be uniformly
    sampled; ``heartbeat``: progress lines (:func:`_columns`)."""
    nominal = model.sim.build()  # the user's values: intervals and relative changes are reported against them
    start = model.sim.build(**model.kwargs)
    kw = {k: _number(start.params[k]) for k in model.params}
    for _ in range(iterations):
        wf, names, cols, none = _columns(model, {**model.kwargs, **kw}, rec, law, heartbeat=heartbeat)
        coef, V, G, rss = _solve(wf, cols)
        step = {nm.split(":", 1)[1]: float(c) for nm, c in zip(names, coef) if nm.startswith("param:")}
        kw = {k: v * math.exp(float(np.clip(step.get(k, 0.0), -1.0, 1.0))) for k, v in kw.items()}
    tq = float(student_t.ppf(0.975, max(G - 1, 1)))
    sd = np.sqrt(np.maximum(np.diag(V), 0.0))
    params: dict[str, ParamRow] = {}
    arm, terms = [], []
    for j, nm in enumerate(names):
        kind, rest = nm.split(":", 1)
        if kind == "param":
            nom = _number(nominal.params[rest])
            z = math.log(kw[rest] / nom)  # the last step's interval, about the converged value
            params[rest] = ParamRow(nom, kw[rest], (nom * _exp(z - tq * sd[j]), nom * _exp(z + tq * sd[j])),
                                    kw[rest] / nom - 1.0)
        elif kind == ARMATURE.name:
            ci = (float(coef[j] - tq * sd[j]), float(coef[j] + tq * sd[j]))
            arm.append(LawTerm(ARMATURE.name, int(rest), float(coef[j]), ci, 0.0, tq))
        else:
            name, i = rest.split(":")
            s = next(s for s in law if s[0] == name and s[1] == int(i))
            v = float(s[2]) if len(s) > 2 and s[2] is not None else 0.0
            terms.append(LawTerm(name, int(i), float(coef[j]),
                                 (float(coef[j] - tq * sd[j]), float(coef[j] + tq * sd[j])), v, tq))
    interval = f"cluster-robust (CR1) over {G} clusters (time blocks within recordings), t({G - 1}) quantile"
    final = model.build({**model.kwargs, **kw})
    wf_final = weak_form(final, rec, model.window, model.eps, differentiator=model.differentiator)
    fl = FrictionLaw(terms, model.eps, rec.n, rss, int(wf.total.size), interval, own_samples(final, wf_final),
                     own_terms(final))
    return WeakFit({**model.kwargs, **kw}, params, arm, fl, none, interval)


# --------------------------------------------------------------------------- which parameters to calibrate
@dataclass
class ParameterCheck:
    """Leave-one-out check of each parameter: does fitting it predict the left-out weak-form force better?"""

    kept: list[str]
    table: list[dict[str, Any]]  # parameter, t of the left-out improvement, kept
    folds: str
    no_signal: list[str] = field(default_factory=list)  # parameters the weak form cannot see (the model's own damping)

    def to_dict(self) -> dict[str, Any]:
        return {"kept": self.kept, "table": self.table, "folds": self.folds, "no_signal": self.no_signal}


def _fold_labels(wf: WeakForm) -> tuple[np.ndarray, str]:
    """(N, T') fold of every weak-form sample: the recording (>= 3 recordings) or the time block."""
    N = wf.total.shape[0]
    if N >= 3:
        return np.broadcast_to(np.arange(N)[:, None], wf.blocks.shape), f"leave-one-recording-out ({N} folds)"
    return wf.blocks, f"leave-one-time-block-out ({len(np.unique(wf.blocks))} folds)"


@dataclass(frozen=True)
class _FoldGrams:
    """Normal equations of a least squares per fold (columns scaled to unit norm): a leave-one-fold-out fit of any
    subset of the columns and its left-out residual from (p, p) systems, not from the (N, p) design again (seconds
    instead of minutes on a 6-joint arm).  Equal to refitting the design where its columns are independent; the
    squared condition of the normal equations blurs directions below about 1e-7 of the largest singular value."""

    G: np.ndarray  # (F, p, p) X_f' X_f
    b: np.ndarray  # (F, p) X_f' y_f
    yy: np.ndarray  # (F,) y_f' y_f
    count: np.ndarray  # (F,) rows of each fold

    @classmethod
    def of(cls, X: np.ndarray, y: np.ndarray, folds: np.ndarray) -> _FoldGrams:
        Xs = X / (np.linalg.norm(X, axis=0) + 1e-300)
        parts = [(Xs[folds == f], y[folds == f]) for f in np.unique(folds)]
        return cls(np.stack([A.T @ A for A, _ in parts]), np.stack([A.T @ r for A, r in parts]),
                   np.array([float(r @ r) for _, r in parts]), np.array([len(r) for _, r in parts]))

    def left_out_rms(self, cols: list[int]) -> np.ndarray:
        """Per fold: rms of the left-out residual of y on columns ``cols`` fitted on the other folds."""
        G, b = self.G[:, cols][:, :, cols], self.b[:, cols]
        Gt, bt = G.sum(0), b.sum(0)
        out = []
        for f in range(len(self.yy)):
            c = np.linalg.lstsq(Gt - G[f], bt - b[f], rcond=None)[0]
            rss = self.yy[f] - 2.0 * float(c @ b[f]) + float(c @ G[f] @ c)
            out.append(math.sqrt(max(rss, 0.0) / self.count[f]))
        return np.asarray(out)


def check_parameters(model: WeakModel, rec: Recordings, law: list[Spec],
                     heartbeat: Heartbeat | None = None) -> ParameterCheck:
    """Backward elimination of ``model.params`` by prediction on left-out recordings (the weak form linearized at the
    simulator's values, with ``law`` and the armature columns always in): a parameter stays only if dropping it makes
    the left-out weak-form force residual significantly worse (one-sided paired t-test over the folds, 5%).  A
    calibration that only bends parameters to soak up model error does not predict left-out recordings better.
    ``heartbeat``: progress lines while the columns are built and the rounds run (minutes on a 6-joint arm)."""
    wf, names, cols, none = _columns(model, dict(model.kwargs), rec, law, heartbeat=heartbeat)
    folds, txt = _fold_labels(wf)
    n = wf.n
    X = np.stack([c.reshape(-1) for c in cols], 1)
    y = (wf.total - wf.own).reshape(-1)
    grams = _FoldGrams.of(X, y, np.repeat(np.asarray(folds).reshape(-1), n))
    params = [j for j, nm in enumerate(names) if nm.startswith("param:")]
    rest = [j for j in range(len(names)) if j not in params]
    G = len(grams.yy)
    tq = float(student_t.ppf(0.95, max(G - 1, 1)))
    kept, table = list(params), {}
    started = time.monotonic()
    while kept:
        base = grams.left_out_rms(kept + rest)
        ts = {}
        for j in kept:
            d = grams.left_out_rms([k for k in kept if k != j] + rest) - base
            se = float(np.std(d, ddof=1) / math.sqrt(len(d))) if len(d) > 1 else 0.0
            ts[j] = float(np.mean(d)) / max(se, 1e-300)
        worst = min(ts, key=lambda j: ts[j])
        for j, t in ts.items():
            table[names[j].split(":", 1)[1]] = t
        if ts[worst] >= tq:
            break
        kept.remove(worst)
        if heartbeat is not None and heartbeat.due():
            heartbeat.say(f"  weak-form parameter check: {len(kept)} of {len(params)} parameters left "
                          f"({time.monotonic() - started:.0f} s; at most {len(kept)} more rounds)")
    out = [names[j].split(":", 1)[1] for j in kept]
    rows = [{"parameter": k, "t_left_out_improvement": t, "kept": k in out} for k, t in table.items()]
    return ParameterCheck(out, rows, txt + f"; kept when dropping it worsens the left-out residual with t >= {tq:.3g}",
                          [k for k in none if not k.startswith("armature:")])
