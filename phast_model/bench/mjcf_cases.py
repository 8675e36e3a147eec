"""Concealed-effect cases for ``phast-mismatch`` with a MuJoCo model file as the simulator.

``benchmarks/mjcf_cases.py`` runs them.  Each case has a nominal MJCF file (the repository's
``mjcf_models/`` beside this module, :func:`cases`).  Its "reality" is the same file edited through ``mujoco.MjSpec``
(the effect hidden in MuJoCo's own terms: a joint's ``frictionloss`` / ``damping``, an actuator's ``gear``, the bodies'
``mass`` / ``ipos`` / ``inertia``), written to a temporary file and simulated by MuJoCo (RK4, 1 ms) under closed-loop
control: each recording interval (dt = 0.01 s) a PD controller (with gravity compensation from the nominal model for the
arms; on the 6-joint arm a computed-torque PD, acting through the nominal mass matrix) to smooth random targets computes
the motor commands from the measured, noisy q; the commands actually applied are recorded as ``u``.  The tool gets the
recordings (q with Gaussian noise, u, dt) and the NOMINAL file; the last 25% of the trajectories are held out.

* ``furuta``: rotary pendulum, the arm driven about z, the pendulum unactuated; hidden: pendulum frictionloss.
* ``arm3``: 3-joint arm (yaw, shoulder, elbow), 3 motors; hidden: shoulder damping and elbow frictionloss.
* ``arm3_cad``: the same arm, every non-zero body mass / centre of mass / principal inertia 3-8% off its file
  value (random signs); nothing else.
* ``weak_motor``: the same arm, the shoulder motor's gear 0.85 instead of 1.
* ``arm2_drives``: a 2-joint planar arm (shoulder, elbow), 2 motors; hidden: rotor inertia on both joints,
  shoulder frictionloss, elbow damping.
* ``arm6_mixed``: the 6-joint arm with the drives of ``arm6_drives`` and every body value 3-8% off at once (a
  vendor's file against the machine: motors left out, CAD values off); the drives are the rows to find.
* ``ur10e_mixed``: a UR10e-like arm built from Universal Robots' published DH parameters, masses and centres of mass,
  with a UR10e's drives (rotor inertia of 0.2-5 kg m^2, Coulomb friction of 2-15 N m and viscous friction on every
  joint, drawn about the real arm's identified sizes) and every body value 3-8% off; recorded under the machine's
  own computed-torque controller.
* ``cartpole``: a cart on a rail with a hanging pole, force on the cart; hidden: pole-hinge damping and cart
  frictionloss.

A case is right (as in ``phast-mismatch-bench``) when
* effect cases: the found rows (term, joint) are exactly the hidden ones, every coefficient within 30% of the
  hidden MuJoCo value, and the augmented model's held-out rollout RMSE <= 0.7x the calibrated one;
* ``arm3_cad``: no missing-physics row (parameter changes are the expected answer);
* ``weak_motor``: no term other than ``actuator_gain`` on the shoulder, and the shoulder's delivered gain
  (calibrated ``m_shoulder.gear`` times any ``actuator_gain`` coefficient) within 5% of 0.85.

``eff/noise`` in the table (:func:`table`) is the RMS of q(real) - q(nominal) over the first 100 samples of every
trajectory, both driven open loop by the recorded commands from the true initial state, in units of the q-noise
(as in ``phast-mismatch-bench``).
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np

if TYPE_CHECKING:
    import mujoco  # untyped to mypy (pyproject.toml): the annotations name MuJoCo's classes for the reader

    from ..mismatch import Report

#: the hidden physics of a case: (the real model's MjSpec, rng) -> the edits it makes
HiddenEdits = Callable[["mujoco.MjSpec", np.random.Generator], "list[Hidden]"]

#: where the repository keeps the cases' nominal files; the results name a case's model by this path
#: the nominal model files, shipped as package data
MODELS_DIR = Path(__file__).resolve().parent / "mjcf_models"
MODELS_LABEL = "phast_model/bench/mjcf_models"
DT = 0.01
#: the held-out share of the trajectories (the last ones)
HOLDOUT_SHARE = 0.25
#: judgement, as phast-mismatch-bench: coefficient within 30%, augmented/calibrated held-out RMSE <= 0.7,
#: a changed parameter (here: the weak motor's gear) within 5%
COEF_TOL, RATIO_MAX, PARAM_TOL = 0.3, 0.7, 0.05


@dataclass(frozen=True)
class Hidden:
    """One concealed edit of the nominal file: ``value`` replaces the attribute (element 0 of an array)."""

    kind: str  # joint | actuator | body
    target: str  # the element's name in the file
    attr: str  # frictionloss, damping, gear, mass, ipos_x, inertia_y, ...
    value: float
    term: str | None = None  # the vocabulary term that names it (None: a parameter change, not a term)

    @property
    def param(self) -> str:
        """The tool's parameter name of the edited attribute (``<name>.<attr>``)."""
        return f"{self.target}.{self.attr}"


@dataclass(frozen=True)
class Targets:
    """Smooth random targets of one actuated joint: centre + sum of ``n_sines`` sines of total amplitude ``amp``."""

    center: float = 0.0
    center_spread: float = 0.0  # per-trajectory centre uniform in center +- spread
    amp: float = 0.5
    f_lo: float = 0.2  # Hz
    f_hi: float = 1.0


