"""Placing 2D pattern pieces around the mannequin before sewing (Chen 2013; Fan et al. 1998: pieces positioned around the
body, front/back/sleeves, bent around it so that sewing starts close). Numpy only.

The body
--------
`Body.from_mesh` analyses a closed, outward-wound body mesh in the mannequin's convention (metres, Y up, soles
on the ground, symmetric about x = 0, +z the front, +x the body's left, arms hanging apart from the torso in
an A-pose):

- armpit: the lowest height where the arms' horizontal cross-sections have joined the torso's (slice loops,
  bisection to 0.1 mm);
- part labels per vertex (PARTS): below the armpit, the mesh's connected pieces (the arms fall apart from
  the torso); above it, an arm is what lies beyond its armhole plane: through the armpit point, vertical in
  z, its normal halfway between the lateral direction and the arm's downward axis (it leaves the top of
  the shoulder about 0.04 m outside the armpit). "torso" is everything that is not an arm: trunk, neck,
  head and legs (a skirt must clear the legs as it clears the hips);
- upper-arm axis: the arm's centre line is tracked by cross-sections perpendicular to it from just below
  the armpit toward the hand; the elbow is its sharpest bend before the wrist; the axis is the line fitted
  to the centre line above the elbow, pointing from the elbow to the shoulder;
- landmark heights [m]: crotch (lowest torso point near the mid-plane), waist (smallest girth between
  crotch + 0.1 and armpit - 0.05), hips (the buttocks' most posterior point between crotch and waist),
  chest (the bust: where the torso reaches furthest forward off the mid-plane beyond its reach on it),
  armpit, shoulder (where the armhole plane leaves the top of the shoulder), neck (smallest girth in the
  0.12 m above the shoulder); girths are convex-hull perimeters of torso cross-sections, as a tape
  measures (Body.girths).

Frames (`BodyFrame`): torso_front/back at chest height, waist_front/back, hips_front/back (origin: the
centroid of the torso cross-section at that height, axis +y, front +z / -z), arm_left/right (origin: the
middle of the upper arm, halfway between the armpit's and the elbow's projections on the axis; axis up the
arm; front: the arm's outer side, the lateral direction +x / -x made perpendicular to the axis, so that a
sleeve drawn with its cap on top lands with the cap on the top of the arm and its underarm seams, the piece's
left and right edges, meeting on the inner side, toward the torso).

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

The body's surface is looked up in cylindrical bins about each frame's axis (1 cm x 2.5 degrees: max / min
radius of surface samples 3 mm apart, dilated by one angular bin; built once per frame, about 0.1 s);
`Body.radial_extent` reads them (conservative: never inside the surface, on average 5-7 mm outside it).

Measured on the shipped mannequin (tests/test_garment_placement.py; offset 0.02 m, 1 cm grids): a 0.5 m x
0.6 m piece at torso_front: min clearance 0.032 m, max strain 0.048; at torso_back: 0.024 m, 0.047; a
0.45 m x 0.25 m sleeve (0.13 m cap) at arm_left: 0.025 m, 0.049, wrapping 306 degrees.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clothbase.errors import MeshError
from clothbase.meshes import connected_components, validate_triangle_mesh
from collision.distance import candidates, pairs_by_cell, point_key, unsigned_distance

# the plane slicer and the convex-hull girth live with the body's girth gauge, which measures the same sections
from ..body.section import Loop as _Loop
from ..body.section import MeshSlicer as _Mesh
from ..body.section import loop_girth as _girth
from ..errors import PatternError

__all__ = ["ANGLE_BINS", "AXIAL_BIN", "Body", "BodyFrame", "MAX_STRETCH", "MAX_WRAP", "PARTS", "Placement", "REACH",
           "place"]

#: part labels of Body.labels
PARTS = ("torso", "arm_left", "arm_right")
#: [m] surface of another part counts only where it comes closer to the frame's axis than this
REACH = 0.35
#: [m] axial bin of the cylindrical body tables and row height of the radius profile
AXIAL_BIN = 0.01
#: angular bins of the cylindrical body tables (2.5 degrees)
ANGLE_BINS = 144
#: a wrapped row covers at most this fraction of a full turn
MAX_WRAP = 0.95
#: the radius profile changes slowly enough that the axial stretch of the placed piece stays below this
MAX_STRETCH = 0.05
_SAMPLE_SPACING = 0.003   # [m] surface samples this dense leave few empty bins at the arm's radius
_RADIUS_STEP = 0.002      # [m] candidate radii
_SMOOTH_ROWS = 1          # running-mean half width (rows); the running max uses twice this, twice
_TRACK_STEP = 0.01        # [m] arm centre-line tracking step


# ----------------------------------------------------------------------------------------------- frames

@dataclass(frozen=True, eq=False)
class BodyFrame:
    """A named anchor on the body: a piece is wrapped around the frame's axis.

    name: str; origin: (3,) float64 [m], a point on the axis (torso frames: the centroid of the torso
    cross-section at the anchor's height; arm frames: the middle of the upper arm on its axis);
    axis: (3,) unit, the direction of a piece's 2D +v (torso: +y; arms: up the arm, elbow to shoulder);
    front: (3,) unit, perpendicular to axis, where the piece's `at` point lands (torso_front +z, torso_back
    -z, arm_left/right: the arm's outer side); part: the body part (PARTS) the placement must clear.
    """

    name: str
    origin: np.ndarray
    axis: np.ndarray
    front: np.ndarray
    part: str

    @property
    def side(self) -> np.ndarray:
        """(3,) unit axis x front: where a piece's 2D +u goes (torso_front: +x, torso_back: -x)."""
        return np.cross(self.axis, self.front)

    def to_local(self, points: np.ndarray):
        """(n,3) [m] -> (s, r, phi): axial position [m], distance from the axis [m], angle [rad] from front
        toward side in (-pi, pi]; each (n,) float64."""
        d = np.asarray(points, dtype=np.float64) - self.origin
        s = d @ self.axis
        x, y = d @ self.front, d @ self.side
        return s, np.hypot(x, y), np.arctan2(y, x)


def _frame(name, origin, axis, front, part) -> BodyFrame:
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    front = np.asarray(front, dtype=np.float64)
    front = front - (front @ axis) * axis
    front = front / np.linalg.norm(front)
    return BodyFrame(name, np.asarray(origin, dtype=np.float64).copy(), axis, front, part)


# ------------------------------------------------------------------------------------------- the body

def _armpit_height(mesh: _Mesh, y0: float, height: float) -> float:
    """The lowest height where fewer than three large loops (torso + two arms) remain, to 0.1 mm."""
    def separate(y):
        return sum(loop.length > 0.1 for loop in mesh.level(y)) >= 3

    lo = y0 + 0.68 * height
    if not separate(lo):
        raise MeshError("body mesh: the arms do not hang apart from the torso at 68% of the height "
                        "(an A-pose body is needed)")
    hi = lo
    while separate(hi):
        hi += 0.005
        if hi > y0 + 0.9 * height:
            raise MeshError("body mesh: no armpit found below 90% of the height")
    lo = hi - 0.005
    while hi - lo > 1e-4:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if separate(mid) else (lo, mid)
    return lo


def _arm_centre_line(mesh: _Mesh, arm_mask: np.ndarray, armpit: float):
    """Track the arm's centre line from just below the armpit toward the hand by perpendicular slices.

    Returns points (k,3) [m] and loop perimeters (k,) [m]."""
    def centre(y):
        loops = mesh.level(y, arm_mask)
        if not loops:
            raise MeshError("body mesh: no arm cross-section below the armpit")
        return max(loops, key=lambda lp: lp.length)

    first = centre(armpit - 0.03)
    d = centre(armpit - 0.06).centroid - first.centroid
    d /= np.linalg.norm(d)
    path, lengths = [first.centroid], [first.length]
    for _ in range(80):
        q = path[-1] + _TRACK_STEP * d
        loops = mesh.slice(q, d, arm_mask)
        if not loops:
            break
        loop = min(loops, key=lambda lp: np.linalg.norm(lp.centroid - q))
        if np.linalg.norm(loop.centroid - q) > 0.04:
            break
        step = loop.centroid - path[-1]
        d = d + step / max(np.linalg.norm(step), 1e-12)   # half-and-half: a smoothed heading
        d /= np.linalg.norm(d)
        path.append(loop.centroid)
        lengths.append(loop.length)
    return np.array(path), np.array(lengths)


def _elbow_index(path: np.ndarray, lengths: np.ndarray) -> int:
    """Index of the sharpest bend of the centre line before the wrist (4-step chords on either side); the
    wrist is where the cross-section's perimeter falls below 3/4 of the upper arm's."""
    n = len(path)
    thin = np.flatnonzero(lengths < 0.75 * np.median(lengths[:5]))
    end = min(int(thin[0]) if len(thin) else n, n - 4)
    best, best_angle = min(4, n - 1), -1.0
    for i in range(4, end):
        a = path[i] - path[i - 4]
        b = path[i + 4] - path[i]
        cos = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
        angle = math.acos(max(-1.0, min(1.0, cos)))
        if angle > best_angle:
            best, best_angle = i, angle
    return best


def _line_fit(points: np.ndarray):
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c)
    return c, vt[0]


