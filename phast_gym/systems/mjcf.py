"""A robot described by a MuJoCo model (MJCF, or URDF through MuJoCo's importer) as a port-Hamiltonian system.

:func:`mjcf_system` reads the file once (:mod:`.mjcf_tree`: MuJoCo compiles it) and returns a :class:`MJCFSystem`
subclass whose parameters are the file's own attributes, named ``<body>.mass``, ``<body>.ipos_x|y|z``,
``<body>.inertia_x|y|z`` (``diaginertia`` about the ``iquat`` axes), ``<joint>.armature|damping|frictionloss|stiffness``,
``<actuator>.gear``, plus ``gravity`` (the magnitude of ``option/gravity``, a known constant).  The file's values
are the defaults, so ``cls()`` is the robot as written.

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

import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from .base import NUMPY, ArrayNamespace, Components, Param, System
from .mjcf_tree import MJCFTree, ModelFileError, read_tree

__all__ = ["MJCFSystem", "ModelFileError", "mjcf_system", "param_specs"]

#: sign(qdot) of frictionloss is smoothed as tanh(qdot / eps) (rad/s or m/s), as the mismatch tool's Coulomb term
FRICTION_EPS = 1e-2
AXES = ("x", "y", "z")
JOINT_ATTRS = ("armature", "damping", "frictionloss", "stiffness")


def param_specs(tree: MJCFTree) -> dict[str, Param]:
    """The model's parameters in the file's names, with the file's values as defaults."""
    out: dict[str, Param] = {}
    for b, name in enumerate(tree.body_names):
        out[f"{name}.mass"] = Param(float(tree.body_mass[b]), f"mass of body {name} [kg]", "nonnegative")
        for k, ax in enumerate(AXES):
            out[f"{name}.ipos_{ax}"] = Param(float(tree.body_ipos[b, k]), f"centre of mass of {name}, {ax} in its frame [m]", "any")
        for k, ax in enumerate(AXES):
            doc = f"principal moment of inertia of {name} about its {ax} inertia axis [kg m^2]"
            out[f"{name}.inertia_{ax}"] = Param(float(tree.body_inertia[b, k]), doc, "nonnegative")
    for j, name in enumerate(tree.joint_names):
        for attr in JOINT_ATTRS:
            out[f"{name}.{attr}"] = Param(float(getattr(tree, attr)[j]), f"joint {name} {attr}", "nonnegative")
    for a in tree.actuators:
        # a transmission ratio the file states, held like gravity: a motor that delivers less than u is a port term
        # (actuator_gain, adopted on left-out evidence only) written back into this gear; --free <actuator>.gear calibrates it
        out[f"{a.name}.gear"] = Param(a.gear, f"gear of actuator {a.name} (on joint {tree.joint_names[a.joint]})", "any",
                                      known=True)
    out["gravity"] = Param(float(np.linalg.norm(tree.gravity)), "gravitational acceleration [m/s^2] (option/gravity)",
                           "nonnegative", known=True)
    return out


class _Arrays:
    """The array functions of the tree formulas, for numpy or torch (``phast_gym`` never imports torch itself:
    a torch tensor comes in only from the world model)."""

    def __init__(self, like: Any) -> None:
        self.torch: Any = None
        if type(like).__module__.startswith("torch"):
            import torch

            self.torch = torch

    def stack(self, xs: Any, axis: int = -1) -> Any:
        if self.torch is not None:
            return self.torch.stack(self.torch.broadcast_tensors(*xs), dim=axis)
        if len({np.shape(x) for x in xs}) == 1:  # the hot path: no broadcasting needed
            return np.stack(xs, axis=axis)
        return np.stack(np.broadcast_arrays(*xs), axis=axis)

    def const(self, a: Any, like: Any) -> Any:
        if self.torch is not None:
            if self.torch.is_tensor(a):  # a learned parameter (phast_model.components.rigid_body): keep its graph
                return a.to(dtype=like.dtype, device=like.device)
            return self.torch.as_tensor(np.asarray(a), dtype=like.dtype, device=like.device)
        if type(a) is np.ndarray and a.dtype == like.dtype:
            return a
        return np.asarray(a, dtype=like.dtype)

    def sqrt(self, x: Any) -> Any:
        return self.torch.sqrt(x) if self.torch is not None else np.sqrt(x)

    def cat(self, xs: list, axis: int = -1) -> Any:
        return self.torch.cat(xs, dim=axis) if self.torch is not None else np.concatenate(xs, axis=axis)

    def move(self, x: Any, src: int, dst: int) -> Any:
        return self.torch.movedim(x, src, dst) if self.torch is not None else np.moveaxis(x, src, dst)

    def solve(self, M: Any, b: Any) -> Any:
        if self.torch is not None:
            return self.torch.linalg.solve(M, b.unsqueeze(-1)).squeeze(-1)
        return np.linalg.solve(M, b[..., None])[..., 0]

    def trig(self, x: Any) -> tuple[Any, Any]:
        return (self.torch.cos(x), self.torch.sin(x)) if self.torch is not None else (np.cos(x), np.sin(x))

    def tanh(self, x: Any) -> Any:
        return self.torch.tanh(x) if self.torch is not None else np.tanh(x)


