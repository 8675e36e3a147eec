"""Friction from q-only recordings: a non-parametric friction curve, weak-form law fits and law selection by prediction.

The momentum balance of a port-Hamiltonian model, d/dt p = F_cons(q, p) + u - f(q, qdot), with F_cons = -dH/dq and
f the *total* dissipative generalized force (the model's own D(q) qdot plus whatever it leaves out), is used in
weak form: one smooth filter (cubic Savitzky-Golay, window ``window`` samples) is applied to both sides,

    f~(t) = [S * (F_cons + u)](t) - d/dt [S * p](t),

so the noisy second derivative of q never appears alone and a law's force is compared after the *same* filter
(``S * f_law``).  p = M(q) qdot through the system's own mass matrix (:func:`.shooting.momentum`), q and qdot from the
same filter, u the recorded port force held over each interval.  Everything here is per coordinate (friction is
diagonal, as in the vocabulary).

* :func:`friction_curve`: the total friction force f~ (sign convention: positive = opposes motion, i.e. f~ sign(qdot))
  averaged in speed bands, with block-bootstrap 95% intervals (resampling whole time blocks / recordings, since
  samples in a band are time-correlated), and the model's own dissipative force in the same bands.
* :func:`fit_law`: least squares of f~ - S*(own) on S*(basis) of vocabulary terms (:func:`.terms.friction_basis`),
  coefficients sign-free, cluster-robust 95% intervals; a Stribeck velocity is profiled on a grid.
* :func:`is_passive`: the *total* force (own + law) opposes motion at every speed up to the largest observed one
  (a negative coefficient is allowed when the total stays passive; it is named).
* :func:`check_against_curve`: band by band, is the law inside the curve's interval?
* :func:`select_law`: candidate laws (subsets of up to 3 terms per coordinate), each fitted on all training
  recordings but one and scored on the left-out one (default: by how well it predicts the left-out recording's
  friction curve; rollout criteria are available), with a paired one-standard-error parsimony rule over the folds.
  Laws that are not passive over the observed speeds, or with a coefficient not distinguishable from zero, are not
  chosen.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from scipy.signal import savgol_filter
from scipy.stats import t as student_t

from phast_gym.systems import angle_diff
from phast_gym.systems.base import NUMPY, System

from .recordings import Recordings
from .shooting import _odd, estimate_noise, momentum, smooth, time_scale
from .terms import AugmentedSystem, Term, friction_basis

#: dissipative vocabulary terms a law is built from
LAW_TERMS = ("viscous_damping", "coulomb_friction", "quadratic_drag", "position_dependent_damping", "stribeck_friction")
#: Stribeck velocities tried, as fractions of the coordinate's rms speed (log grid).  Stribeck friction is the excess
#: friction near rest; a "Stribeck" term whose v_s reaches the typical speed is a curve-fitting device, not that effect
#: (on the real pendulum such terms fit segments 1-4 as well as physical laws and predict held-out swings erratically).
STRIBECK_FRACTIONS = tuple(float(x) for x in np.geomspace(0.03, 0.3, 7))
#: parameters a term costs in the parsimony rule (a Stribeck term carries its v_s)
_COST = {"stribeck_friction": 2}
_SHORT = {"viscous_damping": "viscous", "coulomb_friction": "coulomb", "quadratic_drag": "quadratic",
          "position_dependent_damping": "position_dependent", "stribeck_friction": "stribeck"}


# --------------------------------------------------------------------------- weak form
@dataclass
class WeakForm:
    """Filtered momentum balance of recordings under a system (edges of the filter trimmed).

    Arrays are (N, T', n): ``qs``, ``vs`` the smoothed state, ``total`` the filtered total dissipative force f~
    (positive along +qdot means it decelerates +qdot motion), ``own`` the filtered dissipative force of the model
    itself (D(q) qdot plus the friction terms of an :class:`AugmentedSystem`).  ``blocks`` (N, T') cluster labels."""

    qs: np.ndarray
    vs: np.ndarray
    total: np.ndarray
    own: np.ndarray
    blocks: np.ndarray
    window: int
    dt: float
    eps: float
    trim: int
    q_raw: np.ndarray = field(repr=False)  # (N, T, n) smoothed untrimmed (for filtering law forces)
    v_raw: np.ndarray = field(repr=False)

    @property
    def n(self) -> int:
        return self.qs.shape[2]

    def filt(self, x: np.ndarray) -> np.ndarray:
        """The weak-form filter S along time of an untrimmed (N, T, ...) array, then trimmed."""
        y = savgol_filter(x, self.window, 3, axis=1, mode="interp")
        return y[:, self.trim: x.shape[1] - self.trim]

    def basis(self, name: str, i: int, vs_: float = 0.0) -> np.ndarray:
        """S * f(q_i, qdot_i) of a vocabulary term, (N, T')."""
        return self.filt(np.asarray(friction_basis(name, self.q_raw[..., i], self.v_raw[..., i], self.eps, vs_, NUMPY)))


def _own_dissipation(system: System, qc: tuple, v: np.ndarray) -> np.ndarray:
    """The model's dissipative force (positive opposes motion): D(q) qdot (+ friction terms of an AugmentedSystem)."""
    shape = v.shape[:-1]
    d = system.damping(qc, NUMPY)
    own = np.stack([np.broadcast_to(np.asarray(d[i], dtype=float), shape) * v[..., i] for i in range(v.shape[-1])], -1)
    if isinstance(system, AugmentedSystem):
        extra = system.extra_dissipation(qc, tuple(v[..., i] for i in range(v.shape[-1])), NUMPY)
        own = own - np.stack([np.broadcast_to(np.asarray(e, dtype=float), shape) for e in extra], -1)
    return own


def default_window(rec: Recordings) -> int:
    """Filter window [samples]: 0.15 of an oscillation period, as the mismatch tool smooths (>= 7)."""
    period = 2 * math.pi * time_scale(rec.q, rec.dt)
    return _odd(max(7, int(round(0.15 * period / rec.dt))))


def default_eps(rec: Recordings, window: int) -> float:
    """tanh smoothing of sign(qdot): 0.005 x the median rms speed (the mismatch tool's ``coulomb_eps_rel``)."""
    _, vs = smooth(rec.q, rec.dt, window)
    return float(0.005 * np.median(np.sqrt(np.mean(vs**2, axis=(0, 1)))) + 1e-12)


def _block_labels(N: int, T: int, block: int) -> np.ndarray:
    """(N, T) cluster label: recording x consecutive time block of ``block`` samples (a short tail joins the last)."""
    nb = max(1, T // max(block, 1))
    b = np.minimum(np.arange(T) // max(block, 1), nb - 1)
    return np.arange(N)[:, None] * nb + b[None, :]


@dataclass
class Balance:
    """The momentum balance along the smoothed recordings, untrimmed (N, T, n): q, qdot, d/dt S*p and the model's pdot."""

    qs: np.ndarray
    vs: np.ndarray
    dp: np.ndarray
    pdot: np.ndarray

    @property
    def qc(self) -> tuple:
        return tuple(self.qs[..., i] for i in range(self.qs.shape[-1]))


def momentum_balance(system: System, rec: Recordings, window: int) -> Balance:
    """Smoothed q, qdot (measurement map undone), d/dt of the filtered momentum p = M(q) qdot, and the model's pdot
    (conservative, port and dissipative force) at those states with the recorded u held per interval."""
    n, dt = rec.n, rec.dt
    qs, vs = smooth(rec.q, dt, window)
    qs = getattr(system, "unmeasure", lambda y: y)(qs)
    p = momentum(system, qs, vs)
    dp = savgol_filter(p, window, 3, deriv=1, delta=dt, axis=1, mode="interp")
    u = None
    if rec.u is not None:
        uu = np.concatenate([rec.u, rec.u[:, -1:]], axis=1)
        u = tuple(uu[..., i] for i in range(n))
    qc, pc = tuple(qs[..., i] for i in range(n)), tuple(p[..., i] for i in range(n))
    pdot = np.stack([np.broadcast_to(f, qs.shape[:-1]) for f in system.rhs(qc, pc, u, NUMPY)[1]], -1)
    return Balance(qs, vs, dp, pdot)


def weak_form(system: System, rec: Recordings, window: int | None = None, eps: float | None = None,
              block: int | None = None) -> WeakForm:
    """The filtered momentum balance of ``rec`` under ``system`` (see the module docstring).

    ``block``: cluster length [samples] for intervals (default: the larger of 2 oscillation periods and 5 windows;
    each recording is cut into such blocks; with many recordings one may pass ``block=rec.T`` for recording clusters)."""
    window = _odd(window or default_window(rec))
    window = min(window, _odd(rec.T // 3))
    eps = float(eps if eps is not None else (system.coulomb_eps if isinstance(system, AugmentedSystem) else default_eps(rec, window)))
    dt = rec.dt
    bal = momentum_balance(system, rec, window)
    qs, vs, dp = bal.qs, bal.vs, bal.dp
    own = _own_dissipation(system, bal.qc, vs)
    cons = bal.pdot + own  # conservative + port force (the model's dissipation added back)
    tr = window // 2
    sl = slice(tr, rec.T - tr)
    total = savgol_filter(cons, window, 3, axis=1, mode="interp")[:, sl] - dp[:, sl]
    own_f = savgol_filter(own, window, 3, axis=1, mode="interp")[:, sl]
    if block is None:
        period = 2 * math.pi * time_scale(rec.q, dt)
        block = max(int(round(2 * period / dt)), 5 * window)
    Tt = rec.T - 2 * tr
    return WeakForm(qs[:, sl], vs[:, sl], total, own_f, _block_labels(rec.n_traj, Tt, int(block)), window, dt, eps, tr, qs, vs)


# --------------------------------------------------------------------------- the curve
@dataclass
class FrictionBand:
    """One speed band of one coordinate: the mean total friction force there (positive = opposes motion)."""

    coordinate: int
    direction: str  # "both" (odd-symmetric average), "+" or "-" (qdot > 0 / < 0)
    speed_lo: float
    speed_hi: float
    speed_mean: float
    force: float
    ci95: tuple[float, float]
    model_force: float  # the calibrated model's own dissipative force in the band, same filter
    n_samples: int
    n_blocks: int

    @property
    def missing(self) -> float:
        """What the model leaves out in this band (force - model_force)."""
        return self.force - self.model_force


@dataclass
class FrictionCurve:
    """Non-parametric friction curve: total dissipative generalized force vs |qdot|, per coordinate, with 95% intervals.

    ``quantity`` says what is averaged.  The weak form it was computed from is kept (``weak``, not serialized) so that
    :func:`check_against_curve` can pass a law through the same filter and bands."""

    bands: list[FrictionBand]
    quantity: str
    filter: dict[str, Any]
    interval: str
    max_speed: list[float]  # per coordinate, largest |qdot| of the smoothed recordings
    n_recordings: int
    weak: WeakForm | None = field(default=None, repr=False)
    band_index: list[np.ndarray] = field(default_factory=list, repr=False)  # per band: boolean mask over weak samples

    def coordinate(self, i: int, direction: str = "both") -> list[FrictionBand]:
        return [b for b in self.bands if b.coordinate == i and b.direction == direction]

    def to_dict(self) -> dict[str, Any]:
        return {"quantity": self.quantity, "filter": self.filter, "interval": self.interval, "max_speed": self.max_speed,
                "n_recordings": self.n_recordings,
                "bands": [{**asdict(b), "ci95": list(b.ci95), "missing": b.missing} for b in self.bands]}

    def table(self) -> str:
        rows = ["| coord | dir | |qdot| band | force [95% CI] | model's own | missing |", "|---|---|---|---|---|---|"]
        for b in self.bands:
            rows.append(f"| {b.coordinate} | {b.direction} | {b.speed_lo:.3g}-{b.speed_hi:.3g} | {b.force:.4g} "
                        f"[{b.ci95[0]:.4g}, {b.ci95[1]:.4g}] | {b.model_force:.4g} | {b.missing:.4g} |")
        return "\n".join(rows)


def _edges(speed: np.ndarray, bands: int | str | Sequence[float], n_bands: int) -> np.ndarray:
    if not isinstance(bands, str) and not isinstance(bands, int):
        return np.asarray(bands, dtype=float)
    k = bands if isinstance(bands, int) else n_bands
    hi = float(np.max(speed))
    if bands == "log":
        lo = max(float(np.quantile(speed, 0.02)), 1e-3 * hi)
        e = np.geomspace(lo, hi, k + 1)
        e[0] = 0.0
        return e
    e = np.quantile(speed, np.linspace(0, 1, k + 1))
    e[-1] = hi * (1 + 1e-12)
    return e


def _boot_ratio(num: np.ndarray, den: np.ndarray, rng: np.random.Generator, n_boot: int) -> tuple[float, tuple[float, float]]:
    """Ratio estimate sum(num)/sum(den) over clusters with a cluster-bootstrap percentile 95% interval."""
    G = len(num)
    est = float(num.sum() / max(den.sum(), 1e-300))
    if G < 2:
        return est, (float("nan"), float("nan"))
    w = rng.multinomial(G, np.full(G, 1.0 / G), size=n_boot).astype(float)
    d = w @ den
    r = (w @ num)[d > 0] / d[d > 0]
    lo, hi = np.quantile(r, [0.025, 0.975])
    return est, (float(lo), float(hi))


def friction_curve(system: System, rec: Recordings, window: int | None = None, bands: int | str | Sequence[float] = "quantile",
                   n_bands: int = 8, directions: bool = False, eps: float | None = None, block: int | None = None,
                   n_boot: int = 2000, seed: int = 0, min_speed: float = 0.0) -> FrictionCurve:
    """Total friction force (the model's own dissipation plus what it leaves out) vs |qdot|, per coordinate.

    ``bands``: "quantile" (equal sample counts, default), "log" (log-spaced), an int (quantile bands) or explicit
    edges in |qdot|.  ``directions=True`` adds the qdot > 0 and qdot < 0 halves separately (direction "+" / "-").
    Intervals: percentile bootstrap over clusters (time blocks of each recording, see :func:`weak_form`); the band
    value is a ratio estimate sum(f sign(qdot)) / count over the band.  Samples with |qdot| < ``min_speed`` are left out."""
    wf = weak_form(system, rec, window, eps, block)
    rng = np.random.default_rng(seed)
    out: list[FrictionBand] = []
    masks: list[np.ndarray] = []
    labels = wf.blocks
    G = int(labels.max()) + 1
    for i in range(wf.n):
        v = wf.vs[..., i]
        s = np.sign(v)
        sp = np.abs(v)
        keep = sp >= min_speed
        e = _edges(sp[keep], bands, n_bands)
        dirs = [("both", np.ones_like(keep))] + ([("+", v > 0), ("-", v < 0)] if directions else [])
        for dname, dm in dirs:
            for a, b in zip(e[:-1], e[1:]):
                m = keep & dm & (sp >= a) & (sp < b)
                if not np.any(m):
                    continue
                num = np.bincount(labels[m], weights=(wf.total[..., i] * s)[m], minlength=G)
                den = np.bincount(labels[m], minlength=G).astype(float)
                own = float(np.sum((wf.own[..., i] * s)[m]) / m.sum())
                est, ci = _boot_ratio(num, den, rng, n_boot)
                out.append(FrictionBand(i, dname, float(a), float(b), float(sp[m].mean()), est, ci, own, int(m.sum()),
                                        int(np.sum(den > 0))))
                masks.append(m)
    blk = int(np.bincount(labels[0]).max()) if labels.size else 0
    return FrictionCurve(out, "total dissipative generalized force f = S*(F_cons + u) - d/dt S*p, times sign(qdot) "
                         "(positive opposes motion; includes the model's own dissipation, listed as model_force)",
                         {"kind": "savitzky-golay cubic, same on both sides", "window_samples": wf.window, "dt": wf.dt,
                          "coulomb_eps": wf.eps},
                         f"95% percentile bootstrap over {G} clusters (time blocks of {blk} samples within each recording)",
                         [float(np.max(np.abs(wf.vs[..., i]))) for i in range(wf.n)], int(rec.n_traj), wf, masks)


# --------------------------------------------------------------------------- laws
@dataclass
class LawTerm:
    """One fitted term: coefficient (sign free) of the force -c f(q, qdot) *added* to the model's own dissipation."""

    term: str
    coordinate: int
    coefficient: float
    ci95: tuple[float, float]
    velocity: float = 0.0  # Stribeck v_s
    t_quantile: float = 1.959964  # the quantile the 95% interval was built with

    def to_term(self) -> Term:
        return Term(self.term, self.coordinate, self.coefficient, self.velocity)

    @property
    def excludes_zero(self) -> bool:
        return self.ci95[0] * self.ci95[1] > 0

    @property
    def t(self) -> float:
        """coefficient / standard error (from the 95% interval's half width and its t quantile)."""
        return self.coefficient / max((self.ci95[1] - self.ci95[0]) / 2 / self.t_quantile, 1e-300)


@dataclass
class FrictionLaw:
    """A friction law: vocabulary terms added to the model's own dissipation (total = own + sum of terms).

    ``own_samples`` per coordinate: (q_i, D_ii(q) ) at observed states, for the passivity check of the total force."""

    terms: list[LawTerm]
    eps: float
    n: int
    rss: float = float("nan")
    n_obs: int = 0
    interval: str = ""
    own_samples: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list, repr=False)
    own_terms: list[Term] = field(default_factory=list, repr=False)  # friction terms the system already has (AugmentedSystem)

    @property
    def name(self) -> str:
        if not self.terms:
            return "model only"
        return " + ".join(f"{_SHORT[t.term]}[{t.coordinate}]" + (f"(v_s={t.velocity:.3g})" if t.term == "stribeck_friction" else "")
                          for t in self.terms)

    @property
    def n_params(self) -> int:
        return sum(_COST.get(t.term, 1) for t in self.terms)

    def force(self, i: int, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The law's added force on coordinate i (positive opposes +qdot), unfiltered."""
        f = np.zeros(np.broadcast(q, v).shape)
        for t in self.terms:
            if t.coordinate == i:
                f = f + t.coefficient * np.asarray(friction_basis(t.term, q, v, self.eps, t.velocity, NUMPY))
        return f

    def augmented(self, system: System) -> AugmentedSystem:
        """``system`` plus the law's terms (an AugmentedSystem's own terms are kept)."""
        terms = [t.to_term() for t in self.terms]
        if isinstance(system, AugmentedSystem):
            return AugmentedSystem(system.base, list(system.terms) + terms, self.eps, system.deadzone_width)
        return AugmentedSystem(system, terms, self.eps)

    def to_dict(self) -> dict[str, Any]:
        return {"law": self.name, "terms": [{**asdict(t), "ci95": list(t.ci95)} for t in self.terms], "coulomb_eps": self.eps,
                "rss": self.rss, "n_obs": self.n_obs, "interval": self.interval,
                "every_ci_excludes_zero": all(t.excludes_zero for t in self.terms)}


Spec = tuple  # (name, coordinate) or ("stribeck_friction", coordinate, v_s or None)


def _own_samples(system: System, wf: WeakForm, k: int = 64) -> list[tuple[np.ndarray, np.ndarray]]:
    q = wf.qs.reshape(-1, wf.n)
    idx = np.unique(np.linspace(0, len(q) - 1, min(k, len(q))).round().astype(int))
    q = q[idx]
    d = system.damping(tuple(q[:, i] for i in range(wf.n)), NUMPY)
    own = []
    for i in range(wf.n):
        di = np.broadcast_to(np.asarray(d[i], dtype=float), (len(q),)).copy()
        own.append((q[:, i].copy(), di))
    return own


def _own_terms(system: System) -> list[Term]:
    return [t for t in getattr(system, "terms", ()) if t.component == "dissipation"] if isinstance(system, AugmentedSystem) else []


def _cluster_cov(X: np.ndarray, r: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, int]:
    XtXi = np.linalg.pinv(X.T @ X)
    G = np.unique(g)
    s = np.stack([X[g == k].T @ r[g == k] for k in G]) if len(G) else np.zeros((0, X.shape[1]))
    meat = s.T @ s
    n, p = X.shape
    corr = len(G) / max(len(G) - 1, 1) * (n - 1) / max(n - p, 1)
    return corr * XtXi @ meat @ XtXi, len(G)


def _design(wf: WeakForm, specs: Sequence[Spec], cache: dict | None = None) -> np.ndarray:
    cols = []
    for s in specs:
        key = (s[0], s[1], s[2] if len(s) > 2 else 0.0)
        if cache is not None and key in cache:
            cols.append(cache[key])
            continue
        c = wf.basis(s[0], s[1], key[2])
        if cache is not None:
            cache[key] = c
        cols.append(c)
    return np.stack(cols, -1) if cols else np.zeros(wf.qs.shape[:2] + (0,))


def _fit(wf: WeakForm, specs: Sequence[Spec], rows: np.ndarray | None,
         cache: dict | None) -> tuple[np.ndarray, np.ndarray, float, int, int]:
    """(coefficients, covariance, rss, n_obs, clusters) of a fixed-v_s law; ``rows`` (N,) recordings used."""
    coef, cov, rss, nobs, G = [], [], 0.0, 0, 0
    specs = list(specs)
    sel = slice(None) if rows is None else rows
    X_all = _design(wf, specs, cache)[sel]
    g = wf.blocks[sel]
    for i in range(wf.n):
        y = (wf.total[..., i] - wf.own[..., i])[sel].reshape(-1)
        idx = [k for k, s in enumerate(specs) if s[1] == i]
        if not idx:
            rss += float(y @ y)
            nobs += y.size
            continue
        X = X_all[..., idx].reshape(-1, len(idx))
        sc = np.linalg.norm(X, axis=0) + 1e-300
        c = np.linalg.lstsq(X / sc, y, rcond=None)[0] / sc
        r = y - X @ c
        V, G = _cluster_cov(X, r, g.reshape(-1))
        coef.append((idx, c))
        cov.append((idx, V))
        rss += float(r @ r)
        nobs += y.size
    C = np.zeros(len(specs))
    Vfull = np.zeros((len(specs), len(specs)))
    for (idx, c), (_, V) in zip(coef, cov):
        C[idx] = c
        Vfull[np.ix_(idx, idx)] = V
    return C, Vfull, rss, nobs, G


def _vs_grid(wf: WeakForm, i: int) -> list[float]:
    v_rms = float(np.sqrt(np.mean(wf.vs[..., i] ** 2)))
    return [f * v_rms for f in STRIBECK_FRACTIONS]


def _fit_law(wf: WeakForm, specs: Sequence[Spec], rows: np.ndarray | None = None, cache: dict | None = None,
             own: list | None = None, own_terms: Sequence[Term] = ()) -> FrictionLaw:
    """Fit, profiling any Stribeck velocity left None over the grid (lowest weak-form rss)."""
    specs = [tuple(s) for s in specs]
    free = [k for k, s in enumerate(specs) if s[0] == "stribeck_friction" and (len(s) < 3 or s[2] is None)]
    choices = [[(k, v) for v in _vs_grid(wf, specs[k][1])] for k in free]
    best = None
    for combo in itertools.product(*choices) if choices else [()]:
        sp = list(specs)
        for k, v in combo:
            sp[k] = ("stribeck_friction", specs[k][1], v)
        res = _fit(wf, sp, rows, cache)
        if best is None or res[2] < best[1][2]:
            best = (sp, res)
    sp, (C, V, rss, nobs, G) = best
    tq = float(student_t.ppf(0.975, max(G - 1, 1)))
    terms = []
    for k, s in enumerate(sp):
        sd = math.sqrt(max(V[k, k], 0.0))
        terms.append(LawTerm(s[0], int(s[1]), float(C[k]), (float(C[k] - tq * sd), float(C[k] + tq * sd)),
                             float(s[2]) if len(s) > 2 and s[2] is not None else 0.0, tq))
    interval = (f"cluster-robust (CR1) over {G} clusters (time blocks within recordings), t({G - 1}) quantile"
                + ("; conditional on the profiled Stribeck velocity" if free else ""))
    return FrictionLaw(terms, wf.eps, wf.n, rss, nobs, interval, own or [], list(own_terms or []))


def _parse_terms(terms: Sequence[Any], n: int) -> list[Spec]:
    """Accept ("coulomb_friction", 0), ("stribeck_friction", 0, v_s|None), Term objects, or bare names (coordinate 0 .. n-1)."""
    out: list[Spec] = []
    for t in terms:
        if isinstance(t, Term):
            out.append((t.name, t.coordinate) + ((t.velocity,) if t.name == "stribeck_friction" else ()))
        elif isinstance(t, str):
            out += [(t, i) for i in range(n)]
        else:
            out.append(tuple(t))
    for s in out:
        if s[0] not in LAW_TERMS:
            raise ValueError(f"{s[0]!r} is not a dissipative vocabulary term; use one of {LAW_TERMS}")
    return out


def fit_law(system: System, rec: Recordings, terms: Sequence[Any], window: int | None = None, eps: float | None = None,
            block: int | None = None, weak: WeakForm | None = None) -> FrictionLaw:
    """Weak-form force-balance least squares of a friction law, coefficients sign free.

    ``terms``: (name, coordinate) pairs, ("stribeck_friction", i, v_s) (v_s None: profiled on a grid of fractions
    of the rms speed), :class:`.terms.Term` objects, or bare names (every coordinate).  The law is *added* to the
    model's own dissipation: a negative viscous coefficient lowers the model's damping.  95% intervals are
    cluster-robust over time blocks within recordings (see :func:`weak_form`)."""
    wf = weak or weak_form(system, rec, window, eps, block)
    return _fit_law(wf, _parse_terms(terms, rec.n), cache={}, own=_own_samples(system, wf), own_terms=_own_terms(system))


# --------------------------------------------------------------------------- passivity and the curve check
@dataclass
class Passivity:
    passive: bool
    per_coordinate: list[dict[str, Any]]  # {"coordinate", "passive", "max_speed", "worst_speed", "min_force", "negative_terms"}

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def is_passive(law: FrictionLaw, speeds: float | Sequence[float] | FrictionCurve, n_grid: int = 400, tol: float = 0.0) -> Passivity:
    """Does the *total* dissipative force (model's own D(q) qdot + the law) oppose motion at every speed up to the
    largest observed one?  Checked on a grid of speeds (log-spaced from eps/100 and linear, both directions) at the
    observed positions (the law's ``own_samples``; |sin q| and D(q) enter through them).  ``speeds``: max |qdot| per
    coordinate, one float for all, or a :class:`FrictionCurve`.  Names the negative terms of a passive combination."""
    if isinstance(speeds, FrictionCurve):
        vmax = list(speeds.max_speed)
    elif np.ndim(speeds) == 0:
        vmax = [float(speeds)] * law.n
    else:
        vmax = [float(s) for s in speeds]
    per = []
    for i in range(law.n):
        vm = vmax[i]
        grid = np.unique(np.concatenate([np.geomspace(max(law.eps * 1e-2, vm * 1e-6), vm, n_grid), np.linspace(0, vm, n_grid)[1:]]))
        v = np.concatenate([grid, -grid])
        if law.own_samples:
            qi, di = law.own_samples[i]
        else:
            qi, di = np.array([0.0, math.pi / 2]), np.zeros(2)
        Q, Vv = np.meshgrid(qi, v, indexing="ij")
        total = di[:, None] * Vv + law.force(i, Q, Vv)
        for t in law.own_terms:
            if t.coordinate == i:
                total = total + t.coefficient * np.asarray(friction_basis(t.name, Q, Vv, law.eps, t.velocity, NUMPY))
        power = total * np.sign(Vv)  # force along the motion's opposite direction
        k = np.unravel_index(int(np.argmin(power)), power.shape)
        ok = bool(power[k] >= -tol)
        neg = [f"{_SHORT[t.term]}[{i}]" for t in law.terms if t.coordinate == i and t.coefficient < 0]
        per.append({"coordinate": i, "passive": ok, "max_speed": vm, "worst_speed": float(abs(Vv[k])), "min_force": float(power[k]),
                    "negative_terms": neg})
    return Passivity(all(p["passive"] for p in per), per)


def law_band_forces(law: FrictionLaw, curve: FrictionCurve) -> list[float]:
    """The total force of ``law`` (model's own + law) in each band of ``curve``, through the curve's filter."""
    wf = curve.weak
    if wf is None:
        raise ValueError("this FrictionCurve carries no weak form (built from a dict?); recompute it with friction_curve")
    out = []
    cache: dict[int, np.ndarray] = {}
    for b, m in zip(curve.bands, curve.band_index):
        i = b.coordinate
        if i not in cache:
            cache[i] = wf.filt(law.force(i, wf.q_raw[..., i], wf.v_raw[..., i])) + wf.own[..., i]
        s = np.sign(wf.vs[..., i])
        out.append(float(np.sum((cache[i] * s)[m]) / max(m.sum(), 1)))
    return out


def check_against_curve(law: FrictionLaw, curve: FrictionCurve) -> list[dict[str, Any]]:
    """Band by band: is the law's total force (same filter, same samples) inside the curve's 95% interval?"""
    vals = law_band_forces(law, curve)
    return [{"coordinate": b.coordinate, "direction": b.direction, "band": [b.speed_lo, b.speed_hi], "curve": b.force,
             "ci95": list(b.ci95), "law": v, "inside": bool(b.ci95[0] <= v <= b.ci95[1])} for b, v in zip(curve.bands, vals)]


def plot_friction_curve(curve: FrictionCurve, laws: dict[str, FrictionLaw] | Sequence[FrictionLaw] | None, path: str) -> str:
    """Curve (bands with 95% intervals, and the model's own force) per coordinate, with candidate laws overlaid
    (through the same filter and bands, and as their unfiltered force vs speed).  Writes a PNG (matplotlib Agg)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if laws is None:
        laws = {}
    if not isinstance(laws, dict):
        laws = {lw.name: lw for lw in laws}
    coords = sorted({b.coordinate for b in curve.bands})
    fig, axes = plt.subplots(1, len(coords), figsize=(6.5 * len(coords), 4.5), squeeze=False)
    law_vals = {k: law_band_forces(lw, curve) for k, lw in laws.items()} if curve.weak is not None else {}
    for ax, i in zip(axes[0], coords):
        idx = [k for k, b in enumerate(curve.bands) if b.coordinate == i and b.direction == "both"]
        bs = [curve.bands[k] for k in idx]
        x = np.array([b.speed_mean for b in bs])
        y = np.array([b.force for b in bs])
        lo = np.array([b.ci95[0] for b in bs])
        hi = np.array([b.ci95[1] for b in bs])
        ax.errorbar(x, y, yerr=[y - lo, hi - y], fmt="ko", capsize=3, label="data (total friction, 95% CI)")
        ax.plot(x, [b.model_force for b in bs], "k--", lw=1, label="calibrated model's own")
        vg = np.linspace(0, curve.max_speed[i], 300)[1:]
        for k, (name, lw) in enumerate(laws.items()):
            col = f"C{k % 10}"
            if name in law_vals:
                ax.plot(x, [law_vals[name][j] for j in idx], "s", color=col, ms=5, mfc="none")
            own = lw.own_samples[i][1].mean() if lw.own_samples else 0.0
            qline = np.full_like(vg, math.pi / 2)  # |sin q| = 1: position-dependent damping at its largest
            ax.plot(vg, own * vg + lw.force(i, qline, vg), "-", color=col, lw=1.2, label=name)
        ax.set_xlabel(f"|qdot{i}|")
        ax.set_ylabel("friction force (opposing motion)")
        ax.set_title(f"coordinate {i}: total dissipative force vs speed")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


# --------------------------------------------------------------------------- selection
def coordinate_laws(i: int, max_terms: int = 3, terms: Sequence[str] = LAW_TERMS) -> list[list[Spec]]:
    """Every subset of up to ``max_terms`` of ``terms`` on coordinate ``i`` (Stribeck v_s profiled), including none."""
    subsets = [()] + [c for k in range(1, max_terms + 1) for c in itertools.combinations(terms, k)]
    return [[(nm, i) + ((None,) if nm == "stribeck_friction" else ()) for nm in sub] for sub in subsets]


def candidate_laws(n: int, max_terms: int = 3, terms: Sequence[str] = LAW_TERMS) -> list[list[Spec]]:
    """Per coordinate, every subset of up to ``max_terms`` of ``terms`` (Stribeck v_s profiled), including none;
    for n > 1 the per-coordinate subsets are combined (the product grows fast: pass ``terms`` to narrow it)."""
    per = [[()]] + [list(c) for k in range(1, max_terms + 1) for c in itertools.combinations(terms, k)]
    out = []
    for combo in itertools.product(per, repeat=n):
        spec: list[Spec] = []
        for i, sub in enumerate(combo):
            spec += [(nm, i) + ((None,) if nm == "stribeck_friction" else ()) for nm in sub if nm]
        out.append(spec)
    return out


def rollout_score(system: System, rec: Recordings, window: int | None, init_samples: int, sg: int,
                  sigma: np.ndarray | None = None, relative: bool = True) -> tuple[float, np.ndarray]:
    """Open-loop rollout error of ``system`` on ``rec`` cut into windows of ``window`` samples (None: whole recordings),
    initial state re-fitted on each window's first ``init_samples`` samples (:func:`.analysis.evaluate_models`).
    ``relative``: each window's RMSE divided by that window's rms |q - mean| (so small swings count as much as large
    ones); returns (mean over windows, per-window values)."""
    from .evaluate import evaluate_models

    recw = rec.windows(window) if window else rec
    sigma = estimate_noise(rec.q) if sigma is None else sigma
    sigma = np.maximum(sigma, 1e-6 * (rec.q.reshape(-1, rec.n).std(0) + 1e-12))
    qs, vs = smooth(recw.q, recw.dt, min(sg, _odd(recw.T // 2 - 1)))
    x_scale = np.concatenate([np.sqrt(np.mean(qs**2, axis=(0, 1))) + 1e-9, np.sqrt(np.mean(vs**2, axis=(0, 1))) + 1e-12])
    _, rolls = evaluate_models({"m": system}, recw, sigma, x_scale, min(init_samples, recw.T), min(sg, _odd(recw.T // 2 - 1)),
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
class CandidateScore:
    law: str
    n_params: int
    fold_scores: list[float]
    mean: float
    se: float
    passive: bool
    every_ci_excludes_zero: bool
    weak_form_loro: float  # mean over folds of the left-out weak-form force RMSE
    diff_se: float = 0.0  # paired standard error of (fold scores - the best candidate's fold scores)
    curve_agreement: float = 1.0  # share of the training curve's speed bands whose 95% interval holds the law
    not_worse: bool = False  # eligible and not significantly worse than the best (one-sided paired t-test, 5%)
    fitted: FrictionLaw | None = field(default=None, repr=False)  # fitted on all training recordings

    def to_dict(self) -> dict[str, Any]:
        d = {k: v for k, v in asdict(self).items() if k != "fitted"}
        d["fitted"] = self.fitted.to_dict() if self.fitted else None
        return d


@dataclass
class Selection:
    chosen: FrictionLaw
    chosen_name: str
    criterion: str
    scores: list[CandidateScore]  # sorted by mean score
    folds: str
    rule: str

    def to_dict(self) -> dict[str, Any]:
        return {"chosen": self.chosen.to_dict(), "criterion": self.criterion, "folds": self.folds, "rule": self.rule,
                "candidates": [s.to_dict() for s in self.scores]}


def _folds(rec: Recordings, n_blocks: int) -> tuple[list[tuple[Recordings, Recordings]], str]:
    if rec.n_traj >= 2:
        out = [(rec.subset(np.array([j for j in range(rec.n_traj) if j != k])), rec.subset(slice(k, k + 1))) for k in range(rec.n_traj)]
        return out, f"leave-one-recording-out ({rec.n_traj} folds)"
    # one recording: contiguous time blocks, each held out in turn (fit on the rest, concatenated as separate recordings)
    e = np.linspace(0, rec.T, n_blocks + 1).round().astype(int)
    out = []
    for k in range(n_blocks):
        parts = [rec.time_slice(e[j], e[j + 1]) for j in range(n_blocks) if j != k]
        L = min(p.T for p in parts)
        q = np.concatenate([p.q[:, :L] for p in parts])
        u = None if rec.u is None else np.concatenate([p.u[:, : L - 1] for p in parts])
        out.append((Recordings(q, rec.dt, u, rec.angle_dims, rec.source, rec.meta), rec.time_slice(e[k], e[k + 1])))
    return out, f"one recording: {n_blocks} contiguous time blocks, each held out in turn"


@dataclass
class LawSelectionOptions:
    """Knobs of :func:`select_law` (criterion and eligibility rules)."""

    criterion: str = "curve"  # "curve", "window_rollout", "rollout" or "weak_form"
    rollout_window: float | None = None  # [s] for "window_rollout" (default 3 periods)
    init_samples: int | None = None  # samples each rollout's initial state is fitted to
    n_time_blocks: int = 4  # folds when there is one recording
    max_terms: int = 3
    require_significant: bool = True
    min_t: float = 3.0
    min_share: float = 0.01  # rms force of a term / rms total friction force
    min_agreement: float = 0.75  # share of the training curve's bands whose interval holds the law
    relative: bool | None = None  # rollout criteria: RMSE relative to each window's amplitude
    bands: str = "quantile"
    n_bands: int = 8
    progress: bool = False


@dataclass
class _Scoring:
    """What every candidate is scored against: the weak forms of all recordings and of each fold, the curve."""

    system: System
    rec: Recordings
    opts: LawSelectionOptions
    wf_all: WeakForm
    folds: list[tuple[WeakForm, WeakForm, Recordings]]  # (training weak form, left-out weak form, left-out recordings)
    fold_txt: str
    curve: FrictionCurve
    edges: list[np.ndarray]
    ref: list[np.ndarray]  # pooled |curve| per band: the common denominator of the curve score
    scored: list[int] | None  # coordinates the score looks at (None: all)
    own: list
    W: int  # rollout window [samples]
    K: int  # rollout initial-state samples
    sigma: np.ndarray
    caches: list[tuple[dict, dict]] = field(default_factory=list)
    cache_all: dict = field(default_factory=dict)


def _pooled_reference(wf: WeakForm, edges: list[np.ndarray]) -> list[np.ndarray]:
    """|curve| of all recordings per coordinate and band (floored at 5% of the largest band)."""
    ref = []
    for i in range(wf.n):
        sp, sg_ = np.abs(wf.vs[..., i]), np.sign(wf.vs[..., i])
        vals = [abs(float(np.mean((wf.total[..., i] * sg_)[(sp >= a) & (sp < b)]))) if np.any((sp >= a) & (sp < b)) else 0.0
                for a, b in zip(edges[i][:-1], edges[i][1:])]
        ref.append(np.maximum(np.asarray(vals), 0.05 * max(vals + [1e-300])))
    return ref


def _scoring(system: System, rec: Recordings, window: int | None, eps: float | None, block: int | None,
             coordinate: int | None, opts: LawSelectionOptions) -> _Scoring:
    wf_all = weak_form(system, rec, window, eps, block)
    window, eps = wf_all.window, wf_all.eps
    folds, fold_txt = _folds(rec, opts.n_time_blocks)
    period = 2 * math.pi * time_scale(rec.q, rec.dt)
    W = int(round((opts.rollout_window or 3 * period) / rec.dt)) + 1
    K = int(opts.init_samples or max(10, int(round(0.5 * period / rec.dt)) // 4))
    fold_wf = [(weak_form(system, tr, window, eps, block), weak_form(system, te, window, eps, block), te) for tr, te in folds]
    curve = friction_curve(system, rec, window, bands=opts.bands, n_bands=opts.n_bands, eps=eps, block=block)
    edges = [_edges(np.abs(wf_all.vs[..., i]).reshape(-1), opts.bands, opts.n_bands) for i in range(rec.n)]
    return _Scoring(system, rec, opts, wf_all, fold_wf, fold_txt, curve, edges, _pooled_reference(wf_all, edges),
                    None if coordinate is None else [coordinate], _own_samples(system, wf_all), W, K, estimate_noise(rec.q),
                    [({}, {}) for _ in folds])


def _fold_score(sc: _Scoring, specs: Sequence[Spec], k: int) -> tuple[float, float]:
    """(criterion score, left-out weak-form rms) of the law ``specs`` fitted without fold k."""
    wtr, wte, te = sc.folds[k]
    ctr, cte = sc.caches[k]
    opts, n = sc.opts, sc.rec.n
    law = _fit_law(wtr, specs, cache=ctr, own=sc.own, own_terms=_own_terms(sc.system))
    fixed = [(t.term, t.coordinate) + ((t.velocity,) if t.term == "stribeck_friction" else ()) for t in law.terms]  # fold's v_s
    X = _design(wte, fixed, cte)
    res = []
    for i in range(n):
        idx = [j for j, t in enumerate(law.terms) if t.coordinate == i]
        pi = np.einsum("ntk,k->nt", X[..., idx], np.array([law.terms[j].coefficient for j in idx])) if idx else 0.0
        res.append((wte.total[..., i] - wte.own[..., i] - pi).reshape(-1))
    wfs = float(np.sqrt(np.mean(np.concatenate(res) ** 2)))
    if opts.criterion == "weak_form":
        return wfs, wfs
    if opts.criterion in ("window_rollout", "rollout"):
        rel = (opts.criterion == "window_rollout") if opts.relative is None else opts.relative
        W = sc.W if opts.criterion == "window_rollout" else None
        return rollout_score(law.augmented(sc.system), te, W, sc.K, wtr.window, sc.sigma, relative=rel)[0], wfs
    if opts.criterion == "curve":
        return _curve_score(law, wte, sc.edges, max(10, 2 * wtr.window), sc.ref, sc.scored), wfs
    raise ValueError(f"unknown criterion {opts.criterion!r}")


def _score(sc: _Scoring, specs: Sequence[Spec]) -> CandidateScore:
    """Fit on all recordings (passivity, significance, curve agreement) and on each fold (the scores)."""
    opts, wf = sc.opts, sc.wf_all
    full = _fit_law(wf, specs, cache=sc.cache_all, own=sc.own, own_terms=_own_terms(sc.system))
    passive = is_passive(full, [float(np.max(np.abs(wf.vs[..., i]))) for i in range(sc.rec.n)]).passive
    tot_rms = [float(np.sqrt(np.mean(wf.total[..., i] ** 2))) + 1e-300 for i in range(sc.rec.n)]
    share = [float(np.sqrt(np.mean((t.coefficient * _design(wf, [(t.term, t.coordinate, t.velocity)], sc.cache_all)) ** 2)))
             / tot_rms[t.coordinate] for t in full.terms]
    sig = all(t.excludes_zero and abs(t.t) >= opts.min_t and sh >= opts.min_share for t, sh in zip(full.terms, share))
    fs, wfs = zip(*[_fold_score(sc, specs, k) for k in range(len(sc.folds))])
    se = float(np.std(fs, ddof=1) / math.sqrt(len(fs))) if len(fs) > 1 else 0.0
    inside = [r["inside"] for r in check_against_curve(full, sc.curve) if sc.scored is None or r["coordinate"] in sc.scored]
    return CandidateScore(full.name, full.n_params, [float(x) for x in fs], float(np.mean(fs)), se, passive, sig, float(np.mean(wfs)),
                          curve_agreement=float(np.mean(inside)) if inside else 1.0, fitted=full)


def _choose(scores: list[CandidateScore], opts: LawSelectionOptions) -> tuple[CandidateScore, str]:
    """The eligible law with the fewest parameters not significantly worse than the best; and the rule in words."""
    sig_ok = [s for s in scores if s.passive and (s.every_ci_excludes_zero or not opts.require_significant)]
    ok = [s for s in sig_ok if s.curve_agreement >= opts.min_agreement] or sig_ok or [s for s in scores if s.passive] or scores
    scored = [s for s in ok if math.isfinite(s.mean)]
    if not scored:  # e.g. a few short recordings: no fold could score any law
        for s in scores:
            s.not_worse = False
        pick = min(ok, key=lambda s: s.n_params)
        return pick, ("not enough data to decide: no candidate law could be scored on left-out recordings, so the one with "
                      "the fewest parameters is kept")
    ok = scored
    best = min(ok, key=lambda s: s.mean)
    for s in scores:  # paired standard error of the fold-wise difference to the best candidate
        d = np.asarray(s.fold_scores) - np.asarray(best.fold_scores)
        s.diff_se = float(np.std(d, ddof=1) / math.sqrt(len(d))) if len(d) > 1 else 0.0
    # not significantly worse than the best: one-sided paired t-test at 5% over the folds
    t_margin = float(student_t.ppf(0.95, max(len(best.fold_scores) - 1, 1)))
    for s in ok:
        s.not_worse = s is best or s.mean - best.mean <= t_margin * s.diff_se
    pick = min([s for s in ok if s.not_worse], key=lambda s: (s.n_params, s.mean))
    sig_txt = (f", every coefficient |t| >= {opts.min_t:g} (95% interval excludes zero) and its rms force >= {opts.min_share:g} "
               "of the rms total friction force" if opts.require_significant else "")
    rule = ("passive over observed speeds" + sig_txt + f", inside the training friction curve's 95% interval in >= "
            f"{opts.min_agreement:.0%} of its speed bands; fewest parameters (a Stribeck term counts 2) among those not "
            f"significantly worse than the best (one-sided paired t-test over the folds at 5%: mean difference <= "
            f"{t_margin:.3g} x its standard error); ties: lower mean")
    return pick, rule


def select_law(system: System, rec: Recordings, candidates: Sequence[Sequence[Any]] | None = None,
               window: int | None = None, eps: float | None = None, block: int | None = None, coordinate: int | None = None,
               options: LawSelectionOptions | None = None, **overrides: Any) -> Selection:
    """Choose a friction law by prediction on data not used for its fit.

    Each candidate (a list of terms as in :func:`fit_law`; default :func:`candidate_laws`) is fitted by the weak form on
    all training recordings but one and scored on the left-out one (one recording: ``n_time_blocks`` time blocks).
    ``criterion``:

    * ``"curve"`` (default): how well the law predicts the left-out recording's friction curve: rms over speed bands
      (quantile bands of the pooled |qdot|, or ``bands="log"``) of (law - curve) / |pooled curve|, law and curve through
      the same filter.  Every speed range weighs the same; no simulation, so phase drift cannot enter.  On the real
      pendulum this is the criterion whose ranking follows the held-out rollout improvement;
    * ``"window_rollout"``: open-loop rollouts over consecutive windows of ``rollout_window`` seconds (default 3
      periods) of the left-out recording, initial state re-fitted per window (:func:`.analysis.evaluate_models`), RMSE
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
    opts = replace(options or LawSelectionOptions(), **overrides)
    if candidates is not None:
        specs_list = [_parse_terms(c, rec.n) for c in candidates]
    elif coordinate is not None:
        specs_list = coordinate_laws(coordinate, opts.max_terms)
    else:
        specs_list = candidate_laws(rec.n, opts.max_terms)
    return _select(_scoring(system, rec, window, eps, block, coordinate, opts), specs_list)


def _select(sc: _Scoring, specs_list: list[list[Spec]]) -> Selection:
    """Score every candidate law against ``sc`` and choose."""
    opts = sc.opts
    scores = []
    for c_idx, specs in enumerate(specs_list):
        scores.append(_score(sc, specs))
        if opts.progress:
            s = scores[-1]
            print(f"[select_law {c_idx + 1}/{len(specs_list)}] {s.law}: {s.mean:.4g} +- {s.se:.2g} passive={s.passive} "
                  f"sig={s.every_ci_excludes_zero}", flush=True)
    scores.sort(key=lambda s: s.mean)
    pick, rule = _choose(scores, opts)
    return Selection(pick.fitted, pick.law, opts.criterion, scores, sc.fold_txt, rule)


def select_friction(system: System, rec: Recordings, **kwargs: Any) -> tuple[FrictionLaw, list[Selection]]:
    """:func:`select_law` coordinate by coordinate (friction is diagonal: the weak-form balance of coordinate i holds
    only the terms on i, so the choices are independent and the candidate count stays linear in n).  Returns the
    merged law and the per-coordinate selections."""
    opts = replace(LawSelectionOptions(), **{k: v for k, v in kwargs.items() if k not in ("window", "eps", "block")})
    sc = _scoring(system, rec, kwargs.get("window"), kwargs.get("eps"), kwargs.get("block"), None, opts)  # weak forms, folds
    # and curve computed once, shared by the coordinates
    sels = [_select(replace(sc, scored=[i]), coordinate_laws(i, opts.max_terms)) for i in range(rec.n)]
    first = sels[0].chosen
    merged = FrictionLaw([t for s in sels for t in s.chosen.terms], first.eps, first.n, float(sum(s.chosen.rss for s in sels)),
                         first.n_obs, first.interval, first.own_samples, first.own_terms)
    return merged, sels