@dataclass(frozen=True)
class _Arm:
    origin: np.ndarray
    axis: np.ndarray          # up the arm
    armpit: np.ndarray        # (3,) the armpit point
    elbow: np.ndarray         # (3,) on the axis
    shoulder: np.ndarray      # (3,) where the armhole plane leaves the top of the shoulder
    cut_normal: np.ndarray    # (3,) armhole plane normal, pointing into the arm


def _analyse_arm(mesh: _Mesh, arm_mask: np.ndarray, armpit: float, sign: float) -> _Arm:
    """The arm on the +x (sign 1, the body's left) or -x side; arm_mask: (V,) its vertices below the armpit."""
    v = mesh.v
    loops = mesh.level(armpit - 2e-4)
    if not loops:
        raise MeshError("body mesh: no cross-section at the armpit")
    ring = max(loops, key=lambda lp: sign * lp.centroid[0]).points   # the outermost loop on this side
    pit = ring[np.argmin(sign * ring[:, 0])]           # the arm's innermost point meets the torso there

    path, lengths = _arm_centre_line(mesh, arm_mask, armpit)
    k = _elbow_index(path, lengths)
    centre, axis = _line_fit(path[:k + 1])
    if axis @ (path[0] - path[k]) < 0:
        axis = -axis
    elbow = centre + ((path[k] - centre) @ axis) * axis
    s_pit = (pit - centre) @ axis
    s_elbow = (elbow - centre) @ axis
    origin = centre + 0.5 * (s_pit + s_elbow) * axis

    # armhole plane: vertical in z, its normal halfway between the lateral direction and the arm's downward
    # axis (for a T-pose that is the vertical plane x = armpit x), pointing into the arm
    down = np.array([-axis[0], -axis[1], 0.0])
    normal = np.array([sign, 0.0, 0.0]) + down / np.linalg.norm(down)
    normal /= np.linalg.norm(normal)
    near = (np.abs((v - pit) @ normal) < 0.006) & (v[:, 1] > armpit) & (sign * v[:, 0] > 0)
    shoulder = v[near][np.argmax(v[near, 1])] if near.any() else pit
    return _Arm(origin, axis, pit, elbow, shoulder, normal)


