"""The selection stage's forward selection: parameter changes and new terms in one selection by shooting.

Parameters before terms: the search starts from the fit with every pivot parameter free (a full-rank calibration,
:mod:`..calibrate`), so a term is judged only on what no change of the simulator's parameters explains.  Each round
ranks the candidate terms by the chi^2 gain of the linearized shooting problem (window states and the current
globals projected out; friction coefficients must come out positive) and confirms the best few, and every one of
equal evidence with the best (:data:`.search.EQUAL_EVIDENCE`), by nonlinear refits.  A term is added when its chi^2 gain
exceeds threshold^2 and |z| / std >= threshold; between terms of equal evidence the one that keeps the parameters
nearer their nominal values wins, then the one listed first in the vocabulary.  Where dissipation laws of equal
evidence met on one joint, :mod:`.law_look` compares them on longer windows.

Then the parameter changes are pruned to those the recordings need; sensor / port terms that a nonlinear refit with
every pivot free replaces are dropped; changes that act as one parameter are reported as it, and changes that act
as an actuator gain as that gain (:func:`_port_gain_equivalent`: a datasheet error does not scale a whole
coordinate).  Every chosen item must predict recordings left out of its fit by *two-fold validation* on the
training recordings (:func:`_two_fold_validation`: each fold predicted by the fit on the other; not the held-out
recordings of :mod:`..evaluate`, which no stage fits, nor the leave-one-out of :mod:`..friction.lawselect`); a sensor or
port term needs a left-out gain of threshold^2 over every parameter change open (local evidence).  A chosen
term's velocity (a Stribeck v_s) is refined by profiling the refit cost in its kind's steps (quarter octaves).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
from scipy.stats import t as student_t

from ...identify.shooting import ShootFit
from ..calibrate import ParameterScreen
from ..fitting.linear import flat
from ..fitting.problem import Problem
from ..options import Z95
from ..vocabulary.candidates import Candidate, ParamCandidate
from ..vocabulary.registry import ACTUATOR_GAIN, COULOMB, ActuatorDeadzone
from .law_look import contenders, look_longer
from .search import EQUAL_EVIDENCE, AnyCandidate, Search, Selection

#: refit iterations while confirming a shortlisted candidate (the winner is finished with Options.max_iter)
CONFIRM_ITER = 6
#: components whose terms need local evidence (a left-out gain of threshold^2) to be adopted
LOCAL_EVIDENCE = ("sensor", "port")
#: a Stribeck term beside a Coulomb term is weighed against that Coulomb edge made this many times sharper
SHARPER_EDGE = 4.0


def _component(cand: AnyCandidate) -> str:
    return "parameter" if isinstance(cand, ParamCandidate) else cand.component


def _rank(s: Search, pool: list[int], r_o: np.ndarray, cols_o: np.ndarray, col_of: dict[int, int],
          s2: float) -> list[tuple[float, int, float]]:
    """(chi^2 gain, candidate, linear z) of each candidate term of ``pool``, best first."""
    ranked = []
    for k in pool:
        c = cols_o[:, col_of[k]]
        cc = float(c @ c)
        if cc <= 0 or len(s.chosen) - s.n_params() >= s.problem.opts.max_terms:
            continue
        z = -float(c @ r_o) / cc
        if s.cands[k].must_be_positive and z <= 0:
            continue  # a friction coefficient must be positive (passivity)
        ranked.append((float(c @ r_o) ** 2 / cc / s2, k, z))
    ranked.sort(reverse=True)
    if s.problem.opts.progress:
        s.problem.log("screening gains (chi^2): " + ", ".join(f"{s.cands[k].label} {g:.3g}" for g, k, _ in ranked[:6]))
    return ranked


#: most candidates refitted in one round
MAX_SHORTLIST = 6


def _shortlist(ranked: list[tuple[float, int, float]], thr2: float) -> list[tuple[int, float]]:
    """The two best, and every candidate of equal evidence with the best (so that equivalent explanations are
    compared by their refits)."""
    if not ranked or ranked[0][0] < thr2:
        return []
    top = ranked[0][0]
    equal = top - max(2.0, EQUAL_EVIDENCE * top)
    return [(k, z) for i, (g, k, z) in enumerate(ranked[:MAX_SHORTLIST]) if g >= thr2 and (i < 2 or g >= equal)]


def _displacement(s: Search, fit: ShootFit, cov: np.ndarray, order: list[int]) -> float:
    """How far a fit moves the simulator's parameters from their nominal values: sum of (z / std)^2."""
    out = 0.0
    for j, k in enumerate(order):
        if s.cands[k].is_param:
            out += float(fit.g[j]) ** 2 / max(float(cov[j, j]), 1e-300)
    return out


