"""Write a model file back with new values: the user's MJCF / URDF as MJCF, edited through MuJoCo's ``MjSpec``.

Parameters are named as :mod:`phast_gym.systems.mjcf` names them (``<body>.mass``, ``<body>.ipos_x``,
``<body>.inertia_y``, ``<joint>.damping``, ``<actuator>.gear``, ``gravity``); a body whose mass, centre of mass or
inertia changes gets an explicit ``<inertial>`` with the compiled principal axes (``iquat``).  The written file is
compiled once more before it is returned, so what a caller saves loads with ``mujoco.MjModel.from_xml_path``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from phast_gym.systems.mjcf import AXES, JOINT_ATTRS, is_body_value
from phast_gym.systems.mjcf_tree import MJCFTree, ModelFileError, urdf_spec

if TYPE_CHECKING:
    import mujoco  # untyped to mypy (pyproject.toml): the annotations name MuJoCo's classes for the reader


@dataclass(frozen=True)
class Edit:
    """Add ``value`` to (``op="add"``) or multiply by it (``op="scale"``) one joint / actuator attribute."""

    target: str  # joint or actuator name
    attr: str  # armature, damping, frictionloss, stiffness (joint) or gear (actuator)
    value: float
    op: str = "add"

    def applied(self, old: float) -> float:
        """The attribute's value after this edit, from its value ``old`` in the file."""
        return old * self.value if self.op == "scale" else old + self.value


def _spec(source: str) -> mujoco.MjSpec:
    import mujoco

    p = Path(source).resolve()
    if p.suffix.lower() == ".urdf":
        return urdf_spec(p.read_text())
    spec = mujoco.MjSpec.from_file(str(p))
    if any(len(getattr(spec, kind, ())) for kind in ("meshes", "textures", "hfields", "skins")):
        for attr in ("meshdir", "texturedir"):  # asset paths that still resolve from wherever the written file is saved
            d = getattr(spec, attr, None)
            if isinstance(d, str):
                setattr(spec, attr, str((p.parent / d).resolve()) if d else str(p.parent))
    return spec