@dataclass
class Case:
    name: str
    model: str  # file name in the models folder
    kind: str  # effect | cad | gear
    describe: str
    targets: dict[str, Targets]  # actuated joint -> targets
    bandwidth_hz: dict[str, float]  # actuated joint -> PD bandwidth (critically damped, zeta 0.7)
    hidden: HiddenEdits = field(repr=False, default=lambda spec, rng: [])
    gravity_comp: bool = False
    #: the PD acts through the nominal mass matrix (computed torque): every mode of a long chain gets the bandwidth;
    #: a per-joint PD on the diagonal alone drives the 6-joint arm's fast modes unstable at 100 Hz
    computed_torque: bool = False
    #: the PD and the gravity torque through the machine's own model (its controller knows its drives and inertias,
    #: as an industrial arm's does), not the nominal file's: a wrist whose rotor inertia is a hundred times its link's
    #: would barely move under gains sized for the link alone
    own_controller: bool = False
    free_q0: dict[str, float] = field(default_factory=dict)  # unactuated joint -> initial angle uniform in +- value
    n_traj: int = 16
    T: int = 400
    noise: float = 0.002  # q noise std (rad, m)
    rollout_window: float | None = None  # held-out rollout windows [s] (None: whole trajectories)
    models_dir: Path | None = None  # the folder of ``model`` (set by :func:`cases`)


def _joint_edit(target: str, attr: str, value: float, term: str) -> HiddenEdits:
    return lambda spec, rng: [Hidden("joint", target, attr, value, term)]


def _rigid(factors: dict[str, float], moments: np.ndarray) -> dict[str, float]:
    """The principal moments' error factors, all of one sign (the first's) where the drawn ones break A + B >= C (a
    slender link: a CAD error leaves a rigid body), and all the first's where even that breaks it; the same factors
    otherwise."""
    keys = [f"inertia_{a}" for a in "xyz"]
    if not all(k in factors for k in keys):
        return factors

    def rigid(f: dict[str, float]) -> bool:
        new = moments * np.array([f[k] for k in keys])
        return bool(np.all(2 * new <= new.sum()))

    if rigid(factors):
        return factors
    sign = math.copysign(1.0, factors[keys[0]] - 1.0)
    same = {**factors, **{k: 1.0 + sign * abs(factors[k] - 1.0) for k in keys}}
    return same if rigid(same) else {**factors, **{k: factors[keys[0]] for k in keys}}


def _cad_errors(spec: mujoco.MjSpec, rng: np.random.Generator) -> list[Hidden]:
    """Every non-zero mass, centre-of-mass coordinate and principal inertia of every body 3-8% off (random signs; a
    body stays rigid: :func:`_rigid`)."""
    out = []
    for body in spec.bodies:
        if not body.name or body.name == "world":
            continue
        vals = {"mass": body.mass, **{f"ipos_{a}": body.ipos[k] for k, a in enumerate("xyz")},
                **{f"inertia_{a}": body.inertia[k] for k, a in enumerate("xyz")}}
        # a body whose inertia MuJoCo infers from its geoms has none to edit
        factors = {attr: 1.0 + rng.choice([-1.0, 1.0]) * rng.uniform(0.03, 0.08)
                   for attr, v in vals.items() if v != 0.0 and np.isfinite(v)}
        factors = _rigid(factors, np.array(body.inertia, dtype=float))
        out += [Hidden("body", body.name, attr, float(f"{float(vals[attr]) * f:.6g}"))  # as to_xml writes it
                for attr, f in factors.items()]
    return out


ARM_TARGETS = {"yaw": Targets(0.0, 0.3, 0.6, 0.15, 0.8), "shoulder": Targets(0.5, 0.2, 0.45, 0.2, 1.0),
               "elbow": Targets(0.4, 0.2, 0.5, 0.2, 1.2)}
ARM_BANDWIDTH = {"yaw": 1.5, "shoulder": 1.5, "elbow": 1.5}


class CaseSize(TypedDict):
    """A case's recordings: ``n_traj`` trajectories of ``T`` samples (:class:`Case` fields)."""

    n_traj: int
    T: int


#: the arm's size: its analysis time is set by the number of integration steps the fits take (the per-call cost of the
#: 3-body model), hardly by the number of recordings, so the arm cases use the smaller end of 12-16 x 300-400
ARM_SIZE: CaseSize = {"n_traj": 12, "T": 300}

ARM6_JOINTS = [f"j{i}" for i in range(1, 7)]
ARM6_TARGETS = {j: Targets(0.0, 0.2, 0.5 - 0.04 * k, 0.2, 1.0) for k, j in enumerate(ARM6_JOINTS)}
ARM6_BANDWIDTH = {j: 1.5 for j in ARM6_JOINTS}


def _drives6(spec: mujoco.MjSpec, rng: np.random.Generator) -> list[Hidden]:
    """Geared motors the file leaves out: rotor inertia behind j2..j6, frictionloss on j2, j4, j6 and damping on j1, j3.
    Behind j1 a rotor inertia is one number with link1's inertia about that axis, and behind j2 with link2's
    ``inertia_x`` (j2's axis is a principal axis of link2 and link1 turns about an orthogonal one): the data cannot tell
    them apart, and the tool, which tries a CAD file's drives before its body values, names the j2 one a rotor
    inertia as it was hidden."""
    arm = [Hidden("joint", f"j{i}", "armature", a, "armature")
           for i, a in zip(range(2, 7), (0.04, 0.02, 0.015, 0.008, 0.004))]
    fric = [Hidden("joint", j, "frictionloss", c, "coulomb_friction")
            for j, c in (("j2", 0.3), ("j4", 0.15), ("j6", 0.05))]
    damp = [Hidden("joint", j, "damping", c, "viscous_damping") for j, c in (("j1", 0.2), ("j3", 0.1))]
    return arm + fric + damp