def _better(s: Search, gain: float, k: int, disp: float, best: tuple | None) -> bool:
    """Whether term k (chi^2 ``gain``, parameter displacement ``disp``) beats the best so far: between terms of equal
    evidence the one that keeps the parameters nearer their nominal values (an equivalent explanation that needs
    fewer parameter changes), then the one listed first in the vocabulary."""
    if best is None:
        return True
    b_gain, b_k, b_disp = best[0], best[1], best[6]
    margin = max(2.0, EQUAL_EVIDENCE * max(gain, b_gain))
    if abs(gain - b_gain) <= margin and max(disp, b_disp) > s.thr2 and (disp < 0.5 * b_disp or b_disp < 0.5 * disp):
        return disp < b_disp
    return gain > b_gain + 2.0 or (gain >= b_gain - 2.0 and s.cands[k].vocabulary_rank < s.cands[b_k].vocabulary_rank)


#: a shortlisted candidate whose linear gain is below this share of the best confirmed gain is not refitted (on the
#: three-link rig a refit's chi^2 gain came out 0.90-1.15 x its linear gain, so 3/4 cannot catch up)
CATCH_UP = 0.75


def _confirm(s: Search, shortlist: list[tuple[int, float]], s2: float, linear: dict[int, float]) -> tuple | None:
    """Nonlinear refit with each shortlisted candidate: the best passing one as (gain, k, fit, family, cov, order,
    parameter displacement).  A candidate whose linear gain ``linear[k]`` cannot catch up with the best refit so far
    (below :data:`CATCH_UP` of it) is not refitted."""
    shooter, best = s.screen.shooter, None
    for k, z0 in shortlist:
        cand = s.cands[k]
        if best is not None and linear.get(k, math.inf) < CATCH_UP * best[0]:
            continue
        fam_new, g0, order = s.add(k, s.fam, s.fit.g, z0)
        X0 = s.state_step(k, z0)
        # threshold: start from the best of a
        if isinstance(cand, Candidate) and isinstance(cand.kind, ActuatorDeadzone):
            j = order.index(k)                                                       # coarse grid (zero slope at c = 0)
            grid = np.linspace(*ActuatorDeadzone.START_GRID)
            costs = [float(np.sum(shooter.residual(fam_new.build(np.concatenate([g0[:j], [zz], g0[j + 1:]])), X0) ** 2))
                     for zz in grid]
            g0[j] = grid[int(np.argmin(costs))]
        fit_new = shooter.fit(fam_new.build, X0, g0, max_iter=CONFIRM_ITER)
        if not fit_new.cost < s.fit.cost and X0 is not s.fit.X:  # the linear step's states led the refit astray: a
            fit_new = shooter.fit(fam_new.build, s.fit.X, g0, max_iter=CONFIRM_ITER)  # failed descent, not evidence
        cov_new = fit_new.covariance()
        gain = (s.fit.cost - fit_new.cost) / s2
        ok = s.item_ok(fit_new, cov_new, order, k) and gain >= s.thr2
        if s.problem.opts.progress:
            j = order.index(k)
            zz, sd = fit_new.g[j], math.sqrt(max(cov_new[j, j], 1e-300))
            s.problem.log(f"  refit with {cand.label}: chi^2 gain {gain:.3g}, value "
                          f"{cand.coefficient(zz):.4g}, |t| = {abs(zz) / sd:.3g}{'' if ok else ' (rejected)'}")
        disp = _displacement(s, fit_new, cov_new, order)
        if ok and _better(s, gain, k, disp, best):
            best = (gain, k, fit_new, fam_new, cov_new, order, disp)
    return best