def _arm_girth(mesh: _Mesh, arm: _Arm, arm_mask: np.ndarray) -> float:
    """Upper-arm girth [m] perpendicular to the axis at the arm frame's origin; arm_mask: every vertex labelled
    as this arm (the below-armpit piece alone would cut the top of the section off)."""
    loops = mesh.slice(arm.origin, arm.axis, arm_mask)
    return _girth(min(loops, key=lambda lp: np.linalg.norm(lp.centroid - arm.origin)), arm.axis) if loops else 0.0


def _label_parts(v: np.ndarray, below: np.ndarray, arm_masks: dict, arms: dict) -> np.ndarray:
    """(V,) part labels: the arms' pieces below the armpit plus what lies beyond each armhole plane above it."""
    labels = np.full(len(v), "torso", dtype="<U9")
    for name, mask in arm_masks.items():
        labels[mask] = name
        arm = arms[name]
        labels[~below & ((v - arm.armpit) @ arm.cut_normal > 0)] = name
    return labels


def _buttock_height(v, torso, crotch, waist) -> float:
    """Height [m] of the torso's most posterior point between crotch and waist (where hips are measured)."""
    sel = torso & (v[:, 1] > crotch) & (v[:, 1] < waist)
    return float(v[sel][np.argmin(v[sel, 2]), 1])


def _torso_loop(mesh: _Mesh, y: float, mask: np.ndarray):
    loops = mesh.level(y, mask)
    return max(loops, key=lambda lp: lp.length) if loops else None


