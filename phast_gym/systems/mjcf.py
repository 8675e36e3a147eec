"""A robot described by a MuJoCo model (MJCF, or URDF through MuJoCo's importer) as a port-Hamiltonian system.

:func:`mjcf_system` reads the file once (:mod:`.mjcf_tree`: MuJoCo compiles it) and returns a :class:`MJCFSystem`
subclass whose parameters are the file's own attributes, named ``<body>.mass``, ``<body>.ipos_x|y|z``,
``<body>.inertia_x|y|z`` (``diaginertia`` about the ``iquat`` axes),
``<joint>.armature|damping|frictionloss|stiffness``, ``<actuator>.gear``, plus ``gravity`` (the magnitude of
``option/gravity``, a known constant).  The file's values are the defaults, so ``cls()`` is the robot as written.

The dynamics are MuJoCo's rigid-body equations written once over numpy or torch arrays (``q`` = ``qpos`` of the
hinge and slide joints, ``p = M(q) qdot``)::

    M(q)    = sum_b m_b Jv_b^T Jv_b + Jw_b^T R_b I_b R_b^T Jw_b + diag(armature)      (MuJoCo's mj_fullM)
    V(q)    = -sum_b m_b g . c_b(q) + sum_j stiffness_j (q_j - springref_j)^2 / 2
    dH/dq|p = dV/dq - v^T (dM/dq) v / 2            (dM/dq from the joint screw motions)
    pdot    = -dH/dq - damping v - frictionloss tanh(v / eps) + actuator forces

with each joint transmission actuator delivering ``gear (gain ctrl + bias0 + bias1 gear q + bias2 gear qdot)``
(motor, position and velocity actuators).  Contacts, joint limits and ``ctrlrange`` clamping are not modelled.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from . import tree_dynamics as td
from .base import NUMPY, Array, ArrayNamespace, Components, Param, System
from .mjcf_tree import MJCFTree, ModelFileError, read_tree
from .tree_dynamics import Ops, TreeParams

__all__ = ["BODY_ATTRS", "MJCFSystem", "ModelFileError", "is_body_value", "mjcf_system", "param_specs"]

#: sign(qdot) of frictionloss is smoothed as tanh(qdot / eps) (rad/s or m/s), as the mismatch tool's Coulomb term
FRICTION_EPS = 1e-2
AXES = ("x", "y", "z")
JOINT_ATTRS = ("armature", "damping", "frictionloss", "stiffness")
#: a body's inertial values, as parameters ``<body>.mass``, ``<body>.ipos_<axis>``, ``<body>.inertia_<axis>``
BODY_ATTRS = ("mass", "ipos", "inertia")


def is_body_value(name: str) -> bool:
    """Whether parameter ``name`` is a body's mass, centre of mass or principal moment (not a joint's or a gear's)."""
    owner, dot, attr = name.rpartition(".")
    return bool(dot and owner) and attr.split("_")[0] in BODY_ATTRS


def param_specs(tree: MJCFTree) -> dict[str, Param]:
    """The model's parameters in the file's names, with the file's values as defaults."""
    out: dict[str, Param] = {}
    for b, name in enumerate(tree.body_names):
        out[f"{name}.mass"] = Param(float(tree.body_mass[b]), f"mass of body {name} [kg]", "nonnegative")
        for k, ax in enumerate(AXES):
            out[f"{name}.ipos_{ax}"] = Param(float(tree.body_ipos[b, k]),
                                             f"centre of mass of {name}, {ax} in its frame [m]", "any")
        for k, ax in enumerate(AXES):
            doc = f"principal moment of inertia of {name} about its {ax} inertia axis [kg m^2]"
            out[f"{name}.inertia_{ax}"] = Param(float(tree.body_inertia[b, k]), doc, "nonnegative")
    for j, name in enumerate(tree.joint_names):
        for attr in JOINT_ATTRS:
            out[f"{name}.{attr}"] = Param(float(getattr(tree, attr)[j]), f"joint {name} {attr}", "nonnegative")
    for a in tree.actuators:
        # a transmission ratio the file states, held like gravity: a motor that delivers less than u is a port term
        # (actuator_gain, adopted on left-out evidence only) written back into this gear; --free <actuator>.gear
        # calibrates it
        out[f"{a.name}.gear"] = Param(a.gear, f"gear of actuator {a.name} (on joint {tree.joint_names[a.joint]})",
                                      "any", known=True)
    out["gravity"] = Param(float(np.linalg.norm(tree.gravity)), "gravitational acceleration [m/s^2] (option/gravity)",
                           "nonnegative", known=True)
    return out