def _mixed(drives: HiddenEdits) -> HiddenEdits:
    """``drives`` and, at once, every body value 3-8% off (:func:`_cad_errors`): the situation of a real arm from its
    vendor's file, motors left out and a CAD model that is not the machine.  The drives are the rows to find; the
    body values are parameter changes, not missing physics."""
    return lambda spec, rng: drives(spec, rng) + _cad_errors(spec, rng)


ARM7_JOINTS = [f"j{i}" for i in range(1, 8)]
ARM7_TARGETS = {j: Targets(0.0, 0.2, 0.45 - 0.03 * k, 0.2, 1.0) for k, j in enumerate(ARM7_JOINTS)}
ARM7_BANDWIDTH = {j: 1.5 for j in ARM7_JOINTS}


def _drives7(spec: mujoco.MjSpec, rng: np.random.Generator) -> list[Hidden]:
    """Geared motors on every joint with random sizes (drawn from the seed): rotor inertia on j2..j7 (j1's is one
    number with link1's inertia about z), and on each joint either frictionloss or damping (or both, on the base
    roll), each value 0.5-2x a nominal size that falls towards the wrist."""
    out = []
    for k, j in enumerate(ARM7_JOINTS):
        scale = 0.6 ** k
        if k > 0:
            out.append(Hidden("joint", j, "armature", float(f"{0.05 * scale * rng.uniform(0.5, 2.0):.4g}"), "armature"))
        kinds = ("frictionloss", "damping") if k == 0 else (("frictionloss",) if rng.uniform() < 0.5 else ("damping",))
        for attr in kinds:
            size = (0.4 if attr == "frictionloss" else 0.3) * scale * rng.uniform(0.5, 2.0)
            term = "coulomb_friction" if attr == "frictionloss" else "viscous_damping"
            out.append(Hidden("joint", j, attr, float(f"{size:.4g}"), term))
    return out


def _drives3(spec: mujoco.MjSpec, rng: np.random.Generator) -> list[Hidden]:
    """The 3-joint arm's geared motors: rotor inertia on every joint (behind the yaw one number with the turret's
    inertia), frictionloss on the shoulder and elbow, damping on the yaw."""
    return [Hidden("joint", "yaw", "armature", 0.004, "armature"),
            Hidden("joint", "shoulder", "armature", 0.012, "armature"),
            Hidden("joint", "elbow", "armature", 0.006, "armature"),
            Hidden("joint", "shoulder", "frictionloss", 0.08, "coulomb_friction"),
            Hidden("joint", "elbow", "frictionloss", 0.04, "coulomb_friction"),
            Hidden("joint", "yaw", "damping", 0.03, "viscous_damping")]