def _forward(s: Search, r_o: np.ndarray, cols_o: np.ndarray, pool: list[int], col_of: dict[int, int]) -> None:
    """Greedy forward selection: rank on the linearized problem, confirm the best few by nonlinear refits."""
    opts = s.problem.opts
    while pool:
        s2 = max(s.fit.cost / s.fit.dof, 1e-300)
        ranked = _rank(s, pool, r_o, cols_o, col_of, s2)
        shortlist = _shortlist(ranked, s.thr2)
        best = _confirm(s, shortlist, s2, {k: g for g, k, _ in ranked}) if shortlist else None
        if best is None:
            break
        _, k, fit_new, fam_new, cov_new, order, _ = best
        s.marks.contenders += contenders(s, k, ranked)
        if fit_new.iterations >= CONFIRM_ITER:  # finish the winner's refit
            fit_new = s.screen.shooter.fit(fam_new.build, fit_new.X, fit_new.g, max_iter=opts.max_iter)
            cov_new = fit_new.covariance()
        s.gains[k] = s.fit.cost - fit_new.cost
        s.chosen, s.fit, s.fam, s.cov = order, fit_new, fam_new, cov_new
        s.problem.log(f"added {s.cands[k].label}: chi2/dof = {s.fit.chi2_red:.3g} ({s.fit.iterations} it)")
        added = s.cands[k]
        if isinstance(added, Candidate) and added.kind.refines_velocity:  # its velocity before the next round: a wrong
            _refine_velocities(s)  # v_s leaves a residual that another term would then absorb
        pool = [kk for kk in pool if kk not in s.chosen and s.cands[kk].key != s.cands[k].key]
        if pool:
            r_o, _, cols_o = s.columns(s.fit, s.fam, pool)
            col_of = {kk: j for j, kk in enumerate(pool)}


def _refit(s: Search, keep: list[int]) -> None:
    """Refit with the chosen items ``keep`` only (the others set to no effect)."""
    g0 = np.array([s.fit.g[s.pos(k)] for k in keep])
    s.chosen = list(keep)
    s.fam = s.family_of(s.chosen)
    s.fit = s.screen.shooter.fit(s.fam.build, s.fit.X, g0, max_iter=s.problem.opts.max_iter)
    s.cov = s.fit.covariance() if s.chosen else None


def _prune(s: Search) -> None:
    """Earlier items must stay significant once later ones are in."""
    if len(s.chosen) <= 1 or s.cov is None:
        return
    keep = [k for k in s.chosen if s.item_ok(s.fit, s.cov, s.chosen, k)]
    if len(keep) < len(s.chosen):
        _refit(s, keep)


def _two_folds(s: Search) -> tuple[np.ndarray, str] | None:
    """The two validation folds of the windows: alternate training recordings, else the first and second half of the one
    recording."""
    w = s.screen.shooter.w
    trajs = np.unique(w.traj)
    if len(trajs) >= 2:
        rank = np.searchsorted(trajs, w.traj)
        return rank % 2, f"two folds of the training recordings ({len(trajs)} recordings, alternating)"
    if w.count >= 4:
        return (w.start >= np.median(w.start)).astype(int), "two halves in time of the one training recording"
    return None


def _open_parameter_columns(s: Search) -> np.ndarray | None:
    """(W, L*n, E) projected columns, at the current fit, of the examined parameters not chosen (None when none)."""
    extra = [k for k, c in enumerate(s.cands) if c.is_param and k not in s.chosen and k not in s.marks.swapped]
    if not extra:
        return None
    _, cols_p, _ = s.columns(s.fit, s.fam, extra)
    return cols_p.reshape(s.fit.r.shape + (len(extra),))


