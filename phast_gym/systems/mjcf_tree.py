"""Read a MuJoCo model (MJCF, or URDF through MuJoCo's importer) into the numbers its dynamics depend on.

MuJoCo compiles the file (defaults, ``inertiafromgeom``, URDF conversion); :func:`read_tree` keeps the compiled
kinematic tree, inertias, joint attributes, actuators and gravity as plain arrays (:class:`MJCFTree`), so the
port-Hamiltonian system built from it (:mod:`.mjcf`) needs no MuJoCo object and copies like any other system.
``mujoco`` is imported only here, when a model file is read.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import mujoco  # untyped to mypy (pyproject.toml): the annotations name MuJoCo's classes for the reader

#: MuJoCo's enum values used below (mjtJoint, mjtTrn, mjtGain, mjtBias, mjtDyn)
_FREE, _BALL, _SLIDE, _HINGE = 0, 1, 2, 3
_TRN_JOINT, _GAIN_FIXED, _BIAS_NONE, _BIAS_AFFINE, _DYN_NONE = 0, 0, 0, 1, 0


class ModelFileError(ValueError):
    """A model file that cannot be used: it does not compile, or it has features the tool cannot represent."""


@dataclass(frozen=True)
class Actuator:
    """A joint actuator: generalized force ``gear * (gain * ctrl + bias0 + bias1 * gear * q + bias2 * gear * qdot)``."""

    name: str
    joint: int  # index into the tree's joints (= qpos column)
    gear: float
    gain: float
    bias: tuple[float, float, float]


@dataclass(frozen=True)
class MJCFTree:
    """The compiled model's rigid-body tree and attributes, in MuJoCo's own conventions and names.

    Bodies are the moving ones (those with a joint on their path to the world), in model order; ``parent`` is an
    index into them, or -1 for a body attached (possibly through fixed bodies) to the world.
    """

    source: str
    model_name: str
    joint_names: tuple[str, ...]
    joint_hinge: tuple[bool, ...]  # True: hinge (angle), False: slide
    joint_body: tuple[int, ...]  # index into bodies
    joint_pos: np.ndarray  # (n, 3) anchor in the body frame
    joint_axis: np.ndarray  # (n, 3) unit axis in the body frame
    qpos0: np.ndarray  # (n,) reference configuration (``ref``)
    qpos_spring: np.ndarray  # (n,) spring reference (``springref``)
    body_names: tuple[str, ...]
    body_parent: tuple[int, ...]
    body_pos: np.ndarray  # (nb, 3) frame offset in the parent frame (world frame for parent -1)
    body_rot: np.ndarray  # (nb, 3, 3) frame rotation in the parent frame
    body_irot: np.ndarray  # (nb, 3, 3) principal axes of inertia in the body frame (``iquat``)
    body_mass: np.ndarray  # (nb,)
    body_ipos: np.ndarray  # (nb, 3) centre of mass in the body frame
    body_inertia: np.ndarray  # (nb, 3) principal moments (``diaginertia``)
    armature: np.ndarray  # (n,)
    damping: np.ndarray  # (n,)
    frictionloss: np.ndarray  # (n,)
    stiffness: np.ndarray  # (n,)
    actuators: tuple[Actuator, ...]
    joint_range: np.ndarray  # (n, 2) the limits of limited joints, (-inf, inf) elsewhere (not modelled: checked)
    gravity: np.ndarray  # (3,)
    timestep: float

    @property
    def n(self) -> int:
        return len(self.joint_names)

    @property
    def nb(self) -> int:
        return len(self.body_names)

    @cached_property
    def body_joints(self) -> tuple[tuple[int, ...], ...]:
        """The joints of each body, in order."""
        return tuple(tuple(j for j in range(self.n) if self.joint_body[j] == b) for b in range(self.nb))

    def actuated_dofs(self) -> tuple[int, ...]:
        return tuple(a.joint for a in self.actuators)


def _mujoco() -> ModuleType:
    try:
        import mujoco
    except ImportError:  # pragma: no cover - mujoco is a dependency
        raise ModelFileError("reading MJCF/URDF needs MuJoCo: pip install mujoco") from None
    return mujoco


def strip_urdf_meshes(text: str) -> str:
    """A URDF without visual geometry and without mesh collision geometry: meshes do not enter the dynamics (the
    inertias are given in ``<inertial>``), and a missing mesh file must not stop the tool."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise ModelFileError(f"not a readable XML file: {exc}") from None
    for link in root.iter("link"):
        for tag in ("visual", "collision"):
            for el in list(link.findall(tag)):
                if tag == "visual" or el.find("geometry/mesh") is not None:
                    link.remove(el)
    return ET.tostring(root, encoding="unicode")


