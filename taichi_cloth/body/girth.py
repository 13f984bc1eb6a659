"""Girths of a body, measured like a tape (Zhang et al. 2017, section 3.1.2), on any morph of one base body.

Zhang et al. 2017 cut the body at a feature (the waist), fits cubic splines through the section's points (two natural
splines, z >= 0 and z <= 0, as functions z(x)) and sums short chords along them. Here:

- `periodic_spline_length(points2d)`: the length [m] of the closed curve through ordered 2D points (n,2) [m]:
  ONE periodic cubic spline (scipy CubicSpline, bc_type="periodic") in both coordinates, parametrised by
  cumulative chord length with the first point repeated at the end, its length integrated exactly enough by
  8-point Gauss-Legendre on every interval (|S'(t)| is smooth between knots). No split into front and back,
  no z(x) graph, which a section that folds back on itself in x (the sides of the torso) is not.
- `tape_girth(points2d)`: a tape around the body bridges the hollows (between the breasts, along the spine),
  so the spline goes through the section's convex-hull vertices (unordered points in, the hull orders them).
  It is never shorter than the hull's perimeter, and longer by what the hull's chords cut off the rounded
  surface between section points, plus a slight outward bow of the spline where the hull bridges a hollow.
  On the shipped mannequin (spline vs hull, m): chest 0.7997 / 0.7986 (+0.13 %), underbust 0.7288 / 0.7275,
  waist 0.6703 / 0.6692, hips 0.9569 / 0.9546 (+0.23 %), neck 0.3147 / 0.3133, upper arm 0.2524 / 0.2511,
  thigh 0.5322 / 0.5295 (+0.51 %: coarse faces, 2 cm apart, on the thigh).

`GirthGauge` measures named girths on a base body and any morph of it (same vertices and triangles), without
analysing the body again: `GirthGauge.from_body(vertices, triangles)` runs the landmark analysis
(taichi_cloth.body.landmarks.Body.from_mesh, about 0.5-1 s) once, and `measure(vertices)` then takes a few
ms per girth. Each girth is a plane and a vertex mask fixed on the base; the plane passes through an anchor
vertex (the base vertex nearest the landmark point), moved by a fixed offset (the landmark point minus the
anchor on the base), so on the base the plane goes through the landmark exactly and on a morph it follows the
anchor vertex (a bust that drops takes its plane with it). The section is the plane's loops over edges whose
both ends are in the mask; one loop is chosen:

| girth | plane | mask | loop | landmark point (anchor) |
|---|---|---|---|---|
| chest | horizontal at landmark "chest" (the bust) | torso | largest | foremost point (bust apex) |
| underbust | horizontal at `underbust_height` (default chest - 0.05 m) | torso | largest | foremost point |
| waist | horizontal at landmark "waist" | torso | largest | foremost point |
| hips | horizontal at landmark "hips" (buttocks) | torso | largest | hindmost point |
| neck | horizontal at landmark "neck" | torso | largest | foremost point |
| thigh | horizontal 0.05 m below "crotch" | torso (incl. legs) | largest with x > 0 (left leg) | foremost point |
| upper_arm | through arm_left's origin, normal its axis | arm_left | nearest the origin | the origin |

For the mannequin `GirthGauge.from_blendshapes` puts the underbust where the underbust channel acts (the
|delta|-weighted mean height of its larger limit: 1.166 m on the shipped body). Units: metres throughout.
"""
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from ..errors import BodyError
from .landmarks import Body
from .section import MeshSlicer, convex_hull, hull_perimeter, plane_basis

__all__ = ["GIRTHS", "GirthDefinition", "GirthGauge", "periodic_spline_length", "tape_girth"]

#: the girths a GirthGauge measures, in this order
GIRTHS = ("chest", "underbust", "waist", "hips", "neck", "upper_arm", "thigh")
UNDERBUST_BELOW_CHEST = 0.05   # [m] default underbust plane below the bust when no underbust channel says where
THIGH_BELOW_CROTCH = 0.05      # [m] the thigh is measured this far below the crotch

_GL_X, _GL_W = np.polynomial.legendre.leggauss(8)


