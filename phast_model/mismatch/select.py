"""Stage 2, explain: which candidate terms the recordings need (greedy forward selection by shooting).

Each round ranks the remaining candidates by the chi^2 gain of the linearized
shooting problem (window states and current globals projected out; friction
coefficients must come out positive), in the first round also at the nominal
point (calibrated parameters may have absorbed part of a missing term), and
confirms the best few by nonlinear refits.  A term is added when its chi^2 gain
exceeds threshold^2 and |z| / std >= threshold; gains within 2 of each other
prefer the term listed first in the vocabulary.  Earlier terms must stay
significant once later ones are in; a chosen Stribeck term's velocity is refined
by profiling the refit cost in quarter octaves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .calibrate import Calibration
from .candidates import Candidate, Family
from .linear import flat, orth_against
from .options import Z95
from .problem import Problem
from .shooting import ShootFit
from .terms import VOCABULARY

#: refit iterations while confirming a shortlisted candidate (the winner is finished with Options.max_iter)
CONFIRM_ITER = 6


@dataclass
class Selection:
    """Result of :func:`select_terms`."""

    candidates: list[Candidate]  # as screened (a chosen Stribeck term carries its refined velocity)
    usable: list[int]  # indices of candidates not absorbed by the calibrated parameters
    columns: np.ndarray  # (N, len(candidates)) their shooting columns at the calibrated fit, parameters projected out
    absorbed: dict[str, str]  # label -> why the candidate was not screened
    chosen: list[int]  # indices of the selected terms, in fit order
    gains: dict[int, float]  # chi^2 drop when each was added
    family: Family
    fit: ShootFit
    cov: np.ndarray | None  # covariance of fit.g (None when nothing was chosen)

    @property
    def terms(self) -> list[Candidate]:
        return [self.candidates[k] for k in self.chosen]

    @property
    def system(self) -> Any:
        return self.family.build(self.fit.g)


@dataclass
class _Search:
    """Shared state of one selection: the problem, the calibration and the (mutable) current model."""

    problem: Problem
    cal: Calibration
    cands: list[Candidate]
    fit: ShootFit
    fam: Family
    cov: np.ndarray | None = None
    chosen: list[int] = field(default_factory=list)
    gains: dict[int, float] = field(default_factory=dict)

    @property
    def P0(self) -> int:
        return len(self.cal.selected)

    def columns(self, fit: ShootFit, fam: Family, ks: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Residual and candidate columns at ``fit`` with window states and current globals projected out."""
        zc = fit.g
        builds = [(lambda c=self.cands[k]: fam.plus(c).build(np.concatenate([zc, [c.fd_step]]))) for k in ks]
        cols = self.cal.shooter.columns(builds, fit, fit.r, [self.cands[k].fd_step for k in ks])
        r_p, cols_p = fit.projected(cols)
        _, jg_p = fit.projected()
        G = flat(jg_p) if fit.g.size else None
        r_p = r_p.reshape(-1)
        cols_p = flat(cols_p)
        if G is not None:
            r_p = r_p - G @ np.linalg.lstsq(G, r_p, rcond=None)[0]
        return r_p, cols_p, orth_against(cols_p, G)

    def term_ok(self, fit: ShootFit, cov: np.ndarray, j: int, k: int) -> bool:
        """Term j of ``fit`` (candidate k) is significant (|z| / std >= threshold) and of the passive sign."""
        cand = self.cands[k]
        z, sd = fit.g[self.P0 + j], math.sqrt(max(cov[self.P0 + j, self.P0 + j], 1e-300))
        wrong_sign = cand.must_be_positive and cand.coefficient(z) <= 0
        return abs(z) / sd >= self.problem.opts.threshold and not wrong_sign


def _screen(s: _Search) -> tuple[np.ndarray, np.ndarray, list[int], dict[str, str]]:
    """Columns of all candidates at the calibrated fit; those the calibrated parameters absorb are set aside."""
    r, cols, cols_o = s.columns(s.cal.fit, s.cal.family, list(range(len(s.cands))))
    absorbed, usable = {}, []
    for k, cand in enumerate(s.cands):
        n0 = float(np.linalg.norm(cols[:, k]))
        if n0 == 0 or not np.all(np.isfinite(cols[:, k])):
            continue
        if float(np.linalg.norm(cols_o[:, k])) / n0 < 0.05:
            absorbed[cand.label] = f"indistinguishable from the calibrated parameter(s) {[p for p, _ in s.cal.selected]}"
            continue
        usable.append(k)
    return r, cols_o, usable, absorbed


