"""Placing 2D pattern pieces around the mannequin before sewing (Chen 2013; Fan et al. 1998: pieces positioned around the
body, front/back/sleeves, bent around it so that sewing starts close). Numpy only.

Placement rule (`place`)
------------------------
A 2D piece point (u, v) [m], drawn as seen from outside, goes to the axial position s = v - at_v + height
along the frame's axis and to the arc position u - at_u around it. With `wrap`:

    theta = (u - at_u) / R(s) + angle,     x = origin + s axis + R(s) (cos theta front + sin theta side),

side = axis x front, so the piece's +u runs toward `side` and its outside faces out. R(s) is chosen per
1 cm row of s (and for ceil(offset / 1 cm) rows beyond the piece's top and bottom): the smallest radius (2 mm
steps) at which every ray of the angular span that the row covers, widened by `offset` of arc at either
edge, [(u_lo(s) - offset) / R + angle, (u_hi(s) + offset) / R + angle], clears the body:

- the frame's own part: R >= its outermost surface on the ray + offset (0 where the ray misses it);
- every other part whose nearest surface on the ray is closer to the axis than REACH (0.35 m): R is not
  within offset of the part's extent along the ray [inner, outer], so a torso piece passes through the gap
  between the torso and an arm hanging beside it, or goes round the arm; where the part reaches past REACH
  it is a wall (R <= inner - offset), e.g. the torso seen from an arm's axis. A ray that meets another part
  only beyond REACH (the hands, seen from the hips) ignores it;
- a row never wraps more than MAX_WRAP (0.95) of a full turn, so a sleeve's edges do not overlap.

A row where no radius satisfies all of this takes the radius with the fewest violating rays (own-part
violations weighed first): e.g. a full-width sleeve row above the armpit, which no cylinder about the arm
can fit; a sleeve cap there is narrow and fits. The row radii are then made into a smooth profile: the
smallest profile above them whose slope keeps the axial stretch of the row's outermost column within
MAX_STRETCH (below), a running max over +-2 rows and two +-1-row running means (all three never lower it);
rows that smoothing pushed into another part are raised to their next clear radius and the profile is
rebuilt until stable. Points between row centres interpolate R(s) linearly.

What is kept and what is stretched: along a row (constant v) the arc length equals the 2D length exactly
(the row lies on one circle of radius R(s)); across rows the piece is stretched where R changes: a column at
u has the 3D length element sqrt(1 + R'(s)^2 (1 + ((u - at_u) / R)^2)) per unit of v, kept <= 1 + MAX_STRETCH
(5%) by the slope limit (approximately: the limit uses the row radius before smoothing). A cylinder about an
elliptical torso leaves more room in front and behind than at the sides, where the widest part of the span
sets R.

Without `wrap` the piece is flat: the plane facing front (turned by `angle` about the axis) at distance
(largest forward extent of the body under the piece's bounding box widened by offset + 1 cm, parts beyond
REACH excluded) + offset from the axis; 2D lengths are kept exactly.

The body, its frames and its cylindrical tables: taichi_cloth.body.landmarks.

Measured on the shipped mannequin (tests/test_garment_placement.py; offset 0.02 m, 1 cm grids): a 0.5 m x
0.6 m piece at torso_front: min clearance 0.032 m, max strain 0.048; at torso_back: 0.024 m, 0.047; a
0.45 m x 0.25 m sleeve (0.13 m cap) at arm_left: 0.025 m, 0.049, wrapping 306 degrees.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..body.landmarks import AXIAL_BIN, Body, BodyFrame, CylinderTable
from ..errors import PatternError

__all__ = ["MAX_STRETCH", "MAX_WRAP", "Placement", "REACH", "place"]

#: [m] surface of another part counts only where it comes closer to the frame's axis than this
REACH = 0.35
#: a wrapped row covers at most this fraction of a full turn
MAX_WRAP = 0.95
#: the radius profile changes slowly enough that the axial stretch of the placed piece stays below this
MAX_STRETCH = 0.05
_RADIUS_STEP = 0.002      # [m] candidate radii
_SMOOTH_ROWS = 1          # running-mean half width (rows); the running max uses twice this, twice


# ------------------------------------------------------------------------------------------- placement

def _check_number(name: str, value, minimum=None) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise PatternError(f"placement {name} must be a number, got {value!r}") from None
    if not math.isfinite(x):
        raise PatternError(f"placement {name} must be finite, got {value!r}")
    if minimum is not None and x < minimum:
        raise PatternError(f"placement {name} must be >= {minimum} m, got {x}")
    return x


@dataclass(frozen=True)
class Placement:
    """Where a piece goes (module docstring: placement rule).

    anchor: a Body.frames name; at: (2,) [m] the piece point that lands on the anchor (default: the centre
    of the piece's bounding box); offset [m] >= 0: clearance between body and piece; wrap: bend around the
    axis (False: a flat plane facing front); height [m]: shift of `at` along the axis from the frame's
    origin; angle [deg]: turn about the axis, from front toward side.
    """

    anchor: str
    at: tuple | None = None
    offset: float = 0.02
    wrap: bool = True
    height: float = 0.0
    angle: float = 0.0

    def __post_init__(self):
        if not isinstance(self.anchor, str) or not self.anchor:
            raise PatternError(f"placement anchor must be a frame name, got {self.anchor!r}")
        _check_number("offset", self.offset, minimum=0.0)
        _check_number("height", self.height)
        _check_number("angle", self.angle)
        if not isinstance(self.wrap, (bool, np.bool_)):
            raise PatternError(f"placement wrap must be True or False, got {self.wrap!r}")
        if self.at is not None:
            at = np.asarray(self.at, dtype=np.float64) if _is_numeric(self.at) else None
            if at is None or at.shape != (2,) or not np.all(np.isfinite(at)):
                raise PatternError(f"placement at must be two finite numbers (u, v) in m, got {self.at!r}")


def _is_numeric(x) -> bool:
    try:
        np.asarray(x, dtype=np.float64)
        return True
    except (TypeError, ValueError):
        return False


def _check_points(points2d) -> np.ndarray:
    if not _is_numeric(points2d):
        raise PatternError("piece points must be numbers, shape (n, 2) in m")
    p = np.asarray(points2d, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) == 0:
        raise PatternError(f"piece points must have shape (n, 2), got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise PatternError("piece points must be finite")
    return p


def place(points2d, placement: Placement, body: Body) -> np.ndarray:
    """Place a piece's 2D points (n,2) [m] around the body: (n,3) float64 [m] (module docstring)."""
    p = _check_points(points2d)
    frame = body.frame(placement.anchor)
    at = (0.5 * (p.min(axis=0) + p.max(axis=0)) if placement.at is None
          else np.asarray(placement.at, dtype=np.float64))
    u = p[:, 0] - at[0]
    s = p[:, 1] - at[1] + float(placement.height)
    turn = math.radians(float(placement.angle))
    offset = float(placement.offset)
    if placement.wrap:
        radius = _wrap_radii(body.table(frame), u, s, offset, turn)
        theta = u / radius + turn
        radial = np.cos(theta)[:, None] * frame.front + np.sin(theta)[:, None] * frame.side
        return frame.origin + s[:, None] * frame.axis + radius[:, None] * radial
    front = math.cos(turn) * frame.front + math.sin(turn) * frame.side
    side = np.cross(frame.axis, front)
    distance = _flat_distance(body, frame, front, side, u, s, offset)
    return frame.origin + s[:, None] * frame.axis + u[:, None] * side + distance * front


def _flat_distance(body: Body, frame: BodyFrame, front, side, u, s, offset) -> float:
    pts, lab = body.samples()
    d = pts - frame.origin
    a, f, w = d @ frame.axis, d @ front, d @ side
    margin = offset + AXIAL_BIN
    under = ((a > s.min() - margin) & (a < s.max() + margin) & (w > u.min() - margin) & (w < u.max() + margin)
             & ((lab == frame.part) | (np.hypot(f, w) < REACH)))
    return float(max(f[under].max(), 0.0) if under.any() else 0.0) + offset


def _row_spans(rows: np.ndarray, u: np.ndarray, pad: int):
    """Per local row (m,) the piece's u range, for rows 0 .. rows.max() + pad (the points' rows must start at
    `pad`); rows without points take the union of their nearest neighbours' (the pad rows copy the ends)."""
    m = rows.max() + 1 + pad
    lo = np.full(m, np.inf)
    hi = np.full(m, -np.inf)
    np.minimum.at(lo, rows, u)
    np.maximum.at(hi, rows, u)
    empty = ~np.isfinite(lo)
    if empty.any():
        idx = np.arange(m)
        filled = np.flatnonzero(~empty)
        below = filled[np.clip(np.searchsorted(filled, idx, side="right") - 1, 0, len(filled) - 1)]
        above = filled[np.clip(np.searchsorted(filled, idx, side="left"), 0, len(filled) - 1)]
        lo = np.where(empty, np.minimum(lo[below], lo[above]), lo)
        hi = np.where(empty, np.maximum(hi[below], hi[above]), hi)
    return lo, hi


def _row_costs(own, inner, outer, lo, hi, offset, turn):
    """Cost (m, K) of each candidate radius per row: 1e6 x own-part violations + other-part violations
    (+1e12 if the row would wrap more than MAX_WRAP of a turn), and the radii (K,)."""
    need = max(float(own.max()), float(np.where(outer < REACH, outer, -np.inf).max(initial=0.0)),
               float((hi - lo).max()) / (2 * math.pi * MAX_WRAP)) + offset + 0.05
    radii = _RADIUS_STEP * np.arange(1, int(math.ceil(need / _RADIUS_STEP)) + 1)
    r = radii[None, None, :]
    own_bad = r < own[:, :, None] + offset
    other_bad = np.zeros_like(own_bad)
    for q in range(inner.shape[0]):
        near = (inner[q] < REACH)[:, :, None]
        beyond = (outer[q] > REACH)[:, :, None]
        other_bad |= near & (r > inner[q][:, :, None] - offset) & ((r < outer[q][:, :, None] + offset) | beyond)
    n_ang = own.shape[1]
    width = 2 * math.pi / n_ang

    def span_count(bad):
        doubled = np.concatenate([bad, bad], axis=1).astype(np.int32)
        prefix = np.concatenate([np.zeros_like(doubled[:, :1]), np.cumsum(doubled, axis=1)], axis=1)
        # the rays within `offset` of arc beyond the piece's edges count too: the body beside an edge
        j_lo = np.floor(((lo[:, None] - offset) / radii + turn + math.pi) / width).astype(np.int64)
        j_hi = np.floor(((hi[:, None] + offset) / radii + turn + math.pi) / width).astype(np.int64)
        length = np.minimum(j_hi - j_lo + 1, n_ang)
        start = j_lo % n_ang
        rows = np.arange(len(lo))[:, None]
        k = np.arange(len(radii))[None, :]
        return prefix[rows, start + length, k] - prefix[rows, start, k]

    cost = 1_000_000 * span_count(own_bad).astype(np.int64) + span_count(other_bad)
    cost += np.where(radii[None, :] * 2 * math.pi * MAX_WRAP < (hi - lo)[:, None], 10**12, 0)
    return cost, radii


def _running(a: np.ndarray, half: int, op) -> np.ndarray:
    if half <= 0 or len(a) == 1:
        return a
    padded = np.concatenate([np.full(half, a[0]), a, np.full(half, a[-1])])
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    return op(windows, axis=1)


def _slope_limits(lo: np.ndarray, hi: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Per row (m,): the largest |R'(s)| at which the row's farthest column (|u| = max(|lo|, |hi|)) on a radius
    >= `radius` is stretched axially by at most MAX_STRETCH: sqrt(1 + R'^2 (1 + (u/R)^2)) <= 1 + MAX_STRETCH."""
    u = np.maximum(np.abs(lo), np.abs(hi))
    return math.sqrt((1 + MAX_STRETCH) ** 2 - 1) / np.sqrt(1 + (u / radius) ** 2)


def _envelope(r: np.ndarray, slope: np.ndarray) -> np.ndarray:
    """The smallest profile >= r whose change between neighbouring rows stays within both rows' slope."""
    out = r.astype(np.float64).copy()
    step = np.minimum(slope[1:], slope[:-1]) * AXIAL_BIN
    for i in range(1, len(out)):
        out[i] = max(out[i], out[i - 1] - step[i - 1])
    for i in range(len(out) - 2, -1, -1):
        out[i] = max(out[i], out[i + 1] - step[i])
    return out


def _smooth(r: np.ndarray, slope: np.ndarray) -> np.ndarray:
    """Slope-limited envelope, a running max over +-2h rows, then two +-h running means: >= r everywhere."""
    h = _SMOOTH_ROWS
    out = _running(_envelope(r, slope), 2 * h, np.max)
    return _running(_running(out, h, np.mean), h, np.mean)


def _wrap_radii(tab: CylinderTable, u: np.ndarray, s: np.ndarray, offset: float, turn: float) -> np.ndarray:
    """R(s) at each piece point (n,) [m] (module docstring: placement rule)."""
    global_rows = np.floor((s - tab.s0) / AXIAL_BIN).astype(int)
    pad = int(math.ceil(offset / AXIAL_BIN))     # the body beyond the piece's top and bottom rows counts too
    first = global_rows.min() - pad
    lo, hi = _row_spans(global_rows - first, u, pad)
    rows = first + np.arange(len(lo))
    own, inner, outer = tab.take(rows)
    cost, radii = _row_costs(own, inner, outer, lo, hi, offset, turn)
    best = np.argmin(cost, axis=1)
    best_cost = cost[np.arange(len(lo)), best]
    need = radii[best]
    slope = _slope_limits(lo, hi, need)
    k_all = np.arange(len(radii))[None, :]
    for _ in range(50):
        smooth = _smooth(need, slope)
        k = np.clip(np.rint(smooth / _RADIUS_STEP).astype(int) - 1, 0, len(radii) - 1)
        worse = cost[np.arange(len(lo)), k] > best_cost
        if not worse.any():
            break
        good = (cost == best_cost[:, None]) & (k_all >= k[:, None])
        has = good.any(axis=1) & worse
        if not has.any():
            break
        raised = radii[np.argmax(good, axis=1)]
        need = np.where(has, np.maximum(need, raised), need)
    smooth = _smooth(need, slope)
    centres = tab.s0 + (rows + 0.5) * AXIAL_BIN
    return np.interp(s, centres, smooth)