def _loop_girth(loop: _Loop) -> float:
    return _girth(loop, [0.0, 1.0, 0.0])


def _bust_prominence(loop: _Loop) -> float:
    """How far the loop reaches forward off the mid-plane beyond its reach on it [m]: largest at the bust
    points (at the belly the mid-plane is foremost)."""
    x, z = np.abs(loop.points[:, 0]), loop.points[:, 2]
    off, mid = x > 0.03, x < 0.015
    return float(z[off].max() - z[mid].max()) if off.any() and mid.any() else -np.inf


def _extreme_height(mesh, mask, lo, hi, key, largest: bool):
    """(height, loop) of the torso loop with the largest / smallest key(loop) on a 5 mm grid in [lo, hi],
    refined to 1 mm."""
    def scan(ys):
        best = None
        for y in ys:
            loop = _torso_loop(mesh, y, mask)
            if loop is None:
                continue
            k = key(loop)
            if best is None or (k > best[0] if largest else k < best[0]):
                best = (k, y, loop)
        if best is None:
            raise MeshError(f"body mesh: no torso cross-section between {lo:.3f} and {hi:.3f} m")
        return best

    _, y, _ = scan(np.arange(lo, hi + 1e-9, 0.005))
    _, y, loop = scan(np.arange(max(lo, y - 0.004), min(hi, y + 0.004) + 1e-9, 0.001))
    return float(y), loop


def _torso_landmarks(mesh: _Mesh, torso: np.ndarray, height: float, armpit: float, shoulder: float):
    """Landmark heights {name: m} (module docstring) and the torso loops {chest, underarm, waist, hips, neck}."""
    v = mesh.v
    mid = torso & (np.abs(v[:, 0]) < 0.01 * height)
    crotch = float(v[mid, 1].min())
    waist, waist_loop = _extreme_height(mesh, torso, crotch + 0.1, armpit - 0.05, _loop_girth, largest=False)
    hips = _buttock_height(v, torso, crotch, waist)
    chest, chest_loop = _extreme_height(mesh, torso, waist + 0.05, armpit - 0.01, _bust_prominence, largest=True)
    neck, neck_loop = _extreme_height(mesh, torso, shoulder, shoulder + 0.12, _loop_girth, largest=False)
    landmarks = {"crotch": crotch, "hips": hips, "waist": waist, "chest": chest, "armpit": armpit,
                 "shoulder": shoulder, "neck": neck}
    loops = {"chest": chest_loop, "underarm": _torso_loop(mesh, armpit - 0.005, torso), "waist": waist_loop,
             "hips": _torso_loop(mesh, hips, torso), "neck": neck_loop}
    return landmarks, loops


def _frames(loops: dict, arms: dict) -> dict:
    frames = {}
    for key, loop in (("torso", loops["chest"]), ("waist", loops["waist"]), ("hips", loops["hips"])):
        for face, z in (("front", 1.0), ("back", -1.0)):
            frames[f"{key}_{face}"] = _frame(f"{key}_{face}", loop.centroid, [0, 1, 0], [0, 0, z], "torso")
    for name, sign in (("arm_left", 1.0), ("arm_right", -1.0)):
        frames[name] = _frame(name, arms[name].origin, arms[name].axis, [sign, 0, 0], name)
    return frames


# ------------------------------------------------------------------------------- cylindrical body tables

def _surface_samples(vertices, triangles, spacing: float):
    """Points (N,3) [m] on every triangle no farther than about `spacing` apart, and their triangle ids (N,)."""
    p = vertices[triangles]
    longest = np.max(np.linalg.norm(p - np.roll(p, 1, axis=1), axis=2), axis=1)
    levels = np.maximum(1, np.ceil(longest / spacing).astype(int))
    out, ids = [], []
    for k in np.unique(levels):
        sel = np.flatnonzero(levels == k)
        i, j = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
        keep = i + j <= k
        b = np.stack([i[keep], j[keep]], axis=1) / k           # barycentric (w1, w2)
        w = np.column_stack([1 - b.sum(axis=1), b])             # (m,3)
        out.append(np.einsum("mk,tkd->tmd", w, p[sel]).reshape(-1, 3))
        ids.append(np.repeat(sel, len(w)))
    return np.concatenate(out), np.concatenate(ids)


