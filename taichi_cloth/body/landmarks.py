"""The body's landmarks for placing garments on it: parts, frames, landmark heights and girths of a body mesh, and
its surface in cylindrical bins about each frame (numpy only; used by taichi_cloth.garment.placement).

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

The body's surface is looked up in cylindrical bins about each frame's axis (1 cm x 2.5 degrees: max / min
radius of surface samples 3 mm apart, dilated by one angular bin; built once per frame, about 0.1 s);
`Body.radial_extent` reads them (conservative: never inside the surface, on average 5-7 mm outside it).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clothbase.errors import MeshError
from clothbase.meshes import connected_components, validate_triangle_mesh
from collision.distance import candidates, pairs_by_cell, point_key, unsigned_distance
from collision.mannequin import load_mannequin

from ..errors import PatternError
from .section import Loop, MeshSlicer, loop_girth

__all__ = ["ANGLE_BINS", "AXIAL_BIN", "Body", "BodyFrame", "CylinderTable", "PARTS"]

#: part labels of Body.labels
PARTS = ("torso", "arm_left", "arm_right")
#: [m] axial bin of the cylindrical body tables (and the row height of a placement's radius profile)
AXIAL_BIN = 0.01
#: angular bins of the cylindrical body tables (2.5 degrees)
ANGLE_BINS = 144
_SAMPLE_SPACING = 0.003   # [m] surface samples this dense leave few empty bins at the arm's radius
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

def _armpit_height(mesh: MeshSlicer, y0: float, height: float) -> float:
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


def _arm_centre_line(mesh: MeshSlicer, arm_mask: np.ndarray, armpit: float):
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


def _analyse_arm(mesh: MeshSlicer, arm_mask: np.ndarray, armpit: float, sign: float) -> _Arm:
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


def _arm_girth(mesh: MeshSlicer, arm: _Arm, arm_mask: np.ndarray) -> float:
    """Upper-arm girth [m] perpendicular to the axis at the arm frame's origin; arm_mask: every vertex labelled
    as this arm (the below-armpit piece alone would cut the top of the section off)."""
    loops = mesh.slice(arm.origin, arm.axis, arm_mask)
    return loop_girth(min(loops, key=lambda lp: np.linalg.norm(lp.centroid - arm.origin)), arm.axis) if loops else 0.0


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


def _torso_loop(mesh: MeshSlicer, y: float, mask: np.ndarray):
    loops = mesh.level(y, mask)
    return max(loops, key=lambda lp: lp.length) if loops else None


def _loop_girth(loop: Loop) -> float:
    return loop_girth(loop, [0.0, 1.0, 0.0])


def _bust_prominence(loop: Loop) -> float:
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


def _torso_landmarks(mesh: MeshSlicer, torso: np.ndarray, height: float, armpit: float, shoulder: float):
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
class CylinderTable:
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


def _build_table(frame: BodyFrame, samples, sample_labels) -> CylinderTable:
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
    return CylinderTable(s0, _dilate(own.reshape(shape), np.maximum),
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
        """The Body of a collision.mannequin.Mannequin (default: load_mannequin(), the shipped CC0 body); a
        MeshError names its file."""
        if mannequin is None:
            mannequin = load_mannequin()
        source = f"body {mannequin.path}" if getattr(mannequin, "path", None) is not None else "body mesh"
        return cls.from_mesh(mannequin.vertices, mannequin.triangles, source)

    @classmethod
    def from_mesh(cls, vertices, triangles, source: str = "body mesh") -> "Body":
        """Analyse any closed, outward-wound body mesh in the mannequin's pose convention (module docstring).

        vertices (V,3) [m], triangles (T,3) int. Raises MeshError, its message starting with `source` (the body's
        file, or what it is), when the mesh is unusable or the arms cannot be told from the torso."""
        try:
            return cls._analyse(vertices, triangles)
        except MeshError as exc:
            if source == "body mesh":
                raise
            raise MeshError(f"{source}: {str(exc).removeprefix('body mesh: ')}") from None

    @classmethod
    def _analyse(cls, vertices, triangles) -> "Body":
        validate_triangle_mesh(vertices, triangles, "body mesh")
        v = np.array(vertices, dtype=np.float64)
        t = np.array(triangles, dtype=np.int64)
        mesh = MeshSlicer(v, t)
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

    def samples(self) -> tuple[np.ndarray, np.ndarray]:
        """Points (N,3) [m] on the surface about 3 mm apart and their part labels (N,) str (built once)."""
        if self._samples is None:
            pts, tri = _surface_samples(self.vertices, self.triangles, _SAMPLE_SPACING)
            self._samples = (pts, self._triangle_labels()[tri])
        return self._samples

    def table(self, frame: BodyFrame) -> CylinderTable:
        """The body's surface in cylindrical bins about `frame`'s axis (built once per frame)."""
        key = (frame.part, frame.origin.tobytes(), frame.axis.tobytes(), frame.front.tobytes())
        if key not in self._tables:
            self._tables[key] = _build_table(frame, *self.samples())
        return self._tables[key]

    def radial_extent(self, frame, heights, angles) -> np.ndarray:
        """Distance [m] from the frame's axis to the outermost surface of frame.part along rays.

        frame: a BodyFrame or a frame name; heights: (n,) axial positions [m] along frame.axis from
        frame.origin; angles: (n,) [rad] from frame.front toward frame.side. Returns (n,) float64, 0 where
        the ray misses the part. Binned (1 cm x 2.5 degrees, dilated by one bin): slightly conservative."""
        frame = self.frame(frame)
        tab = self.table(frame)
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
        if not math.isfinite(float(offset)):
            raise PatternError(f"anchor offset must be finite, got {offset!r}")
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