def _cross(a: Any, b: Any, ar: _Arrays) -> Any:
    """a x b over the last axis (3)."""
    a0, a1, a2, b0, b1, b2 = a[..., 0], a[..., 1], a[..., 2], b[..., 0], b[..., 1], b[..., 2]
    if ar.torch is not None:
        return ar.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), dtype=np.result_type(a, b))
    np.subtract(a1 * b2, a2 * b1, out=out[..., 0])
    np.subtract(a2 * b0, a0 * b2, out=out[..., 1])
    np.subtract(a0 * b1, a1 * b0, out=out[..., 2])
    return out


@dataclass(frozen=True)
class _JointRotation:
    """Rodrigues' constants of a hinge axis a: R(theta) = a a^T + cos(theta) (I - a a^T) + sin(theta) [a]x."""

    aa: np.ndarray
    rest: np.ndarray
    K: np.ndarray

    @classmethod
    def of(cls, axis: np.ndarray) -> _JointRotation:
        aa = np.outer(axis, axis)
        K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
        return cls(aa, np.eye(3) - aa, K)

    def matrix(self, theta: Any, ar: _Arrays) -> Any:
        """(..., 3, 3) rotation by theta (...,)."""
        c, s = ar.trig(theta)
        like = c[..., None, None]
        return ar.const(self.aa, like) + like * ar.const(self.rest, like) + s[..., None, None] * ar.const(self.K, like)


class _Kinematics:
    """World-frame joint axes and anchors, body frames and origins at the configuration theta (MuJoCo's
    mj_kinematics: each joint's axis and anchor are taken before its own motion is applied)."""

    def __init__(self, tree: MJCFTree, rotations: tuple[_JointRotation | None, ...], theta: Any, ar: _Arrays) -> None:
        n = tree.n
        R_w: list[Any] = []
        x_w: list[Any] = []
        axes: list[Any] = [None] * n
        anchors: list[Any] = [None] * n
        one = theta[..., :1, None] * 0.0 + 1.0  # (..., 1, 1) ones of theta's type
        for b in range(tree.nb):
            par = tree.body_parent[b]
            if par < 0:
                R, x = one * ar.const(tree.body_rot[b], one), one[..., 0] * ar.const(tree.body_pos[b], one)
            else:
                R = R_w[par] @ ar.const(tree.body_rot[b], one)
                x = x_w[par] + R_w[par] @ ar.const(tree.body_pos[b], one)
            for j in tree.body_joints[b]:
                axis = R @ ar.const(tree.joint_axis[j], one)
                anchor = x + R @ ar.const(tree.joint_pos[j], one)
                axes[j], anchors[j] = axis, anchor
                rot = rotations[j]
                if rot is not None:
                    R = R @ rot.matrix(theta[..., j], ar)
                    x = anchor - R @ ar.const(tree.joint_pos[j], one)
                else:
                    x = x + axis * theta[..., j, None]
            R_w.append(R)
            x_w.append(x)
        self.axes = ar.stack(axes, -2)  # (..., n, 3)
        self.anchors = ar.stack(anchors, -2)
        self.R = ar.stack(R_w, -3)  # (..., nb, 3, 3)
        self.x = ar.stack(x_w, -2)  # (..., nb, 3)


