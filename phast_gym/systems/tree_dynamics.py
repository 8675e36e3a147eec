"""The rigid-body formulas of a kinematic tree, in MuJoCo's conventions, over numpy or torch arrays.

Layout: vector and matrix components come first and the batch axes last (``q`` is ``(n, *batch)``, a body frame
``(3, 3, nb, *batch)``), so every operation runs over contiguous batches; small matrix products are written as
broadcast sums, which beat batched ``matmul`` of 3 x 3 blocks by an order of magnitude.  With ``h_k`` 1 for a hinge
and 0 for a slide, ``a_k`` / ``x_k`` a joint's world axis and anchor, ``c_b`` a body's centre of mass::

    Jv_bk = anc_bk (h_k a_k x (c_b - x_k) + (1 - h_k) a_k),   Jw_bk = anc_bk h_k a_k
    M(q)  = sum_b m_b Jv_b^T Jv_b + Jw_b^T R_b I_b R_b^T Jw_b + diag(armature)          (MuJoCo's mj_fullM)
    V(q)  = -sum_b m_b g . c_b + sum_j stiffness_j (q_j - springref_j)^2 / 2
    v^T (dM/dq_k) v / 2 = dT/dq_k at fixed rates (:func:`kinetic_dq`)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .base import solve_spd
from .mjcf_tree import MJCFTree


@dataclass(frozen=True)
class TreeParams:
    """The parameter arrays: numpy (``(nb,)``, ``(nb, 3)``, ...), a batch of parameter sets (a leading ``(B, ...)``
    axis: several systems simulated as one batch) or torch tensors (learned parameters)."""

    mass: Any  # (nb,)
    ipos: Any  # (nb, 3)
    inertia: Any  # (nb, 3) principal moments
    armature: Any  # (n,)
    stiffness: Any  # (n,)
    gravity: Any  # (3,)


class Ops:
    """numpy or torch, for arrays whose last ``nbat`` axes are the batch."""

    def __init__(self, like: Any, nbat: int) -> None:
        self.like, self.nbat = like, nbat
        self.torch: Any = None
        if type(like).__module__.startswith("torch"):
            import torch

            self.torch = torch

    def const(self, a: Any) -> Any:
        """A constant (numpy array) or a learned tensor, with singleton batch axes appended."""
        if self.torch is not None:
            t = a.to(self.like.dtype) if self.torch.is_tensor(a) else self.torch.as_tensor(np.asarray(a), dtype=self.like.dtype)
            return t.reshape(tuple(t.shape) + (1,) * self.nbat)
        a = np.asarray(a, dtype=self.like.dtype)
        return a.reshape(a.shape + (1,) * self.nbat)

    def param(self, a: Any, ndim: int) -> Any:
        """A parameter array of ``ndim`` structure axes; a leading batch axis (parameter sets) moves to the end."""
        if np.ndim(a) > ndim:
            a = self.torch.movedim(a, 0, -1) if self.torch is not None else np.moveaxis(np.asarray(a), 0, -1)
            return a.to(self.like.dtype) if self.torch is not None else a
        return self.const(a)

    def stack(self, xs: list, axis: int = 0) -> Any:
        return self.torch.stack(xs, dim=axis) if self.torch is not None else np.stack(xs, axis=axis)

    def trig(self, x: Any) -> tuple[Any, Any]:
        return (self.torch.cos(x), self.torch.sin(x)) if self.torch is not None else (np.cos(x), np.sin(x))

    def sqrt(self, x: Any) -> Any:
        return self.torch.sqrt(x) if self.torch is not None else np.sqrt(x)

    def swap01(self, x: Any) -> Any:
        return x.transpose(0, 1) if self.torch is not None else np.swapaxes(x, 0, 1)


def mv(A: Any, v: Any) -> Any:
    """(i, j, ...) times (j, ...) -> (i, ...)."""
    return (A * v[None]).sum(1)


def mm(A: Any, B: Any) -> Any:
    """(i, j, ...) times (j, k, ...) -> (i, k, ...)."""
    return (A[:, :, None] * B[None]).sum(1)


def cross(a: Any, b: Any, ops: Ops) -> Any:
    """a x b over the first axis (3, ...)."""
    return ops.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@dataclass(frozen=True)
class TreeConsts:
    """What the formulas need of a tree beyond its parameters, computed once per model."""

    tree: MJCFTree
    rodrigues: tuple[tuple[np.ndarray, np.ndarray, np.ndarray] | None, ...]  # per joint (a a^T, I - a a^T, [a]x); None: slide
    irot: np.ndarray  # (3, 3, nb) principal axes in the body frames
    ancestor: np.ndarray  # (nb, n): joint k moves body b
    order: np.ndarray  # (n, n): joint j acts before joint k on k's path
    hinge: np.ndarray  # (n,)

    @classmethod
    def of(cls, tree: MJCFTree) -> TreeConsts:
        rod: list[tuple[np.ndarray, np.ndarray, np.ndarray] | None] = []
        for j in range(tree.n):
            a = tree.joint_axis[j]
            K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
            aa = np.outer(a, a)
            rod.append((aa, np.eye(3) - aa, K) if tree.joint_hinge[j] else None)
        anc = np.zeros((tree.nb, tree.n))
        for b in range(tree.nb):
            a_ = b
            while a_ >= 0:
                anc[b, list(tree.body_joints[a_])] = 1.0
                a_ = tree.body_parent[a_]
        order = np.zeros((tree.n, tree.n))
        for k in range(tree.n):
            bk = tree.joint_body[k]
            for j in range(tree.n):
                same = tree.joint_body[j] == bk and j < k
                order[k, j] = 1.0 if same or (tree.joint_body[j] != bk and anc[bk, j]) else 0.0
        return cls(tree, tuple(rod), np.moveaxis(tree.body_irot, 0, -1), anc, order, np.array(tree.joint_hinge, dtype=float))


@dataclass(frozen=True)
class Frames:
    """World-frame joint axes (3, n, ...) and anchors, body rotations (3, 3, nb, ...) and origins (3, nb, ...)."""

    axes: Any
    anchors: Any
    R: Any
    x: Any


def _rotation(rod: tuple[np.ndarray, np.ndarray, np.ndarray], theta: Any, ops: Ops) -> Any:
    """Rodrigues: a a^T + cos(theta) (I - a a^T) + sin(theta) [a]x, (3, 3, ...)."""
    c, s = ops.trig(theta)
    aa, rest, K = (ops.const(m) for m in rod)
    return aa + c * rest + s * K


def frames(tc: TreeConsts, theta: Any, ops: Ops) -> Frames:
    """MuJoCo's mj_kinematics: each joint's axis and anchor are taken before its own motion is applied."""
    t = tc.tree
    one = theta[0] * 0.0 + 1.0
    R_w: list[Any] = []
    x_w: list[Any] = []
    axes: list[Any] = [None] * t.n
    anchors: list[Any] = [None] * t.n
    for b in range(t.nb):
        par = t.body_parent[b]
        if par < 0:
            R, x = ops.const(t.body_rot[b]) * one, ops.const(t.body_pos[b]) * one
        else:
            R = mm(R_w[par], ops.const(t.body_rot[b]))
            x = x_w[par] + mv(R_w[par], ops.const(t.body_pos[b]))
        for j in t.body_joints[b]:
            axis, pos = mv(R, ops.const(t.joint_axis[j])), ops.const(t.joint_pos[j])
            anchor = x + mv(R, pos)
            axes[j], anchors[j] = axis, anchor
            rod = tc.rodrigues[j]
            if rod is not None:
                R = mm(R, _rotation(rod, theta[j], ops))
                x = anchor - mv(R, pos)
            else:
                x = x + axis * theta[j]
        R_w.append(R)
        x_w.append(x)
    return Frames(ops.stack(axes, 1), ops.stack(anchors, 1), ops.stack(R_w, 2), ops.stack(x_w, 1))


@dataclass(frozen=True)
class Bodies:
    """Every body's Jacobians (3, nb, n, ...), inertia axes RI (3, 3, nb, ...) and centre of mass C (3, nb, ...)."""

    Jv: Any
    Jw: Any
    RI: Any
    C: Any
    axes: Any  # (3, n, ...)