def urdf_spec(text: str) -> mujoco.MjSpec:
    """``mujoco.MjSpec`` of a URDF: meshes dropped (:func:`strip_urdf_meshes`) and, since MuJoCo's importer brings no
    actuators (URDF transmissions are not imported), one torque motor (gear 1) per hinge / slide joint, named after
    the joint and in joint order: the ``u`` columns of a URDF robot are its joints' torques / forces."""
    mujoco = _mujoco()
    spec = mujoco.MjSpec.from_string(strip_urdf_meshes(text))
    if not len(spec.actuators):
        driven = (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)
        for j in spec.joints:
            if j.type in driven:
                spec.add_actuator(name=j.name, target=j.name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
    return spec


def compile_model(path: str | Path) -> mujoco.MjModel:
    """``mujoco.MjModel`` of an MJCF (``.xml``) or URDF (``.urdf``) file; ModelFileError with MuJoCo's message."""
    mujoco = _mujoco()
    p = Path(path).expanduser()
    if not p.is_file():
        raise ModelFileError(f"model file {str(p)!r} not found")
    try:
        if p.suffix.lower() == ".urdf":
            return urdf_spec(p.read_text()).compile()
        return mujoco.MjModel.from_xml_path(str(p))
    except ValueError as exc:  # MuJoCo's compiler error
        raise ModelFileError(f"{p.name} does not compile: {str(exc).strip()}") from None


def _name(model: mujoco.MjModel, objtype: mujoco.mjtObj, i: int, prefix: str) -> str:
    mujoco = _mujoco()
    nm = mujoco.mj_id2name(model, objtype, i)
    return nm if nm else f"{prefix}{i}"


def _quat_to_rot(q: np.ndarray) -> np.ndarray:
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _check_supported(model: mujoco.MjModel, src: str) -> None:
    """Refuse what the port-Hamiltonian tree cannot represent, naming it."""
    mujoco = _mujoco()
    kinds = {_FREE: "free", _BALL: "ball"}
    bad = [f"{_name(model, mujoco.mjtObj.mjOBJ_JOINT, j, 'joint')} ({kinds[int(t)]})"
           for j, t in enumerate(model.jnt_type) if int(t) in kinds]
    if bad:
        raise ModelFileError(f"{src}: free and ball joints are not supported (joints {', '.join(bad)}); the tool takes "
                             "hinge and slide joints (a fixed-base robot): fix the base with no joint on the root body")
    if model.njnt == 0:
        raise ModelFileError(f"{src}: the model has no hinge or slide joint")
    if model.neq:
        raise ModelFileError(f"{src}: equality constraints ({model.neq}) are not supported")
    for a in range(model.nu):
        name = _name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a, "actuator")
        if int(model.actuator_trntype[a]) != _TRN_JOINT:
            raise ModelFileError(f"{src}: actuator {name!r} does not act on a joint "
                                 "(tendon/site transmissions are not supported)")
        if int(model.actuator_dyntype[a]) != _DYN_NONE or int(model.actuator_gaintype[a]) != _GAIN_FIXED \
                or int(model.actuator_biastype[a]) not in (_BIAS_NONE, _BIAS_AFFINE):
            raise ModelFileError(f"{src}: actuator {name!r} has activation dynamics or a non-affine gain/bias; "
                                 "motor, position and velocity actuators are supported")
    joints = [int(model.actuator_trnid[a, 0]) for a in range(model.nu)]
    if len(set(joints)) != len(joints):
        raise ModelFileError(f"{src}: two actuators drive one joint; give one actuator per joint")


def _bodies(model: mujoco.MjModel) -> tuple[list[int], dict[int, int]]:
    """The moving bodies (a joint on the path to the world) in model order, and MuJoCo body id -> their index."""
    moving = [False] * model.nbody
    for b in range(1, model.nbody):
        moving[b] = bool(model.body_jntnum[b]) or moving[int(model.body_parentid[b])]
    ids = [b for b in range(1, model.nbody) if moving[b]]
    return ids, {b: i for i, b in enumerate(ids)}


