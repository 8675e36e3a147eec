"""What the shooting selection's modules share: the state of one selection and its result.

:class:`Search` is the (mutable) state of one selection: the problem, the parameter screen, the current model (the
chosen items in g order, their fit and family) and the candidates' shooting columns at it.  :func:`.forward.select`
runs the forward selection and its checks on it, :mod:`.law_look` its longer look at dissipation laws of equal
evidence; :class:`Selection` is what the selection returns.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

import numpy as np

from phast_gym.systems.base import System

from ...identify.shooting import ShootFit
from ..calibrate import ParameterScreen
from ..fitting.linear import flat, orth_against
from ..fitting.problem import Problem
from ..options import Z95
from ..vocabulary.candidates import Candidate, Family, ParamCandidate

#: gains within this share of each other are equal evidence (a parameter change then wins over a term)
EQUAL_EVIDENCE = 0.05


AnyCandidate = Candidate | ParamCandidate


@dataclass
class Selection:
    """Result of :func:`.forward.select`: the chosen parameter changes and terms, fitted together."""

    candidates: list[AnyCandidate]  # as screened (a chosen Stribeck term carries its refined velocity)
    usable: list[int]  # indices of candidates with a usable column
    columns: np.ndarray  # (N, len(candidates)) the terms' shooting columns at the full-rank calibration (parameters: 0)
    chosen: list[int]  # indices of the selected items, in g order (parameters first, then terms)
    gains: dict[int, float]  # chi^2 drop when each was added
    family: Family
    fit: ShootFit
    cov: np.ndarray | None  # covariance of fit.g (None when nothing was chosen)
    # the two-fold validation of every item examined (report.json: details.held_out_check, its name kept for readers)
    validation: list[dict[str, Any]] = field(default_factory=list)
    # parameter changes reported as an equivalent (one parameter, a port gain)
    equivalent_swap: dict[str, Any] | None = None
    # covariance of fit.g for the reported intervals (ShootFit.interval_covariance)
    interval_cov: np.ndarray | None = None
    q95: float = Z95  # their 95% quantile (Student's t over the recordings)

    @property
    def params(self) -> list[tuple[str, float]]:
        """The changed parameters (name, nominal), in g order."""
        return [(c.name, c.nominal) for c in (self.candidates[k] for k in self.chosen) if isinstance(c, ParamCandidate)]

    @property
    def terms(self) -> list[Candidate]:
        return [c for c in (self.candidates[k] for k in self.chosen) if isinstance(c, Candidate)]

    @property
    def term_indices(self) -> list[int]:
        return [k for k in self.chosen if not self.candidates[k].is_param]

    @property
    def system(self) -> System:
        return self.family.build(self.fit.g)


@dataclass
class Marks:
    """Items already handled: parameters reported as their equivalent port gain, terms whose velocity was refined."""

    swapped: set[int] = field(default_factory=set)
    refined: set[int] = field(default_factory=set)
    # (chosen term, another law of equal evidence on its coordinate, that law's linear z) for the longer look
    contenders: list[tuple[int, int, float]] = field(default_factory=list)  # (.law_look)
    longer_look: set[int] = field(default_factory=set)  # terms adopted on the longer windows (their evidence is there)


def _structure_groups(cands: list[AnyCandidate], ks: list[int]) -> list[list[int]]:
    """``ks`` in groups whose systems can be simulated as one batch: the parameter changes, the force terms by
    component (an armature changes how the vector field is assembled, so those terms go together), port and sensor
    terms by kind (a smoothed deadzone at zero threshold is not the identity)."""
    groups: dict[str, list[int]] = {}
    for k in ks:
        c = cands[k]
        if isinstance(c, ParamCandidate):
            key = "param"
        else:
            key = c.component if c.component in ("dissipation", "potential", "inertia") else c.term
        groups.setdefault(key, []).append(k)
    return list(groups.values())


@dataclass
class Search:
    """Shared state of one selection: the problem, the parameter screen and the (mutable) current model."""

    problem: Problem
    screen: ParameterScreen
    cands: list[AnyCandidate]
    fit: ShootFit
    fam: Family
    cov: np.ndarray | None = None
    chosen: list[int] = field(default_factory=list)  # in g order: parameters, then terms
    gains: dict[int, float] = field(default_factory=dict)
    raw: dict[int, np.ndarray] = field(default_factory=dict)  # unprojected columns of the last :meth:`columns` call
    marks: Marks = field(default_factory=Marks)
    eps: tuple[float, ...] | None = None  # the Coulomb edges when one was made sharper (None: the problem's)

    @property
    def thr2(self) -> float:
        return self.problem.opts.threshold ** 2

    def pos(self, k: int) -> int:
        return self.chosen.index(k)

    def add(self, k: int, fam: Family, g: np.ndarray, z: float) -> tuple[Family, np.ndarray, list[int]]:
        """Family, globals and g-ordered chosen list with candidate k added at ``z``."""
        fam2, g2 = self.cands[k].add_to(fam, g, z)
        order = list(self.chosen)
        order.insert(self.n_params() if self.cands[k].is_param else len(order), k)
        return fam2, g2, order

    def family_of(self, order: list[int], cands: list[AnyCandidate] | None = None) -> Family:
        """The family of the items ``order`` (of ``cands``, default the search's candidates), in g order."""
        pool = self.cands if cands is None else cands
        params = [(c.name, c.nominal) for c in (pool[k] for k in order) if isinstance(c, ParamCandidate)]
        terms = [c.family_term for c in (pool[k] for k in order) if isinstance(c, Candidate)]
        nominal = (self.problem.nominal_family if self.eps is None
                   else replace(self.problem.nominal_family, eps=self.eps))
        return nominal.with_(params=params, terms=terms)

    def columns(self, fit: ShootFit, fam: Family, ks: list[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Residual and candidate columns at ``fit`` with window states and current globals projected out; the raw
        columns are kept in :attr:`raw` (for the window-state part of a linear step)."""
        def build(k: int) -> System:
            fam2, g2 = self.cands[k].add_to(fam, fit.g, self.cands[k].fd_step)
            return fam2.build(g2)

        def stand_in(k: int, group: list[int]) -> System:  # every term of the group present, all but k at no effect
            terms = [c.family_term for c in (self.cands[j] for j in group) if isinstance(c, Candidate)]
            steps = [self.cands[j].fd_step if j == k else 0.0 for j in group]
            return fam.with_(terms=fam.terms + terms).build(np.concatenate([fit.g, steps]))

        cols = np.empty(fit.r.shape + (len(ks),))
        for group in _structure_groups(self.cands, ks):
            builds: list[Callable[[], System]] = [partial(build, k) for k in group]
            stand_ins: list[Callable[[], System]] | None = \
                None if self.cands[group[0]].is_param else [partial(stand_in, k, group) for k in group]
            cols[..., [ks.index(k) for k in group]] = self.screen.shooter.columns(
                builds, fit, fit.r, [self.cands[k].fd_step for k in group], stand_ins)
        self.raw = {k: cols[..., j] for j, k in enumerate(ks)}
        r_p, cols_p = fit.projected(cols)
        _, jg_p = fit.projected()
        G = flat(jg_p) if fit.g.size else None
        r_p = r_p.reshape(-1)
        cols_p = flat(cols_p)
        if G is not None:
            r_p = r_p - G @ np.linalg.lstsq(G, r_p, rcond=None)[0]
        return r_p, cols_p, orth_against(cols_p, G)

    def state_step(self, k: int, z: float) -> np.ndarray:
        """Window states after the linear step that adds candidate k at ``z`` (each window's state re-fitted to the
        change its column predicts): a start close to the new optimum when the change is large."""
        fit, col = self.fit, self.raw.get(k)
        if col is None:
            return fit.X
        JX = fit.JX
        A = np.einsum("wla,wlb->wab", JX, JX) + 1e-12 * np.eye(JX.shape[2])
        b = np.einsum("wla,wl->wa", JX, fit.r + col * z)
        return fit.X - np.linalg.solve(A, b[..., None])[..., 0]

    def item_ok(self, fit: ShootFit, cov: np.ndarray, order: list[int], k: int) -> bool:
        """Item k of ``fit`` is significant (|z| / std >= threshold) and of the passive sign."""
        j = order.index(k)
        cand = self.cands[k]
        z, sd = fit.g[j], math.sqrt(max(cov[j, j], 1e-300))
        wrong_sign = cand.must_be_positive and cand.coefficient(z) <= 0
        return abs(z) / sd >= self.problem.opts.threshold and not wrong_sign

    def system_now(self) -> System:
        return self.fam.build(self.fit.g)

    def n_params(self) -> int:
        return sum(self.cands[k].is_param for k in self.chosen)
