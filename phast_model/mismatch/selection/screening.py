"""The candidate terms the selection screens: every vocabulary term on every coordinate where it can act, scaled (by
its kind, :meth:`..vocabulary.registry.TermKind.scales`) so that z = 1 is about the force scale of that coordinate."""

from __future__ import annotations

import numpy as np

from phast_gym.systems.base import NUMPY

from ...identify.shooting import momentum
from ..fitting.problem import Problem
from ..vocabulary.candidates import Candidate
from ..vocabulary.registry import VOCABULARY, ScaleContext, TermKind
from ..vocabulary.terms import AugmentedSystem


def _screened(problem: Problem) -> list[TermKind]:
    """The kinds the selection screens (``Options.terms``, default the whole vocabulary), in that order."""
    return [VOCABULARY[name] for name in problem.opts.terms or tuple(VOCABULARY)]


def _coordinate_scales(problem: Problem, system: AugmentedSystem) -> tuple[np.ndarray, np.ndarray]:
    """rms of the conservative force (plus the port force) and of M_ii per coordinate, along the smoothed training
    states."""
    qs, vs, n, train = problem.qs, problem.vs, problem.n, problem.train
    qc = tuple(qs[..., i] for i in range(n))
    p = momentum(system, qs, vs)
    pc = tuple(p[..., i] for i in range(n))
    force_rms = np.array([float(np.sqrt(np.mean(np.asarray(f) ** 2))) for f in system.base.dH_dq(qc, pc, NUMPY)])
    if train.u is not None:
        force_rms = force_rms + np.sqrt(np.mean(train.u**2, axis=(0, 1)))
    force_rms = np.where(force_rms > 0, force_rms, 1.0)
    mass_rms = np.ones(n)
    if any(k.component == "inertia" for k in _screened(problem)):
        M = system.base.mass_matrix(qc, NUMPY)
        mass_rms = np.array([float(np.sqrt(np.mean(np.broadcast_to(np.asarray(M[i][i], float), qs.shape[:-1]) ** 2)))
                             for i in range(n)])
    return force_rms, mass_rms


def candidates(problem: Problem, system: AugmentedSystem) -> list[Candidate]:
    """Every term of the vocabulary (``Options.terms``) on every coordinate where it can act, at the calibrated
    ``system``:
    each kind scales its own candidates (:meth:`..vocabulary.registry.TermKind.scales`)."""
    qs, vs, train = problem.qs, problem.vs, problem.train
    force_rms, mass_rms = _coordinate_scales(problem, system)
    sensor_scale = problem.sigma * 10 + 1e-3 * problem.q_std
    out: list[Candidate] = []
    for i in range(problem.n):
        ctx = ScaleContext(qs[..., i], vs[..., i], float(force_rms[i]), float(mass_rms[i]), float(sensor_scale[i]),
                           problem.eps_coord[i], train.u[..., i] if problem.has_u[i] and train.u is not None else None,
                           i in train.angle_dims, float(train.dt), problem.n)
        for kind in _screened(problem):
            out += [Candidate(kind.name, i, sc.scale, sc.fd_step, sc.velocity) for sc in kind.scales(ctx)]
    return out
