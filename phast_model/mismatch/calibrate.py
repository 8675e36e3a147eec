"""Stage 1: the nominal fit, and which combinations of the simulator's parameters the recordings determine.

Every non-zero numeric parameter of the simulator is examined, except the known constants (``Param(known=True)``,
gravity) that the user has not freed (``Options.free``).  Its shooting column at the nominal fit (window states
projected out, log-relative change) is its sensitivity.  A rank-revealing QR factorisation with column pivoting of
the unit-normalised columns gives the identifiable combinations (a rigid arm's base parameters): the pivot set is a
full-rank set that spans them (taken in order of preference: parameters outside M(q) first, then the system's order),
and every other parameter's column is written in terms of the pivots (the change of that parameter the data cannot
tell from a change of the pivots).

Which parameters are *changed* is not decided here: every identifiable parameter is a candidate of the one selection
of :mod:`.selection`, where parameter changes and new terms compete (a parameter wins at equal evidence).
:func:`calibration` then refits the chosen parameters alone: the report's "calibrated" model.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
import scipy.linalg

from phast_gym.systems.base import System

from ..identify.shooting import Shooter, ShootFit
from ..identify.simulators import known_params
from .fitting.linear import flat, rel_resid
from .fitting.problem import Problem
from .vocabulary.candidates import Family, ParamCandidate
from .vocabulary.terms import Term

#: finite-difference step of a parameter column (log-relative)
PARAM_STEP = 1e-3
#: a pivot whose unit column keeps less than this share independent of the earlier pivots is not identifiable
REL_TOL = 0.05
#: a pivot is the preferred column among those keeping at least this share of the largest remaining residual
PIVOT_SLACK = 0.5
#: a parameter is "determined" when a change of this size (relative) moves the fit by more than the noise
VISIBLE_CHANGE = 0.05


@dataclass(frozen=True)
class Identifiability:
    """Which parameter combinations the recordings fix (pivoted QR of the sensitivities at the nominal fit)."""

    examined: tuple[str, ...]  # parameters with a visible column, in the system's order
    basis: tuple[str, ...]  # pivots: a full-rank set spanning the identifiable combinations
    independence: tuple[float, ...]  # |R_jj| of each pivot (share of its unit column independent of earlier pivots)
    equivalents: dict[str, dict[str, float]]  # non-pivot parameter -> {pivot: d log pivot per d log parameter}

    @property
    def rank(self) -> int:
        return len(self.basis)

    def to_dict(self) -> dict[str, Any]:
        return {"examined": list(self.examined), "rank": self.rank, "basis": list(self.basis),
                "independence": dict(zip(self.basis, self.independence)),
                "equivalents": {k: {p: round(v, 4) for p, v in e.items()} for k, e in self.equivalents.items()},
                "method": "rank-revealing QR with column pivoting of the unit-normalised shooting sensitivities "
                          "d q / d log(parameter) at the nominal fit (window states projected out)"}

    def sentence(self, name: str) -> str | None:
        """'a change of ``name`` acts like ...' for a parameter outside the basis, None otherwise."""
        eq = {p: a for p, a in self.equivalents.get(name, {}).items() if abs(a) >= 0.02}
        if not eq:
            return None
        parts = " ".join(f"{'+' if a >= 0 else '-'} {abs(a):.3g} x {p}" for p, a in eq.items()).lstrip("+ ")
        return f"d log {name} acts on these recordings like {parts} (relative changes)"


@dataclass
class ParameterScreen:
    """Result of :func:`screen_parameters`: the nominal fit and the parameter candidates of the selection."""

    shooter: Shooter  # on the windows kept after outlier rejection
    fit_nominal: ShootFit  # window states only, nominal parameters
    n_dropped: int  # windows the nominal model could not follow at all
    # identifiable parameters (every examined one; the selection keeps the parsimonious)
    candidates: list[ParamCandidate]
    notes: dict[str, str]  # parameters not examined, with the reason
    identifiability: Identifiability
    fit_full: ShootFit  # every pivot fitted: the most a parameter change alone can do (for the explained share)
    family_full: Family
    #: the terms a trial of the drives found (rotor inertia, joint friction): the weak-form answer's refit in the engine
    #: starts there and considers them too (:mod:`.friction.engine_refit`)
    starts: tuple[Term, ...] = ()
    #: the drives trial was far from following the windows (a real arm's model error): the weak-form answer is not
    #: refitted in the engine, which could not bring it to the noise either
    far: bool = False
    #: the drives did not follow the windows to the noise: the weak form fits the file's body values after them, where
    #: fitting them predicts left-out recordings better (a rotor inertia kept from a link's inertia)
    bodies_after: bool = False


@dataclass
class Calibration:
    """The calibrated model: the parameters the selection changed, refitted without the terms."""

    screen: ParameterScreen
    selected: list[tuple[str, float]]  # changed parameters (name, nominal value), in fit order
    family: Family
    fit: ShootFit

    @property
    def shooter(self) -> Shooter:
        return self.screen.shooter

    @property
    def fit_nominal(self) -> ShootFit:
        return self.screen.fit_nominal

    @property
    def n_dropped(self) -> int:
        return self.screen.n_dropped

    @property
    def notes(self) -> dict[str, str]:
        return self.screen.notes

    @property
    def system(self) -> System:
        return self.family.build(self.fit.g)


def followed_windows(r: np.ndarray) -> np.ndarray:
    """(W,) the windows a model follows at all: mean squared standardized residual within 30x the median window's
    (and below 50); the others (e.g. a separatrix crossing the fitted state put on the wrong side) are set aside."""
    per_win = np.mean(r**2, axis=1)
    return per_win <= max(30.0 * float(np.median(per_win)), 50.0)


def fit_nominal(problem: Problem) -> tuple[Shooter, ShootFit, int]:
    """Window states of the nominal model; windows it cannot follow at all (e.g. a separatrix crossing) are dropped."""
    opts = problem.opts
    system = problem.nominal_family.build(np.zeros(0))
    shooter = problem.shooter(problem.shooting.windows)
    fit = shooter.fit_states(system, problem.shooting.X0, max_iter=opts.max_iter)
    keep = followed_windows(fit.r)
    n_dropped = int(np.sum(~keep))
    if n_dropped and np.sum(keep) >= 2:
        shooter = problem.shooter(problem.shooting.windows.select(keep))
        fit = shooter.fit(lambda g: system, fit.X[keep], np.zeros(0), max_iter=opts.max_iter)
    problem.log(f"nominal fit: chi2/dof = {fit.chi2_red:.3g} ({fit.iterations} it)")
    return shooter, fit, n_dropped


#: windows (at most) of the sample on which a motor-driven model file is first fitted, and the iterations of that fit:
#: enough to tell a model that follows the windows from one that follows none
SHARE_WINDOWS, SHARE_ITER = 16, 8


def nominal_sample(problem: Problem, simulated: System) -> tuple[Shooter, ShootFit]:
    """The nominal model (``simulated``: as an engine simulates it) fitted to at most :data:`SHARE_WINDOWS` of the
    shooting windows, spread evenly over them, in at most :data:`SHARE_ITER` iterations: a model that follows the
    recordings is told from one that follows none at a fraction of the cost of all windows."""
    windows = problem.shooting.windows
    pick = np.unique(np.linspace(0, len(windows.traj) - 1, min(SHARE_WINDOWS, len(windows.traj))).round().astype(int))
    shooter = problem.shooter(windows.select(pick))
    return shooter, shooter.fit_states(simulated, problem.shooting.X0[pick],
                                       max_iter=min(SHARE_ITER, problem.opts.max_iter))


def _parameter_columns(problem: Problem, shooter: Shooter, nominal_fit: ShootFit,
                       params: list[tuple[str, float]]) -> np.ndarray:
    """(N, len(params)) projected shooting columns d r / d log(parameter) at the nominal fit."""
    nominal, h = problem.nominal_family, PARAM_STEP
    if not params:
        return np.zeros((nominal_fit.r.size, 0))

    def build(k: str, nom: float) -> System:
        return nominal.with_(params=[(k, nom)]).build(np.array([h]))

    builds: list[Callable[[], System]] = [partial(build, k, nom) for k, nom in params]
    return flat(nominal_fit.projected(shooter.columns(builds, nominal_fit, nominal_fit.r, [h] * len(params)))[1])


def identifiability(names: list[str], cols: np.ndarray) -> Identifiability:
    """The rank from a pivoted QR of the unit-normalised columns; the pivots then taken one at a time like column
    pivoting, but among the columns within :data:`PIVOT_SLACK` of the largest remaining residual the first in the
    order of ``names`` (the preferred parameters) is taken; every other parameter's column written in the pivots."""
    if not names:
        return Identifiability((), (), (), {})
    norms = np.linalg.norm(cols, axis=0)
    unit = cols / norms
    R = scipy.linalg.qr(unit, mode="r", pivoting=True)[0]
    d = np.abs(np.diag(R))
    rank = int(np.sum(d >= REL_TOL * max(d[0], 1e-300))) if d.size else 0
    basis: list[int] = []
    for _ in range(rank):  # Gram-Schmidt with a preference: among the columns within PIVOT_SLACK of the largest
        rest = [j for j in range(len(names)) if j not in basis]  # remaining residual, the first in ``names`` order
        res = [rel_resid(unit[:, j], unit[:, basis] if basis else None) for j in rest]
        top = max(res)
        basis.append(next(j for j, r in zip(rest, res) if r >= PIVOT_SLACK * top))
    equivalents: dict[str, dict[str, float]] = {}
    for j in range(len(names)):
        if j not in basis and basis:
            a = np.linalg.lstsq(unit[:, basis], unit[:, j], rcond=None)[0]
            equivalents[names[j]] = {names[b]: float(a[i] * norms[j] / norms[b]) for i, b in enumerate(basis)}
    indep = [rel_resid(unit[:, b], unit[:, [c for c in basis if c != b]] if len(basis) > 1 else None) for b in basis]
    return Identifiability(tuple(names), tuple(names[b] for b in basis), tuple(indep), equivalents)


