"""A model file's answer as MuJoCo simulates it: the fitted model is the model that is written back.

When the simulator is a MuJoCo model file (MJCF / URDF), every model the held-out comparison scores (nominal,
calibrated, augmented, a challenger) is written back as MJCF through ``MjSpec`` (:func:`~phast_model.identify.
mjcf_write.calibrated_xml`: the changed body values, and each term as the joint / actuator attribute that expresses it)
and simulated by MuJoCo with the file's own timestep and integrator (:func:`~phast_model.identify.mujoco_sim.
mujoco_simulated`).  So Coulomb friction is MuJoCo's ``frictionloss`` constraint, not a smoothed ``sign(qdot)`` under
explicit substeps, and the held-out table scores what a MuJoCo user gets from ``calibrated.xml``.  A model with a
term no attribute expresses (a delay, a sensor map, a drag law MuJoCo lacks) is simulated by the tool's own
integrator, as before.
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from phast_gym.systems.base import System
from phast_gym.systems.mjcf import MJCFSystem
from phast_gym.systems.mjcf_tree import MJCFTree, ModelFileError

from ..identify.mjcf_write import Edit, calibrated_xml
from ..identify.mujoco_sim import StepProbe, mujoco_simulated, steps_per_interval
from ..identify.shooting import Windows
from .fitting.problem import Problem
from .vocabulary.registry import VOCABULARY
from .vocabulary.terms import AugmentedSystem

__all__ = ["in_mujoco", "is_model_file_system", "term_edit", "text_simulated", "written_form"]


def is_model_file_system(system: object) -> bool:
    """Whether ``system`` (or the base of an augmented one) is a model file's (MJCF / URDF)."""
    return isinstance(getattr(system, "base", system), MJCFSystem)


def term_edit(term: str, coordinate: int, coefficient: float, tree: MJCFTree) -> Edit | None:
    """The attribute edit that writes one found term into the model, or None (no attribute expresses it)."""
    attr = VOCABULARY[term].mjcf
    if attr is None:
        return None
    if attr == "gear":
        act = next((a for a in tree.actuators if a.joint == coordinate), None)
        return None if act is None else Edit(act.name, "gear", coefficient, "scale")
    return Edit(tree.joint_names[coordinate], attr, coefficient)


def _changed(base: MJCFSystem) -> dict[str, float] | None:
    """The base's parameters that differ from the file's values (None: one is not a single finite number, e.g. a
    merged batch of parameter sets)."""
    nominal = type(base)().params
    out = {}
    for k, v in base.params.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            return None
        if v != nominal[k]:
            out[k] = float(v)
    return out


def written_form(system: System) -> tuple[MJCFTree, dict[str, float], list[Edit]] | None:
    """(the file's tree, changed parameters, term edits) that write ``system`` back as MJCF, or None when it is not a
    model file's system or holds a term no MuJoCo attribute expresses."""
    base, terms = (system.base, system.terms) if isinstance(system, AugmentedSystem) else (system, ())
    if not isinstance(base, MJCFSystem):
        return None
    params = _changed(base)
    if params is None:
        return None
    edits = [term_edit(t.name, t.coordinate, t.coefficient, base.TREE) for t in terms]
    if any(e is None for e in edits):
        return None
    return base.TREE, params, [e for e in edits if e is not None]


def in_mujoco(system: System) -> System:
    """``system`` written back and simulated by MuJoCo (:mod:`this module <.written>`), or ``system`` itself when it
    cannot be written (not a model file's, a term MuJoCo lacks) or the written model does not compile (a negative
    total damping, say)."""
    if getattr(system, "external_rollout", None) is not None:  # already simulated by another engine
        return system
    form = written_form(system)
    if form is None:
        return system
    try:
        text = calibrated_xml(*form).text
    except ModelFileError:
        return system
    return text_simulated(text)


def text_simulated(text: str) -> System:
    """The MJCF ``text`` as MuJoCo simulates it (:func:`~phast_model.identify.mujoco_sim.mujoco_simulated`)."""
    with tempfile.TemporaryDirectory(prefix="phast-written-") as d:
        path = Path(d) / "model.xml"
        path.write_text(text)
        return mujoco_simulated(path)


# --------------------------------------------------------------------------- the step MuJoCo takes in the fits
#: RMS departure, in noise units, that the fits' coarser MuJoCo step may leave from the file's step on the nominal
#: model's shooting windows (:func:`coarse_substeps`)
COARSE_TOL = 0.05


def coarse_substeps(sys0: System, windows: Windows, X0: np.ndarray, substeps: int, sigma: np.ndarray,
                    x_scale: np.ndarray) -> int | None:
    """The fewest MuJoCo steps an interval, from the fits' RK4 ``substeps`` doubling, at which the nominal model file
    follows its own step within :data:`COARSE_TOL` noise units RMS (:class:`~..identify.mujoco_sim.StepProbe`).
    None (the file's step everywhere): not a MuJoCo-simulated RK4 file, or no coarser step holds.  The held-out
    rollouts are always at the file's step, and the answer is checked again at the end (``analysis``: a fitted
    friction can make the coarser step depart where the nominal model did not)."""
    system = in_mujoco(sys0)
    if not getattr(system, "engine_coarsens", False) or not windows.count:
        return None
    file_step = float(system.engine_timestep)  # type: ignore[attr-defined]
    file_k = steps_per_interval(float(np.mean(windows.sim_dt)), file_step)
    probe = StepProbe(system, windows, X0, substeps, sigma, x_scale)
    k = substeps
    while k < file_k:
        if probe.departure(k) <= COARSE_TOL:
            return k
        k *= 2
    return None


def with_coarse_step(problem: Problem) -> Problem:
    """``problem`` whose fits run a model file's MuJoCo at :func:`coarse_substeps` (unchanged for other simulators or
    when no coarser step holds)."""
    s = problem.shooting
    coarse = coarse_substeps(problem.sys0, s.windows, s.X0, s.substeps, problem.sigma, problem.x_scale)
    if coarse is None:
        return problem
    problem.log(f"MuJoCo in the fits at {coarse} steps a sample (the file's step for held-out rollouts)")
    return replace(problem, shooting=replace(s, engine_substeps=coarse))
