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

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .base import Array, Components, solve_spd
from .mjcf_tree import MJCFTree


@dataclass(frozen=True)
class TreeParams:
    """The parameter arrays: numpy (``(nb,)``, ``(nb, 3)``, ...), a batch of parameter sets (a leading ``(B, ...)``
    axis: several systems simulated as one batch) or torch tensors (learned parameters)."""

    mass: Array  # (nb,)
    ipos: Array  # (nb, 3)
    inertia: Array  # (nb, 3) principal moments
    armature: Array  # (n,)
    stiffness: Array  # (n,)
    gravity: Array  # (3,)


class Ops:
    """numpy or torch, for arrays whose last ``nbat`` axes are the batch.  ``cache``: converted constants of one
    :class:`TreeConsts`, by array identity (:meth:`k`)."""

    def __init__(self, like: Any, nbat: int, cache: dict | None = None) -> None:
        self.like, self.nbat = like, nbat
        self.torch: Any = None
        self.cache = {} if cache is None else cache
        if type(like).__module__.startswith("torch"):
            import torch

            self.torch = torch
        self._key = (self.torch is not None, str(like.dtype), str(getattr(like, "device", "")), nbat)

    def const(self, a: Any) -> Array:
        """A constant (numpy array) or a learned tensor, with singleton batch axes appended."""
        if self.torch is not None:
            t = (a.to(self.like.dtype) if self.torch.is_tensor(a)
                 else self.torch.as_tensor(np.asarray(a), dtype=self.like.dtype))
            return t.reshape(tuple(t.shape) + (1,) * self.nbat)
        a = np.asarray(a, dtype=self.like.dtype)
        return a.reshape(a.shape + (1,) * self.nbat)

    def k(self, a: np.ndarray) -> Array:
        """:meth:`const` of a load-time constant (an array that lives as long as the cache), converted once."""
        key = (id(a),) + self._key
        c = self.cache.get(key)
        if c is None:
            c = self.cache[key] = self.const(a)
        return c

    def k0(self, a: np.ndarray) -> Array:
        """A load-time constant as it is (no batch axes), as a tensor on the torch path; converted once."""
        if self.torch is None:
            return a
        key = (id(a), "k0") + self._key
        c = self.cache.get(key)
        if c is None:
            c = self.cache[key] = self.torch.as_tensor(a, dtype=self.like.dtype, device=self.like.device)
        return c

    def param(self, a: Any, ndim: int) -> Array:
        """A parameter array of ``ndim`` structure axes; a leading batch axis (parameter sets) moves to the end."""
        if np.ndim(a) > ndim:
            a = self.torch.movedim(a, 0, -1) if self.torch is not None else np.moveaxis(np.asarray(a), 0, -1)
            return a.to(self.like.dtype) if self.torch is not None else a
        if isinstance(a, np.ndarray) and self.torch is None and a.dtype == self.like.dtype:
            return a.reshape(a.shape + (1,) * self.nbat)
        return self.const(a)

    def stack(self, xs: list, axis: int = 0) -> Array:
        return self.torch.stack(xs, dim=axis) if self.torch is not None else np.stack(xs, axis=axis)

    def trig(self, x: Array) -> tuple[Array, Array]:
        return (self.torch.cos(x), self.torch.sin(x)) if self.torch is not None else (np.cos(x), np.sin(x))

    def swap01(self, x: Array) -> Array:
        return x.transpose(0, 1) if self.torch is not None else np.swapaxes(x, 0, 1)

    def einsum(self, spec: str, *xs: Array) -> Array:
        """Contraction over structure axes, the batch in ``...`` (broadcast): one call instead of a product and a
        sum."""
        return self.torch.einsum(spec, *xs) if self.torch is not None else np.einsum(spec, *xs)

    def cat(self, xs: list) -> Array:
        return self.torch.cat(xs, 0) if self.torch is not None else np.concatenate(xs, 0)


