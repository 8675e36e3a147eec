"""Stage 1, calibrate: nominal window-state fit, outlier windows, identifiable parameters, calibrated fit.

Every non-zero numeric parameter of the simulator is a candidate.  Its shooting
column at the nominal fit (window states projected out) decides: taken in the
system's order, mass-matrix parameters last; held at nominal when it does not
move the fit beyond the noise (5% change), when it lies (85%) in the span of those
already taken, or when it is visible only through the port u (an actuator gain).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from phast_gym.systems.base import NUMPY

from .candidates import Family, ScaledTerm
from .linear import flat, rel_resid
from .problem import Problem
from .shooting import Shooter, ShootFit
from .simulators import Simulator

#: finite-difference step of a parameter column (log-relative)
PARAM_STEP = 1e-3


@dataclass
class Calibration:
    """Result of :func:`calibrate`."""

    shooter: Shooter  # on the windows kept after outlier rejection
    fit_nominal: ShootFit  # window states only, nominal parameters
    n_dropped: int  # windows the nominal model could not follow at all
    selected: list[tuple[str, float]]  # fitted parameters (name, nominal value), in fit order
    columns: np.ndarray  # (N, len(selected)) their projected columns at the nominal fit
    notes: dict[str, str]  # parameters held at nominal, with the reason
    family: Family  # the calibrated family (selected parameters, no terms)
    fit: ShootFit  # the calibrated fit

    @property
    def system(self) -> Any:
        return self.family.build(self.fit.g)


def param_in_mass(sim: Simulator, kwargs: dict, name: str, q: np.ndarray) -> bool:
    """Whether a 1% change of parameter ``name`` changes M(q) at the configurations ``q``."""
    a = sim.build(**kwargs)
    kw = dict(kwargs)
    kw[name] = a.params[name] * 1.01
    b = sim.build(**kw)
    qc = tuple(q[:, i] for i in range(q.shape[1]))
    Ma, Mb = a.mass_matrix(qc, NUMPY), b.mass_matrix(qc, NUMPY)
    return any(not np.allclose(np.asarray(x), np.asarray(y)) for ra, rb in zip(Ma, Mb) for x, y in zip(ra, rb))


def fit_nominal(problem: Problem) -> tuple[Shooter, ShootFit, int]:
    """Window states of the nominal model; windows it cannot follow at all (e.g. a separatrix crossing) are dropped."""
    opts, fam0 = problem.opts, problem.fam0
    shooter = problem.shooter(problem.windows)
    fit = shooter.fit_states(fam0.build(np.zeros(0)), problem.X0, max_iter=opts.max_iter)
    per_win = np.mean(fit.r**2, axis=1)
    keep = per_win <= max(30.0 * float(np.median(per_win)), 50.0)
    n_dropped = int(np.sum(~keep))
    if n_dropped and np.sum(keep) >= 2:
        shooter = problem.shooter(problem.windows.select(keep))
        fit = shooter.fit(lambda g: fam0.build(g), fit.X[keep], np.zeros(0), max_iter=opts.max_iter)
    problem.log(f"nominal fit: chi2/dof = {fit.chi2_red:.3g} ({fit.iterations} it)")
    return shooter, fit, n_dropped


def _parameter_columns(problem: Problem, shooter: Shooter, fitN: ShootFit,
                       params: list[tuple[str, float]]) -> tuple[np.ndarray, np.ndarray | None]:
    """Projected shooting columns of the parameters and of the actuator gains (where u acts) at the nominal fit."""
    fam0, h = problem.fam0, PARAM_STEP
    if params:
        builds = [lambda k=k, nom=nom: fam0.with_(params=[(k, nom)]).build(np.array([h])) for k, nom in params]
        cols = shooter.columns(builds, fitN, fitN.r, [h] * len(params))
    else:
        cols = np.zeros(fitN.r.shape + (0,))
    cols_p = flat(fitN.projected(cols)[1])
    if not any(problem.has_u):
        return cols_p, None
    gains = [lambda i=i: fam0.with_(terms=[ScaledTerm("actuator_gain", i, 1.0)]).build(np.array([h]))
             for i in range(problem.n) if problem.has_u[i]]
    return cols_p, flat(fitN.projected(shooter.columns(gains, fitN, fitN.r, [h] * len(gains)))[1])


def _identifiable(problem: Problem, params: list[tuple[str, float]], cols: np.ndarray,
                  port_cols: np.ndarray | None) -> tuple[list[tuple[str, float]], list[np.ndarray], dict[str, str]]:
    """The parameters the recordings determine, their columns, and a note for each one held at nominal."""
    selected: list[tuple[str, float]] = []
    sel_cols: list[np.ndarray] = []
    notes: dict[str, str] = {}
    for j, (k, nom) in enumerate(params):
        c = cols[:, j]
        norm = float(np.linalg.norm(c))
        if norm == 0.0:
            notes[k] = "does not enter the dynamics of q (held at nominal)"
            continue
        if norm * 0.05 < 1.0:
            notes[k] = "not determined by these recordings (a 5% change moves the fit by less than the noise)"
            continue
        basis = np.stack(sel_cols, 1) if sel_cols else None
        rr = rel_resid(c, basis)
        problem.log(f"param {k}: column norm {norm:.3g}, independent part {rr:.3g}")
        if rr < 0.15:
            notes[k] = f"enters only through a combination already fitted ({', '.join(s for s, _ in selected)}); held at nominal"
            continue
        if port_cols is not None:
            pb = port_cols if basis is None else np.concatenate([basis, port_cols], 1)
            if rel_resid(c, pb) < 0.15:
                notes[k] = "visible only through the port u: a change is indistinguishable from an actuator_gain; held at nominal"
                continue
        selected.append((k, nom))
        sel_cols.append(c)
    return selected, sel_cols, notes


def calibrate(problem: Problem) -> Calibration:
    """Fit the identifiable parameters of the nominal simulator by shooting."""
    shooter, fitN, n_dropped = fit_nominal(problem)
    params = [(k, v) for k, v in problem.sim.numeric_params(problem.sys0).items() if v != 0]
    qsamp = problem.q_sample()
    in_mass = {k: param_in_mass(problem.sim, problem.fam0.kwargs, k, qsamp) for k, _ in params}
    params.sort(key=lambda kv: in_mass[kv[0]])  # stable: PARAMS order, mass-matrix parameters last
    cols, port_cols = _parameter_columns(problem, shooter, fitN, params)
    selected, sel_cols, notes = _identifiable(problem, params, cols, port_cols)
    famC = problem.fam0.with_(params=selected)
    fitC = shooter.fit(famC.build, fitN.X, np.zeros(len(selected)), max_iter=problem.opts.max_iter)
    problem.log(f"calibrated {[k for k, _ in selected]}: chi2/dof = {fitC.chi2_red:.3g} ({fitC.iterations} it)")
    columns = np.stack(sel_cols, 1) if sel_cols else np.zeros((cols.shape[0], 0))
    return Calibration(shooter, fitN, n_dropped, selected, columns, notes, famC, fitC)


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