def _nominal_rank(s: _Search, usable: list[int]) -> tuple[list[int], dict[int, np.ndarray]]:
    """The two best candidates ranked at the nominal point, with joint linear starts (parameters and the term)."""
    cal = s.cal
    if not cal.selected or not usable:
        return [], {}
    fitN = cal.fit_nominal
    zN = np.zeros(len(cal.selected))
    builds = [(lambda c=s.cands[k]: cal.family.plus(c).build(np.concatenate([zN, [c.fd_step]]))) for k in usable]
    colsN = flat(fitN.projected(cal.shooter.columns(builds, fitN, fitN.r, [s.cands[k].fd_step for k in usable]))[1])
    rN = flat(fitN.projected(np.zeros(fitN.r.shape + (1,)))[0]).reshape(-1)
    Pm = cal.columns
    rN0 = rN - Pm @ np.linalg.lstsq(Pm, rN, rcond=None)[0]
    colsNo = orth_against(colsN, Pm)
    gains, start = [], {}
    for j, k in enumerate(usable):
        cc = float(colsNo[:, j] @ colsNo[:, j])
        if cc <= 0:
            continue
        gains.append((float(colsNo[:, j] @ rN0) ** 2 / cc, k))
        start[k] = np.linalg.lstsq(np.concatenate([Pm, colsN[:, [j]]], 1), -rN, rcond=None)[0]
    return [k for _, k in sorted(gains, reverse=True)[:2]], start


def _rank(s: _Search, pool: list[int], r_o: np.ndarray, cols_o: np.ndarray, col_of: dict[int, int],
          s2: float) -> list[tuple[float, int, float]]:
    """(chi^2 gain, candidate, linear z) of each candidate of ``pool``, best first."""
    ranked = []
    for k in pool:
        c = cols_o[:, col_of[k]]
        cc = float(c @ c)
        if cc <= 0:
            continue
        z = -float(c @ r_o) / cc
        if s.cands[k].must_be_positive and z <= 0:
            continue  # a friction coefficient must be positive (passivity)
        ranked.append((float(c @ r_o) ** 2 / cc / s2, k, z))
    ranked.sort(reverse=True)
    if s.problem.opts.progress:
        s.problem.log("screening gains (chi^2): " + ", ".join(f"{s.cands[k].label} {g:.3g}" for g, k, _ in ranked[:6]))
    return ranked


def _confirm(s: _Search, shortlist: list[tuple[int, np.ndarray, np.ndarray]], s2: float) -> tuple | None:
    """Nonlinear refit with each shortlisted candidate: the best passing one as (gain, k, fit, family, cov), or None."""
    shooter, thr2, best = s.cal.shooter, s.problem.opts.threshold**2, None
    for k, g0, X_start in shortlist:
        cand = s.cands[k]
        fam_new = s.fam.plus(cand)
        if cand.term == "actuator_deadzone":  # threshold: start from the best of a coarse grid (zero slope at c = 0)
            grid = np.linspace(0.1, 1.5, 15)
            costs = [float(np.sum(shooter.residual(fam_new.build(np.concatenate([g0[:-1], [zz]])), X_start) ** 2)) for zz in grid]
            g0 = np.concatenate([g0[:-1], [grid[int(np.argmin(costs))]]])
        fit_new = shooter.fit(fam_new.build, X_start, g0, max_iter=CONFIRM_ITER)
        cov_new = fit_new.covariance()
        gain = (s.fit.cost - fit_new.cost) / s2
        ok = s.term_ok(fit_new, cov_new, len(s.chosen), k) and gain >= thr2
        if s.problem.opts.progress:
            j = s.P0 + len(s.chosen)
            zz, sd = fit_new.g[j], math.sqrt(max(cov_new[j, j], 1e-300))
            s.problem.log(f"  refit with {cand.label}: chi^2 gain {gain:.3g}, coefficient "
                          f"{cand.coefficient(zz):.4g}, |t| = {abs(zz) / sd:.3g}{'' if ok else ' (rejected)'}")
        # statistically indistinguishable gains (chi^2 within 2): prefer the term listed first in the vocabulary
        if ok and (best is None or gain > best[0] + 2.0
                   or (gain >= best[0] - 2.0 and cand.vocabulary_rank < s.cands[best[1]].vocabulary_rank)):
            best = (gain, k, fit_new, fam_new, cov_new)
    return best