def _two_fold_gains(s: Search) -> tuple[dict[int, float], str] | None:
    """Per chosen item: how much worse each validation fold is predicted without it (chi^2 units, linearized problem:
    every global refitted on one fold, window states of the other fold refitted, and back).  A sensor or port term is
    compared with every parameter change open (it must predict what no parameter change can: local evidence)."""
    folds = _two_folds(s)
    if folds is None or not s.chosen:
        return None
    fold, txt = folds
    r_p, J_p = s.fit.projected()
    local = [k for k in s.chosen if _component(s.cands[k]) in LOCAL_EVIDENCE]
    open_cols = _open_parameter_columns(s) if local else None
    s2 = max(s.fit.chi2_red, 1.0)
    gains = dict.fromkeys(s.chosen, 0.0)
    for f in (0, 1):
        A, B = fold != f, fold == f
        rA, rB = flat(r_p[A]).reshape(-1), flat(r_p[B]).reshape(-1)
        for j, k in enumerate(s.chosen):
            J = J_p if open_cols is None or k not in local else np.concatenate([J_p, open_cols], axis=-1)
            JA, JB = flat(J[A]), flat(J[B])
            with_all = float(np.sum((rB + JB @ np.linalg.lstsq(JA, -rA, rcond=None)[0]) ** 2))
            rest = [i for i in range(J.shape[-1]) if i != j]
            dj = -s.fit.g[j]  # back to "no effect" (z = 0: nominal value, or the term's default)
            d = np.linalg.lstsq(JA[:, rest], -(rA + JA[:, j] * dj), rcond=None)[0] if rest else np.zeros(0)
            without = float(np.sum((rB + JB[:, j] * dj + JB[:, rest] @ d) ** 2))
            gains[k] += (without - with_all) / s2
    return gains, txt


def _parameter_effect(s: Search) -> np.ndarray:
    """The joint effect of the chosen parameter changes on the projected residual (linear)."""
    n = s.n_params()
    _, J_p = s.fit.projected()
    return flat(J_p)[:, :n] @ s.fit.g[:n]


def _replace_if_as_good(s: Search, order: list[int], g0: np.ndarray) -> ShootFit | None:
    """Refit with the items ``order`` from ``g0``; adopt it when it fits as well as the current model (equal evidence:
    chi^2 within 2 x chi^2/dof or 1%).  Returns the new fit, or None (nothing changed)."""
    fam = s.family_of(order)
    fit = s.screen.shooter.fit(fam.build, s.fit.X, g0, max_iter=s.problem.opts.max_iter)
    if fit.cost > s.fit.cost + max(2.0 * max(s.fit.chi2_red, 1.0), 0.01 * s.fit.cost):
        return None
    s.chosen, s.fam, s.fit = order, fam, fit
    s.cov = fit.covariance()
    return fit


def _sparser_parameters(s: Search) -> dict[str, Any] | None:
    """When the chosen parameter changes (two or more) act together exactly like a change of one parameter (cosine
    >= 0.99 of their joint effect with its column; e.g. an RLC circuit's resistance and inductance moved together are
    its capacitance), report that one change if it fits as well: the sparsest equivalent."""
    params = [k for k in s.chosen if s.cands[k].is_param]
    if len(params) < 2:
        return None
    v = _parameter_effect(s)
    others = [k for k, c in enumerate(s.cands) if c.is_param]
    _, cols_p, _ = s.columns(s.fit, s.fam, others)
    cos = [abs(float(cols_p[:, j] @ v)) / (float(np.linalg.norm(cols_p[:, j]) * np.linalg.norm(v)) + 1e-300)
           for j in range(len(others))]
    j = int(np.argmax(cos))
    if cos[j] < 0.99:
        return None
    k, c = others[j], cols_p[:, j]
    terms = [kk for kk in s.chosen if not s.cands[kk].is_param]
    before = s.fit.chi2_red
    g0 = np.array([float(c @ v) / float(c @ c)] + [s.fit.g[s.pos(kk)] for kk in terms])
    if _replace_if_as_good(s, [k] + terms, g0) is None:
        return None
    swap = {"replaced": [s.cands[kk].label for kk in params], "by": s.cands[k].label, "cosine": round(cos[j], 4),
            "chi2_per_dof": [before, s.fit.chi2_red]}
    s.problem.log(f"{swap['replaced']} act as {swap['by']} (cosine {cos[j]:.4f}): the one change is reported")
    return swap