def _frame_to_moving(model: mujoco.MjModel, b: int, index: dict[int, int]) -> tuple[int, np.ndarray, np.ndarray]:
    """Body b's frame relative to its nearest moving ancestor (or the world): (parent index or -1, pos, rot),
    composing the fixed bodies in between."""
    pos, rot = model.body_pos[b].copy(), _quat_to_rot(model.body_quat[b])
    parent = int(model.body_parentid[b])
    while parent != 0 and parent not in index:
        prot = _quat_to_rot(model.body_quat[parent])
        pos, rot = model.body_pos[parent] + prot @ pos, prot @ rot
        parent = int(model.body_parentid[parent])
    return (index[parent] if parent in index else -1), pos, rot


def read_tree(path: str | Path) -> MJCFTree:
    """The dynamics-relevant content of a model file (see :class:`MJCFTree`); ModelFileError on what it cannot use."""
    model = compile_model(path)
    src = Path(path).name
    _check_supported(model, src)
    return _tree_from_model(model, str(path), src)


def _joint_ranges(model: mujoco.MjModel) -> np.ndarray:
    out = np.tile([-np.inf, np.inf], (model.njnt, 1))
    for j in range(model.njnt):
        if bool(model.jnt_limited[j]):
            out[j] = model.jnt_range[j]
    return out


def _tree_from_model(model: mujoco.MjModel, source: str, src: str) -> MJCFTree:
    mujoco = _mujoco()
    ids, index = _bodies(model)
    frames = [_frame_to_moving(model, b, index) for b in ids]
    J = range(model.njnt)
    dof = [int(model.jnt_dofadr[j]) for j in J]
    def bias(a: int) -> tuple[float, float, float]:
        b = model.actuator_biasprm[a, :3] if int(model.actuator_biastype[a]) else np.zeros(3)
        return float(b[0]), float(b[1]), float(b[2])

    acts = tuple(Actuator(name=_name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, a, "actuator"),
                          joint=int(model.actuator_trnid[a, 0]), gear=float(model.actuator_gear[a, 0]),
                          gain=float(model.actuator_gainprm[a, 0]), bias=bias(a))
                 for a in range(model.nu))
    model_name = re.sub(r"\W+", "_", Path(source).stem) or "robot"
    return MJCFTree(
        source=source, model_name=model_name,
        joint_names=tuple(_name(model, mujoco.mjtObj.mjOBJ_JOINT, j, "joint") for j in J),
        joint_hinge=tuple(int(model.jnt_type[j]) == _HINGE for j in J),
        joint_body=tuple(index[int(model.jnt_bodyid[j])] for j in J),
        joint_pos=np.array(model.jnt_pos, dtype=float).reshape(-1, 3),
        joint_axis=np.array(model.jnt_axis, dtype=float).reshape(-1, 3),
        qpos0=np.array([model.qpos0[int(model.jnt_qposadr[j])] for j in J], dtype=float),
        qpos_spring=np.array([model.qpos_spring[int(model.jnt_qposadr[j])] for j in J], dtype=float),
        body_names=tuple(_name(model, mujoco.mjtObj.mjOBJ_BODY, b, "body") for b in ids),
        body_parent=tuple(f[0] for f in frames),
        body_pos=np.array([f[1] for f in frames]).reshape(-1, 3),
        body_rot=np.array([f[2] for f in frames]).reshape(-1, 3, 3),
        body_irot=np.array([_quat_to_rot(model.body_iquat[b]) for b in ids]).reshape(-1, 3, 3),
        body_mass=np.array([model.body_mass[b] for b in ids], dtype=float),
        body_ipos=np.array([model.body_ipos[b] for b in ids], dtype=float).reshape(-1, 3),
        body_inertia=np.array([model.body_inertia[b] for b in ids], dtype=float).reshape(-1, 3),
        armature=np.array([model.dof_armature[d] for d in dof], dtype=float),
        damping=np.array([model.dof_damping[d] for d in dof], dtype=float),
        frictionloss=np.array([model.dof_frictionloss[d] for d in dof], dtype=float),
        stiffness=np.array(model.jnt_stiffness, dtype=float).reshape(-1),
        actuators=acts, joint_range=_joint_ranges(model),
        gravity=np.array(model.opt.gravity, dtype=float), timestep=float(model.opt.timestep))
