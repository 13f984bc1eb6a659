"""Plane sections of a triangle mesh and convex hulls of their points: the raw material of girths.

Shared by the body's landmarks (taichi_cloth.body.landmarks, which finds them with it) and by the girth gauge
(taichi_cloth.body.girth). Numpy only.

- `MeshSlicer(vertices, triangles)`: vertices (V,3) float64 [m], triangles (T,3) int64; builds the unique edges
  once (clothbase.meshes.edges_of) and cuts the surface with planes: `slice(origin, normal, vmask)` returns
  the closed loops (`Loop`) where the plane crosses the surface. `with_vertices(v)` reuses the topology for a
  morph of the same mesh (same triangles), which is how a girth gauge measures many morphs cheaply.
- `Loop`: centroid (3,) [m], polyline length [m], points (k,3) [m]. The points are the plane's crossings of the
  loop's edges, UNORDERED (one per crossed edge); anything that needs an order takes their convex hull.
- `convex_hull(points2d)`: the hull's vertices (h,2), counter-clockwise, collinear points dropped;
  `hull_perimeter(points2d)` its perimeter [m]: a tape measure's girth as a polygon (it bridges hollows).
- `plane_basis(normal)`: two unit vectors (e1, e2) spanning the plane, for projecting a loop to 2D;
  `loop_girth(loop, normal)`: the hull perimeter of a loop projected onto its plane.
"""
import numpy as np

from clothbase.meshes import connected_components, edges_of

__all__ = ["Loop", "MeshSlicer", "convex_hull", "hull_perimeter", "loop_girth", "plane_basis"]


class Loop:
    """One closed curve where a plane cuts the surface.

    centroid: (3,) float64, length-weighted centroid of the loop's segments [m]; length: polyline perimeter
    [m]; points: (k,3) float64, the loop's points [m], unordered (one per crossed edge).
    """

    __slots__ = ("centroid", "length", "points")

    def __init__(self, centroid: np.ndarray, length: float, points: np.ndarray):
        self.centroid = centroid
        self.length = length
        self.points = points

    def __repr__(self) -> str:
        c = ", ".join(f"{x:.4f}" for x in self.centroid)
        return f"Loop(length={self.length:.4f} m, {len(self.points)} points, centroid=({c}))"


class MeshSlicer:
    """Vertices, triangles and their unique edges, for plane slices.

    v: (V,3) float64 [m]; t: (T,3) int64; edges: (E,2) int64 unique undirected edges; face_edge: (T,3) int64,
    the edge id of each triangle's corner k -> k+1.
    """

    def __init__(self, vertices, triangles, _edges=None):
        self.v = vertices
        self.t = triangles
        if _edges is None:
            self.edges, self.face_edge, _ = edges_of(triangles)
        else:
            self.edges, self.face_edge = _edges

    @property
    def vertices(self) -> np.ndarray:
        return self.v

    @property
    def triangles(self) -> np.ndarray:
        return self.t

    def with_vertices(self, vertices) -> "MeshSlicer":
        """A slicer for a morph of this mesh: new vertices (V,3), the same triangles and edges (no rebuild)."""
        v = np.asarray(vertices, dtype=np.float64)
        if v.shape != self.v.shape:
            raise ValueError(f"vertices of shape {v.shape} do not match the slicer's mesh {self.v.shape}")
        return MeshSlicer(v, self.t, (self.edges, self.face_edge))

    def slice(self, origin, normal, vmask=None) -> list:
        """The closed loops (list of Loop) where the plane through origin (3,) with normal (3,) cuts the surface,
        restricted to edges whose both ends are in vmask ((V,) bool, or None for all)."""
        d = (self.v - origin) @ normal
        da, db = d[self.edges[:, 0]], d[self.edges[:, 1]]
        cross = (da < 0) != (db < 0)
        if vmask is not None:
            cross &= vmask[self.edges[:, 0]] & vmask[self.edges[:, 1]]
        idx = np.flatnonzero(cross)
        if len(idx) == 0:
            return []
        t = da[idx] / (da[idx] - db[idx])
        a, b = self.v[self.edges[idx, 0]], self.v[self.edges[idx, 1]]
        pts = a + t[:, None] * (b - a)
        local = np.full(len(self.edges), -1)
        local[idx] = np.arange(len(idx))
        fc = cross[self.face_edge]
        two = fc.sum(axis=1) == 2   # a plane crossing a triangle crosses exactly two of its edges
        pairs = local[self.face_edge[two][fc[two]].reshape(-1, 2)]
        _, comp = np.unique(connected_components(len(idx), pairs), return_inverse=True)
        seg_len = np.linalg.norm(pts[pairs[:, 0]] - pts[pairs[:, 1]], axis=1)
        seg_mid = 0.5 * (pts[pairs[:, 0]] + pts[pairs[:, 1]])
        seg_comp = comp[pairs[:, 0]]
        loops = []
        for c in range(comp.max() + 1):   # a handful of loops per plane
            sel = seg_comp == c
            length = float(seg_len[sel].sum())
            if length <= 0:
                continue
            centroid = (seg_mid[sel] * seg_len[sel, None]).sum(axis=0) / length
            loops.append(Loop(centroid, length, pts[comp == c]))
        return loops

    def level(self, y: float, vmask=None) -> list:
        """The loops of the horizontal plane at height y [m]."""
        return self.slice(np.array([0.0, y, 0.0]), np.array([0.0, 1.0, 0.0]), vmask)


def convex_hull(points2d) -> np.ndarray:
    """Vertices (h,2) float64 of the convex hull of 2D points (k,2), counter-clockwise, starting at the lowest x
    (then lowest y); collinear and duplicate points (equal after rounding to 1e-9 m) dropped. Fewer than three
    distinct points give what there is (h < 3). Andrew's monotone chain."""
    p = np.unique(np.round(np.asarray(points2d, dtype=np.float64).reshape(-1, 2), 9), axis=0)  # sorted by x, y
    if len(p) < 3:
        return p
    pts = p.tolist()

    def half(points):
        # the chain is a stack that pops on every non-left turn: inherently sequential, over the loop's
        # few hundred points only
        h = []
        for q in points:
            while len(h) >= 2 and ((h[-1][0] - h[-2][0]) * (q[1] - h[-2][1])
                                   - (h[-1][1] - h[-2][1]) * (q[0] - h[-2][0])) <= 0:
                h.pop()
            h.append(q)
        return h

    return np.array(half(pts)[:-1] + half(pts[::-1])[:-1], dtype=np.float64)


def hull_perimeter(points2d) -> float:
    """Perimeter [m] of the convex hull of 2D points (k,2) (a tape measure's girth as a polygon); 0 for fewer
    than three distinct points."""
    hull = convex_hull(points2d)
    if len(hull) < 3:
        return 0.0
    return float(np.linalg.norm(hull - np.roll(hull, 1, axis=0), axis=1).sum())


def plane_basis(normal):
    """Two unit vectors (e1, e2), each (3,) float64, orthogonal to `normal` and to each other, e1 x e2 along
    normal (for a horizontal plane, normal +y: e1 = -z, e2 = -x). Girths do not depend on the choice."""
    normal = np.asarray(normal, dtype=np.float64)
    normal = normal / np.linalg.norm(normal)
    e1 = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(normal, e1)


def loop_girth(loop: Loop, normal) -> float:
    """Convex-hull perimeter [m] of a loop projected onto the plane with this normal (3,)."""
    e1, e2 = plane_basis(normal)
    return hull_perimeter(np.stack([loop.points @ e1, loop.points @ e2], axis=1))
