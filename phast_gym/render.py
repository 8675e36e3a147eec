"""Pure-numpy frames of every system (``env.render()`` in ``rgb_array`` mode).

No pygame and no matplotlib: shapes are rasterized with distance masks over
their bounding boxes and anti-aliased edges, so a frame costs about a
millisecond and works on headless machines.  :func:`render_frame` is the
entry point; :class:`Canvas` holds the few drawing primitives.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from .systems import CartPole, DoublePendulum, HeatExchange, Oscillator, Pendulum, PredatorPrey, RLCCircuit, System

RGB = tuple[int, int, int]
BACKGROUND: RGB = (248, 248, 244)
INK: RGB = (40, 40, 48)
ROD: RGB = (70, 90, 140)
BOB: RGB = (200, 70, 50)
PORT: RGB = (230, 140, 0)
TRACK: RGB = (150, 150, 150)
BLUE: RGB = (60, 110, 200)
RED: RGB = (210, 60, 50)
GREEN: RGB = (60, 160, 80)
PARTICLE_COLORS: tuple[RGB, ...] = ((200, 70, 50), (60, 110, 200), (60, 160, 80))


class Canvas:
    """An RGB image with a world -> pixel transform (world y points up).

    ``scale`` pixels per world unit, ``center`` the world point at the image centre.
    """

    def __init__(self, height: int = 256, width: int = 256, scale: float = 50.0,
                 center: tuple[float, float] = (0.0, 0.0), background: RGB = BACKGROUND) -> None:
        if height < 16 or width < 16:
            raise ValueError(f"frame size must be at least 16 x 16, got {height} x {width}")
        self.h, self.w, self.scale = int(height), int(width), float(scale)
        self.cx, self.cy = center
        self.img = np.empty((self.h, self.w, 3), dtype=np.float32)
        self.img[:] = background

    def px(self, x: float, y: float) -> tuple[float, float]:
        """World (x, y) -> pixel (column, row) as floats."""
        return (self.w / 2 + (x - self.cx) * self.scale, self.h / 2 - (y - self.cy) * self.scale)

    # ---- low level: blend a coverage mask over a pixel box ---------------------------
    def _box(self, c0: float, r0: float, c1: float, r1: float, pad: float
             ) -> tuple[slice, slice, np.ndarray, np.ndarray] | None:
        a, b = max(int(math.floor(min(c0, c1) - pad)), 0), min(int(math.ceil(max(c0, c1) + pad)) + 1, self.w)
        c, d = max(int(math.floor(min(r0, r1) - pad)), 0), min(int(math.ceil(max(r0, r1) + pad)) + 1, self.h)
        if a >= b or c >= d:
            return None
        cols = np.arange(a, b, dtype=np.float32) + 0.5
        rows = np.arange(c, d, dtype=np.float32)[:, None] + 0.5
        return slice(c, d), slice(a, b), cols, rows

    def _blend(self, rs: slice, cs: slice, cover: np.ndarray, color: RGB) -> None:
        cover = np.clip(cover, 0.0, 1.0)[..., None]
        patch = self.img[rs, cs]
        patch += cover * (np.asarray(color, dtype=np.float32) - patch)

    # ---- primitives in pixel units ----------------------------------------------------
    def line_px(self, c0: float, r0: float, c1: float, r1: float, width: float, color: RGB) -> None:
        """Segment with round caps, ``width`` pixels wide."""
        box = self._box(c0, r0, c1, r1, width / 2 + 1)
        if box is None:
            return
        rs, cs, cols, rows = box
        dc, dr = c1 - c0, r1 - r0
        L2 = dc * dc + dr * dr
        if L2 > 0:
            t = np.clip(((cols - c0) * dc + (rows - r0) * dr) / L2, 0.0, 1.0)
        else:
            t = np.zeros_like(cols) + 0.0 * rows
        dist = np.hypot(cols - (c0 + t * dc), rows - (r0 + t * dr))
        self._blend(rs, cs, width / 2 + 0.5 - dist, color)

    def disc_px(self, c: float, r: float, radius: float, color: RGB) -> None:
        box = self._box(c, r, c, r, radius + 1)
        if box is None:
            return
        rs, cs, cols, rows = box
        self._blend(rs, cs, radius + 0.5 - np.hypot(cols - c, rows - r), color)

    def rect_px(self, c0: float, r0: float, c1: float, r1: float, color: RGB) -> None:
        box = self._box(c0, r0, c1, r1, 1)
        if box is None:
            return
        rs, cs, cols, rows = box
        lo_c, hi_c, lo_r, hi_r = min(c0, c1), max(c0, c1), min(r0, r1), max(r0, r1)
        cover_c = np.clip(np.minimum(cols - lo_c, hi_c - cols) + 0.5, 0.0, 1.0)
        cover_r = np.clip(np.minimum(rows - lo_r, hi_r - rows) + 0.5, 0.0, 1.0)
        self._blend(rs, cs, cover_c * cover_r, color)

    def arc_px(self, c: float, r: float, radius: float, a0: float, a1: float, width: float, color: RGB) -> None:
        """Arc from angle ``a0`` to ``a1`` (radians, counter-clockwise on screen, 0 = +x)."""
        box = self._box(c - radius, r - radius, c + radius, r + radius, width / 2 + 1)
        if box is None:
            return
        rs, cs, cols, rows = box
        lo, hi = min(a0, a1), max(a0, a1)
        ang = np.arctan2(-(rows - r), cols - c)  # screen rows grow downwards
        inside = ((ang - lo) % (2 * math.pi)) <= (hi - lo)
        ring = width / 2 + 0.5 - np.abs(np.hypot(cols - c, rows - r) - radius)
        self._blend(rs, cs, np.where(inside, ring, 0.0), color)

    def arrow_px(self, c0: float, r0: float, c1: float, r1: float, width: float, color: RGB) -> None:
        """Arrow from (c0, r0) to (c1, r1) with a two-stroke head."""
        self.line_px(c0, r0, c1, r1, width, color)
        ang = math.atan2(r1 - r0, c1 - c0)
        head = 3.0 * width + 4.0
        for s in (+1, -1):
            a = ang + math.pi + s * 0.5
            self.line_px(c1, r1, c1 + head * math.cos(a), r1 + head * math.sin(a), width, color)

    # ---- primitives in world units ------------------------------------------------------
    def line(self, p0: Sequence[float], p1: Sequence[float], width: float, color: RGB) -> None:
        self.line_px(*self.px(*p0), *self.px(*p1), width, color)

    def disc(self, p: Sequence[float], radius_px: float, color: RGB) -> None:
        self.disc_px(*self.px(*p), radius_px, color)

    def rect(self, p0: Sequence[float], p1: Sequence[float], color: RGB) -> None:
        self.rect_px(*self.px(*p0), *self.px(*p1), color)

    def torque(self, p: Sequence[float], u: float, u_max: float, radius_px: float = 28.0) -> None:
        """Curved arrow around ``p``: counter-clockwise for u > 0, sweep proportional to |u| / u_max."""
        if u == 0.0 or not math.isfinite(u):
            return
        c, r = self.px(*p)
        span = 0.3 + 1.5 * math.pi * min(abs(u) / u_max, 1.0)
        a0 = math.pi / 2 - span / 2
        a1 = a0 + span
        self.arc_px(c, r, radius_px, a0, a1, 3.0, PORT)
        end = a1 if u > 0 else a0  # arrow head at the end the torque turns towards
        ec, er = c + radius_px * math.cos(end), r - radius_px * math.sin(end)
        tang = end + (math.pi / 2 if u > 0 else -math.pi / 2)
        tc, tr = math.cos(tang), -math.sin(tang)
        self.arrow_px(ec - 6 * tc, er - 6 * tr, ec, er, 3.0, PORT)

    def force(self, p: Sequence[float], fx: float, fy: float, u_max: float, length_px: float = 50.0) -> None:
        """Straight arrow at ``p`` along (fx, fy), length proportional to |f| / u_max."""
        mag = math.hypot(fx, fy)
        if mag == 0.0 or not math.isfinite(mag):
            return
        c, r = self.px(*p)
        L = length_px * (0.25 + 0.75 * min(mag / u_max, 1.0))
        self.arrow_px(c, r, c + L * fx / mag, r - L * fy / mag, 3.0, PORT)

    def image(self) -> np.ndarray:
        return np.clip(self.img + 0.5, 0, 255).astype(np.uint8)


def temperature_color(t: float, lo: float = 0.0, hi: float = 2.5) -> RGB:
    """Blue (cold) -> white -> red (hot) colour for a temperature."""
    x = min(max((t - lo) / (hi - lo), 0.0), 1.0)
    if x < 0.5:
        a = x / 0.5
        return (int(60 + a * 190), int(110 + a * 140), int(200 + a * 50))
    a = (x - 0.5) / 0.5
    return (int(250 - a * 40), int(250 - a * 190), int(250 - a * 200))


# --------------------------------------------------------------------------- per-system pictures
def _pendulum(cv: Canvas, system: Pendulum, q: np.ndarray, p: np.ndarray | None, u: np.ndarray) -> None:
    L = float(system.length)
    th = float(q[0])
    cv.scale = 0.4 * min(cv.h, cv.w) / L
    bob = (L * math.sin(th), -L * math.cos(th))
    cv.line((0, 0), bob, 5, ROD)
    cv.disc(bob, 0.05 * min(cv.h, cv.w), BOB)
    cv.disc((0, 0), 5, INK)
    cv.torque((0, 0), float(u[0]), system.default_max_action)


def _cartpole(cv: Canvas, system: CartPole, q: np.ndarray, p: np.ndarray | None, u: np.ndarray) -> None:
    L = float(system.length)
    x, th = float(q[0]), float(q[1])
    cv.scale = 0.3 * min(cv.h, cv.w) / L
    cv.cx = x if abs(x) > 1.5 * L else 0.0  # follow the cart once it leaves the central window
    half = cv.w / (2 * cv.scale)
    cv.line((cv.cx - half, 0), (cv.cx + half, 0), 2, TRACK)
    for k in range(int(math.floor(cv.cx - half)), int(math.ceil(cv.cx + half)) + 1):  # unit ticks on the track
        cv.line((k, -0.05 * L), (k, 0.05 * L), 1, TRACK)
    w, h = 0.5 * L, 0.25 * L
    cv.rect((x - w / 2, -h / 2), (x + w / 2, h / 2), INK)
    tip = (x + L * math.sin(th), -L * math.cos(th))
    cv.line((x, 0), tip, 5, ROD)
    cv.disc(tip, 0.04 * min(cv.h, cv.w), BOB)
    cv.force((x, h / 2 + 0.1 * L), float(u[0]), 0.0, system.default_max_action)
    cv.torque((x, 0), float(u[1]), system.default_max_action, radius_px=20.0)


def _double_pendulum(cv: Canvas, system: DoublePendulum, q: np.ndarray, p: np.ndarray | None, u: np.ndarray) -> None:
    l1, l2 = float(system.length1), float(system.length2)
    cv.scale = 0.45 * min(cv.h, cv.w) / (l1 + l2)
    t1, t2 = float(q[0]), float(q[1])
    if getattr(system, "coordinates", "absolute") == "relative":  # q2 is link 2's angle relative to link 1
        t2 += t1
    j1 = (l1 * math.sin(t1), -l1 * math.cos(t1))
    j2 = (j1[0] + l2 * math.sin(t2), j1[1] - l2 * math.cos(t2))
    cv.line((0, 0), j1, 5, ROD)
    cv.line(j1, j2, 5, ROD)
    r = 0.035 * min(cv.h, cv.w)
    cv.disc(j1, r, BOB)
    cv.disc(j2, r, BOB)
    cv.disc((0, 0), 5, INK)
    cv.torque((0, 0), float(u[0]), system.default_max_action, radius_px=22.0)
    cv.torque(j1, float(u[1]), system.default_max_action, radius_px=22.0)


def _particles(cv: Canvas, system: Any, q: np.ndarray, p: np.ndarray | None, u: np.ndarray) -> None:
    xy = q.reshape(-1, 2)
    if system.name == "nbody3":
        extent, radius = 2.0 * float(system.radius), 0.25  # bodies are points: draw them large enough to see
    else:
        extent, radius = 1.6 * float(system.sigma), 0.5 * float(system.sigma)
    cv.cx, cv.cy = (float(v) for v in xy.mean(axis=0))  # keep the cluster in view
    cv.scale = 0.5 * min(cv.h, cv.w) / extent
    for k in (-1, 0, 1):  # light grid so drift of the centre of mass is visible
        for axis in range(2):
            off = round(cv.cx if axis == 0 else cv.cy) + k
            if axis == 0:
                cv.line((off, cv.cy - extent * 2), (off, cv.cy + extent * 2), 1, (225, 225, 220))
            else:
                cv.line((cv.cx - extent * 2, off), (cv.cx + extent * 2, off), 1, (225, 225, 220))
    for i, (x, y) in enumerate(xy):
        cv.disc((x, y), radius * cv.scale, PARTICLE_COLORS[i % len(PARTICLE_COLORS)])
        cv.force((x, y), float(u[2 * i]), float(u[2 * i + 1]), system.default_max_action, length_px=30.0)


def _oscillator(cv: Canvas, system: Oscillator, q: np.ndarray, p: np.ndarray | None, u: np.ndarray) -> None:
    # a mass on a 2-D spring anchored at the origin: zigzag spring, disc, force arrow
    cv.scale = 0.4 * min(cv.h, cv.w) / 3.0  # +-3 (three standard deviations of the initial q) in view
    for k in (-2, -1, 0, 1, 2):
        cv.line((k, -3.5), (k, 3.5), 1, (225, 225, 220))
        cv.line((-3.5, k), (3.5, k), 1, (225, 225, 220))
    x, y = float(q[0]), float(q[1])
    L = math.hypot(x, y)
    nx, ny = (-y / L, x / L) if L > 0 else (0.0, 0.0)
    pts = [(0.0, 0.0)]
    for k in range(1, 12):
        s = k / 12
        off = 0.12 * (1 if k % 2 else -1)
        pts.append((s * x + off * nx, s * y + off * ny))
    pts.append((x, y))
    for a, b in zip(pts[:-1], pts[1:]):
        cv.line(a, b, 2, ROD)
    cv.disc((0, 0), 4, INK)
    cv.disc((x, y), 0.05 * min(cv.h, cv.w), BOB)
    cv.force((x, y), float(u[0]), float(u[1]), system.default_max_action, length_px=35.0)


def _bar(cv: Canvas, col: float, value: float, full: float, color: RGB, width_px: float) -> None:
    """Vertical bar from the baseline row (70 % height), up for value > 0 and down for < 0."""
    base = 0.7 * cv.h if full > 0 else 0.5 * cv.h
    top = 0.1 * cv.h
    frac = max(min(value / abs(full), 1.0), -1.0) if full else 0.0
    cv.rect_px(col - width_px / 2, base - (base - top) * frac, col + width_px / 2, base, color)
    cv.line_px(col - width_px / 2 - 6, base, col + width_px / 2 + 6, base, 2, INK)


def _rlc(cv: Canvas, system: RLCCircuit, q: np.ndarray, p: np.ndarray | None, u: np.ndarray) -> None:
    # capacitor: two plates, fill proportional to the charge (red +, blue -); inductor current as a bar
    h, w = cv.h, cv.w
    qc = float(q[0])
    qmax = 3.0 * float(system.capacitance)
    mid = 0.5 * h
    cv.line_px(0.2 * w, 0.25 * h, 0.2 * w, 0.75 * h, 4, INK)
    cv.line_px(0.4 * w, 0.25 * h, 0.4 * w, 0.75 * h, 4, INK)
    frac = max(min(abs(qc) / qmax, 1.0), 0.0)
    cv.rect_px(0.22 * w, mid - 0.24 * h * frac, 0.38 * w, mid + 0.24 * h * frac, RED if qc >= 0 else BLUE)
    if p is not None:
        current = float(p[0]) / float(system.inductance)  # i = phi / L
        _bar_centered(cv, 0.65 * w, current, 3.0, GREEN, 0.12 * w)
    if u[0] != 0.0:  # source voltage: arrow at the bottom, right for u > 0
        c, r = 0.3 * w, 0.9 * h
        L = 0.15 * w * (0.25 + 0.75 * min(abs(float(u[0])) / system.default_max_action, 1.0))
        cv.arrow_px(c, r, c + math.copysign(L, float(u[0])), r, 3.0, PORT)


def _bar_centered(cv: Canvas, col: float, value: float, full: float, color: RGB, width_px: float) -> None:
    mid = 0.5 * cv.h
    frac = max(min(value / full, 1.0), -1.0)
    cv.rect_px(col - width_px / 2, mid - 0.4 * cv.h * frac, col + width_px / 2, mid, color)
    cv.line_px(col - width_px / 2 - 6, mid, col + width_px / 2 + 6, mid, 2, INK)


def _heat_exchange(cv: Canvas, system: HeatExchange, q: np.ndarray, p: np.ndarray | None, u: np.ndarray) -> None:
    h, w = cv.h, cv.w
    boxes = ((0.08 * w, 0.3 * h, 0.42 * w, 0.7 * h), (0.58 * w, 0.3 * h, 0.92 * w, 0.7 * h))
    cv.rect_px(0.42 * w, 0.46 * h, 0.58 * w, 0.54 * h, TRACK)  # the thermal coupling kc
    for i, (c0, r0, c1, r1) in enumerate(boxes):
        cv.rect_px(c0 - 3, r0 - 3, c1 + 3, r1 + 3, INK)
        cv.rect_px(c0, r0, c1, r1, temperature_color(float(q[i])))
        if u[i] != 0.0:  # heating (up) or cooling (down) arrow above the block
            cc = 0.5 * (c0 + c1)
            L = 0.15 * h * (0.25 + 0.75 * min(abs(float(u[i])) / system.default_max_action, 1.0))
            cv.arrow_px(cc, r0 - 8, cc, r0 - 8 - math.copysign(L, float(u[i])), 3.0, PORT)


def _predator_prey(cv: Canvas, system: PredatorPrey, q: np.ndarray, p: np.ndarray | None, u: np.ndarray) -> None:
    w = cv.w
    full = float(system.K)
    _bar(cv, 0.3 * w, float(q[0]), full, GREEN, 0.25 * w)
    if p is not None:
        _bar(cv, 0.7 * w, float(p[0]), 0.5 * full, RED, 0.25 * w)
    if u[0] != 0.0:  # predators added (u > 0) or removed
        c, r = 0.7 * w, 0.85 * cv.h
        L = 0.1 * cv.h * (0.25 + 0.75 * min(abs(float(u[0])) / system.default_max_action, 1.0))
        cv.arrow_px(c, r, c, r - math.copysign(L, float(u[0])), 3.0, PORT)


#: system name -> picture; each drawer takes its own System subclass (the name picks it), hence ``Any``
_DRAWERS: dict[str, Callable[[Canvas, Any, np.ndarray, np.ndarray | None, np.ndarray], None]] = {
    "pendulum": _pendulum,
    "cartpole": _cartpole,
    "double_pendulum": _double_pendulum,
    "lennard_jones3": _particles,
    "nbody3": _particles,
    "oscillator": _oscillator,
    "rlc": _rlc,
    "heat_exchange": _heat_exchange,
    "predator_prey": _predator_prey,
}


def render_frame(
    system: System,
    q: npt.ArrayLike,
    u: npt.ArrayLike | None = None,
    actuated_dofs: Sequence[int] = (),
    p: npt.ArrayLike | None = None,
    size: tuple[int, int] = (256, 256),
) -> np.ndarray:
    """Draw the configuration ``q`` of ``system`` -> ``(H, W, 3)`` uint8 image.

    ``u`` is the port input on ``actuated_dofs`` (default: every coordinate),
    drawn as torque arcs / force arrows; ``p`` (optional) adds what q alone
    cannot show (predator density, inductor current).
    """
    drawer = _DRAWERS.get(system.name)
    if drawer is None:
        raise ValueError(f"no renderer for system {system.name!r}; known: {sorted(_DRAWERS)}")
    n = system.n
    q = np.asarray(q, dtype=np.float64).reshape(-1)
    if q.shape != (n,):
        raise ValueError(f"q must have {n} components for {system.name}, got shape {q.shape}")
    if p is not None:
        p = np.asarray(p, dtype=np.float64).reshape(-1)
        if p.shape != (n,):
            raise ValueError(f"p must have {n} components for {system.name}, got shape {p.shape}")
    dofs = tuple(actuated_dofs) if len(actuated_dofs) else tuple(range(n))
    u_full = np.zeros(n)
    if u is not None:
        ua = np.asarray(u, dtype=np.float64).reshape(-1)
        if ua.shape != (len(dofs),):
            raise ValueError(f"u must have {len(dofs)} components (actuated dofs {list(dofs)}), got shape {ua.shape}")
        u_full[list(dofs)] = ua
    cv = Canvas(*size)
    drawer(cv, system, q, p, u_full)
    return cv.image()