@dataclass(frozen=True)
class TreeState:
    """The model at one configuration: q (n, ...), its array ops, the bodies' Jacobians and M(q) (n, n, ...)."""

    Q: Array
    ops: Ops
    bodies: td.Bodies
    M: Array


class MJCFSystem(System):
    """A MuJoCo model's rigid-body tree as a port-Hamiltonian system; built by :func:`mjcf_system`."""

    TREE: ClassVar[MJCFTree]
    CONSTS: ClassVar[td.TreeConsts]
    # parameter arrays: numpy, a (K*reps, ...) batch of parameter sets, or torch tensors of learned parameters
    _mass: Array
    _ipos: Array
    _inertia: Array
    _armature: Array
    _damping: Array
    _frictionloss: Array
    _stiffness: Array
    _gear: Array
    separable = False
    dt = 0.01
    substeps = 2  # RK4 substeps of 5 ms
    default_max_action = 1e3

    # ---- derived constants -------------------------------------------------
    # The parameter arrays (_mass (nb,), _ipos (nb, 3), ..., _gear (m,)) may also carry a leading batch axis, one row
    # per sample: the mismatch tool then simulates several parameter sets as one batch (every formula broadcasts).
    def _finalize(self) -> None:
        t = self.TREE
        p = self.params
        self._mass = np.array([p[f"{b}.mass"] for b in t.body_names], dtype=float)
        self._ipos = np.array([[p[f"{b}.ipos_{a}"] for a in AXES] for b in t.body_names], dtype=float).reshape(-1, 3)
        self._inertia = np.array([[p[f"{b}.inertia_{a}"] for a in AXES] for b in t.body_names],
                                 dtype=float).reshape(-1, 3)
        joint = {attr: np.array([p[f"{j}.{attr}"] for j in t.joint_names], dtype=float) for attr in JOINT_ATTRS}
        self._armature, self._damping = joint["armature"], joint["damping"]
        self._frictionloss, self._stiffness = joint["frictionloss"], joint["stiffness"]
        self._gear = np.array([p[f"{a.name}.gear"] for a in t.actuators], dtype=float)
        g = float(np.linalg.norm(t.gravity))
        self._g = t.gravity / g * float(p["gravity"] or 0.0) if g > 0 else np.zeros(3)
        self._consts = self.CONSTS

    def tree_params(self) -> TreeParams:
        """The parameter arrays the rigid-body formulas take."""
        return TreeParams(self._mass, self._ipos, self._inertia, self._armature, self._stiffness, self._g)

    def with_armature(self, extra: Any) -> MJCFSystem:
        """This model with ``extra`` (n,) added to every joint's armature (a rotor inertia found by the mismatch
        tool)."""
        out = copy.copy(self)
        out._armature = self._armature + np.asarray(extra, dtype=float)
        return out

    @cached_property
    def actuated_dofs(self) -> tuple[int, ...]:
        """The joint (qpos column) each actuator (ctrl column) drives, in actuator order."""
        return self.TREE.actuated_dofs()

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.TREE.joint_names

    # ---- the rigid-body formulas (phast_gym.systems.tree_dynamics), components in, components out ----
    def _state(self, q: Components) -> tuple[Array, Array, Ops, td.Bodies]:
        """(q, theta = q - qpos0) as (n, ...) arrays, their ops and the bodies at q."""
        first = q[0]
        if not hasattr(first, "shape"):
            q = tuple(np.asarray(c, dtype=float) for c in q)
            first = q[0]
        ops = Ops(first, len(first.shape), self._consts.cache)
        Q = ops.stack(list(q) if len({tuple(c.shape) for c in q}) == 1 else _broadcast(q, ops))
        theta = Q - ops.k(self._consts.qpos0)
        return Q, theta, ops, td.bodies(self._consts, self.tree_params(), theta, ops)

    def tree_state(self, q: Components) -> TreeState:
        """Everything at the configuration q that V, M and dT/dq share (computed once, reused by the ``*_at``
        methods)."""
        Q, _, ops, bd = self._state(q)
        return TreeState(Q, ops, bd, self._mass_matrix(bd, ops))

    def grad_potential_at(self, st: TreeState) -> Array:
        """dV/dq (n, ...) at a :meth:`tree_state`."""
        return self._grad_V(st.Q, st.bodies, st.ops)

    def velocity_at(self, st: TreeState, p: Components) -> tuple:
        """M(q)^-1 p at a :meth:`tree_state`."""
        return self._velocity(st.M, p, st.Q)

    def kinetic_dq_at(self, st: TreeState, v: Components) -> Array:
        """d(p^T M^-1 p / 2)/dq at fixed p = -v^T (dM/dq) v / 2 (n, ...), v = M^-1 p, at a :meth:`tree_state`."""
        return -td.kinetic_dq(self._consts, self.tree_params(), st.bodies, st.ops.stack(list(v)), st.ops)

    def _mass_matrix(self, bd: td.Bodies, ops: Ops) -> Array:
        """M(q) (n, n, ...) of the bodies at q."""
        return td.mass_matrix(self._consts, self.tree_params(), bd, ops)

    def _grad_V(self, Q: Array, bd: td.Bodies, ops: Ops) -> Array:
        tp = self.tree_params()
        spring = ops.param(tp.stiffness, 1) * (Q - ops.k(self._consts.qpos_spring))
        return td.gravity_gradient(tp, bd, ops) + spring

    def _velocity(self, M: Array, p: Components, Q: Array) -> tuple:
        return td.solve(M, tuple(pi + 0.0 * Q[i] for i, pi in enumerate(p)))

    # ---- System interface ------------------------------------------------
    def mass_matrix(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple[tuple, ...]:
        _, _, ops, bd = self._state(q)
        M = self._mass_matrix(bd, ops)
        return tuple(tuple(M[i, j] for j in range(self.n)) for i in range(self.n))

    def potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> Any:
        Q, _, ops, bd = self._state(q)
        d = Q - ops.k(self._consts.qpos_spring)
        spring = 0.5 * (ops.param(self._stiffness, 1) * d * d).sum(0)
        return td.gravity_potential(self.tree_params(), bd, ops) + spring

    def grad_potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        Q, _, ops, bd = self._state(q)
        g = self._grad_V(Q, bd, ops)
        return tuple(g[i] for i in range(self.n))

    def velocity(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        Q, _, ops, bd = self._state(q)
        return self._velocity(self._mass_matrix(bd, ops), p, Q)

    def dH_dq(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        Q, _, ops, bd = self._state(q)
        tp = self.tree_params()
        v = self._velocity(self._mass_matrix(bd, ops), p, Q)
        d = self._grad_V(Q, bd, ops) - td.kinetic_dq(self._consts, tp, bd, ops.stack(list(v)), ops)
        return tuple(d[i] for i in range(self.n))

    def damping(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        return tuple(qi * 0.0 + self._damping[..., j] for j, qi in enumerate(q))

    def has_damping(self) -> bool:
        return bool(np.any(self._damping > 0) or np.any(self._frictionloss > 0))

    def actuator_force(self, q: Components, v: Components, u: Components | None) -> list:
        """Generalized forces of the actuators for ``u`` (one component per coordinate: the ctrl of the actuator on
        that joint, 0 where none) - MuJoCo's ``gear (gain ctrl + bias0 + bias1 length + bias2 velocity)``."""
        f = [qi * 0.0 for qi in q]
        for k, a in enumerate(self.TREE.actuators):
            gear = self._gear[..., k]
            j = a.joint
            ctrl = u[j] if u is not None else 0.0
            b0, b1, b2 = a.bias
            force = a.gain * ctrl
            if b0 or b1 or b2:
                force = force + b0 + b1 * gear * q[j] + b2 * gear * v[j]
            f[j] = f[j] + gear * force
        return f

    def nonconservative_force(self, q: Components, v: Components, u: Components | None,
                              xp: ArrayNamespace = NUMPY) -> tuple:
        """Joint damping, frictionloss (smoothed sign) and the actuators: everything in pdot but -dH/dq."""
        f = self.actuator_force(q, v, u)
        tanh = _tanh(v[0])
        out = []
        for j, fj in enumerate(f):
            fj = fj - self._damping[..., j] * v[j]
            if np.any(self._frictionloss[..., j] > 0):
                fj = fj - self._frictionloss[..., j] * tanh(v[j] / FRICTION_EPS)
            out.append(fj)
        return tuple(out)

    def rhs(self, q: Components, p: Components, u: Components | None,
            xp: ArrayNamespace = NUMPY) -> tuple[tuple, tuple]:
        """Eq. 1-3 with the bodies and M computed once per call."""
        Q, _, ops, bd = self._state(q)
        tp = self.tree_params()
        v = self._velocity(self._mass_matrix(bd, ops), p, Q)
        dH = self._grad_V(Q, bd, ops) - td.kinetic_dq(self._consts, tp, bd, ops.stack(list(v)), ops)
        f = self.nonconservative_force(tuple(Q[i] for i in range(self.n)), v, u, xp)
        return tuple(v), tuple(fi - dH[i] for i, fi in enumerate(f))

    def power_balance(self, q: Components, p: Components, u: Components | None,
                      xp: ArrayNamespace = NUMPY) -> tuple[Any, Any]:
        v = self.velocity(q, p, xp)
        passive = self.nonconservative_force(q, v, None, xp)
        active = self.actuator_force(q, v, u)
        unforced = self.actuator_force(q, v, None)
        diss = sum(-(fp - fu) * vi for fp, fu, vi in zip(passive, unforced, v))
        supplied = sum(fa * vi for fa, vi in zip(active, v))
        return diss, supplied

    def sample_initial(self, rng: np.random.Generator, size: int) -> np.ndarray:
        """Joints within +-0.5 (rad or m) of the reference configuration, rates in [-1, 1], p = M(q) qdot."""
        n = self.n
        q = self.TREE.qpos0 + rng.uniform(-0.5, 0.5, size=(size, n))
        w = rng.uniform(-1.0, 1.0, size=(size, n))
        M = np.stack([np.stack(row, -1) for row in self.mass_matrix(tuple(q.T))], -2)
        return np.concatenate([q, (M @ w[..., None])[..., 0]], axis=1)


def _broadcast(q: Components, ops: Ops) -> list:
    if ops.torch is not None:
        return list(ops.torch.broadcast_tensors(*q))
    return list(np.broadcast_arrays(*q))


def _tanh(like: Any) -> Any:
    if type(like).__module__.startswith("torch"):
        import torch

        return torch.tanh
    return np.tanh if hasattr(like, "shape") else math.tanh


def mjcf_system(path: str | Path) -> type[MJCFSystem]:
    """The :class:`MJCFSystem` subclass of a model file (``.xml`` MJCF or ``.urdf``); ModelFileError when MuJoCo
    cannot compile it or it has free/ball joints, equality constraints or non-joint actuators."""
    tree = read_tree(path)
    names = tree.joint_names
    attrs = {
        "TREE": tree, "CONSTS": td.TreeConsts.of(tree), "name": f"mjcf:{tree.model_name}", "n": tree.n,
        "angle_dims": tuple(j for j in range(tree.n) if tree.joint_hinge[j]),
        "coordinate_names": names, "PARAMS": param_specs(tree), "__module__": __name__,
    }
    return type(f"MJCF_{tree.model_name}", (MJCFSystem,), attrs)