def param_in_mass(problem: Problem, name: str, nominal: float) -> bool:
    """Whether a 1% change of parameter ``name`` changes M(q) at about 200 recorded configurations."""
    from phast_gym.systems.base import NUMPY

    q = problem.q_sample()
    a, b = problem.sim.build(), problem.sim.build(**{name: nominal * 1.01})
    qc = tuple(q[:, i] for i in range(q.shape[1]))
    Ma, Mb = a.mass_matrix(qc, NUMPY), b.mass_matrix(qc, NUMPY)
    return any(not np.allclose(np.asarray(x), np.asarray(y)) for ra, rb in zip(Ma, Mb) for x, y in zip(ra, rb))


def _examined(problem: Problem, shooter: Shooter,
              nominal_fit: ShootFit) -> tuple[list[tuple[str, float]], np.ndarray, dict[str, str]]:
    """The free parameters whose change is visible in the recordings, their columns, and a note for every other one."""
    known = known_params(problem.sys0) - set(problem.opts.free)
    params = [(k, v) for k, v in problem.sim.numeric_params(problem.sys0).items() if v != 0]
    notes = {k: f"a known constant (held fixed; free it with --free {k} if it is not)" for k, _ in params if k in known}
    params = [(k, v) for k, v in params if k not in known]
    # preference among equivalent parameters: those outside M(q) first (a mass change that acts like a damping change
    # on a free pendulum is reported as the damping), then the system's order
    params.sort(key=lambda kv: param_in_mass(problem, *kv))
    cols = _parameter_columns(problem, shooter, nominal_fit, params)
    keep = []
    for j, (k, _) in enumerate(params):
        norm = float(np.linalg.norm(cols[:, j]))
        if norm == 0.0 or not np.isfinite(norm):
            notes[k] = "does not enter the dynamics of q (held at nominal)"
        elif norm * VISIBLE_CHANGE < 1.0:
            notes[k] = (f"not determined by these recordings (a {VISIBLE_CHANGE:.0%} change moves the fit by less "
                        "than the noise)")
        else:
            keep.append(j)
    return [params[j] for j in keep], cols[:, keep], notes