def _dilate(a: np.ndarray, op) -> np.ndarray:
    """Max/min filter over one angular bin either side (angles wrap around): fills the bins that fall
    between surface samples at small radii (2.5 degrees is 1.7 mm at an arm's 4 cm)."""
    return op(op(a, np.roll(a, 1, axis=-1)), np.roll(a, -1, axis=-1))


@dataclass(frozen=True)
class _Table:
    """Body surface about a frame's axis in (row, angle) bins: row i covers s in s0 + [i, i+1) AXIAL_BIN."""

    s0: float
    own: np.ndarray      # (rows, ANGLE_BINS) outermost radius of the frame's part [m], 0 if none
    inner: np.ndarray    # (P, rows, ANGLE_BINS) nearest radius of each other part [m], inf if none
    outer: np.ndarray    # (P, rows, ANGLE_BINS) farthest radius of each other part [m], -inf if none

    @property
    def rows(self) -> int:
        return self.own.shape[0]

    def take(self, rows: np.ndarray):
        """own (m,A), inner (P,m,A), outer (P,m,A) for row indices (m,), empty outside the table."""
        ok = (rows >= 0) & (rows < self.rows)
        r = np.clip(rows, 0, self.rows - 1)
        own = np.where(ok[:, None], self.own[r], 0.0)
        inner = np.where(ok[None, :, None], self.inner[:, r], np.inf)
        outer = np.where(ok[None, :, None], self.outer[:, r], -np.inf)
        return own, inner, outer


def _build_table(frame: BodyFrame, samples, sample_labels) -> _Table:
    s, r, phi = frame.to_local(samples)
    s0 = math.floor(s.min() / AXIAL_BIN) * AXIAL_BIN
    rows = int(math.floor((s.max() - s0) / AXIAL_BIN)) + 1
    i = np.minimum(((s - s0) / AXIAL_BIN).astype(int), rows - 1)
    j = np.floor((phi + math.pi) / (2 * math.pi) * ANGLE_BINS).astype(int) % ANGLE_BINS
    flat = i * ANGLE_BINS + j
    own = np.zeros(rows * ANGLE_BINS)
    sel = sample_labels == frame.part
    np.maximum.at(own, flat[sel], r[sel])
    others = [p for p in PARTS if p != frame.part]
    inner = np.full((len(others), rows * ANGLE_BINS), np.inf)
    outer = np.full((len(others), rows * ANGLE_BINS), -np.inf)
    for q, part in enumerate(others):
        sel = sample_labels == part
        np.minimum.at(inner[q], flat[sel], r[sel])
        np.maximum.at(outer[q], flat[sel], r[sel])
    shape = (rows, ANGLE_BINS)
    return _Table(s0, _dilate(own.reshape(shape), np.maximum),
                  _dilate(inner.reshape((-1,) + shape), np.minimum),
                  _dilate(outer.reshape((-1,) + shape), np.maximum))