UR_JOINTS = [f"{j}_joint" for j in ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")]
UR_TARGETS = {j: Targets(c, 0.2, 0.4, 0.2, 0.8) for j, c in zip(UR_JOINTS, (0.0, -1.57, 1.57, -1.57, -1.57, 0.0))}
UR_BANDWIDTH = {j: 3.0 for j in UR_JOINTS}
#: a UR10e's drives at the sizes identified on the real arm (docs/robot_models.md, "A real UR10e"): reflected rotor
#: inertia [kg m^2], gearbox Coulomb friction [N m] and viscous friction [N m s] per joint
UR_DRIVES = {"armature": (4.2, 5.3, 1.1, 0.24, 0.26, 0.32), "frictionloss": (14.0, 15.0, 6.0, 2.3, 2.8, 2.4),
             "damping": (20.0, 19.0, 8.6, 3.0, 2.3, 3.0)}
UR_TERMS = {"armature": "armature", "frictionloss": "coulomb_friction", "damping": "viscous_damping"}


def _ur_drives(spec: mujoco.MjSpec, rng: np.random.Generator) -> list[Hidden]:
    """Every joint's rotor inertia, Coulomb and viscous friction at a UR10e's sizes, each 0.8-1.25 times them (drawn
    from the seed): 18 drive values."""
    return [Hidden("joint", j, attr, float(f"{v * rng.uniform(0.8, 1.25):.4g}"), UR_TERMS[attr])
            for attr, values in UR_DRIVES.items() for j, v in zip(UR_JOINTS, values)]


CASES: dict[str, Case] = {c.name: c for c in [
    Case("furuta", "furuta.xml", "effect", "rotary pendulum; hidden: pendulum frictionloss",
         {"arm": Targets(0.0, 0.5, 0.8, 0.2, 1.0)}, {"arm": 2.0},
         _joint_edit("pendulum", "frictionloss", 3e-4, "coulomb_friction"), free_q0={"pendulum": 0.3}),
    Case("arm3", "arm3.xml", "effect", "3-joint arm; hidden: shoulder damping, elbow frictionloss", ARM_TARGETS,
         ARM_BANDWIDTH,
         lambda spec, rng: [Hidden("joint", "shoulder", "damping", 0.05, "viscous_damping"),
                            Hidden("joint", "elbow", "frictionloss", 0.03, "coulomb_friction")], gravity_comp=True,
         **ARM_SIZE),
    Case("arm3_cad", "arm3.xml", "cad", "3-joint arm; hidden: every body mass/ipos/inertia 3-8% off", ARM_TARGETS,
         ARM_BANDWIDTH, _cad_errors, gravity_comp=True, **ARM_SIZE),
    Case("weak_motor", "arm3.xml", "gear", "3-joint arm; hidden: shoulder motor gear 0.85", ARM_TARGETS, ARM_BANDWIDTH,
         lambda spec, rng: [Hidden("actuator", "m_shoulder", "gear", 0.85)], gravity_comp=True, **ARM_SIZE),
    Case("arm3_drives", "arm3.xml", "effect", "3-joint arm; hidden: rotor inertia on every joint (behind the yaw it "
         "is one number with the turret's inertia), frictionloss on two joints, damping on one", ARM_TARGETS,
         ARM_BANDWIDTH,
         _drives3, gravity_comp=True, **ARM_SIZE),
    Case("arm2_drives", "arm2.xml", "effect", "2-joint planar arm; hidden: rotor inertia on both joints (the "
         "shoulder's is one number with the upper arm's inertia about its axis), frictionloss on the shoulder, "
         "damping on the elbow", {j: ARM_TARGETS[j] for j in ("shoulder", "elbow")},
         {j: ARM_BANDWIDTH[j] for j in ("shoulder", "elbow")},
         lambda spec, rng: [Hidden("joint", "shoulder", "armature", 0.01, "armature"),
                            Hidden("joint", "elbow", "armature", 0.005, "armature"),
                            Hidden("joint", "shoulder", "frictionloss", 0.06, "coulomb_friction"),
                            Hidden("joint", "elbow", "damping", 0.02, "viscous_damping")], gravity_comp=True,
         **ARM_SIZE),
    Case("arm6_drives", "arm6.xml", "effect", "6-joint spatial arm; hidden: rotor inertia on five joints, "
         "frictionloss on three, damping on two", ARM6_TARGETS, ARM6_BANDWIDTH, _drives6, gravity_comp=True,
         computed_torque=True, n_traj=16, T=400),
    Case("arm6_mixed", "arm6.xml", "effect", "6-joint spatial arm; hidden: the drives of arm6_drives and every "
         "body value 3-8% off", ARM6_TARGETS, ARM6_BANDWIDTH, _mixed(_drives6), gravity_comp=True,
         computed_torque=True, n_traj=16, T=400),
    Case("cartpole", "cartpole.xml", "effect", "cart with hanging pole; hidden: pole damping, cart frictionloss",
         {"slider": Targets(0.0, 0.05, 0.15, 0.15, 0.6)}, {"slider": 1.0},
         lambda spec, rng: [Hidden("joint", "hinge", "damping", 0.004, "viscous_damping"),
                            Hidden("joint", "slider", "frictionloss", 0.3, "coulomb_friction")],
         free_q0={"hinge": 0.3}),
    Case("arm7_drives", "arm7.xml", "effect", "7-joint spatial arm (roll, pitch/yaw, wrist roll); hidden: drives "
         "with random sizes on every joint (rotor inertia on six, frictionloss or damping on each)", ARM7_TARGETS,
         ARM7_BANDWIDTH, _drives7, gravity_comp=True, computed_torque=True, n_traj=16, T=400),
    Case("ur10e_mixed", "ur10e_like.xml", "effect", "UR10e-like arm (UR's published DH, masses, centres of mass); "
         "hidden: rotor inertia, Coulomb and viscous friction on every joint at a UR10e's sizes and every body value "
         "3-8% off", UR_TARGETS, UR_BANDWIDTH, _mixed(_ur_drives), gravity_comp=True, computed_torque=True,
         own_controller=True, n_traj=16, T=400),
    Case("arm3_mixed", "arm3.xml", "effect", "3-joint arm; hidden: the drives of arm3_drives and every body value "
         "3-8% off (17 values)", ARM_TARGETS, ARM_BANDWIDTH, _mixed(_drives3), gravity_comp=True, **ARM_SIZE),
    Case("arm7_mixed", "arm7.xml", "effect", "7-joint spatial arm; hidden: the drives of arm7_drives (drawn from the "
         "seed) and every body value 3-8% off", ARM7_TARGETS, ARM7_BANDWIDTH, _mixed(_drives7), gravity_comp=True,
         computed_torque=True, n_traj=16, T=400),
]}


# ----------------------------------------------------------------------------------------------------- the models


def cases(models_dir: str | Path = MODELS_DIR) -> dict[str, Case]:
    """:data:`CASES` with their nominal files in ``models_dir`` (by default the package's ``mjcf_models``)."""
    return {name: replace(c, models_dir=Path(models_dir)) for name, c in CASES.items()}


def nominal_path(case: Case) -> Path:
    if case.models_dir is None:
        raise ValueError(f"case {case.name!r} has no models folder: take it from cases(models_dir)")
    return case.models_dir / case.model


def apply_hidden(spec: mujoco.MjSpec, hidden: list[Hidden]) -> None:
    """Write the concealed values into ``spec`` (MuJoCo 4: joint damping / stiffness and actuator gear are arrays)."""
    for h in hidden:
        if h.kind == "joint":
            el = spec.joint(h.target)
        elif h.kind == "actuator":
            el = spec.actuator(h.target)
        else:
            el = spec.body(h.target)
        if el is None:
            raise ValueError(f"no {h.kind} {h.target!r} in the model")
        name, _, axis = h.attr.partition("_")
        if h.kind == "body" and axis:
            arr = np.array(getattr(el, name), dtype=float)
            arr["xyz".index(axis)] = h.value
            setattr(el, name, arr)
            continue
        old = getattr(el, h.attr)
        if np.ndim(old):
            arr = np.array(old, dtype=float)
            arr[0] = h.value
            setattr(el, h.attr, arr)
        else:
            setattr(el, h.attr, float(h.value))


def hidden_effects(case: Case, seed: int) -> list[Hidden]:
    import mujoco

    spec = mujoco.MjSpec.from_file(str(nominal_path(case)))
    return case.hidden(spec, np.random.default_rng([seed, 7]))


def write_real(case: Case, hidden: list[Hidden], out_dir: str | Path) -> Path:
    """The "real" model: the nominal file with the hidden edits, saved as ``out_dir/<case>_real.xml``."""
    import mujoco

    spec = mujoco.MjSpec.from_file(str(nominal_path(case)))
    apply_hidden(spec, hidden)
    spec.compile()
    path = Path(out_dir) / f"{case.name}_real.xml"
    path.write_text(spec.to_xml())
    mujoco.MjModel.from_xml_path(str(path))
    return path


def parameter_values(path: str | Path) -> dict[str, float]:
    """The model's parameters in the tool's names (``<body>.mass``, ``<joint>.damping``, ``<act>.gear``, ...)."""
    from phast_gym.systems.mjcf import param_specs
    from phast_gym.systems.mjcf_tree import read_tree

    return {k: float(p.default) for k, p in param_specs(read_tree(path)).items() if isinstance(p.default, (int, float))}


#: compiled-model fields that must not differ between nominal and real (the structure: kinematics, joint types,
#: transmissions, actuator dynamics, options) - everything a hidden edit must leave alone
STRUCTURE = ("body_parentid", "body_pos", "body_quat", "body_iquat", "jnt_type", "jnt_bodyid", "jnt_pos", "jnt_axis",
             "qpos0", "qpos_spring", "actuator_trntype", "actuator_trnid", "actuator_gaintype", "actuator_gainprm",
             "actuator_biastype", "actuator_biasprm", "actuator_dyntype", "actuator_ctrllimited", "actuator_ctrlrange")


def model_differences(nominal: str | Path, real: str | Path) -> dict[str, tuple[float, float]]:
    """Every parameter whose value differs between the two files, ``name -> (nominal, real)``; raises when their
    structure (kinematics, joints, transmissions, options) differs."""
    import mujoco

    a, b = mujoco.MjModel.from_xml_path(str(nominal)), mujoco.MjModel.from_xml_path(str(real))
    for f in STRUCTURE:
        if not np.array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f))):
            raise AssertionError(f"the real model's {f} differs from the nominal one")
    for f in ("gravity", "timestep", "integrator", "disableflags"):
        if not np.array_equal(np.asarray(getattr(a.opt, f)), np.asarray(getattr(b.opt, f))):
            raise AssertionError(f"the real model's option {f} differs from the nominal one")
    pa, pb = parameter_values(nominal), parameter_values(real)
    if set(pa) != set(pb):
        raise AssertionError("the two models have different parameter names")
    return {k: (pa[k], pb[k]) for k in pa if pa[k] != pb[k]}