def _compensating_terms(s: Search) -> list[str]:
    """Sensor and port terms that only stand in for parameter changes: refit without them, every pivot parameter free
    from the current values (the nonlinear check; the selection's screening is linear around the calibration).
    When that fits as well, the terms go and the parameters stay free (pruned again).  Returns the dropped labels."""
    local = [k for k in s.chosen if _component(s.cands[k]) in LOCAL_EVIDENCE]
    if not local:
        return []
    basis = s.screen.identifiability.basis
    params = [k for k, c in enumerate(s.cands) if isinstance(c, ParamCandidate) and (c.name in basis or k in s.chosen)]
    keep_terms = [k for k in s.chosen if not s.cands[k].is_param and k not in local]
    order = params + keep_terms
    g0 = np.array([s.fit.g[s.pos(k)] if k in s.chosen else 0.0 for k in order])
    if _replace_if_as_good(s, order, g0) is None:
        return []
    dropped = [s.cands[k].label for k in local]
    s.problem.log(f"{dropped} only stand in for parameter changes (chi2/dof {s.fit.chi2_red:.3g} without them): "
                  "dropped")
    _prune_parameters(s)
    return dropped


def _port_gain_equivalent(s: Search) -> dict[str, Any] | None:
    """When the chosen parameter changes act together exactly like an actuator gain (cosine >= 0.99 of their joint
    effect with the gain's column), replace them by the gain if it fits as well: the equivalent that keeps the
    simulator's parameters.  Returns the swap made (for the report), or None."""
    params = [k for k in s.chosen if s.cands[k].is_param]
    gains = [k for k, c in enumerate(s.cands) if not c.is_param and c.term == ACTUATOR_GAIN.name and k not in s.chosen]
    if not params or not gains:
        return None
    v = _parameter_effect(s)
    _, cols_p, _ = s.columns(s.fit, s.fam, gains)
    for j, k in enumerate(gains):
        c = cols_p[:, j]
        cos = abs(float(c @ v)) / (float(np.linalg.norm(c) * np.linalg.norm(v)) + 1e-300)
        if cos < 0.99:
            continue
        keep = [kk for kk in s.chosen if not s.cands[kk].is_param]
        before = s.fit.chi2_red
        g0 = np.array([s.fit.g[s.pos(kk)] for kk in keep] + [float(c @ v) / float(c @ c)])
        if _replace_if_as_good(s, keep + [k], g0) is not None:
            swap = {"replaced": [s.cands[kk].label for kk in params], "by": s.cands[k].label, "cosine": round(cos, 4),
                    "chi2_per_dof": [before, s.fit.chi2_red]}
            s.problem.log(f"{swap['replaced']} act as {swap['by']} (cosine {cos:.4f}): the port gain is reported")
            s.marks.swapped = set(params)
            return swap
    return None


def _two_fold_validation(s: Search) -> list[dict[str, Any]]:
    """Two-fold validation on the training recordings: drop, one at a time, the item that predicts the other fold
    least (sensor / port terms need threshold^2).  Returns the table of every item examined."""
    table: list[dict[str, Any]] = []
    while s.chosen:
        res = _two_fold_gains(s)
        if res is None:
            for k in s.chosen:
                table.append({"item": s.cands[k].label, "left_out_gain": None, "kept": True,
                              "note": "not enough recordings to leave any out"})
            return table
        gains, txt = res
        need = {k: s.thr2 if _component(s.cands[k]) in LOCAL_EVIDENCE else 0.0 for k in s.chosen}
        open_ = [k for k in s.chosen if k not in s.marks.longer_look]  # (a law settled on longer windows stays)
        worst = min(open_, key=lambda k: gains[k] - need[k]) if open_ else None
        if worst is None or gains[worst] > need[worst]:
            table += [{"item": s.cands[k].label, "left_out_gain": gains[k], "required": need[k], "kept": True,
                       "folds": txt}
                      for k in s.chosen]
            return table
        table.append({"item": s.cands[worst].label, "left_out_gain": gains[worst], "required": need[worst],
                      "kept": False,
                      "folds": txt})
        s.problem.log(f"dropped {s.cands[worst].label}: left-out chi^2 gain {gains[worst]:.3g} <= {need[worst]:.3g}")
        _refit(s, [k for k in s.chosen if k != worst])
    return table