def screen_parameters(problem: Problem, made: tuple[Shooter, ShootFit, int] | None = None) -> ParameterScreen:
    """Nominal fit (``made``: :func:`fit_nominal`'s, when already made), parameter sensitivities, identifiable
    combinations, and the fit with every pivot free."""
    shooter, nominal_fit, n_dropped = made or fit_nominal(problem)
    params, cols, notes = _examined(problem, shooter, nominal_fit)
    ident = identifiability([k for k, _ in params], cols)
    problem.log(f"identifiable: rank {ident.rank} of {len(params)} examined parameters; basis {list(ident.basis)}")
    nominal = dict(params)
    for k in ident.equivalents:
        if (s := ident.sentence(k)) is not None:
            problem.log(f"  {s}")
    family_full = problem.nominal_family.with_(params=[(k, nominal[k]) for k in ident.basis])
    fit_full = nominal_fit
    if ident.rank:
        fit_full = shooter.fit(family_full.build, nominal_fit.X, np.zeros(ident.rank), max_iter=problem.opts.max_iter)
    problem.log(f"every pivot fitted: chi2/dof = {fit_full.chi2_red:.3g}")
    cands = [ParamCandidate(k, v, PARAM_STEP) for k, v in params]
    return ParameterScreen(shooter, nominal_fit, n_dropped, cands, notes, ident, fit_full, family_full)