def periodic_spline_length(points2d) -> float:
    """Length [m] of the periodic cubic spline through ordered 2D points (n,2) [m] of a closed curve.

    The first point is repeated at the end (a closing point given already is dropped), consecutive duplicates
    are dropped; parametrised by cumulative chord length; length by 8-point Gauss-Legendre per interval. At
    least three distinct points are needed (BodyError otherwise)."""
    p = np.asarray(points2d, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or not np.all(np.isfinite(p)):
        raise BodyError(f"periodic_spline_length: expected finite points of shape (n, 2), got {p.shape}")
    if len(p) > 1 and np.array_equal(p[0], p[-1]):
        p = p[:-1]
    if len(p) > 1:
        keep = np.any(p != np.roll(p, 1, axis=0), axis=1)   # a zero chord would repeat a knot
        keep[0] = True
        p = p[keep]
    if len(p) < 3:
        raise BodyError(f"periodic_spline_length: need at least 3 distinct points, got {len(p)}")
    closed = np.vstack([p, p[:1]])
    chord = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(chord)])
    spline = CubicSpline(s, closed, bc_type="periodic")
    h = np.diff(s)
    t = s[:-1, None] + 0.5 * h[:, None] * (_GL_X[None, :] + 1.0)        # (n, 8) nodes per interval
    speed = np.linalg.norm(spline(t.ravel(), 1), axis=1).reshape(t.shape)
    return float(np.sum(0.5 * h * (speed @ _GL_W)))


def tape_girth(points2d) -> float:
    """Girth [m] of a section's 2D points (k,2) [m] (any order) as a tape measures it: the periodic spline
    length through their convex-hull vertices. BodyError for fewer than three non-collinear points."""
    hull = convex_hull(points2d)
    if len(hull) < 3:
        raise BodyError(f"tape_girth: the {len(np.asarray(points2d).reshape(-1, 2))} points span no area")
    return periodic_spline_length(hull)


@dataclass(frozen=True, eq=False)
class GirthDefinition:
    """Where one girth is measured (module docstring).

    name: a GIRTHS name; anchor: base vertex id the plane follows; offset: (3,) [m] plane point minus the
    anchor vertex (on the base); normal: (3,) unit plane normal; mask: (V,) bool, the vertices whose edges the
    plane may cut; part: the mask's name; select: "largest" (the longest loop), "left" (the longest loop with
    centroid x > 0) or "nearest" (the loop whose centroid is nearest the plane point); base_point: (3,) [m]
    the plane point on the base body.
    """

    name: str
    anchor: int
    offset: np.ndarray
    normal: np.ndarray
    mask: np.ndarray
    part: str
    select: str
    base_point: np.ndarray

    def point(self, vertices: np.ndarray) -> np.ndarray:
        """(3,) [m]: the plane point on a morph (the anchor vertex plus the fixed offset)."""
        return vertices[self.anchor] + self.offset

    def __repr__(self) -> str:
        if self.normal[1] == 1.0:
            plane = f"horizontal plane at y = {self.base_point[1]:.4f} m"
        else:
            n = ", ".join(f"{x:.3f}" for x in self.normal)
            o = ", ".join(f"{x:.4f}" for x in self.base_point)
            plane = f"plane through ({o}) m, normal ({n})"
        return (f"GirthDefinition({self.name}: {plane}, following vertex {self.anchor} "
                f"(offset {np.linalg.norm(self.offset) * 1000:.1f} mm); {self.part} ({int(self.mask.sum())} "
                f"vertices), {self.select} loop)")


def _select(loops: list, select: str, point: np.ndarray):
    """The loop a girth measures among a plane's loops (GirthDefinition.select), or None."""
    if select == "left":
        loops = [lp for lp in loops if lp.centroid[0] > 0]
    if not loops:
        return None
    if select == "nearest":
        return min(loops, key=lambda lp: float(np.linalg.norm(lp.centroid - point)))
    return max(loops, key=lambda lp: lp.length)