def _refine_velocities(s: Search) -> None:
    """A chosen term whose kind refines its velocity (a Stribeck v_s): that velocity around the grid value, in the
    kind's steps (:attr:`.vocabulary.registry.TermKind.refine_steps`; profile of the refit cost), never below its
    minimum."""
    for k in s.chosen:
        cand = s.cands[k]
        if not isinstance(cand, Candidate) or not cand.kind.refines_velocity or k in s.marks.refined:
            continue
        s.marks.refined.add(k)
        for step in cand.kind.refine_steps:
            best = (s.fit.cost, s.cands[k], s.fit, s.fam)
            current = s.cands[k]
            assert isinstance(current, Candidate) and current.velocity is not None
            for f in (1 / step, step):
                velocity = current.velocity * f
                if velocity < cand.kind.min_velocity(s.problem.eps_coord[cand.coordinate]):
                    continue
                c_new = current.with_velocity(velocity)
                trial = [c_new if kk == k else s.cands[kk] for kk in range(len(s.cands))]
                fam_v = s.family_of(s.chosen, trial)
                fit_v = s.screen.shooter.fit(fam_v.build, s.fit.X, s.fit.g, max_iter=CONFIRM_ITER)
                if fit_v.cost < best[0]:
                    best = (fit_v.cost, c_new, fit_v, fam_v)
            _, s.cands[k], s.fit, s.fam = best
        s.cov = s.fit.covariance()
        s.problem.log(f"velocity refined: {s.cands[k].label}, chi2/dof = {s.fit.chi2_red:.3g}")


def _sharper_edge(s: Search) -> list[dict[str, Any]]:
    """A Stribeck term (a kind with ``excess_near_rest``) beside a Coulomb term on the same coordinate may only stand
    in for a real Coulomb edge sharper
    than the fits' tanh smoothing (the excess friction near rest that a smoothed edge leaves): refit without it, that
    coordinate's edge :data:`SHARPER_EDGE` times sharper; when that fits within threshold^2 of the chi^2 with the
    Stribeck term, the sharper edge is the answer (one fewer term; the edge is not a new physical effect)."""
    out: list[dict[str, Any]] = []
    for k in list(s.chosen):
        cand = s.cands[k]
        if not isinstance(cand, Candidate) or not cand.kind.excess_near_rest:
            continue
        i = cand.coordinate
        if not any(isinstance(c, Candidate) and c.term == COULOMB.name and c.coordinate == i
                   for c in (s.cands[kk] for kk in s.chosen)):
            continue
        eps = list(s.eps or s.problem.eps_coord)
        eps[i] /= SHARPER_EDGE
        keep = [kk for kk in s.chosen if kk != k]
        fam = replace(s.family_of(keep), eps=tuple(eps))
        fit = s.screen.shooter.fit(fam.build, s.fit.X, np.array([s.fit.g[s.pos(kk)] for kk in keep]),
                                   max_iter=s.problem.opts.max_iter)
        rise = fit.cost - s.fit.cost
        row = {"item": cand.label, "chi2_rise_without_it": float(rise), "required": s.thr2,
               "alternative": f"coordinate {i}'s Coulomb edge {SHARPER_EDGE:g}x sharper (tanh(qdot/{eps[i]:.3g}))"}
        if np.isfinite(rise) and rise < s.thr2:
            s.chosen, s.fam, s.fit, s.eps = keep, fam, fit, tuple(eps)
            s.cov = s.fit.covariance() if s.chosen else None
            out.append({**row, "kept": False,
                        "note": "stands in for a sharper Coulomb edge (refit without it fits as well)"})
            s.problem.log(f"dropped {cand.label}: a {SHARPER_EDGE:g}x sharper Coulomb edge fits as well (chi^2 "
                          f"{rise:+.3g})")
        else:
            out.append({**row, "kept": True})
    return out


