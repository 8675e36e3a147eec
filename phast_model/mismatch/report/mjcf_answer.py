"""The answer in a MuJoCo model's own terms (docs/mismatch.md, "Your robot as MJCF / URDF").

When the simulator is a model file, every term row names its joint and the MuJoCo attribute that expresses it; the
calibrated parameters and every term an attribute expresses are written back as ``calibrated.xml`` (the user's
model, edited through ``MjSpec``), which MuJoCo then simulates on the held-out recordings as one more row of the
fit table.  Terms no attribute expresses are listed with what a MuJoCo user would add.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from phast_gym.systems.base import System
from phast_gym.systems.mjcf_tree import MJCFTree, ModelFileError

from ...identify.mjcf_write import Edit, calibrated_xml
from ...identify.recordings import Recordings
from ..evaluate import HeldOut
from ..rows import TermRow
from ..vocabulary.registry import VOCABULARY
from ..written import term_edit, text_simulated
from .document import Report
from .files import CALIBRATED_MODEL

#: the fit table's row of the written model
CALIBRATED_XML_ROW = "calibrated_xml"


@dataclass(frozen=True)
class MJCFWriteBack:
    """What the written model holds: the changed parameters, the term edits, and the terms it cannot hold."""

    params: dict[str, float]
    edits: list[Edit]
    not_expressed: list[dict[str, Any]]
    notes: list[str]

    def to_dict(self) -> dict[str, Any]:
        return {"file": CALIBRATED_MODEL, "parameters": self.params,
                "terms_written": [{"target": e.target, "attribute": e.attr, "op": e.op,
                                   "value": e.value} for e in self.edits],
                "terms_not_expressed": self.not_expressed, "notes": self.notes}


def _tree(system: Any) -> MJCFTree:
    return getattr(system, "base", system).TREE


def named_rows(rows: list[TermRow], tree: MJCFTree) -> list[TermRow]:
    """Each row with its joint name and the MuJoCo attribute of its term (None when no attribute expresses it)."""
    return [replace(r, joint=tree.joint_names[r.coordinate], mjcf=VOCABULARY[r.term].mjcf) for r in rows]


def armature_equivalent(tree: MJCFTree, name: str) -> str | None:
    """The joint whose ``armature`` acts exactly like a change of the principal moment ``name``
    (``<body>.inertia_<ax>``):
    the body hangs from the world by that single hinge and the hinge's axis is that principal axis, so the moment
    enters M(q) only as a constant on that joint's diagonal.  None otherwise."""
    body, _, attr = name.rpartition(".")
    if not attr.startswith("inertia_") or body not in tree.body_names:
        return None
    b, k = tree.body_names.index(body), "xyz".index(attr[-1])
    joints = tree.body_joints[b]
    if tree.body_parent[b] >= 0 or len(joints) != 1 or not tree.joint_hinge[joints[0]]:
        return None
    along = abs(float(tree.joint_axis[joints[0]] @ tree.body_irot[b][:, k]))
    return tree.joint_names[joints[0]] if abs(along - 1.0) < 1e-9 else None


def _as_armature(report: Report, tree: MJCFTree) -> tuple[dict[str, float], list[Edit], list[str]]:
    """Changed parameters, with every increase of a principal moment that armature expresses exactly moved to that
    joint's armature (a rotor behind the joint, and a body that stays physical), and sentences saying so."""
    params, edits, notes = {}, [], []
    for k, r in report.calibrated.items():
        if not r.changed:
            continue
        joint, delta = armature_equivalent(tree, k), float(r.fitted) - float(r.nominal)
        if joint is not None and delta > 0:
            edits.append(Edit(joint, "armature", delta))
            notes.append(f"{k} {r.nominal:.4g} -> {r.fitted:.4g} acts exactly like armature {delta:.4g} at joint "
                         f"{joint}: written as {joint}.armature")
        else:
            params[k] = float(r.fitted)
    return params, edits, notes