class Body:
    """The mannequin for placement: vertices, triangles, a per-vertex part label, the frames, and landmarks.

    Attributes:
        vertices: (V,3) float64 [m]; triangles: (T,3) int64, outward-wound.
        labels: (V,) str, one of PARTS per vertex.
        frames: name -> BodyFrame (torso_front, torso_back, waist_front, waist_back, hips_front, hips_back,
            arm_left, arm_right).
        landmarks: name -> height [m]: crotch, hips, waist, chest, armpit, shoulder, neck.
        girths: name -> [m]: chest, waist, hips, neck (torso cross-sections at those landmarks), underarm
            (5 mm below the armpit, the widest the torso gets below the arms), upper_arm (perpendicular to the
            arm at the arm frame's origin); convex-hull perimeters, as a tape measures.
        points: name -> (3,) [m]: armpit_left/right, shoulder_left/right, elbow_left/right.
    """

    def __init__(self, vertices, triangles, labels, frames, landmarks, girths, points):
        self.vertices = vertices
        self.triangles = triangles
        self.labels = labels
        self.frames = frames
        self.landmarks = landmarks
        self.girths = girths
        self.points = points
        self._samples = None
        self._tables: dict = {}

    # -------------------------------------------------------------------------------- construction
    @classmethod
    def from_mannequin(cls, mannequin=None) -> "Body":
        """The Body of a collision.mannequin.Mannequin (default: load_mannequin(), the shipped CC0 body)."""
        if mannequin is None:
            from collision.mannequin import load_mannequin
            mannequin = load_mannequin()
        return cls.from_mesh(mannequin.vertices, mannequin.triangles)

    @classmethod
    def from_mesh(cls, vertices, triangles) -> "Body":
        """Analyse any closed, outward-wound body mesh in the mannequin's pose convention (module docstring).

        vertices (V,3) [m], triangles (T,3) int. Raises MeshError when the mesh is unusable or the arms cannot
        be told from the torso."""
        validate_triangle_mesh(vertices, triangles, "body mesh")
        v = np.array(vertices, dtype=np.float64)
        t = np.array(triangles, dtype=np.int64)
        mesh = _Mesh(v, t)
        y0 = float(v[:, 1].min())
        height = float(v[:, 1].max()) - y0
        armpit = _armpit_height(mesh, y0, height)

        below = v[:, 1] < armpit
        comp = connected_components(len(v), mesh.edges[below[mesh.edges[:, 0]] & below[mesh.edges[:, 1]]])
        arms, arm_masks = {}, {}
        for name, sign, extreme in (("arm_left", 1.0, np.argmax(v[:, 0])), ("arm_right", -1.0, np.argmin(v[:, 0]))):
            if not below[extreme] or comp[extreme] == comp[np.argmin(v[:, 1])]:
                raise MeshError("body mesh: the arms do not come apart from the torso below the armpit")
            arm_masks[name] = below & (comp == comp[extreme])
            arms[name] = _analyse_arm(mesh, arm_masks[name], armpit, sign)
        labels = _label_parts(v, below, arm_masks, arms)

        shoulder = 0.5 * float(arms["arm_left"].shoulder[1] + arms["arm_right"].shoulder[1])
        landmarks, loops = _torso_landmarks(mesh, labels == "torso", height, armpit, shoulder)
        girths = {name: _loop_girth(loop) for name, loop in loops.items()}
        girths["upper_arm"] = 0.5 * sum(_arm_girth(mesh, arm, labels == name) for name, arm in arms.items())
        frames = _frames(loops, arms)
        points = {}
        for name, side in (("arm_left", "left"), ("arm_right", "right")):
            points[f"armpit_{side}"] = arms[name].armpit
            points[f"shoulder_{side}"] = arms[name].shoulder
            points[f"elbow_{side}"] = arms[name].elbow
        return cls(v, t, labels, frames, landmarks, girths, points)

    # ------------------------------------------------------------------------------------- queries
    def frame(self, anchor) -> BodyFrame:
        """The frame named `anchor`; PatternError listing the valid anchors if there is none."""
        if isinstance(anchor, BodyFrame):
            return anchor
        try:
            return self.frames[anchor]
        except (KeyError, TypeError):
            raise PatternError(f"unknown placement anchor {anchor!r}; valid anchors: "
                               f"{', '.join(sorted(self.frames))}") from None

    def _triangle_labels(self) -> np.ndarray:
        lab = self.labels[self.triangles]
        return np.where(lab[:, 1] == lab[:, 2], lab[:, 1], lab[:, 0])

    def _table(self, frame: BodyFrame) -> _Table:
        key = (frame.part, frame.origin.tobytes(), frame.axis.tobytes(), frame.front.tobytes())
        if key not in self._tables:
            if self._samples is None:
                pts, tri = _surface_samples(self.vertices, self.triangles, _SAMPLE_SPACING)
                self._samples = (pts, self._triangle_labels()[tri])
            self._tables[key] = _build_table(frame, *self._samples)
        return self._tables[key]

    def radial_extent(self, frame, heights, angles) -> np.ndarray:
        """Distance [m] from the frame's axis to the outermost surface of frame.part along rays.

        frame: a BodyFrame or a frame name; heights: (n,) axial positions [m] along frame.axis from
        frame.origin; angles: (n,) [rad] from frame.front toward frame.side. Returns (n,) float64, 0 where
        the ray misses the part. Binned (1 cm x 2.5 degrees, dilated by one bin): slightly conservative."""
        frame = self.frame(frame)
        tab = self._table(frame)
        s = np.asarray(heights, dtype=np.float64)
        a = np.asarray(angles, dtype=np.float64)
        rows = np.floor((s - tab.s0) / AXIAL_BIN).astype(int)
        cols = np.floor((a + math.pi) / (2 * math.pi) * ANGLE_BINS).astype(int) % ANGLE_BINS
        ok = (rows >= 0) & (rows < tab.rows)
        return np.where(ok, tab.own[np.clip(rows, 0, tab.rows - 1), cols], 0.0)

    def surface_point(self, anchor, offset: float = 0.0) -> np.ndarray:
        """(3,) [m]: where the ray from the anchor's origin along its front leaves frame.part for the last
        time, moved `offset` [m] further out (e.g. a point to hold a particle at)."""
        frame = self.frame(anchor)
        _check_number("offset", offset)
        tri = self.triangles[self._triangle_labels() == frame.part]
        t = _ray_hits(frame.origin, frame.front, self.vertices[tri])
        if len(t) == 0:
            raise PatternError(f"anchor {frame.name!r}: the ray along its front misses the {frame.part}")
        return frame.origin + (t.max() + float(offset)) * frame.front

    def signed_distance(self, points, max_distance: float = 0.05) -> np.ndarray:
        """(n,) float64 [m]: distance of points (n,3) to the body surface, negative inside; exact up to
        max_distance, clipped to +-max_distance beyond. Inside/outside by ray parity (majority of 3 rays)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        d = unsigned_distance(p, self.vertices[self.triangles], float(max_distance))
        return np.where(_inside(p, self.vertices, self.triangles), -d, d)


# ------------------------------------------------------------------------------------ ray and distance

def _ray_hits(origin, direction, tri: np.ndarray) -> np.ndarray:
    """Distances t >= 0 along a ray at which it crosses triangles (k,3,3) (Moller-Trumbore)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    e1, e2 = b - a, c - a
    pv = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, pv)
    ok = np.abs(det) > 1e-14
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    sv = origin - a
    u = np.einsum("ij,ij->i", sv, pv) * inv
    qv = np.cross(sv, e1)
    w = (qv @ direction) * inv
    t = np.einsum("ij,ij->i", e2, qv) * inv
    hit = ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (t >= 0)
    return t[hit]