def _start_calibrated(s: Search) -> None:
    """Start from the fit with every pivot free (a full-rank set spanning the identifiable combinations)."""
    basis = s.screen.identifiability.basis
    by_name = {c.name: k for k, c in enumerate(s.cands) if isinstance(c, ParamCandidate)}
    s.chosen = [by_name[b] for b in basis if b in by_name]
    s.fit, s.fam = s.screen.fit_full, s.screen.family_full
    s.cov = s.fit.covariance() if s.chosen else None


def _prune_parameters(s: Search) -> None:
    """Backward elimination of the parameter changes (with the terms in): the least significant one goes while its
    |z| / std < threshold, so only the changes the recordings need are reported.  Skipped when model error dominates
    (chi^2/dof above ``Options.systematic_chi2``): the weak form then checks the parameters on left-out recordings."""
    if s.fit.chi2_red > s.problem.opts.systematic_chi2:
        s.problem.log("model error dominates: the weak form decides the parameters (no shooting pruning)")
        return
    while True:
        dropped = False
        while s.cov is not None:  # eliminations on the linearized fit ...
            params = [k for k in s.chosen if s.cands[k].is_param]
            if not params:
                break
            t = {k: abs(s.fit.g[s.pos(k)]) / math.sqrt(max(s.cov[s.pos(k), s.pos(k)], 1e-300)) for k in params}
            worst = min(params, key=lambda k: t[k])
            if t[worst] >= s.problem.opts.threshold:
                break
            s.problem.log(f"parameter {s.cands[worst].label} not needed (|t| = {t[worst]:.3g}): held at nominal")
            s.fit = s.fit.without(s.pos(worst))
            s.chosen = [k for k in s.chosen if k != worst]
            s.cov = s.fit.covariance() if s.chosen else None
            dropped = True
        if not dropped:
            return
        _refit(s, list(s.chosen))  # ... then one nonlinear refit, whose statistics are checked again


#: the shooting selection stops at the calibration when even every candidate term at once, on the linearized problem
#: (:func:`linear_reach`), leaves a chi^2/dof above this many times ``Options.systematic_chi2``: no selection of terms
#: brings the windows near the noise, the weak form answers (model error, :mod:`..friction.systematic`), and the
#: selection's refits would be minutes spent on an answer that is not adopted (on the real C.0 arm: 92 of 221 s)
REACH_FACTOR = 10.0


def linear_reach(r: np.ndarray, cols: np.ndarray) -> float:
    """The chi^2 left when every column of ``cols`` (N, K) is fitted to the residual ``r`` (N,) at once: what the
    whole vocabulary can explain, to first order (friction signs not enforced: optimistic, never too pessimistic
    for the linearized problem)."""
    ok = np.all(np.isfinite(cols), axis=0)
    if not np.any(ok):
        return float(r @ r)
    beta = np.linalg.lstsq(cols[:, ok], r, rcond=None)[0]
    left = r - cols[:, ok] @ beta
    return float(left @ left)


def _beyond_reach(s: Search, r: np.ndarray, cols_o: np.ndarray) -> bool:
    """Whether model error dominates beyond what any selection of terms can change (:data:`REACH_FACTOR`)."""
    bar = s.problem.opts.systematic_chi2
    if not 0.0 < bar < math.inf:
        return False
    reach = linear_reach(r, cols_o) / max(s.fit.dof, 1)
    if reach <= REACH_FACTOR * bar:
        s.problem.log(f"every candidate term at once (linearized) would leave chi2/dof {reach:.3g}")
        return False
    s.problem.log(f"every candidate term at once (linearized) leaves chi2/dof {reach:.3g} > {REACH_FACTOR:g} x "
                  f"{bar:g}: model error dominates, no shooting selection of terms")
    return True