def _forward(s: _Search, r_o: np.ndarray, cols_o: np.ndarray, usable: list[int]) -> None:
    """Greedy forward selection: rank on the linearized problem, confirm the best few by nonlinear refits."""
    opts, thr2 = s.problem.opts, s.problem.opts.threshold**2
    nominal_rank, nominal_start = _nominal_rank(s, usable)
    pool = list(usable)
    col_of = {k: j for j, k in enumerate(pool)}
    while len(s.chosen) < opts.max_terms and pool:
        s2 = s.fit.cost / s.fit.dof
        ranked = _rank(s, pool, r_o, cols_o, col_of, s2)
        shortlist = [(k, np.concatenate([s.fit.g, [z]]), s.fit.X) for g, k, z in ranked[:2] if g >= thr2]
        if not s.chosen:
            shortlist += [(k, nominal_start[k], s.cal.fit_nominal.X) for k in nominal_rank
                          if k not in [kk for kk, _, _ in shortlist] and k in col_of]
        best = _confirm(s, shortlist, s2) if shortlist else None
        if best is None:
            break
        _, k, fit_new, fam_new, cov_new = best
        if fit_new.iterations >= CONFIRM_ITER:  # finish the winner's refit
            fit_new = s.cal.shooter.fit(fam_new.build, fit_new.X, fit_new.g, max_iter=opts.max_iter)
            cov_new = fit_new.covariance()
        s.gains[k] = s.fit.cost - fit_new.cost
        s.chosen.append(k)
        s.fit, s.fam, s.cov = fit_new, fam_new, cov_new
        s.problem.log(f"added {s.cands[k].label}: chi2/dof = {s.fit.chi2_red:.3g} ({s.fit.iterations} it)")
        rest = [kk for kk in pool if kk not in s.chosen]
        if len(s.chosen) < opts.max_terms and rest:
            r_o, cols_o, _ = s.columns(s.fit, s.fam, rest)
            col_of = {kk: j for j, kk in enumerate(rest)}
        pool = rest


def _prune(s: _Search) -> None:
    """Earlier terms must stay significant once later ones are in."""
    if len(s.chosen) <= 1:
        return
    keep_idx = [j for j, k in enumerate(s.chosen) if s.term_ok(s.fit, s.cov, j, k)]
    if len(keep_idx) == len(s.chosen):
        return
    s.chosen = [s.chosen[j] for j in keep_idx]
    s.fam = s.cal.family.with_(terms=[s.cands[k].family_term for k in s.chosen])
    g0 = np.concatenate([s.fit.g[: s.P0], s.fit.g[s.P0:][keep_idx]])
    s.fit = s.cal.shooter.fit(s.fam.build, s.fit.X, g0, max_iter=s.problem.opts.max_iter)
    s.cov = s.fit.covariance()


def _refine_stribeck(s: _Search) -> None:
    """A chosen Stribeck term: its velocity v_s around the grid value (profile of the refit cost, quarter octaves)."""
    for j, k in enumerate(s.chosen):
        if s.cands[k].term != "stribeck_friction":
            continue
        for step in (2**0.5, 2**0.25, 2**0.125):
            best = (s.fit.cost, s.cands[k], s.fit, s.fam)
            for f in (1 / step, step):
                c_new = s.cands[k].with_velocity(s.cands[k].velocity * f)
                fam_v = s.fam.with_(terms=[c_new.family_term if jj == j else t for jj, t in enumerate(s.fam.terms)])
                fit_v = s.cal.shooter.fit(fam_v.build, s.fit.X, s.fit.g, max_iter=CONFIRM_ITER)
                if fit_v.cost < best[0]:
                    best = (fit_v.cost, c_new, fit_v, fam_v)
            _, s.cands[k], s.fit, s.fam = best
        s.cov = s.fit.covariance()
        s.problem.log(f"Stribeck velocity refined: {s.cands[k].label}, chi2/dof = {s.fit.chi2_red:.3g}")