def drives_screen(problem: Problem, nominal: tuple[Shooter, ShootFit, int],
                  starts: Sequence[Term] = (), far: bool = False, bodies_after: bool = False) -> ParameterScreen:
    """The screen of a model file its nominal model cannot follow but its drives describe (rotor inertia and friction
    per driven joint account for the force it leaves): no body value is examined, so none can absorb a drive; the
    weak form then fits the drives with the file's body values (and, with ``bodies_after``, the body values after
    them)."""
    shooter, fit, n_dropped = nominal
    note = ("held at the file's value: the model is described up to its drives, so rotor inertia and friction per "
            "driven joint come first")
    notes = {k: note for k in problem.sim.numeric_params(problem.sys0)}
    return ParameterScreen(shooter, fit, n_dropped, [], notes, Identifiability((), (), (), {}), fit,
                           problem.nominal_family, tuple(starts), far, bodies_after)


def calibration(problem: Problem, screen: ParameterScreen, selected: list[tuple[str, float]], start: ShootFit,
                n_terms: int) -> Calibration:
    """The chosen parameters refitted without the ``n_terms`` terms of the selection's fit ``start`` (which is the
    answer itself when there are none)."""
    fam = problem.nominal_family.with_(params=list(selected))
    if not selected:
        return Calibration(screen, [], fam, screen.fit_nominal)
    if n_terms == 0:
        return Calibration(screen, list(selected), fam, start)
    fit = screen.shooter.fit(fam.build, start.X, start.g[: len(selected)], max_iter=problem.opts.max_iter)
    problem.log(f"calibrated {[k for k, _ in selected]}: chi2/dof = {fit.chi2_red:.3g} ({fit.iterations} it)")
    return Calibration(screen, list(selected), fam, fit)


def explained_share(shooter: Shooter, fit: ShootFit) -> float:
    """How much of the recordings the simulator describes: 1 - cost / cost of a straight line per window and coordinate
    (the same number of free values as the window states).  About 1 for a simulator of the right kind of system, about
    0 when it follows the recordings no better than a line (white noise, another system)."""
    w = shooter.w
    t = w.obs.astype(float)
    q = w.q[:, w.obs]  # (W, L, n)
    A = np.stack([np.ones_like(t), t - t.mean()], 1)
    coef = np.linalg.lstsq(A, q.transpose(1, 0, 2).reshape(len(t), -1), rcond=None)[0]
    line = (A @ coef).reshape(len(t), q.shape[0], q.shape[2]).transpose(1, 0, 2)
    cost_line = float(np.sum(((q - line) / shooter.sigma) ** 2))
    return 1.0 - fit.cost / max(cost_line, 1e-300)

