"""Energy balance (weak form) for dissipative terms: robust when model error, not noise, dominates.

Between two turning points a and b of a free (u = 0) oscillation the port-Hamiltonian
power balance (paper Eq. 4, dH/dt = -v^T D v) integrates to

    H(a) - H(b) = sum_k c_k * integral_a^b f_k(q, v) v dt  (+ the calibrated model's own dissipation),

one linear equation per half-cycle.  At turning points v ~ 0, so H is the potential
of the measured q (no differentiation), and the integrals of f_k(v) v are smooth
averages (for Coulomb friction exactly the distance travelled).  Phase, frequency and
measurement-map errors that dominate a trajectory residual barely enter; an
encoder offset is fitted as a nuisance (it shifts H(a) - H(b) by c (V'(q_a) - V'(q_b))), and on angles
so is the even eccentricity of an off-centre encoder (c (1 - cos q), the ``sensor_eccentricity`` map).
Terms are selected by BIC with the *empirical* residual variance and each must have
|t| >= threshold, so a tiny encoder noise does not turn systematic error into
"significance".  ``stribeck_friction`` has a nonlinear parameter, its Stribeck
velocity v_s: it is profiled over a grid (:data:`STRIBECK_GRID`, relative to the
coordinate's rms velocity), at most one v_s per coordinate enters a subset, and BIC
counts v_s as one more parameter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from phast_gym.systems.base import NUMPY, System

from .recordings import Recordings
from .shooting import momentum, smooth
from .terms import friction_basis

DISSIPATIVE = ("viscous_damping", "coulomb_friction", "quadratic_drag", "position_dependent_damping", "stribeck_friction")
#: Stribeck velocities tried, as fractions of the coordinate's rms velocity
STRIBECK_GRID = tuple(0.05 * 2 ** (k / 2) for k in range(7))  # 0.05 ... 0.4, steps of sqrt(2)


def dissipative_basis(name: str, q: np.ndarray, v: np.ndarray, eps: float, vs: float = 0.0) -> np.ndarray:
    """f(q, v) of a dissipative vocabulary term (force = -c f), the model's own law (:func:`.terms.friction_basis`)."""
    return np.asarray(friction_basis(name, q, v, eps, vs, NUMPY))


@dataclass
class EnergyBalance:
    """Result of :func:`energy_balance` (coefficients in the env's force units)."""

    terms: list[dict[str, Any]]  # {"term", "coordinate", "coefficient", "ci95", "t"}
    damping_scale: float  # factor on the calibrated model's own dissipation
    damping_scale_ci95: list[float]
    n_intervals: int
    residual_std: float  # empirical std of the per-half-cycle energy residual [energy units]
    bic: dict[str, float] = field(default_factory=dict)
    screened: dict[str, float] = field(default_factory=dict)  # |t| of each candidate when added alone
    near: list[str] = field(default_factory=list)  # other subsets within 6 BIC units of the chosen one (weakly distinguishable)

    def to_dict(self) -> dict[str, Any]:
        return {"terms": self.terms, "model_damping_scale": self.damping_scale, "model_damping_scale_ci95": self.damping_scale_ci95,
                "n_half_cycles": self.n_intervals, "residual_std": self.residual_std, "bic": self.bic, "screened_abs_t": self.screened,
                "nearly_as_good": self.near}


def _intervals(v: np.ndarray, margin: int, min_len: int) -> list[tuple[int, int]]:
    s = np.sign(v)
    z = np.where((s[:-1] != s[1:]) & (s[:-1] != 0))[0] + 1
    z = z[(z >= margin) & (z < len(v) - margin)]
    return [(int(a), int(b)) for a, b in zip(z[:-1], z[1:]) if b - a >= min_len]