# ------------------------------------------------------------------------------------------------ the recordings


def _targets(case: Case, rng: np.random.Generator,
             t: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Position and velocity targets of each actuated joint at the times ``t``."""
    pos, vel = {}, {}
    for j, tg in case.targets.items():
        n = 3
        w = rng.dirichlet(np.ones(n)) * tg.amp
        f = rng.uniform(tg.f_lo, tg.f_hi, n) * 2 * math.pi
        ph = rng.uniform(0, 2 * math.pi, n)
        c = tg.center + rng.uniform(-tg.center_spread, tg.center_spread)
        pos[j] = c + np.sum(w[:, None] * np.sin(f[:, None] * t + ph[:, None]), axis=0)
        vel[j] = np.sum((w * f)[:, None] * np.cos(f[:, None] * t + ph[:, None]), axis=0)
    return pos, vel


def _pd_gains(case: Case, nominal: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """Per-actuator PD gains: from the nominal model's mass-matrix diagonal at the targets' centre, or per unit
    inertia for a computed-torque PD (:attr:`Case.computed_torque`); critically damped at zeta 0.7."""
    import mujoco

    d = mujoco.MjData(nominal)
    for j, tg in case.targets.items():
        d.qpos[nominal.joint(j).qposadr[0]] = tg.center
    mujoco.mj_forward(nominal, d)
    M = np.zeros((nominal.nv, nominal.nv))
    mujoco.mj_fullM(nominal, d, M)
    kp, kd = np.zeros(nominal.nu), np.zeros(nominal.nu)
    for a in range(nominal.nu):
        jn = mujoco.mj_id2name(nominal, mujoco.mjtObj.mjOBJ_JOINT, int(nominal.actuator_trnid[a, 0]))
        dof = int(nominal.jnt_dofadr[nominal.joint(jn).id])
        w = 2 * math.pi * case.bandwidth_hz[jn]
        inertia = 1.0 if case.computed_torque else M[dof, dof]
        kp[a], kd[a] = inertia * w**2, 2 * 0.7 * w * inertia
    return kp, kd


@dataclass
class _Controller:
    """The recording's controller: PD on the measured q (filtered finite-difference velocity), optionally through its
    ``model``'s mass matrix, plus that model's gravity torque (``model``: the nominal file, or the machine's own:
    :attr:`Case.own_controller`)."""

    case: Case
    model: mujoco.MjModel
    act_q: list[int]
    act_v: list[int]
    gear: np.ndarray
    alpha: float = 0.5  # first-order filter of the finite-difference velocity

    def __post_init__(self) -> None:
        import mujoco

        self.kp, self.kd = _pd_gains(self.case, self.model)
        self.data = mujoco.MjData(self.model)
        self.reset()

    def reset(self) -> None:
        self.v_est = np.zeros(len(self.act_q))
        self.q_prev: np.ndarray | None = None

    def command(self, qm: np.ndarray, q_ref: np.ndarray, v_ref: np.ndarray) -> np.ndarray:
        """Motor commands for the measured ``qm`` and the actuated joints' targets ``q_ref``, ``v_ref``."""
        import mujoco

        if self.q_prev is not None:
            self.v_est = (1 - self.alpha) * self.v_est + self.alpha * (qm[self.act_q] - self.q_prev[self.act_q]) / DT
        self.q_prev = qm
        tau = self.kp * (q_ref - qm[self.act_q]) + self.kd * (v_ref - self.v_est)
        if self.case.gravity_comp or self.case.computed_torque:
            dn = self.data
            dn.qpos[:] = qm
            dn.qvel[:] = 0
            mujoco.mj_forward(self.model, dn)
            if self.case.computed_torque:
                M = np.zeros((self.model.nv, self.model.nv))
                mujoco.mj_fullM(self.model, dn, M)
                tau = M[np.ix_(self.act_v, self.act_v)] @ tau
            if self.case.gravity_comp:
                tau = tau + dn.qfrc_bias[self.act_v]
        return tau / self.gear


def record(case: Case, real_path: str | Path, n_traj: int, T: int, seed: int,
           noise: float | None = None) -> dict[str, Any]:
    """Closed-loop recordings of the real model: ``q`` (N, T, n) with noise, ``u`` (N, T-1, m) the commands applied
    over each interval, ``dt``; plus ``q_true``, ``q0``, ``v0`` (what the tool is not given)."""
    import mujoco

    noise = case.noise if noise is None else noise
    real = mujoco.MjModel.from_xml_path(str(real_path))
    nom = mujoco.MjModel.from_xml_path(str(nominal_path(case)))
    k = max(1, int(round(DT / real.opt.timestep)))
    real.opt.timestep = DT / k
    d = mujoco.MjData(real)
    act_jnt = [int(nom.actuator_trnid[a, 0]) for a in range(nom.nu)]
    act_names = [mujoco.mj_id2name(nom, mujoco.mjtObj.mjOBJ_JOINT, j) for j in act_jnt]
    act_q = [int(nom.jnt_qposadr[j]) for j in act_jnt]
    ctl = _Controller(case, real if case.own_controller else nom, act_q, [int(nom.jnt_dofadr[j]) for j in act_jnt],
                      nom.actuator_gear[:, 0].copy())
    rng = np.random.default_rng([seed, 1])
    t = np.arange(T) * DT
    n, m = real.nq, real.nu
    q_true, q_meas, u = np.zeros((n_traj, T, n)), np.zeros((n_traj, T, n)), np.zeros((n_traj, T - 1, m))
    q0s, v0s = np.zeros((n_traj, n)), np.zeros((n_traj, n))
    for b in range(n_traj):
        pos, vel = _targets(case, rng, t)
        mujoco.mj_resetData(real, d)
        for a, name in enumerate(act_names):
            d.qpos[act_q[a]] = pos[name][0] + rng.normal(0, 0.03)
        for name, r in case.free_q0.items():
            d.qpos[nom.joint(name).qposadr[0]] = rng.uniform(-r, r)
        q0s[b], v0s[b] = d.qpos.copy(), d.qvel.copy()
        ctl.reset()
        for i in range(T):
            q_true[b, i] = d.qpos
            q_meas[b, i] = d.qpos + rng.normal(0, noise, n)
            if i == T - 1:
                break
            u[b, i] = ctl.command(q_meas[b, i], np.array([pos[nm][i] for nm in act_names]),
                                  np.array([vel[nm][i] for nm in act_names]))
            d.ctrl[:] = u[b, i]
            for _ in range(k):
                mujoco.mj_step(real, d)
    if not (np.all(np.isfinite(q_meas)) and np.all(np.isfinite(u))):
        raise RuntimeError(f"{case.name}: the recording diverged")
    return {"q": q_meas, "u": u, "dt": DT, "q_true": q_true, "q0": q0s, "v0": v0s, "noise": noise}


def effect_over_noise(case: Case, real_path: str | Path, rec: dict[str, Any], window: int = 100) -> float:
    """RMS of q(real) - q(nominal), both open loop under the recorded commands from the true initial states, over
    the first ``window`` samples, in units of the q-noise."""
    from ..identify.mujoco_sim import rollout_q

    n_steps = min(window, rec["u"].shape[1])
    ctrl = rec["u"][:, :n_steps]
    a = rollout_q(str(real_path), rec["q0"], rec["v0"], ctrl, DT, n_steps)
    b = rollout_q(str(nominal_path(case)), rec["q0"], rec["v0"], ctrl, DT, n_steps)
    return float(np.sqrt(np.mean((a - b) ** 2)) / rec["noise"])


#: each case's share of the data seed, frozen as its documented runs drew it (the order of :data:`CASES` at the time):
#: a case added later takes the next number, and reordering the list changes no recording
SEED_INDEX = {"furuta": 0, "arm3": 1, "arm3_cad": 2, "weak_motor": 3, "arm3_drives": 4, "arm6_drives": 5,
              "cartpole": 6, "arm7_drives": 7, "arm6_mixed": 6, "arm2_drives": 5, "ur10e_mixed": 8,
              "arm3_mixed": 9, "arm7_mixed": 10}


def case_seed(seed: int, name: str) -> int:
    """The data seed of one case: the same whichever cases run together, and whatever their order in the list."""
    return 100 * seed + SEED_INDEX[name]


def holdout_indices(n_traj: int) -> list[int]:
    k = max(1, int(round(n_traj * HOLDOUT_SHARE)))
    return list(range(n_traj - k, n_traj))


# ---------------------------------------------------------------------------------------------------- the judgement


def actuator_joint(case: Case, actuator: str) -> str:
    """The name of the joint an actuator of the case's model drives."""
    import mujoco

    m = mujoco.MjModel.from_xml_path(str(nominal_path(case)))
    return str(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.actuator(actuator).trnid[0])))


