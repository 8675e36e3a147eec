"""Friction laws fitted by the weak form: least squares of f~ - S*(own) on S*(basis) of dissipative vocabulary terms.

:func:`fit_law`: coefficients sign-free, cluster-robust 95% intervals; a velocity parameter (the Stribeck v_s) is
profiled on the grid its kind gives (:meth:`..vocabulary.registry.TermKind.velocity_grid`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy.stats import t as student_t

from phast_gym.systems.base import NUMPY, System

from ...identify.recordings import Recordings
from ...identify.weakform import WeakForm, weak_form
from ..fitting.linear import cluster_cov
from ..options import Z95
from ..vocabulary.registry import VOCABULARY, TermKind, VelocityKind, law_terms
from ..vocabulary.terms import AugmentedSystem, Term, friction_basis

#: Stribeck velocities tried, as fractions of the coordinate's rms speed: the default grid of a kind with a velocity
#: (each such kind carries its own, :attr:`..vocabulary.registry.VelocityKind.velocity_fractions`; Stribeck keeps the
#: default)
STRIBECK_FRACTIONS = VelocityKind.velocity_fractions


@dataclass
class LawTerm:
    """One fitted term: coefficient (sign free) of the force -c f(q, qdot) *added* to the model's own dissipation."""

    term: str
    coordinate: int
    coefficient: float
    ci95: tuple[float, float]
    velocity: float = 0.0  # Stribeck v_s
    t_quantile: float = Z95  # the quantile the 95% interval was built with

    @property
    def kind(self) -> TermKind:
        return VOCABULARY[self.term]

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
    # friction terms the system already has (AugmentedSystem)
    own_terms: list[Term] = field(default_factory=list, repr=False)

    @property
    def name(self) -> str:
        if not self.terms:
            return "model only"
        return " + ".join(f"{t.kind.short}[{t.coordinate}]" + (f"(v_s={t.velocity:.3g})" if t.kind.has_velocity else "")
                          for t in self.terms)

    @property
    def n_params(self) -> int:
        return sum(VOCABULARY[t.term].cost for t in self.terms)

    def force(self, i: int, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The law's added force on coordinate i (positive opposes +qdot), unfiltered."""
        f = np.zeros(np.broadcast(q, v).shape)
        for t in self.terms:
            if t.coordinate == i:
                f = f + t.coefficient * np.asarray(VOCABULARY[t.term].basis(q, v, self.eps, t.velocity, NUMPY))
        return f

    def augmented(self, system: System) -> AugmentedSystem:
        """``system`` plus the law's terms (an AugmentedSystem's own terms are kept)."""
        terms = [t.to_term() for t in self.terms]
        if isinstance(system, AugmentedSystem):
            return AugmentedSystem(system.base, list(system.terms) + terms, self.eps, system.deadzone_width)
        return AugmentedSystem(system, terms, self.eps)

    def to_dict(self) -> dict[str, Any]:
        return {"law": self.name, "terms": [{**asdict(t), "ci95": list(t.ci95)} for t in self.terms],
                "coulomb_eps": self.eps,
                "rss": self.rss, "n_obs": self.n_obs, "interval": self.interval,
                "every_ci_excludes_zero": all(t.excludes_zero for t in self.terms)}


Spec = tuple  # (name, coordinate), or (name, coordinate, v_s or None) for a kind with a velocity (Stribeck)


def spec_of(name: str, coordinate: int, velocity: float | None) -> Spec:
    """The spec of a term on a coordinate: with its velocity when its kind carries one (None: profiled)."""
    return (name, coordinate) + ((velocity,) if VOCABULARY[name].has_velocity else ())


def own_samples(system: System, wf: WeakForm, k: int = 64) -> list[tuple[np.ndarray, np.ndarray]]:
    q = wf.qs.reshape(-1, wf.n)
    idx = np.unique(np.linspace(0, len(q) - 1, min(k, len(q))).round().astype(int))
    q = q[idx]
    d = system.damping(tuple(q[:, i] for i in range(wf.n)), NUMPY)
    own = []
    for i in range(wf.n):
        di = np.broadcast_to(np.asarray(d[i], dtype=float), (len(q),)).copy()
        own.append((q[:, i].copy(), di))
    return own


def own_terms(system: System) -> list[Term]:
    return ([t for t in getattr(system, "terms", ()) if t.component == "dissipation"]
            if isinstance(system, AugmentedSystem) else [])


def filtered_basis(wf: WeakForm, name: str, i: int, velocity: float = 0.0) -> np.ndarray:
    """S * f(q_i, qdot_i) of a vocabulary term along the weak form's smoothed recordings, (N, T')."""
    return wf.filt(np.asarray(friction_basis(name, wf.q_raw[..., i], wf.v_raw[..., i], wf.eps, velocity, NUMPY)))


def design(wf: WeakForm, specs: Sequence[Spec], cache: dict | None = None) -> np.ndarray:
    cols = []
    for s in specs:
        key = (s[0], s[1], s[2] if len(s) > 2 else 0.0)
        if cache is not None and key in cache:
            cols.append(cache[key])
            continue
        c = filtered_basis(wf, s[0], s[1], key[2])
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
    X_all = design(wf, specs, cache)[sel]
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
        V, G = cluster_cov(X, r, g.reshape(-1))
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


def _velocity_grid(wf: WeakForm, spec: Spec) -> list[float]:
    """The velocities profiled for a term whose velocity is left free: its kind's grid at the coordinate's rms speed."""
    v_rms = float(np.sqrt(np.mean(wf.vs[..., spec[1]] ** 2)))
    return VOCABULARY[spec[0]].velocity_grid(v_rms)


def fit_law_specs(wf: WeakForm, specs: Sequence[Spec], rows: np.ndarray | None = None, cache: dict | None = None,
             own: list | None = None, own_terms: Sequence[Term] = ()) -> FrictionLaw:
    """Fit, profiling any velocity left None (a Stribeck v_s) over its kind's grid (lowest weak-form rss)."""
    specs = [tuple(s) for s in specs]
    free = [k for k, s in enumerate(specs) if VOCABULARY[s[0]].has_velocity and (len(s) < 3 or s[2] is None)]
    choices = [[(k, v) for v in _velocity_grid(wf, specs[k])] for k in free]
    best = None
    for combo in itertools.product(*choices) if choices else [()]:
        sp = list(specs)
        for k, v in combo:
            sp[k] = (specs[k][0], specs[k][1], v)
        res = _fit(wf, sp, rows, cache)
        if best is None or res[2] < best[1][2]:
            best = (sp, res)
    assert best is not None
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


def parse_terms(terms: Sequence[Term | str | Spec], n: int) -> list[Spec]:
    """Accept (name, coordinate), (name, coordinate, v_s | None) for a kind with a velocity, Term objects, or bare names
    (every coordinate 0 .. n-1)."""
    out: list[Spec] = []
    for t in terms:
        if isinstance(t, Term):
            out.append(spec_of(t.name, t.coordinate, t.velocity))
        elif isinstance(t, str):
            out += [(t, i) for i in range(n)]
        else:
            out.append(tuple(t))
    for s in out:
        if s[0] not in law_terms():
            raise ValueError(f"{s[0]!r} is not a dissipative vocabulary term; use one of {law_terms()}")
    return out


def fit_law(system: System, rec: Recordings, terms: Sequence[Term | str | Spec], window: int | None = None,
            eps: float | None = None, block: int | None = None, weak: WeakForm | None = None) -> FrictionLaw:
    """Weak-form force-balance least squares of a friction law, coefficients sign free.

    ``terms``: (name, coordinate) pairs, (name, i, v_s) for a kind with a velocity (v_s None: profiled on the kind's
    grid
    of fractions of the rms speed), :class:`..vocabulary.terms.Term` objects, or bare names (every coordinate).  The law
    is *added* to the
    model's own dissipation: a negative viscous coefficient lowers the model's damping.  95% intervals are
    cluster-robust over time blocks within recordings (see :func:`weak_form`)."""
    wf = weak or weak_form(system, rec, window, eps, block)
    return fit_law_specs(wf, parse_terms(terms, rec.n), cache={}, own=own_samples(system, wf),
                         own_terms=own_terms(system))