class GirthGauge:
    """Measures the GIRTHS of a base body's morphs (module docstring).

    slicer: a MeshSlicer of the base (its edges are reused); definitions: name -> GirthDefinition;
    landmarks: the base's landmark heights [m] (placement's Body.landmarks plus "underbust" and "thigh").
    """

    def __init__(self, slicer: MeshSlicer, definitions: dict, landmarks: dict):
        self.slicer = slicer
        self.definitions = dict(definitions)
        self.landmarks = dict(landmarks)

    def __repr__(self) -> str:
        lines = "\n".join(f"  {d!r}" for d in self.definitions.values())
        return f"GirthGauge({len(self.slicer.v)} vertices,\n{lines})"

    @property
    def names(self) -> list:
        return list(self.definitions)

    @property
    def base(self) -> np.ndarray:
        """(V,3) [m]: the body the gauge was built on."""
        return self.slicer.v

    # ------------------------------------------------------------------------------------ construction
    @classmethod
    def from_body(cls, vertices, triangles, underbust_height: float | None = None) -> "GirthGauge":
        """Analyse a closed, outward-wound body in the mannequin's convention (landmarks.Body.from_mesh; raises
        MeshError for an unusable mesh) once and define the girths on it. underbust_height [m]: where the
        underbust is measured (default: the chest landmark - 0.05 m)."""
        body = Body.from_mesh(vertices, triangles)
        v, t = body.vertices, body.triangles
        slicer = MeshSlicer(v, t)
        torso = body.labels == "torso"
        left = body.labels == "arm_left"
        lm = dict(body.landmarks)
        lm["underbust"] = (float(underbust_height) if underbust_height is not None
                           else lm["chest"] - UNDERBUST_BELOW_CHEST)
        lm["thigh"] = lm["crotch"] - THIGH_BELOW_CROTCH
        up = np.array([0.0, 1.0, 0.0])
        plan = {"chest": ("chest", "largest", 1), "underbust": ("underbust", "largest", 1),
                "waist": ("waist", "largest", 1), "hips": ("hips", "largest", -1),
                "neck": ("neck", "largest", 1), "thigh": ("thigh", "left", 1)}
        defs = {}
        for name in GIRTHS:
            if name == "upper_arm":
                frame = body.frames["arm_left"]
                defs[name] = _definition(name, v, left, "arm_left", frame.origin, frame.axis, "nearest")
                continue
            key, select, facing = plan[name]
            y = lm[key]
            loop = _select(slicer.level(y, torso), select, np.array([0.0, y, 0.0]))
            if loop is None:
                raise BodyError(f"body mesh: no {name} cross-section of the torso at y = {y:.4f} m")
            # the landmark point: the section's foremost (hindmost for the hips) point, at the plane's height
            landmark = loop.points[np.argmax(facing * loop.points[:, 2])]
            defs[name] = _definition(name, v, torso, "torso", landmark, up, select)
        return cls(slicer, defs, lm)

    @classmethod
    def from_blendshapes(cls, blend) -> "GirthGauge":
        """The gauge of a BlendShapes' base body; the underbust is measured at the |delta|-weighted mean height
        of the "underbust" channel's larger (else smaller) limit if there is one, else chest - 0.05 m."""
        height = None
        channel = blend.channels.get("underbust")
        shape = None if channel is None else (channel.larger or channel.smaller)
        if shape is not None and len(shape):
            w = np.linalg.norm(shape.delta, axis=1)
            height = float((blend.base[shape.index, 1] * w).sum() / w.sum())
        return cls.from_body(blend.base, blend.triangles, underbust_height=height)

    # ---------------------------------------------------------------------------------------- measuring
    def _check(self, vertices, names):
        v = np.asarray(vertices, dtype=np.float64)
        if v.shape != self.slicer.v.shape:
            raise BodyError(f"girth gauge: vertices of shape {v.shape} are not a morph of the gauge's body "
                            f"{self.slicer.v.shape}")
        names = self.names if names is None else ([names] if isinstance(names, str) else list(names))
        for n in names:
            if n not in self.definitions:
                raise BodyError(f"unknown girth {n!r}; valid girths: {', '.join(self.definitions)}")
        return v, names

    def sections(self, vertices, names=None) -> dict:
        """{name: (Loop, e1, e2)}: the chosen section of each girth on a morph and the plane's 2D basis."""
        v, names = self._check(vertices, names)
        slicer = self.slicer.with_vertices(v)
        out = {}
        for n in names:
            d = self.definitions[n]
            point = d.point(v)
            loop = _select(slicer.slice(point, d.normal, d.mask), d.select, point)
            if loop is None:
                raise BodyError(f"girth {n}: the plane ({d!r}) does not cut this body")
            out[n] = (loop, *plane_basis(d.normal))
        return out

    def measure(self, vertices, names=None, method: str = "spline") -> dict:
        """{name: girth [m]} of a morph (V,3) [m] of the gauge's body, for `names` (default: all GIRTHS).

        method "spline": tape_girth (the periodic spline through the hull); "hull": the convex hull's
        perimeter (placement's Body.girths). BodyError for an unknown name or a plane that misses the body."""
        if method not in ("spline", "hull"):
            raise BodyError(f"girth method must be 'spline' or 'hull', got {method!r}")
        girth = tape_girth if method == "spline" else hull_perimeter
        out = {}
        for n, (loop, e1, e2) in self.sections(vertices, names).items():
            out[n] = girth(np.stack([loop.points @ e1, loop.points @ e2], axis=1))
        return out


def _definition(name, v, mask, part, landmark, normal, select) -> GirthDefinition:
    ids = np.flatnonzero(mask)
    anchor = int(ids[np.argmin(np.linalg.norm(v[ids] - landmark, axis=1))])
    normal = np.asarray(normal, dtype=np.float64)
    return GirthDefinition(name, anchor, np.asarray(landmark, dtype=np.float64) - v[anchor],
                           normal / np.linalg.norm(normal), mask, part, select, np.asarray(landmark, dtype=np.float64))