@dataclass(frozen=True)
class _Bodies:
    """Every body's kinematics at one configuration (world frame; ``...`` the batch)."""

    Jv: Any  # (..., nb, n, 3) centre-of-mass linear Jacobians
    Jw: Any  # (..., nb, n, 3) angular Jacobians
    RI: Any  # (..., nb, 3, 3) principal inertia axes
    C: Any  # (..., nb, 3) centres of mass
    axes: Any  # (..., n, 3) joint axes


class MJCFSystem(System):
    """A MuJoCo model's rigid-body tree as a port-Hamiltonian system; built by :func:`mjcf_system`."""

    TREE: ClassVar[MJCFTree]
    # parameter arrays: numpy, a (K*reps, ...) batch of parameter sets, or torch tensors of learned parameters
    _mass: Any
    _ipos: Any
    _inertia: Any
    _armature: Any
    _damping: Any
    _frictionloss: Any
    _stiffness: Any
    _gear: Any
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
        self._inertia = np.array([[p[f"{b}.inertia_{a}"] for a in AXES] for b in t.body_names], dtype=float).reshape(-1, 3)
        joint = {attr: np.array([p[f"{j}.{attr}"] for j in t.joint_names], dtype=float) for attr in JOINT_ATTRS}
        self._armature, self._damping = joint["armature"], joint["damping"]
        self._frictionloss, self._stiffness = joint["frictionloss"], joint["stiffness"]
        self._gear = np.array([p[f"{a.name}.gear"] for a in t.actuators], dtype=float)
        g = float(np.linalg.norm(t.gravity))
        self._g = t.gravity / g * float(p["gravity"] or 0.0) if g > 0 else np.zeros(3)
        self._hinge = np.array(t.joint_hinge, dtype=float)
        self._ancestor = self._ancestors()
        self._order = self._joint_order()
        self._rotations = tuple(_JointRotation.of(t.joint_axis[j]) if t.joint_hinge[j] else None for j in range(t.n))

    def _ancestors(self) -> np.ndarray:
        """(nb, n) 1 where joint j moves body b (j sits on b or on one of its ancestors)."""
        t = self.TREE
        out = np.zeros((t.nb, t.n))
        for b in range(t.nb):
            a = b
            while a >= 0:
                out[b, [j for j in range(t.n) if t.joint_body[j] == a]] = 1.0
                a = t.body_parent[a]
        return out

    def _joint_order(self) -> np.ndarray:
        """(n, n) 1 where joint j acts before joint k on k's path (an ancestor body's joint, or an earlier joint of
        k's own body)."""
        t = self.TREE
        out = np.zeros((t.n, t.n))
        for k in range(t.n):
            b = t.joint_body[k]
            for j in range(t.n):
                same = t.joint_body[j] == b and j < k
                out[k, j] = 1.0 if same or (t.joint_body[j] != b and self._ancestor[b, j]) else 0.0
        return out

    @cached_property
    def actuated_dofs(self) -> tuple[int, ...]:
        """The joint (qpos column) each actuator (ctrl column) drives, in actuator order."""
        return self.TREE.actuated_dofs()

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.TREE.joint_names

    # ---- the rigid-body formulas (numpy or torch arrays, coordinates last) ----
    def _bodies(self, theta: Any, ar: _Arrays) -> _Bodies:
        """Jacobians and inertia frames of every body at the configuration theta."""
        t = self.TREE
        kin = _Kinematics(t, self._rotations, theta, ar)
        C = kin.x + (kin.R @ ar.const(self._ipos, kin.x)[..., None])[..., 0]
        r = C[..., :, None, :] - kin.anchors[..., None, :, :]
        A = kin.axes[..., None, :, :]
        hinge = ar.const(self._hinge, C)[:, None]
        anc = ar.const(self._ancestor, C)[..., None]
        Jv = anc * (hinge * _cross(A, r, ar) + (1.0 - hinge) * A)
        Jw = anc * hinge * A
        RI = kin.R @ ar.const(t.body_irot, C)
        return _Bodies(Jv=Jv, Jw=Jw, RI=RI, C=C, axes=kin.axes)

    def _M(self, bodies: _Bodies, ar: _Arrays) -> Any:
        """M(q) (..., n, n) (Eq. above) as X X^T, X = [sqrt(m_b) Jv_b, Jw_b R_b sqrt(I_b)] over bodies."""
        C = bodies.C
        W = bodies.Jw @ bodies.RI  # angular Jacobians in each body's inertia frame
        sm, si = ar.sqrt(ar.const(self._mass, C)), ar.sqrt(ar.const(self._inertia, C))
        X = ar.cat([bodies.Jv * sm[..., :, None, None], W * si[..., :, None, :]])
        X = ar.move(X, -2, -3)  # (..., n, nb, 6)
        X = X.reshape(X.shape[:-2] + (-1,))
        return X @ ar.move(X, -1, -2) + ar.const(self._armature[..., None] * np.eye(self.n), C)

    def _dT_dq(self, bodies: _Bodies, v: Any, ar: _Arrays) -> Any:
        """v^T (dM/dq_k) v / 2 = dT/dq_k at fixed rates (..., n): a hinge k turns everything after it about its axis
        a_k, a slide k moves it along a_k, so for each body b with centre-of-mass velocity u_b and angular velocity w_b
        (world frame, I_b its world inertia)::

            du_b/dq_k = h_k a_k x u_b[>=k] + w[<k] x Jv_bk,   dw_b/dq_k = h_k a_k x w_b[>k],
            dT/dq_k   = sum_b m_b u_b . du_b/dq_k + (I_b w_b) . dw_b/dq_k + h_k a_k . ((I_b w_b) x w_b)

        where [>=k] sums the joints from k on, [>k] those after k, [<k] those before k (h_k = 1 for a hinge)."""
        C = bodies.C
        order = self._order  # (n, n): 1 where joint j comes strictly before joint k on k's path
        hv = v * ar.const(self._hinge, C)
        Jv_v = bodies.Jv * v[..., None, :, None]  # (..., nb, n, 3)
        Jw_v = bodies.Jw * v[..., None, :, None]
        u = Jv_v.sum(-2)  # (..., nb, 3)
        w = Jw_v.sum(-2)
        u_from = ar.const(order.T + np.eye(self.n), C) @ Jv_v  # u_b[>=k] (..., nb, n, 3)
        w_after = ar.const(order.T, C) @ Jw_v  # w_b[>k]
        w_before = ar.const(order, C) @ (bodies.axes * hv[..., None])  # w[<k] (..., n, 3)
        a = bodies.axes[..., None, :, :] * ar.const(self._hinge, C)[:, None]  # h_k a_k (..., 1, n, 3)
        m = ar.const(self._mass, C)[..., :, None]
        lin = (m * (u[..., None, :] * (_cross(a, u_from, ar) + _cross(w_before[..., None, :, :], bodies.Jv, ar))).sum(-1))
        Iw = (bodies.RI @ (ar.const(self._inertia, C) * (ar.move(bodies.RI, -1, -2) @ w[..., None])[..., 0])[..., None])[..., 0]
        rot = (Iw[..., None, :] * _cross(a, w_after, ar)).sum(-1) + (a * _cross(Iw, w, ar)[..., None, :]).sum(-1)
        return ((lin + rot) * ar.const(self._ancestor, C)).sum(-2)

    def _dV(self, q: Any, Jv: Any, ar: _Arrays) -> Any:
        grav = -((Jv * ar.const(self._g, q)[..., None, None, :]).sum(-1) * ar.const(self._mass, q)[..., :, None]).sum(-2)
        return grav + ar.const(self._stiffness, q) * (q - ar.const(self.TREE.qpos_spring, q))

    def _arrays(self, comps: Components) -> tuple[Any, _Arrays]:
        ar = _Arrays(comps[0])
        x = ar.stack([c if hasattr(c, "shape") else np.asarray(c, dtype=float) for c in comps]) if ar.torch is None \
            else ar.stack(list(comps))
        return x, ar

    def _theta(self, q: Any) -> Any:
        return q - (self.TREE.qpos0 if isinstance(q, np.ndarray) else q.new_tensor(self.TREE.qpos0))

    # ---- System interface ------------------------------------------------
    def mass_matrix(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple[tuple, ...]:
        Q, ar = self._arrays(q)
        M = self._M(self._bodies(self._theta(Q), ar), ar)
        n = self.n
        return tuple(tuple(M[..., i, j] for j in range(n)) for i in range(n))

    def potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> Any:
        Q, ar = self._arrays(q)
        C = self._bodies(self._theta(Q), ar).C
        d = Q - ar.const(self.TREE.qpos_spring, Q)
        return -((C * ar.const(self._g, Q)[..., None, :]).sum(-1) * ar.const(self._mass, Q)).sum(-1) \
            + 0.5 * ((ar.const(self._stiffness, Q) * d * d).sum(-1))

    def grad_potential(self, q: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        Q, ar = self._arrays(q)
        g = self._dV(Q, self._bodies(self._theta(Q), ar).Jv, ar)
        return tuple(g[..., i] for i in range(self.n))

    def velocity(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        Q, ar = self._arrays(q)
        P, _ = self._arrays(p)
        v = ar.solve(self._M(self._bodies(self._theta(Q), ar), ar), P + 0.0 * Q)
        return tuple(v[..., i] for i in range(self.n))

    def dH_dq(self, q: Components, p: Components, xp: ArrayNamespace = NUMPY) -> tuple:
        Q, ar = self._arrays(q)
        P, _ = self._arrays(p)
        bodies = self._bodies(self._theta(Q), ar)
        v = ar.solve(self._M(bodies, ar), P + 0.0 * Q)
        d = self._dV(Q, bodies.Jv, ar) - self._dT_dq(bodies, v, ar)
        return tuple(d[..., i] for i in range(self.n))

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

    def nonconservative_force(self, q: Components, v: Components, u: Components | None, xp: ArrayNamespace = NUMPY) -> tuple:
        """Joint damping, frictionloss (smoothed sign) and the actuators: everything in pdot but -dH/dq."""
        f = self.actuator_force(q, v, u)
        tanh = _Arrays(v[0]).tanh if hasattr(v[0], "shape") else math.tanh
        out = []
        for j, fj in enumerate(f):
            fj = fj - self._damping[..., j] * v[j]
            if np.any(self._frictionloss[..., j] > 0):
                fj = fj - self._frictionloss[..., j] * tanh(v[j] / FRICTION_EPS)
            out.append(fj)
        return tuple(out)

    def rhs(self, q: Components, p: Components, u: Components | None, xp: ArrayNamespace = NUMPY) -> tuple[tuple, tuple]:
        """Eq. 1-3 with M computed once per call."""
        Q, ar = self._arrays(q)
        P, _ = self._arrays(p)
        bodies = self._bodies(self._theta(Q), ar)
        V = ar.solve(self._M(bodies, ar), P + 0.0 * Q)
        dH = self._dV(Q, bodies.Jv, ar) - self._dT_dq(bodies, V, ar)
        v = tuple(V[..., i] for i in range(self.n))
        f = self.nonconservative_force(tuple(Q[..., i] for i in range(self.n)), v, u, xp)
        return v, tuple(fi - dH[..., i] for i, fi in enumerate(f))

    def power_balance(self, q: Components, p: Components, u: Components | None, xp: ArrayNamespace = NUMPY) -> tuple[Any, Any]:
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
        M = self._M(self._bodies(self._theta(q), _Arrays(q)), _Arrays(q))
        return np.concatenate([q, (M @ w[..., None])[..., 0]], axis=1)


def mjcf_system(path: str | Path) -> type[MJCFSystem]:
    """The :class:`MJCFSystem` subclass of a model file (``.xml`` MJCF or ``.urdf``); ModelFileError when MuJoCo
    cannot compile it or it has free/ball joints, equality constraints or non-joint actuators."""
    tree = read_tree(path)
    names = tree.joint_names
    attrs = {
        "TREE": tree, "name": f"mjcf:{tree.model_name}", "n": tree.n,
        "angle_dims": tuple(j for j in range(tree.n) if tree.joint_hinge[j]),
        "coordinate_names": names, "PARAMS": param_specs(tree), "__module__": __name__,
    }
    return type(f"MJCF_{tree.model_name}", (MJCFSystem,), attrs)
