"""A model file's answer as MuJoCo simulates it: the fitted model is the model that is written back.

When the simulator is a MuJoCo model file (MJCF / URDF), every fit (:func:`fits_in_mujoco`) and every model the
held-out comparison scores (nominal, calibrated, augmented, a challenger) is written back through ``MjSpec``
(:func:`~phast_model.identify.mjcf_write.calibrated_model`: the changed body values, and each term as the joint /
actuator attribute that expresses it, compiled in full precision) and simulated by MuJoCo with the file's own
integrator (:func:`~phast_model.identify.mujoco_sim.simulated_by`).  So Coulomb friction is MuJoCo's ``frictionloss``
constraint, not a smoothed ``sign(qdot)``, and the held-out table scores what a MuJoCo user gets from
``calibrated.xml`` (whose text, six digits a value, is scored as well).  A term no attribute expresses acts around
MuJoCo's rollout where it can (:func:`simulated_copy`: a deadzone or delay of the control, a constant force, a sensor
map or delay); a model with a state-dependent force MuJoCo lacks (a cubic stiffness, a drag law) is simulated by the
tool's own integrator.
"""
from __future__ import annotations

import copy
import math
import tempfile
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import TypeVar

import numpy as np

from phast_gym.systems.base import NUMPY, ParameterError, System
from phast_gym.systems.mjcf import MJCFSystem
from phast_gym.systems.mjcf_tree import MJCFTree, ModelFileError

from ..identify.mjcf_write import Edit, calibrated_model
from ..identify.mujoco_sim import StepProbe, mujoco_simulated, simulated_by, steps_per_interval
from ..identify.shooting import Windows
from .fitting.problem import Problem
from .vocabulary.registry import VOCABULARY
from .vocabulary.terms import AugmentedSystem

__all__ = ["family_engine", "fits_in_mujoco", "in_engine", "in_mujoco", "is_model_file_system", "mujoco_runs",
           "simulated_copy", "term_edit", "text_simulated", "written_form"]

_S = TypeVar("_S", bound=System)


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


def mujoco_runs(system: System) -> bool:
    """Whether another engine (MuJoCo) simulates ``system``: :func:`in_mujoco` falls back to the tool's own integrator
    where the written model does not compile or its values are refused (a negative total rotor inertia, say), and a
    refused copy (:func:`_refused`) simulates nothing."""
    return getattr(system, "external_rollout", None) is not None and not getattr(system, "refused", False)


def in_mujoco(system: System) -> System:
    """``system`` written back and simulated by MuJoCo (:mod:`this module <.written>`), or ``system`` itself when it
    cannot be written (not a model file's, a term MuJoCo cannot simulate) or the written model does not compile (a
    negative total damping, say).  Terms no attribute expresses but MuJoCo simulates (:attr:`~.vocabulary.registry.
    TermKind.in_mujoco`) act around the rollout (:func:`simulated_copy`)."""
    if mujoco_runs(system):  # already simulated by another engine
        return system
    if isinstance(system, AugmentedSystem) and any(t.kind.mjcf is None for t in system.terms):
        return simulated_copy(system) or system
    form = written_form(system)
    if form is None:
        return system
    base = system.base if isinstance(system, AugmentedSystem) else system
    assert isinstance(base, MJCFSystem)  # (a written form is a model file's)
    written = _written_values(base.params, form[2])
    if any(v < 0 for v in written.values()):  # a trial step past zero: MuJoCo would compile a negative rotor inertia
        return system  # with a warning, and the file's parameters refuse it
    try:  # compiled from the spec: the values in full precision (the text rounds them to six digits)
        model = calibrated_model(*form)
    except ModelFileError:
        return system
    out = copy.copy(base)
    out.params = {**out.params, **written}  # the values MuJoCo simulates
    return simulated_by(out, model)


def _written_values(params: Mapping[str, object], edits: list[Edit]) -> dict[str, float]:
    """The file's joint / actuator values (every one a parameter of the file's system) after the term edits."""
    out: dict[str, float] = {}
    for e in edits:
        key = f"{e.target}.{e.attr}"
        out[key] = e.applied(out.get(key, float(params[key])))  # type: ignore[arg-type]
    return out