def _batch_aligned(x: Array, lead: int, batch: int) -> Array:
    """``x`` with singleton batch axes inserted after its ``lead`` structure axes, up to ``batch`` batch axes (the
    batch broadcasts from the right, as einsum's ``...`` does)."""
    missing = batch - (x.ndim - lead)
    return x.reshape(x.shape[:lead] + (1,) * missing + x.shape[lead:]) if missing > 0 else x


def mv(A: Array, v: Array, ops: Ops) -> Array:
    """(i, j, ...) times (j, ...) -> (i, ...): a broadcast product and a sum over j (a 3-vector's einsum costs its
    call overhead several times over: 4x on 1,000 poses in torch)."""
    batch = max(A.ndim - 2, v.ndim - 1)
    return (_batch_aligned(A, 2, batch) * _batch_aligned(v, 1, batch)[None]).sum(1)


def mm(A: Array, B: Array, ops: Ops) -> Array:
    """(i, j, ...) times (j, k, ...) -> (i, k, ...), as :func:`mv`."""
    batch = max(A.ndim - 2, B.ndim - 2)
    return (_batch_aligned(A, 2, batch)[:, :, None] * _batch_aligned(B, 2, batch)[None]).sum(1)


def cross(a: Array, b: Array, ops: Ops) -> Array:
    """a x b over the first axis (3, ...): (a_{i+1} b_{i+2} - a_{i+2} b_{i+1})_i from cyclic extensions (four ops)."""
    a5, b5 = ops.cat([a, a[:2]]), ops.cat([b, b[:2]])
    return a5[1:4] * b5[2:5] - a5[2:5] * b5[1:4]


@dataclass(frozen=True)
class JointStep:
    """One joint's motion in :func:`frames`, with the constant products folded in at load time.

    ``static``: the frame before the joint is fixed in the world (a root body's first joint), so its world ``axis``
    and ``anchor`` are constants, its rotation is ``P0 + cos P1 + sin P2`` and the body origin ``e0 + cos e1 + sin e2``
    (a slide: rotation ``P0``, origin ``e0 + axis theta``).  Otherwise, with ``R_ref, x_ref`` the parent's frame (the
    body's first joint) or the body's frame so far (a later joint): axis ``R_ref axis``, anchor ``x_ref + R_ref
    anchor``, rotation ``R_ref (P0 + cos P1 + sin P2)`` and origin ``anchor - R pos`` (a slide: rotation ``R_ref P0``,
    origin ``x_ref + R_ref origin + axis theta``).
    """

    j: int
    hinge: bool
    static: bool
    axis: np.ndarray  # (3,)
    anchor: np.ndarray  # (3,)
    P: tuple[np.ndarray, ...]  # (3, 3) each
    pos: np.ndarray | None  # the anchor in the frame after the joint; None when zero
    origin: tuple[np.ndarray, ...]  # static hinge: (e0, e1, e2); slide: (the origin before the motion,)


@dataclass(frozen=True)
class BodyPlan:
    """How :func:`frames` reaches one body: its parent, the fixed rotation and offset of a jointless body, its
    joints."""

    parent: int
    rot: np.ndarray | None  # None: identity (a jointless body)
    pos: np.ndarray
    steps: tuple[JointStep, ...]