class FoundTerm(TypedDict):
    """A missing-physics row the tool reported (its term, joint and file attribute, coefficient and 95% interval)."""

    term: str
    joint: str | None
    mjcf: str | None
    coefficient: float
    ci95: list[float] | None


def _rows(rep: Report) -> list[FoundTerm]:
    return [{"term": r["term"], "joint": r.get("joint"), "mjcf": r.get("mjcf"), "coefficient": r["coefficient"],
             "ci95": r.get("ci95")} for r in rep.missing_physics]


def _changed(rep: Report) -> dict[str, dict[str, Any]]:
    return {k: v for k, v in rep.sim["calibrated"].items() if v.get("ci95") is not None}


def judge(case: Case, hidden: list[Hidden], found: list[FoundTerm], changed: dict[str, dict[str, Any]],
          fit: dict[str, dict[str, float]]) -> dict[str, Any]:
    """Pass / fail with the reason, and the coefficient errors."""
    got: dict[tuple[str | None, str | None], float] = {(r["term"], r["joint"]): r["coefficient"] for r in found}
    ratio = fit["augmented"]["rollout_rmse"] / max(fit["calibrated"]["rollout_rmse"], 1e-300)
    out: dict[str, Any] = {"ratio_augmented_over_calibrated": ratio, "coef_rel_err": {}}
    if case.kind == "effect":  # the hidden terms are the rows to find; hidden body values may change as parameters
        want = {(h.term, h.target): h.value for h in hidden if h.term is not None}
        errs = {f"{t}[{j}]": abs(got[(t, j)] - v) / v for (t, j), v in want.items() if (t, j) in got}
        out["coef_rel_err"] = errs
        missing, extra = sorted(set(want) - set(got)), sorted(set(got) - set(want))
        bad = [f"{k} {v:.0%} off" for k, v in errs.items() if v > COEF_TOL]
        reasons = ([f"missed {t}[{j}]" for t, j in missing] + [f"extra {t}[{j}]" for t, j in extra] + bad
                   + ([f"augmented/calibrated held-out RMSE {ratio:.2f} > {RATIO_MAX}"] if ratio > RATIO_MAX else []))
        ok = not reasons
        reason = "; ".join(reasons) if reasons else (
            f"found exactly the hidden rows, coefficients within {max(errs.values()):.0%}, "
            f"held-out RMSE ratio {ratio:.2f}")
    elif case.kind == "cad":
        ok = not found
        reason = ("no missing physics named; " + f"{len(changed)} parameter(s) changed" if ok
                  else "named " + ", ".join(f"{t}[{j}]" for t, j in got) + " for CAD errors alone")
    else:  # gear
        h = hidden[0]
        act_joint = actuator_joint(case, h.target)
        others = [f"{t}[{j}]" for t, j in got if not (t == "actuator_gain" and j == act_joint)]
        gear = changed[h.param]["fitted"] if h.param in changed else 1.0
        gain = gear * got.get(("actuator_gain", act_joint), 1.0)
        err = abs(gain - h.value) / h.value
        out["coef_rel_err"] = {f"{h.param} (delivered gain {gain:.4g})": err}
        reasons = [f"extra {e}" for e in others] + ([f"delivered gain {gain:.4g}, {err:.1%} off {h.value}"]
                                                    if err > PARAM_TOL else [])
        ok = not reasons
        term = ("actuator_gain", act_joint)
        how = ", ".join(([f"{h.param} fitted {gear:.4g}"] if h.param in changed else [f"{h.param} unchanged"])
                        + ([f"actuator_gain[{act_joint}] {got[term]:.4g}"] if term in got else []))
        reason = "; ".join(reasons) if reasons else f"{how}: delivered gain {gain:.4g} ({err:.1%} off), no other term"
    out.update(passed=bool(ok), reason=reason)
    return out