def select(problem: Problem, screen: ParameterScreen, cands: list[AnyCandidate]) -> Selection:
    """Terms by forward selection on top of a full-rank calibration, then the parameter changes pruned to those the
    recordings need; prune terms, the port-gain equivalent, the left-out check, velocities (Stribeck's).  Only the
    calibration where no selection of terms could reach the noise (:func:`_beyond_reach`)."""
    s = Search(problem, screen, list(cands), screen.fit_nominal, problem.nominal_family)
    _start_calibrated(s)
    terms = [k for k in range(len(s.cands)) if not s.cands[k].is_param]
    cols = np.zeros((s.fit.r.size, len(s.cands)))
    usable: list[int] = []
    if terms:
        r, cols_p, cols_o = s.columns(s.fit, s.fam, terms)
        cols[:, terms] = cols_p  # the signatures behind the reported alternatives
        usable = [k for j, k in enumerate(terms)
                  if np.all(np.isfinite(cols_p[:, j])) and np.linalg.norm(cols_p[:, j]) > 0]
        keep = [terms.index(k) for k in usable]
        if _beyond_reach(s, r, cols_o[:, keep]):
            return Selection(s.cands, usable, cols, s.chosen, s.gains, s.fam, s.fit, s.cov)
        _forward(s, r, cols_o[:, keep], usable, {k: j for j, k in enumerate(usable)})
    _prune_parameters(s)
    _prune(s)
    law_look = look_longer(s)
    compensating = _compensating_terms(s)
    sparser = _sparser_parameters(s)
    swap = _port_gain_equivalent(s) or sparser
    validation = law_look + _two_fold_validation(s)
    _refine_velocities(s)
    validation += _sharper_edge(s)
    problem.log(f"selected {[s.cands[k].label for k in s.chosen]}: chi2/dof = {s.fit.chi2_red:.3g}")
    validation += [{"item": label, "kept": False,
                    "note": "only stands in for parameter changes (nonlinear refit without it, "
                  "every pivot free, fits as well)"} for label in compensating]
    icov, dof = s.fit.interval_covariance() if s.chosen else (None, None)
    edge = _edge_shift(s)
    if icov is not None and edge is not None:
        icov = icov + np.diag(edge**2)
    return Selection(s.cands, usable, cols, s.chosen, s.gains, s.fam, s.fit, s.cov, validation, swap, icov,
                     quantile95(dof))


#: how much sharper the edge of :func:`_edge_shift`'s refit is
EDGE_CHECK = 2.0
#: how the reported 95% intervals are computed (report.json: details.intervals)
INTERVALS = ("coefficient +- t_0.975(recordings - 1) x standard error; the standard error the largest of: Gauss-Newton "
             "scaled by chi2/dof, a sandwich clustered on windows, a sandwich clustered on recordings (model error "
             "shared by a recording's windows); with a Coulomb-like term, combined in quadrature with how far each "
             f"value moves when the fits' tanh edges of sign(qdot) on its coordinates are made {EDGE_CHECK:g}x sharper "
             "(the smoothing's own bias)")


def _edge_shift(s: Search) -> np.ndarray | None:
    """(P,) how far every item of the final fit moves when the tanh smoothing of sign(qdot) is made
    :data:`EDGE_CHECK` times sharper on the coordinates of its terms with an edge (Coulomb-like, ``stiff_edge``): the
    fits model a real edge, sharper than theirs, and the coefficient they give carries that bias (on the bench a
    cart's Coulomb friction came out 1-1.5% high, 3 standard errors); the shift bounds it.  One refit; None when no
    chosen term has an edge."""
    coords = {c.coordinate for c in (s.cands[k] for k in s.chosen) if isinstance(c, Candidate)
              and (c.kind.stiff_edge or c.kind.excess_near_rest)}
    if not coords or s.fam.engine is not None:  # MuJoCo's frictionloss has no tanh edge to sharpen
        return None
    eps = list(s.eps or s.problem.eps_coord)
    for i in coords:
        eps[i] /= EDGE_CHECK
    sharper = replace(s.fam, eps=tuple(eps))
    fit = s.screen.shooter.fit(sharper.build, s.fit.X, s.fit.g, max_iter=s.problem.opts.max_iter, stats=False)
    shift = fit.g - s.fit.g
    return np.where(np.isfinite(shift), shift, 0.0)


def quantile95(dof: int | None) -> float:
    """The two-sided 95% quantile: Student's t with ``dof`` degrees of freedom (None: the normal's)."""
    return Z95 if dof is None else float(student_t.ppf(0.975, dof))