def _rodrigues(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(a a^T, I - a a^T, [a]x): the rotation by theta about unit a is a a^T + cos(theta) (I - a a^T) + sin(theta)
    [a]x."""
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    aa = np.outer(a, a)
    return aa, np.eye(3) - aa, K


def _joint_step(tree: MJCFTree, j: int, first: bool, root: bool, b: int) -> JointStep:
    """MuJoCo's mj_kinematics for joint j: its axis and anchor are taken before its own motion is applied."""
    a, pj = tree.joint_axis[j], tree.joint_pos[j]
    hinge = bool(tree.joint_hinge[j])
    pos = pj.copy() if np.any(pj) else None
    # the constant rotation and offset between the reference frame and the joint's frame
    pre, base = (tree.body_rot[b], tree.body_pos[b]) if first else (np.eye(3), np.zeros(3))
    anchor = base + pre @ pj
    if first and root:  # the reference frame is the world: fold everything
        if hinge:
            P = tuple(pre @ m for m in _rodrigues(a))
            return JointStep(j, True, True, pre @ a, anchor, P, pos, (anchor - P[0] @ pj, -P[1] @ pj, -P[2] @ pj))
        return JointStep(j, False, True, pre @ a, anchor, (pre,), pos, (base,))
    if hinge:
        return JointStep(j, True, False, pre @ a, anchor, tuple(pre @ m for m in _rodrigues(a)), pos, ())
    return JointStep(j, False, False, pre @ a, anchor, (pre,), pos, (base,))


def _plans(tree: MJCFTree) -> tuple[BodyPlan, ...]:
    out = []
    for b in range(tree.nb):
        root = tree.body_parent[b] < 0
        steps = tuple(_joint_step(tree, j, i == 0, root, b) for i, j in enumerate(tree.body_joints[b]))
        rot = None if np.array_equal(tree.body_rot[b], np.eye(3)) else tree.body_rot[b].copy()
        out.append(BodyPlan(tree.body_parent[b], rot, tree.body_pos[b].copy(), steps))
    return tuple(out)


@dataclass(frozen=True)
class TreeConsts:
    """What the formulas need of a tree beyond its parameters, computed once per model."""

    tree: MJCFTree
    plans: tuple[BodyPlan, ...]
    irot: np.ndarray  # (3, 3, nb) principal axes in the body frames
    ancestor: np.ndarray  # (nb, n): joint k moves body b
    hinge_ancestor: np.ndarray  # (nb, n): ancestor times hinge (the angular Jacobian's mask)
    slide_ancestor: np.ndarray  # (nb, n)
    order: np.ndarray  # (n, n): joint j acts before joint k on k's path
    after: np.ndarray  # (n, n): order.T, joint j acts after joint k
    from_k: np.ndarray  # (n, n): after + identity
    hinge: np.ndarray  # (n,)
    eye: np.ndarray  # (n, n)
    qpos0: np.ndarray
    qpos_spring: np.ndarray
    all_hinges: bool  # no slide joint: the linear Jacobian has no translation columns
    cache: dict = field(default_factory=dict, compare=False, repr=False)  # Ops.k's converted constants

    @classmethod
    def of(cls, tree: MJCFTree) -> TreeConsts:
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
        hinge = np.array(tree.joint_hinge, dtype=float)
        return cls(tree, _plans(tree), np.moveaxis(tree.body_irot, 0, -1), anc, anc * hinge, anc * (1.0 - hinge), order,
                   order.T.copy(), order.T + np.eye(tree.n), hinge, np.eye(tree.n), tree.qpos0.copy(),
                   tree.qpos_spring.copy(), bool(np.all(hinge == 1.0)))


@dataclass(frozen=True)
class Frames:
    """World-frame joint axes (3, n, ...) and anchors, body rotations (3, 3, nb, ...) and origins (3, nb, ...)."""

    axes: Array
    anchors: Array
    R: Array
    x: Array


def frames(tc: TreeConsts, theta: Array, ops: Ops) -> Frames:
    """MuJoCo's mj_kinematics, following the load-time :class:`BodyPlan` of every body."""
    k = ops.k
    one = theta[0] * 0.0 + 1.0
    n = tc.tree.n
    R_w: list[Array | None] = []
    x_w: list[Array | None] = []
    axes: list[Array | None] = [None] * n
    anchors: list[Array | None] = [None] * n
    for plan in tc.plans:
        R = x = None
        if plan.parent >= 0:
            R, x = R_w[plan.parent], x_w[plan.parent]
        for s in plan.steps:
            th = theta[s.j]
            if s.static:
                axes[s.j], anchors[s.j] = k(s.axis) * one, k(s.anchor) * one
                if s.hinge:
                    c, sn = ops.trig(th)
                    R = k(s.P[0]) + c * k(s.P[1]) + sn * k(s.P[2])
                    x = k(s.origin[0]) + c * k(s.origin[1]) + sn * k(s.origin[2]) if s.pos is not None else anchors[s.j]
                else:
                    R = k(s.P[0]) * one
                    x = k(s.origin[0]) + k(s.axis) * th
                continue
            assert R is not None and x is not None
            axis = mv(R, k(s.axis), ops)
            anchor = x + mv(R, k(s.anchor), ops)
            axes[s.j], anchors[s.j] = axis, anchor
            if s.hinge:
                c, sn = ops.trig(th)
                R = mm(R, k(s.P[0]) + c * k(s.P[1]) + sn * k(s.P[2]), ops)
                x = anchor - mv(R, k(s.pos), ops) if s.pos is not None else anchor
            else:
                x = x + mv(R, k(s.origin[0]), ops) + axis * th
                R = mm(R, k(s.P[0]), ops)
        if not plan.steps:
            assert R is not None and x is not None
            x = x + mv(R, k(plan.pos), ops)
            R = mm(R, k(plan.rot), ops) if plan.rot is not None else R
        R_w.append(R)
        x_w.append(x)
    return Frames(ops.stack(axes, 1), ops.stack(anchors, 1), ops.stack(R_w, 2), ops.stack(x_w, 1))


@dataclass(frozen=True)
class Bodies:
    """Every body's Jacobians (3, nb, n, ...), inertia axes RI (3, 3, nb, ...) and centre of mass C (3, nb, ...)."""

    Jv: Array
    Jw: Array
    RI: Array
    C: Array
    axes: Array  # (3, n, ...)


def bodies(tc: TreeConsts, p: TreeParams, theta: Array, ops: Ops) -> Bodies:
    f = frames(tc, theta, ops)
    ipos = ops.swap01(ops.param(p.ipos, 2))  # (3, nb, ...)
    C = f.x + mv(f.R, ipos, ops)
    A = f.axes[:, None]
    Jw = ops.k(tc.hinge_ancestor) * A
    Jv = ops.k(tc.hinge_ancestor) * cross(A, C[:, :, None] - f.anchors[:, None], ops)
    if not tc.all_hinges:
        Jv = Jv + ops.k(tc.slide_ancestor) * A
    return Bodies(Jv, Jw, mm(f.R, ops.k(tc.irot), ops), C, f.axes)


def mass_matrix(tc: TreeConsts, p: TreeParams, bd: Bodies, ops: Ops) -> Array:
    """M(q) (n, n, ...)."""
    m = ops.param(p.mass, 1)  # (nb, ...)
    inertia = ops.swap01(ops.param(p.inertia, 2))  # (3, nb, ...)
    batch = bd.Jv.ndim - 3
    m, inertia = _batch_aligned(m, 1, batch), _batch_aligned(inertia, 2, batch)
    # broadcast products and sums, not einsum: 4-7x faster in torch on 64 to 13,000 poses of a 6-joint arm
    W = (bd.RI[:, :, :, None] * bd.Jw[:, None]).sum(0)  # angular Jacobians in the inertia frames, (3, nb, n, ...)
    M = (((bd.Jv * m[None, :, None])[:, :, :, None] * bd.Jv[:, :, None]).sum((0, 1))
         + ((W * inertia[:, :, None])[:, :, :, None] * W[:, :, None]).sum((0, 1)))
    arm = ops.param(p.armature, 1)
    return M + ops.k(tc.eye) * arm[:, None]


def gravity_gradient(p: TreeParams, bd: Bodies, ops: Ops) -> Array:
    """d(-sum_b m_b g . c_b)/dq (n, ...)."""
    gm = _gravity_mass(p, bd.C.ndim - 2, ops)
    return -(bd.Jv * gm[:, :, None]).sum((0, 1))


def gravity_potential(p: TreeParams, bd: Bodies, ops: Ops) -> Array:
    return -(bd.C * _gravity_mass(p, bd.C.ndim - 2, ops)).sum((0, 1))


def _gravity_mass(p: TreeParams, batch: int, ops: Ops) -> Array:
    """(3, nb, ...) g_x m_b, its batch axes aligned with ``batch`` axes of the poses."""
    g, m = _batch_aligned(ops.param(p.gravity, 1), 1, batch), _batch_aligned(ops.param(p.mass, 1), 1, batch)
    return g[:, None] * m[None]


def kinetic_dq(tc: TreeConsts, p: TreeParams, bd: Bodies, v: Array, ops: Ops) -> Array:
    """v^T (dM/dq_k) v / 2 = dT/dq_k at fixed rates (n, ...).  A hinge k turns everything after it about a_k, a slide
    moves it along a_k; for body b with centre-of-mass velocity u_b, angular velocity w_b and world inertia I_b::

        du_b/dq_k = h_k a_k x u_b[>=k] + w[<k] x Jv_bk,   dw_b/dq_k = h_k a_k x w_b[>k],
        dT/dq_k   = sum_b m_b u_b . du_b/dq_k + (I_b w_b) . dw_b/dq_k + h_k a_k . ((I_b w_b) x w_b)

    where [>=k] sums the joints from k on, [>k] those after k and [<k] those before k.  With the triple product the
    sums over bodies come first::

        dT/dq_k = h_k a_k . (sum_{j>=k} v_j G_j + sum_{j>k} v_j H_j + sum_{b after k} (I_b w_b) x w_b) + w[<k] . G_k,
        G_j = sum_b m_b Jv_bj x u_b,   H_j = sum_b Jw_bj x (I_b w_b)
    """
    batch = bd.Jv.ndim - 3
    const = lambda a: _batch_aligned(ops.k0(a), a.ndim, batch)  # noqa: E731  (a load-time matrix, no batch)
    v = _batch_aligned(v, 1, batch)
    # broadcast products and sums, as in mass_matrix
    u, w = (bd.Jv * v[None, None]).sum(2), (bd.Jw * v[None, None]).sum(2)  # (3, nb, ...)
    inertia = _batch_aligned(ops.swap01(ops.param(p.inertia, 2)), 2, batch)  # (3, nb, ...)
    Iw = mv(bd.RI, inertia * (bd.RI * w[:, None]).sum(0), ops)  # (3, nb, ...)
    # G and H in one cross product: Jv x (m u) and Jw x (I w), summed over the bodies
    m = _batch_aligned(ops.param(p.mass, 1), 1, batch)
    GH = cross(ops.stack([bd.Jv, bd.Jw], 1), ops.stack([m * u, Iw], 1)[:, :, :, None], ops).sum(2)  # (3, 2, n, ...)
    G, H = GH[:, 0], GH[:, 1]
    E = (cross(Iw, w, ops)[:, :, None] * const(tc.ancestor)[None]).sum(1)  # (3, n, ...): over the bodies after k
    over_j = lambda X, vj, K: ((X * vj[None])[:, None] * const(K)[None]).sum(2)  # noqa: E731  sum_j X_j v_j K_kj
    S = over_j(G, v, tc.from_k) + over_j(H, v, tc.after) + E
    w_before = over_j(bd.axes, v * const(tc.hinge), tc.order)  # (3, n_k, ...)
    return (bd.axes * S).sum(0) * const(tc.hinge) + (w_before * G).sum(0)


def solve(M: Array, b: Components) -> tuple:
    """M^-1 b for (n, n, ...) and (n, ...) (elimination over the batch: no per-sample LAPACK call)."""
    n = M.shape[0]
    x = solve_spd(tuple(tuple(M[i, j] for j in range(n)) for i in range(n)), tuple(b[i] for i in range(n)))
    return x