def bodies(tc: TreeConsts, p: TreeParams, theta: Any, ops: Ops) -> Bodies:
    f = frames(tc, theta, ops)
    ipos = ops.swap01(ops.param(p.ipos, 2))  # (3, nb, ...)
    C = f.x + mv(f.R, ipos)
    r = C[:, :, None] - f.anchors[:, None]
    A = f.axes[:, None]
    hinge, anc = ops.const(tc.hinge), ops.const(tc.ancestor)
    Jv = anc * (hinge * cross(A, r, ops) + (1.0 - hinge) * A)
    Jw = anc * hinge * A
    return Bodies(Jv, Jw, mm(f.R, ops.const(tc.irot)), C, f.axes)


def mass_matrix(p: TreeParams, bd: Bodies, ops: Ops) -> Any:
    """M(q) (n, n, ...)."""
    m = ops.param(p.mass, 1)[:, None, None]  # (nb, 1, 1, ...)
    inertia = ops.swap01(ops.param(p.inertia, 2))[:, :, None, None]  # (3, nb, 1, 1, ...)
    W = (bd.RI[:, :, :, None] * bd.Jw[:, None]).sum(0)  # angular Jacobians in the inertia frames, (3, nb, n, ...)
    M = (m * bd.Jv[:, :, :, None] * bd.Jv[:, :, None, :]).sum(0).sum(0) \
        + (inertia * W[:, :, :, None] * W[:, :, None, :]).sum(0).sum(0)
    arm = ops.param(p.armature, 1)
    n = M.shape[0]
    eye = ops.const(np.eye(n))
    return M + eye * arm[:, None]