# ------------------------------------------------------------------------------------------------------- the runner


def run_case(case: Case, seed: int, out_dir: Path | None = None, progress: bool = False, n_traj: int | None = None,
             T: int | None = None, threads: int = 1) -> dict[str, Any]:
    from ..mismatch import analyze

    n_traj, T = n_traj or case.n_traj, T or case.T
    hidden = hidden_effects(case, seed)
    with tempfile.TemporaryDirectory(prefix=f"mjcf-{case.name}-") as tmp:
        real = write_real(case, hidden, tmp)
        diff = model_differences(nominal_path(case), real)
        if set(diff) != {h.param for h in hidden}:
            raise AssertionError(f"{case.name}: the real model differs in {sorted(diff)}, "
                                 f"hidden {sorted(h.param for h in hidden)}")
        t0 = time.time()
        rec = record(case, real, n_traj, T, seed)
        record_s = time.time() - t0
        eff = effect_over_noise(case, real, rec)
        real_text = Path(real).read_text()
    hold = holdout_indices(n_traj)
    t0, c0 = time.time(), time.process_time()
    rep = analyze(str(nominal_path(case)), {"q": rec["q"], "u": rec["u"], "dt": rec["dt"]}, holdout_trajectories=hold,
                  progress=progress, rollout_window=case.rollout_window, threads=threads)
    wall, cpu = time.time() - t0, time.process_time() - c0
    found, changed = _rows(rep), _changed(rep)
    fit = {k: {"rollout_rmse": v["rollout_rmse"], "one_step_mse": v["one_step_mse"]} for k, v in rep.fit.items()
           if isinstance(v, dict) and "rollout_rmse" in v}
    verdict = judge(case, hidden, found, changed, fit)
    if out_dir is not None:
        rep.write(out_dir / case.name)
        (out_dir / case.name / "real_model.xml").write_text(real_text)
    return {"case": case.name, "model": f"{MODELS_LABEL}/{case.model}", "kind": case.kind, "describe": case.describe,
            "hidden": [{"kind": h.kind, "target": h.target, "attr": h.attr, "parameter": h.param,
                        "nominal": diff[h.param][0], "real": h.value, "term": h.term} for h in hidden],
            "n_traj": n_traj, "T": T, "dt": DT, "noise": rec["noise"], "holdout_trajectories": hold,
            "max_abs_q_true": np.max(np.abs(rec["q_true"]), axis=(0, 1)).round(3).tolist(),
            "max_abs_u": np.max(np.abs(rec["u"]), axis=(0, 1)).round(3).tolist(),
            "effect_over_noise_first_100_samples": eff, "found": found, "calibrated_changed": changed, "fit": fit,
            "record_s": record_s, "wall_s": wall, "cpu_s": cpu, "threads": threads,
            "engine_step": rep.diagnostics.get("engine_step"), **verdict, "summary": rep.summary}