def _quat(rot: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix."""
    import mujoco

    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rot, dtype=float).reshape(9))
    return q


#: relative margin by which a raised principal moment clears A + B >= C (:func:`physical_moments`)
TEXT_MARGIN = 1e-5


def physical_moments(name: str, moments: list[float], fixed: set[int]) -> tuple[list[float], list[str]]:
    """Principal moments that satisfy A + B >= C (a rigid body), raising the smaller of the other two moments as little
    as needed, one not in ``fixed`` (those the data did not change) where there is one; with a sentence per raise.
    So a fit of all three moments that takes a body past the bound simulates, and writes, the nearest rigid body
    along that moment (as a friction coefficient past zero simulates zero)."""
    out, notes = list(moments), []
    for c in sorted(range(3), key=lambda i: -out[i]):
        others = [i for i in range(3) if i != c]
        short = out[c] - sum(out[i] for i in others)
        free = [i for i in others if i not in fixed]
        if short > 0:
            short += TEXT_MARGIN * out[c]  # the MJCF text rounds every moment: the bound must hold after rounding
            i = min(free or others, key=lambda j: out[j])
            why = "the recordings did not change it" if free else "the fitted moments broke it"
            notes.append(f"{name}.inertia_{AXES[i]} raised {out[i]:.4g} -> {out[i] + short:.4g} so that the body stays "
                         f"rigid (A + B >= C); {why}")
            out[i] += short
    return out, notes


def _set_body(spec: mujoco.MjSpec, tree: MJCFTree, params: Mapping[str, float], b: int, fixed: set[int]) -> list[str]:
    name = tree.body_names[b]
    body = spec.body(name)
    if body is None:
        raise ModelFileError(f"body {name!r} is not named in the file; name it to write its calibrated inertia")
    body.explicitinertial = True
    body.mass = float(params[f"{name}.mass"])
    body.ipos = [float(params[f"{name}.ipos_{a}"]) for a in AXES]
    body.iquat = _quat(tree.body_irot[b])
    moments, notes = physical_moments(name, [float(params[f"{name}.inertia_{a}"]) for a in AXES], fixed)
    body.inertia = moments
    if hasattr(body, "fullinertia"):
        body.fullinertia = [np.nan] * 6  # the principal moments above, not a full inertia from the file
    return notes


def joint_attr(joint: mujoco.MjsJoint, attr: str) -> float:
    """A joint attribute of an ``MjsJoint`` (``damping`` / ``stiffness`` are arrays in MuJoCo >= 4.0: element 0)."""
    return float(np.atleast_1d(getattr(joint, attr))[0])


def set_joint_attr(joint: mujoco.MjsJoint, attr: str, value: float) -> None:
    """Set a joint attribute of an ``MjsJoint`` (element 0 where MuJoCo holds an array)."""
    old = getattr(joint, attr)
    if np.ndim(old):
        new = np.array(old, dtype=float)
        new[0] = value
        setattr(joint, attr, new)
    else:
        setattr(joint, attr, float(value))


def _apply_params(spec: mujoco.MjSpec, tree: MJCFTree, params: Mapping[str, float]) -> list[str]:
    bodies = {b for b, name in enumerate(tree.body_names) for k in params
              if k.rpartition(".")[0] == name and is_body_value(k)}
    if bodies:
        import mujoco

        spec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_AUTO
    full = {**_tree_values(tree), **params}
    notes = []
    for b in sorted(bodies):
        name = tree.body_names[b]
        notes += _set_body(spec, tree, full, b, {k for k, a in enumerate(AXES) if f"{name}.inertia_{a}" in params})
    for name in tree.joint_names:
        for attr in JOINT_ATTRS:
            key = f"{name}.{attr}"
            if key in params:
                set_joint_attr(spec.joint(name), attr, float(params[key]))
    for a in tree.actuators:
        key = f"{a.name}.gear"
        if key in params:
            act = spec.actuator(a.name)
            gear = np.array(act.gear, dtype=float)
            gear[0] = float(params[key])
            act.gear = gear
    if "gravity" in params:
        g = np.asarray(tree.gravity, dtype=float)
        spec.option.gravity = g / np.linalg.norm(g) * float(params["gravity"])
    return notes


def _tree_values(tree: MJCFTree) -> dict[str, float]:
    from phast_gym.systems.mjcf import param_specs

    return {k: float(p.default) for k, p in param_specs(tree).items() if isinstance(p.default, (int, float))}


def _apply_edit(spec: mujoco.MjSpec, tree: MJCFTree, edit: Edit) -> None:
    if edit.attr == "gear":
        act = spec.actuator(edit.target)
        if act is None:
            raise ModelFileError(f"no actuator {edit.target!r} in the file")
        gear = np.array(act.gear, dtype=float)
        gear[0] = edit.applied(gear[0])
        act.gear = gear
        return
    joint = spec.joint(edit.target)
    if joint is None:
        raise ModelFileError(f"no joint {edit.target!r} in the file")
    old = joint_attr(joint, edit.attr)
    set_joint_attr(joint, edit.attr, edit.applied(old))


@dataclass(frozen=True)
class WrittenModel:
    """A model file's text, and what had to change beyond the given values for MuJoCo to take it."""

    text: str
    notes: list[str]


def _calibrated_spec(tree: MJCFTree, params: Mapping[str, float], edits: Sequence[Edit]
                     ) -> tuple[mujoco.MjSpec, list[str]]:
    """The source model's spec with ``params`` and ``edits`` applied, and the notes of what had to change."""
    spec = _spec(tree.source)
    notes = _apply_params(spec, tree, params)
    for e in edits:
        _apply_edit(spec, tree, e)
    return spec, notes


def calibrated_xml(tree: MJCFTree, params: Mapping[str, float], edits: Sequence[Edit] = ()) -> WrittenModel:
    """The source model with ``params`` (changed parameters, the file's names) and ``edits`` (found terms) applied,
    as MJCF text that MuJoCo compiles."""
    import mujoco

    spec, notes = _calibrated_spec(tree, params, edits)
    try:
        spec.compile()
        text = spec.to_xml()
        mujoco.MjModel.from_xml_string(text)
    except ValueError as exc:
        raise ModelFileError(f"the calibrated model does not compile: {exc}") from None
    return WrittenModel(text, notes)


def calibrated_model(tree: MJCFTree, params: Mapping[str, float], edits: Sequence[Edit] = ()) -> mujoco.MjModel:
    """The same model as :func:`calibrated_xml`, compiled from the spec in full precision: what the fits simulate
    (the text keeps six significant digits, which would round a fit's finite-difference steps away)."""
    spec, _ = _calibrated_spec(tree, params, edits)
    try:
        return spec.compile()
    except ValueError as exc:
        raise ModelFileError(f"the calibrated model does not compile: {exc}") from None