def gravity_gradient(p: TreeParams, bd: Bodies, ops: Ops) -> Any:
    """d(-sum_b m_b g . c_b)/dq (n, ...)."""
    g = ops.param(p.gravity, 1)[:, None, None]  # (3, 1, 1, ...)
    m = ops.param(p.mass, 1)[:, None]  # (nb, 1, ...)
    return -(m * (bd.Jv * g).sum(0)).sum(0)


def gravity_potential(p: TreeParams, bd: Bodies, ops: Ops) -> Any:
    g = ops.param(p.gravity, 1)[:, None]
    return -(ops.param(p.mass, 1) * (bd.C * g).sum(0)).sum(0)


def kinetic_dq(tc: TreeConsts, p: TreeParams, bd: Bodies, v: Any, ops: Ops) -> Any:
    """v^T (dM/dq_k) v / 2 = dT/dq_k at fixed rates (n, ...).  A hinge k turns everything after it about a_k, a slide
    moves it along a_k; for body b with centre-of-mass velocity u_b, angular velocity w_b and world inertia I_b::

        du_b/dq_k = h_k a_k x u_b[>=k] + w[<k] x Jv_bk,   dw_b/dq_k = h_k a_k x w_b[>k],
        dT/dq_k   = sum_b m_b u_b . du_b/dq_k + (I_b w_b) . dw_b/dq_k + h_k a_k . ((I_b w_b) x w_b)

    where [>=k] sums the joints from k on, [>k] those after k and [<k] those before k."""
    order = tc.order
    Jv_v, Jw_v = bd.Jv * v[None, None], bd.Jw * v[None, None]  # (3, nb, n, ...)
    u, w = Jv_v.sum(2), Jw_v.sum(2)  # (3, nb, ...)
    after = ops.const(order.T)  # after[k, j]: joint j acts after joint k
    u_from = (Jv_v[:, :, None] * (after + ops.const(np.eye(len(order))))[None, None]).sum(3)  # (3, nb, n_k, ...)
    w_after = (Jw_v[:, :, None] * after[None, None]).sum(3)
    hv = v * ops.const(tc.hinge)
    w_before = (((bd.axes * hv[None])[:, None]) * ops.const(order)[None]).sum(2)  # (3, n_k, ...)
    a = (bd.axes * ops.const(tc.hinge))[:, None]  # h_k a_k, (3, 1, n, ...)
    m = ops.param(p.mass, 1)[:, None]
    lin = m * (u[:, :, None] * (cross(a, u_from, ops) + cross(w_before[:, None], bd.Jv, ops))).sum(0)
    inertia = ops.swap01(ops.param(p.inertia, 2))  # (3, nb, ...)
    local = (bd.RI * w[:, None]).sum(0)  # R^T w in the inertia frames, (3, nb, ...)
    Iw = mv(bd.RI, inertia * local)
    rot = (Iw[:, :, None] * cross(a, w_after, ops)).sum(0) + (a * cross(Iw, w, ops)[:, :, None]).sum(0)
    return ((lin + rot) * ops.const(tc.ancestor)).sum(0)


def solve(M: Any, b: Any) -> Any:
    """M^-1 b for (n, n, ...) and (n, ...) (elimination over the batch: no per-sample LAPACK call)."""
    n = M.shape[0]
    x = solve_spd(tuple(tuple(M[i, j] for j in range(n)) for i in range(n)), tuple(b[i] for i in range(n)))
    return x