def write_back(report: Report, tree: MJCFTree) -> MJCFWriteBack:
    """The parameters and term edits of ``calibrated.xml``, and the terms it leaves out with advice."""
    params, edits, notes = _as_armature(report, tree)
    left = []
    for row in report.terms:
        e = term_edit(row.term, row.coordinate, row.coefficient, tree)
        if e is not None:
            edits.append(e)
        else:
            left.append({"term": row.term, "joint": tree.joint_names[row.coordinate], "coefficient": row.coefficient,
                         "expression": row.expression, "advice": VOCABULARY[row.term].mjcf_advice})
    return MJCFWriteBack(params, edits, left, notes)


def _score_in_mujoco(text: str, held: HeldOut) -> dict[str, float]:
    """The written model's held-out one-step MSE and rollout RMSE, simulated by MuJoCo (same windows and metrics)."""
    table, _ = held.fit_table({CALIBRATED_XML_ROW: text_simulated(text)})
    return table.to_dict()[CALIBRATED_XML_ROW]


#: a recorded joint within this share of its range's span of a limit is at the limit
LIMIT_MARGIN = 0.02


def joint_limit_contacts(tree: MJCFTree, rec: Recordings) -> list[dict[str, Any]]:
    """The limited joints the recordings drive to a limit, with the trajectories and share of samples: MuJoCo's limit
    constraint is not part of the fitted model, so the residual there is expected (and not a term)."""
    out = []
    for j, (lo, hi) in enumerate(tree.joint_range):
        if not (np.isfinite(lo) and np.isfinite(hi)):
            continue
        margin = LIMIT_MARGIN * (hi - lo)
        at = (rec.q[..., j] <= lo + margin) | (rec.q[..., j] >= hi - margin)
        if at.any():
            out.append({"joint": tree.joint_names[j], "range": [float(lo), float(hi)],
                        "share_of_samples": float(at.mean()),
                        "trajectories": [int(k) for k in np.flatnonzero(at.any(axis=1))]})
    return out


def _limit_sentence(contacts: list[dict[str, Any]]) -> str:
    names = ", ".join(f"{c['joint']} (range {c['range'][0]:g}..{c['range'][1]:g}, {c['share_of_samples']:.1%} of the "
                      "samples)"
                      for c in contacts)
    return (f" The recordings reach joint limits: {names}. MuJoCo's limit constraint is not part of the fitted model, "
            "so a residual near those limits is expected; record inside the range for a clean answer.")


def answer_in_model_terms(report: Report, system: System, held: HeldOut, recordings: Recordings) -> Report:
    """``report`` with joint-named rows, ``calibrated.xml`` among its files, the written model's held-out row
    simulated by MuJoCo, ``details.mjcf`` saying what was written and what could not be, and a sentence when the
    ``recordings`` (all of them, as given) reach a joint limit."""
    tree = _tree(system)
    report = replace(report, terms=named_rows(report.terms, tree), unconfirmed=named_rows(report.unconfirmed, tree))
    contacts = joint_limit_contacts(tree, recordings)
    if contacts:
        report = replace(report, summary=report.summary + _limit_sentence(contacts))
    back = write_back(report, tree)
    info = {**back.to_dict(), "source": tree.source, "joint_limits_reached": contacts}
    try:
        written = calibrated_xml(tree, back.params, back.edits)
        fit = {**report.fit, CALIBRATED_XML_ROW: _score_in_mujoco(written.text, held)}
    except ModelFileError as exc:  # the answer stands; only the file cannot be written (or its values are refused)
        info = {**info, "file": None, "error": str(exc)}
        return replace(report, diagnostics={**report.diagnostics, "mjcf": info})
    info = {**info, "notes": [*back.notes, *written.notes],
            "fit_row": f"fit.{CALIBRATED_XML_ROW}: {CALIBRATED_MODEL} as MuJoCo simulates it"}
    return replace(report, fit=fit, diagnostics={**report.diagnostics, "mjcf": info},
                   files={**report.files, CALIBRATED_MODEL: written.text})