def _energy_state(system: System, rec: Recordings, sg_window: int) -> tuple:
    """Smoothed (q, v) mapped through the inverse sensor map, q components, H, the model's dissipated power, and the
    coordinate whose turning points cut the record into half-cycles."""
    n = rec.n
    qs, vs = smooth(rec.q, rec.dt, sg_window)
    qs = getattr(system, "unmeasure", lambda y: y)(qs)
    p = momentum(system, qs, vs)
    qc = tuple(qs[..., i] for i in range(n))
    pc = tuple(p[..., i] for i in range(n))
    H = np.broadcast_to(system.hamiltonian(qc, pc, NUMPY), qs.shape[:-1])
    P = np.broadcast_to(system.power_balance(qc, pc, None, NUMPY)[0], qs.shape[:-1])
    j = int(np.argmax(np.sqrt(np.mean(vs**2, axis=(0, 1)))))
    return qs, vs, qc, H, P, j


def energy_balance(system: System, rec: Recordings, sg_window: int, eps: float, threshold: float = 3.0,
                   candidates: tuple[str, ...] = DISSIPATIVE, min_intervals: int = 12, max_terms: int = 3,
                   select: bool = True, fixed: tuple[tuple, ...] = ()) -> EnergyBalance | None:
    """Select and fit dissipative terms from the per-half-cycle energy balance of free recordings.

    ``select=False`` fits all ``candidates`` without selection (a diagnostic, e.g. per recording).
    ``fixed``: (term, coordinate, coefficient[, Stribeck velocity]) held at a known value (their energy is subtracted first);
    with ``fixed``, the model's own dissipation is held too (scale 1).
    Returns None when the balance cannot be formed (input u present, too few half-cycles).
    """
    if rec.u is not None and np.any(rec.u != 0):
        return None
    n, dt = rec.n, rec.dt
    qs, vs, qc, H, P_model, j = _energy_state(system, rec, sg_window)
    gradV = np.stack([np.broadcast_to(g, qs.shape[:-1]) for g in system.grad_potential(qc, NUMPY)], -1)
    v_rms = np.sqrt(np.mean(vs**2, axis=(0, 1)))
    cand = [(name, i, 0.0) for i in range(n) for name in candidates if name != "stribeck_friction"
            if not (name == "viscous_damping" and float(np.max(np.abs(P_model))) > 0)]  # own viscous: scaled below
    if "stribeck_friction" in candidates:  # (name, coordinate, v_s) for every v_s of the grid
        cand += [("stribeck_friction", i, float(f * v_rms[i])) for i in range(n) for f in STRIBECK_GRID if v_rms[i] > 0]
    rows, ys, groups = [], [], []
    for tr in range(rec.n_traj):
        for a, b in _intervals(vs[tr, :, j], max(3, sg_window // 2), 4):
            sl = slice(a, b + 1)
            integ = [np.trapezoid(dissipative_basis(nm, qs[tr, sl, i], vs[tr, sl, i], eps, w) * vs[tr, sl, i], dx=dt) for nm, i, w in cand]
            # nuisance: encoder offset (and, on angles, the even eccentricity term c (1 - cos q)) shift H at turning points
            ecc = [gradV[tr, a, i] * (1 - np.cos(qs[tr, a, i])) - gradV[tr, b, i] * (1 - np.cos(qs[tr, b, i])) for i in rec.angle_dims]
            rows.append([np.trapezoid(P_model[tr, sl], dx=dt)] + integ + list(gradV[tr, a] - gradV[tr, b]) + ecc)
            known = sum(c * np.trapezoid(dissipative_basis(nm, qs[tr, sl, i], vs[tr, sl, i], eps, *w) * vs[tr, sl, i], dx=dt)
                        for nm, i, c, *w in fixed)
            if fixed:
                known += rows[-1][0]
                rows[-1][0] = 0.0
            ys.append(H[tr, a] - H[tr, b] - known)
            groups.append(tr)
    if len(ys) < min_intervals:
        return None
    A, y, grp = np.asarray(rows, float), np.asarray(ys, float), np.asarray(groups)
    N = len(y)
    has_model = bool(np.any(A[:, 0] != 0))
    base = ([0] if has_model else []) + list(range(1 + len(cand), A.shape[1]))

    def fit(cols: list[int]) -> tuple[np.ndarray, np.ndarray, float]:
        X = A[:, cols]
        sc = np.linalg.norm(X, axis=0) + 1e-300
        c = np.linalg.lstsq(X / sc, y, rcond=None)[0] / sc
        r = y - X @ c
        rss = float(r @ r)
        s2 = rss / max(N - len(cols), 1)
        XtXi = np.linalg.pinv(X.T @ X)
        cov = s2 * XtXi
        G = np.unique(grp)
        if len(G) >= 3:  # recording-cluster sandwich: half-cycles of one recording share its drifts; keep the wider
            meat = sum(np.outer(X[grp == g].T @ r[grp == g], X[grp == g].T @ r[grp == g]) for g in G)
            cov_cl = len(G) / (len(G) - 1) * XtXi @ meat @ XtXi
            ratio = np.diag(cov_cl) / np.maximum(np.diag(cov), 1e-300)
            cov = cov * max(1.0, float(np.max(ratio)))
        return c, cov, rss

    def n_par(cols: list[int]) -> int:  # a Stribeck term also carries its profiled v_s
        return len(cols) + sum(1 for k in cols if 1 <= k <= len(cand) and cand[k - 1][0] == "stribeck_friction")

    def label(k: int) -> str:
        nm, i, w = cand[k - 1]
        return f"{nm}[{i}]" + (f"(v_s={w:.3g})" if nm == "stribeck_friction" else "")

    def bic(cols: list[int]) -> float:
        return N * math.log(max(fit(cols)[2], 1e-300) / N) + n_par(cols) * math.log(N)

    def ok(cols: list[int], k: int) -> float:
        c, cov, _ = fit(cols)
        t = c[cols.index(k)] / math.sqrt(max(cov[cols.index(k), cols.index(k)], 1e-300))
        return float(t)

    # best subset (the candidate list is short): lowest BIC among subsets whose terms are all positive and significant
    import itertools

    bics = {"model only": bic(base)}
    screened = {label(k): abs(ok(base + [k], k)) for k in range(1, 1 + len(cand))}
    chosen: list[int] = []
    cur = bics["model only"]
    ks = list(range(1, 1 + len(cand)))
    for size in range(1, min(len(ks), max_terms) + 1):
        for sub in itertools.combinations(ks, size):
            coords = [cand[m - 1][1] for m in sub if cand[m - 1][0] == "stribeck_friction"]
            if len(coords) != len(set(coords)):  # one Stribeck velocity per coordinate
                continue
            cols = base + list(sub)
            c = fit(cols)[0]
            if not all(c[cols.index(m)] > 0 and ok(cols, m) >= threshold for m in sub):
                continue
            b = bic(cols)
            bics["+" + "+".join(label(m) for m in sub)] = b
            if b < cur - 2.0 * (n_par(list(sub)) - n_par(chosen)):
                cur, chosen = b, list(sub)
    if select:  # earlier terms must stay significant
        chosen = [k for k in chosen if ok(base + chosen, k) >= threshold]
    else:
        chosen = ks
        if "stribeck_friction" in candidates:  # diagnostic fit: keep only the v_s that fits best alone
            strib = [k for k in ks if cand[k - 1][0] == "stribeck_friction"]
            rest = [k for k in ks if k not in strib]
            best = {}
            for k in strib:
                i = cand[k - 1][1]
                r = fit(base + rest + [k])[2]
                if i not in best or r < best[i][0]:
                    best[i] = (r, k)
            chosen = rest + [k for _, k in best.values()]
    cols = base + chosen
    c, cov, rss = fit(cols)
    scale, scale_ci = 1.0, [1.0, 1.0]
    if has_model:
        scale, sd = float(c[0]), math.sqrt(max(cov[0, 0], 0.0))
        if scale < 0:  # passivity: the calibrated model's own dissipation cannot be negative; drop it
            cols = base[1:] + chosen
            c, cov, rss = fit(cols)
            scale, sd = 0.0, 0.0
        scale_ci = [scale - 1.959964 * sd, scale + 1.959964 * sd]
    terms = []
    for k in chosen:
        m = cols.index(k)
        sd = math.sqrt(max(cov[m, m], 0.0))
        terms.append({"term": cand[k - 1][0], "coordinate": cand[k - 1][1], "coefficient": float(c[m]),
                      "ci95": [float(c[m] - 1.959964 * sd), float(c[m] + 1.959964 * sd)], "t": float(c[m] / max(sd, 1e-300)),
                      **({"velocity": cand[k - 1][2]} if cand[k - 1][0] == "stribeck_friction" else {})})
    best_bics = dict(sorted(bics.items(), key=lambda kv: kv[1])[:8])  # the 8 best subsets, for the report
    chosen_key = "+" + "+".join(label(m) for m in chosen) if chosen else "model only"
    near = [k for k, b in best_bics.items() if k != chosen_key and b < bics.get(chosen_key, cur) + 6.0]
    best_bics.setdefault("model only", bics["model only"])
    return EnergyBalance(terms, scale, [float(x) for x in scale_ci], N, math.sqrt(rss / max(N - len(cols), 1)), best_bics, screened,
                         near)


def energy_check(system: System, rec: Recordings, sg_window: int, min_intervals: int = 4) -> dict[str, Any] | None:
    """Does ``system``'s dissipation account for the energy the recordings lose?  (A check, nothing is fitted.)

    Per half-cycle between turning points, measured loss H(a) - H(b) against the model's
    dissipated energy integral of v^T D v (+ the found friction) dt (paper Eq. 4).  Returns the ratio
    sum(measured) / sum(predicted) with a 95% interval (recording-cluster when there are >= 3
    recordings), and the ratio per recording.  A ratio away from 1 on held-out recordings while it is
    ~1 on the training ones says the dissipation law does not carry over (it changes with amplitude,
    time or conditions in a way the chosen terms do not describe).
    None when the balance cannot be formed (input u, no dissipation, too few half-cycles).
    """
    if rec.u is not None and np.any(rec.u != 0):
        return None
    dt = rec.dt
    _, vs, _, H, P, j = _energy_state(system, rec, sg_window)
    ys, ps, grp = [], [], []
    for tr in range(rec.n_traj):
        for a, b in _intervals(vs[tr, :, j], max(3, sg_window // 2), 4):
            ys.append(H[tr, a] - H[tr, b])
            ps.append(np.trapezoid(P[tr, a:b + 1], dx=dt))
            grp.append(tr)
    y, pr, g = np.asarray(ys), np.asarray(ps), np.asarray(grp)
    if len(y) < min_intervals or not float(np.sum(pr)) > 0:
        return None
    ratio = float(np.sum(y) / np.sum(pr))
    r = y - ratio * pr
    G = np.unique(g)
    if len(G) >= 3:  # ratio estimator, recording-cluster variance
        var = len(G) / (len(G) - 1) * sum(float(np.sum(r[g == k])) ** 2 for k in G) / float(np.sum(pr)) ** 2
    else:
        var = len(y) / max(len(y) - 1, 1) * float(np.sum(r**2)) / float(np.sum(pr)) ** 2
    sd = math.sqrt(max(var, 0.0))
    per = [float(np.sum(y[g == k]) / np.sum(pr[g == k])) if np.sum(pr[g == k]) > 0 else None for k in range(rec.n_traj)]
    return {"measured_over_predicted": ratio, "ci95": [ratio - 1.959964 * sd, ratio + 1.959964 * sd], "per_recording": per,
            "n_half_cycles": int(len(y))}