def simulated_copy(system: AugmentedSystem) -> AugmentedSystem | None:
    """A copy of ``system`` whose rollouts are MuJoCo's: its attribute terms written into the file
    (:func:`in_mujoco`), port terms without an attribute (a deadzone) applied to the recorded control before the
    rollout, constant forces as ``qfrc_applied``, and its own delays and sensor maps around it
    (:func:`~phast_model.identify.shooting.simulate_qv`).  The copy keeps every other method (the weak form's vector
    field).  None when a term is one MuJoCo cannot simulate or the written model does not compile."""
    if not is_model_file_system(system) or not all(t.kind.in_mujoco for t in system.terms):
        return None
    eps, width = system.coulomb_eps_per_coordinate, system.deadzone_width
    engine = in_mujoco(AugmentedSystem(system.base, [t for t in system.terms if t.kind.mjcf is not None], eps, width))
    inner = getattr(engine, "external_rollout", None)
    if inner is None:
        return None
    ports = AugmentedSystem(system.base, [t for t in system.terms if t.component == "port" and t.kind.mjcf is None],
                            eps, width)
    force = np.zeros(system.n)
    for t in system.terms:
        if t.kind.applied_force:
            force[t.coordinate] -= float(t.kind.gradient(0.0, t.coefficient))

    def external_rollout(q0: np.ndarray, v0: np.ndarray, n_steps: int, u: np.ndarray | None,
                         dt: float | np.ndarray, max_substeps: int | None = None) -> np.ndarray:
        if u is not None and ports.terms:
            delivered = ports.port([u[..., i] for i in range(system.n)], NUMPY) or []
            u = np.stack(np.broadcast_arrays(*delivered), -1)
        return inner(q0, v0, n_steps, u, dt, max_substeps, qfrc=force if np.any(force) else None)

    out = copy.copy(system)
    out.external_rollout = external_rollout  # type: ignore[attr-defined]
    out.engine_timestep, out.engine_coarsens = engine.engine_timestep, engine.engine_coarsens  # type: ignore
    return out


def _refused(system: _S) -> _S:
    """A copy of ``system`` whose rollouts are NaN: values MuJoCo refuses (a negative total friction in a trial step)
    give a residual no fit accepts, never a silent switch to another integrator."""
    def external_rollout(q0: np.ndarray, v0: np.ndarray, n_steps: int, u: np.ndarray | None,
                         dt: float | np.ndarray, max_substeps: int | None = None) -> np.ndarray:
        return np.full((q0.shape[0], n_steps + 1, q0.shape[1]), np.nan)

    out = copy.copy(system)
    out.external_rollout = external_rollout  # type: ignore[attr-defined]
    out.refused = True  # type: ignore[attr-defined]
    return out


def in_engine(system: System) -> System:
    """``system`` as MuJoCo simulates it (:func:`in_mujoco`), or refused (:func:`_refused`) where MuJoCo does not
    simulate it (a trial step past a negative total rotor inertia, a body value the compiler rejects): a fit in MuJoCo
    never switches integrators silently."""
    out = in_mujoco(system)
    return out if mujoco_runs(out) else _refused(out)


def family_engine(system: AugmentedSystem) -> AugmentedSystem:
    """A fitted family's system as MuJoCo simulates it (:func:`simulated_copy`), or refused (:func:`_refused`)."""
    return simulated_copy(system) or _refused(system)


def fits_in_mujoco(problem: Problem) -> Problem:
    """``problem`` whose fits simulate a model file with MuJoCo (:func:`family_engine`): the fitted model is the one
    written back (MuJoCo's frictionloss, integrator and step, not a smoothed sign(qdot)).  Unchanged for another
    simulator, or a vocabulary with a term MuJoCo cannot simulate (a cubic stiffness, a drag law): then every fit runs
    the tool's own integrator, so that no chi^2 compares two engines."""
    terms = problem.opts.terms or tuple(VOCABULARY)
    if not is_model_file_system(problem.sys0) or not all(VOCABULARY[t].in_mujoco for t in terms):
        return problem
    return replace(problem, nominal_family=replace(problem.nominal_family, engine=family_engine))


def text_simulated(text: str) -> System:
    """The MJCF ``text`` as MuJoCo simulates it (:func:`~phast_model.identify.mujoco_sim.mujoco_simulated`)."""
    with tempfile.TemporaryDirectory(prefix="phast-written-") as d:
        path = Path(d) / "model.xml"
        path.write_text(text)
        try:
            return mujoco_simulated(path)
        except ParameterError as exc:  # a value the file's parameters refuse (a negative total damping)
            raise ModelFileError(f"the written model's values are refused: {exc}") from None


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