def _hidden_text(r: dict[str, Any]) -> str:
    if r["kind"] == "cad":
        return f"CAD errors on {len(r['hidden'])} body values"
    return ", ".join(f"{h['target']}.{h['attr']}={h['real']:g}" for h in r["hidden"])


def _found_text(r: dict[str, Any]) -> str:
    rows = [f"{f['term']}[{f['joint']}]={f['coefficient']:.4g}" for f in r["found"]]
    if r["kind"] != "effect":
        rows += [f"{k}={v['fitted']:.4g}" for k, v in r["calibrated_changed"].items() if k.endswith(".gear")]
        n_other = sum(not k.endswith(".gear") for k in r["calibrated_changed"])
        if n_other:
            rows.append(f"+{n_other} param(s)")
    return ", ".join(rows) or "-"


def table(rows: list[dict[str, Any]]) -> str:
    hdr = (f"{'case':11s} {'hidden':44s} {'eff/noise':>9s} {'found':58s} {'coef err':>8s} {'nominal':>8s} "
           f"{'calib':>8s} {'augm':>8s} {'xml':>8s} {'ratio':>5s} {'wall':>6s} {'cpu':>6s} ok")
    lines = [hdr]
    for r in rows:
        ce = max(r["coef_rel_err"].values(), default=None)
        fit = r["fit"]
        lines.append(f"{r['case']:11s} {_hidden_text(r):44.44s} {r['effect_over_noise_first_100_samples']:9.1f} "
                     f"{_found_text(r):58.58s} "
                     f"{'-' if ce is None else f'{ce:.3f}':>8s} {fit['nominal']['rollout_rmse']:8.4f} "
                     f"{fit['calibrated']['rollout_rmse']:8.4f} {fit['augmented']['rollout_rmse']:8.4f} "
                     f"{fit.get('calibrated_xml', {}).get('rollout_rmse', float('nan')):8.4f} "
                     f"{r['ratio_augmented_over_calibrated']:5.2f} {r['wall_s']:6.1f} {r['cpu_s']:6.1f} "
                     f"{'Y' if r['passed'] else 'N'}")
    n_ok = sum(r["passed"] for r in rows)
    lines.append(f"{n_ok}/{len(rows)} cases right; max analysis time {max(r['wall_s'] for r in rows):.1f} s wall, "
                 f"{max(r['cpu_s'] for r in rows):.1f} s CPU (one thread: CPU is the time on an idle core); "
                 "held-out rollout RMSE (nominal, calib = calibrated, augm = augmented, "
                 "xml = calibrated.xml in MuJoCo) in rad, std-scaled where a model mixes rad and m (cartpole)")
    for r in rows:
        lines.append(f"  {r['case']}: {r['reason']}")
    return "\n".join(lines)