def select_terms(problem: Problem, cal: Calibration, cands: list[Candidate]) -> Selection:
    """Screen ``cands`` at the calibrated fit, select terms greedily, prune, refine Stribeck velocities."""
    s = _Search(problem, cal, list(cands), cal.fit, cal.family)
    r, cols_o, usable, absorbed = _screen(s)
    _forward(s, r, cols_o, usable)
    _prune(s)
    _refine_stribeck(s)
    problem.log(f"augmented with {[s.cands[k].label for k in s.chosen]}: chi2/dof = {s.fit.chi2_red:.3g}")
    return Selection(s.cands, usable, cols_o, absorbed, s.chosen, s.gains, s.fam, s.fit, s.cov)


# --------------------------------------------------------------------------- report rows
def calibrated_rows(problem: Problem, cal: Calibration, sel: Selection) -> dict[str, dict[str, Any]]:
    """report.sim.calibrated: fitted parameters with 95% intervals (from the augmented fit when terms were added),
    then the parameters held at nominal with the reason."""
    covC = cal.fit.covariance()
    g_src, cov_src = (sel.fit.g, sel.cov) if sel.chosen and sel.cov is not None else (cal.fit.g, covC)
    out: dict[str, dict[str, Any]] = {}
    for j, (k, nom) in enumerate(cal.selected):
        z, sd = g_src[j], math.sqrt(max(cov_src[j, j], 0.0))
        out[k] = {"nominal": nom, "fitted": nom * math.exp(z), "ci95": [nom * math.exp(z - Z95 * sd), nom * math.exp(z + Z95 * sd)],
                  "relative_change": math.exp(z) - 1.0}
    for k, note in cal.notes.items():
        out.setdefault(k, {"nominal": problem.sys0.params[k], "fitted": problem.sys0.params[k], "ci95": None, "note": note})
    return out


def _alternatives(cal: Calibration, sel: Selection, k: int, z: float, c: float) -> list[dict[str, Any]]:
    """Candidates with (>= 97% cosine) the same signature as candidate k, and parameters equivalent to an actuator gain."""
    cands, cols = sel.candidates, sel.columns
    alts = []
    ck = cols[:, k]
    for kk in sel.usable:
        if kk == k or cands[kk].key == cands[k].key:  # (the same term at another Stribeck velocity)
            continue
        ca = cols[:, kk]
        cos = float(ck @ ca) / (np.linalg.norm(ck) * np.linalg.norm(ca) + 1e-300)
        if abs(cos) > 0.97:
            za = z * float(ca @ ck) / float(ca @ ca)
            alts.append({"term": cands[kk].term, "coordinate": cands[kk].coordinate, "coefficient": cands[kk].coefficient(za),
                         "similarity": round(abs(cos), 4)})
    if cands[k].term == "actuator_gain":
        for p, note in cal.notes.items():
            if "actuator_gain" in note:
                alts.append({"parameter": p, "note": f"a {p} change is exactly equivalent with u (scale {p} by about {1.0 / c:.4g})"})
    return alts


def missing_rows(cal: Calibration, sel: Selection) -> list[dict[str, Any]]:
    """report.missing_physics: each selected term with its coefficient, 95% interval, share of the excess chi^2 it
    explains and its non-identifiable alternatives."""
    P0 = len(cal.selected)
    excess0 = max(cal.fit.cost - cal.fit.dof, 1e-300)
    out = []
    for j, k in enumerate(sel.chosen):
        cand = sel.candidates[k]
        z = sel.fit.g[P0 + j]
        sd = math.sqrt(max(sel.cov[P0 + j, P0 + j], 0.0))
        lo, hi = sorted([cand.coefficient(z - Z95 * sd), cand.coefficient(z + Z95 * sd)])
        term = cand.family_term.at(z)
        out.append({"term": cand.term, "coordinate": cand.coordinate, "component": VOCABULARY[cand.term][0],
                    "coefficient": term.coefficient, "ci95": [lo, hi],
                    **({"stribeck_velocity": term.velocity} if cand.term == "stribeck_friction" else {}),
                    "expression": term.expression(), "explains": float(min(1.0, sel.gains.get(k, 0.0) / excess0)),
                    "alternatives": _alternatives(cal, sel, k, z, term.coefficient)})
    return out