def _inside(p: np.ndarray, v: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Ray parity along three slightly tilted, nearly vertical directions; the majority decides."""
    votes = np.zeros(len(p), dtype=int)
    for direction in ((0.0131, 1.0, 0.0217), (-0.0193, 1.0, 0.0071), (0.0057, 1.0, -0.0257)):
        d = np.array(direction) / np.linalg.norm(direction)
        e1 = np.cross(d, [0.0, 0.0, 1.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(d, e1)
        v2 = np.stack([v @ e1, v @ e2], axis=1)
        tri2 = v2[t]
        cell = 0.01
        item, key = pairs_by_cell(tri2.min(axis=1), tri2.max(axis=1), cell)
        p2 = np.stack([p @ e1, p @ e2], axis=1)
        pi, ti = candidates(point_key(p2, cell), item, key)
        a, b, c = tri2[ti, 0], tri2[ti, 1], tri2[ti, 2]
        x = p2[pi]

        def cross2(u, w):
            return u[:, 0] * w[:, 1] - u[:, 1] * w[:, 0]

        area = cross2(b - a, c - a)
        l0 = cross2(b - x, c - x) / np.where(area == 0, 1.0, area)
        l1 = cross2(c - x, a - x) / np.where(area == 0, 1.0, area)
        l2 = 1.0 - l0 - l1
        hit = (area != 0) & (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
        h = v @ d
        height = l0 * h[t[ti, 0]] + l1 * h[t[ti, 1]] + l2 * h[t[ti, 2]]
        hit &= height > p[pi] @ d
        crossings = np.bincount(pi[hit], minlength=len(p))
        votes += crossings % 2
    return votes >= 2


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
        radius = _wrap_radii(body._table(frame), u, s, offset, turn)
        theta = u / radius + turn
        radial = np.cos(theta)[:, None] * frame.front + np.sin(theta)[:, None] * frame.side
        return frame.origin + s[:, None] * frame.axis + radius[:, None] * radial
    front = math.cos(turn) * frame.front + math.sin(turn) * frame.side
    side = np.cross(frame.axis, front)
    distance = _flat_distance(body, frame, front, side, u, s, offset)
    return frame.origin + s[:, None] * frame.axis + u[:, None] * side + distance * front


def _flat_distance(body: Body, frame: BodyFrame, front, side, u, s, offset) -> float:
    if body._samples is None:
        body._table(frame)
    pts, lab = body._samples
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


def _wrap_radii(tab: _Table, u: np.ndarray, s: np.ndarray, offset: float, turn: float) -> np.ndarray:
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
