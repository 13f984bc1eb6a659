"""Local refinement of a merged garment (issue 18; ours): finer where the cloth folds or touches the body, coarse
elsewhere, the mesh conforming everywhere, across the seams too.

Why not the 4-8 bisection of a grid (multilevel.hierarchy.refine_local): an outline level is a 4-8 lattice inside
a band that is re-triangulated on every level (garment.outline), so the band's triangles are not bisected into
the next level's, their edge midpoints are not vertices of the next level, and a merged vertex's pattern point is
in one piece's coordinates only (a triangle across a seam has no uv of its own). What the levels do share are their
vertices: every vertex of level k is a vertex of level k + 1 at the same pattern point (the boundary samples and
the lattice are nested), so a level is a subset of the finest level's vertices, and so is every mesh in between.

So a locally refined garment is a set of active vertices of the finest level (per merged particle: a seam pair
is active on both sides or on neither), each piece triangulated on its active vertices (Delaunay in the pattern
plane, the active boundary samples its outline), assembled and merged the way the levels are
(GarmentLevelPlan.assemble, sewing.merge_seams). One step refines the marked triangles toward the next level:
every finest vertex in a marked triangle becomes active if it exists on the triangle's level + 1 (a vertex's
level is the coarsest level that has it; a triangle's, the lowest `depth` of its corners; depth is a per-vertex
field of the finest level that a step raises inside the marked triangles, never beyond the finest level).
A boundary edge that the Delaunay triangulation misses gets its next boundary sample (on a seam: on both sides),
and an active vertex that still ends outside its piece's outline is dropped, until every piece's outline is
made of mesh edges. The new vertices are placed by the current mesh (barycentric in the pattern triangle they
fall in, per piece; a seam vertex from one of its pieces), so a seam stays closed; the refiner adds back the
momentum the new masses change.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import Delaunay

from multilevel.hierarchy import Level

from .levels import GarmentLevel, MultilevelGarment
from .mesh import PieceMesh, mesh_quality
from .outline import inside_polygon, locate
from .sewing import merge_seams


@dataclass
class LocalMesh:
    """A locally refined garment: its level, and its vertices among the finest level's.

    level:   GarmentLevel (garment: the pieces apart; merged: the cloth the refiner loads; current_of)
    active:  (N,) bool over the finest level's merged particles: the ones this mesh has
    fine_of: (n,) int64 the finest merged particle of every merged particle of `level`
    piece_fine: per piece, (n_i,) int64 the finest piece vertex of every vertex of its mesh
    (the pieces' PieceMesh keep the finest level's hierarchy and level number: a local mesh is no level of it)
    """

    level: GarmentLevel
    active: np.ndarray
    fine_of: np.ndarray
    piece_fine: list


class LocalGarmentRefinement:
    """The local refinement of a MultilevelGarment's merged levels (see the module docstring)."""

    def __init__(self, mg: MultilevelGarment):
        if mg.plan is None:
            raise ValueError("local refinement needs the garment's level plan (build it with multilevel_garment)")
        self.mg = mg
        self.finest = mg.levels[-1]
        self.top = mg.n_levels - 1
        g = self.finest.garment
        self.offsets = g.offsets
        self.born = np.full(self.finest.merged.n_particles, self.top + 1, np.int64)
        self.start = self._level_mesh(mg.start_level)
        for k in range(self.top + 1):
            mesh = self.start if k == mg.start_level else self._level_mesh(k)
            self.born[mesh.fine_of] = np.minimum(self.born[mesh.fine_of], k)
        self.reset()

    def reset(self) -> None:
        """Back to the start level."""
        self.current = self.start
        self.depth = np.full(len(self.born), self.mg.start_level, np.int64)

    def _level_mesh(self, k: int) -> LocalMesh:
        """Level k as a LocalMesh: its vertices matched to the finest level's by pattern point, per piece.
        ValueError when a vertex of level k is not one of the finest level's (the levels are not nested)."""
        lev = self.mg.levels[k]
        piece_fine, members = [], []
        for i, (m, mf) in enumerate(zip(lev.garment.meshes, self.finest.garment.meshes)):
            scale = 1e-7 * float(np.ptp(mf.uv, axis=0).max())
            keys = {tuple(q): j for j, q in enumerate(np.round(mf.uv / scale).astype(np.int64))}
            idx = np.array([keys.get(tuple(q), -1) for q in np.round(m.uv / scale).astype(np.int64)], np.int64)
            if (idx < 0).any():
                raise ValueError(f"local refinement needs nested levels: piece {m.piece.name!r} has a vertex on "
                                 f"level {k + 1} that the finest level lacks")
            piece_fine.append(idx)
            members.append(self.finest.current_of[idx + self.offsets[i]])
        fine_of = np.zeros(lev.merged.n_particles, np.int64)
        fine_of[lev.current_of] = np.concatenate(members)
        active = np.zeros(self.finest.merged.n_particles, bool)
        active[fine_of] = True
        return LocalMesh(lev, active, fine_of, piece_fine)

    # ------------------------------------------------------------------ one step
    def refine(self, marked: np.ndarray) -> tuple[LocalMesh, Level] | None:
        """The mesh with the `marked` triangles ((t,) bool over the current merged triangles) refined one level, and
        the prolongation Level (parents in the current merged numbering, the new mesh's triangles); None when
        nothing is left to refine there."""
        cur = self.current
        depth = self.depth.copy()
        tri_off = np.concatenate([[0], np.cumsum([len(m.triangles) for m in cur.level.garment.meshes])])
        fmeshes = self.finest.garment.meshes
        for i, m in enumerate(cur.level.garment.meshes):
            rows = np.nonzero(marked[tri_off[i]:tri_off[i + 1]])[0]
            if not len(rows):
                continue
            tri = m.triangles[rows]
            fine_ids = self.finest.current_of[self.offsets[i] + np.arange(fmeshes[i].n_vertices)]
            corner_depth = self.depth[cur.fine_of[cur.level.current_of[cur.level.garment.offsets[i] + tri]]]
            target = np.minimum(corner_depth.min(axis=1) + 1, self.top)
            for t, raised in _points_in_triangles(m.uv, tri, fmeshes[i].uv):
                np.maximum.at(depth, fine_ids[raised], target[t])
        new = (depth > self.depth) & (self.born <= depth) & ~cur.active
        if not new.any():
            return None
        local = self._build(cur.active | new)
        self.depth = depth
        if np.array_equal(local.active, cur.active):  # every new vertex gave way to the outline
            return None
        return local, self._prolongation(local)

    def accept(self, local: LocalMesh) -> None:
        self.current = local

    # ------------------------------------------------------------------ the mesh of an active set
    def _build(self, active: np.ndarray) -> LocalMesh:
        for _ in range(64):
            meshes, piece_fine, grow, drop = [], [], [], []
            for i, mf in enumerate(self.finest.garment.meshes):
                on = active[self.finest.current_of[self.offsets[i] + np.arange(mf.n_vertices)]]
                mesh, fine, missing, outside = _triangulate(mf, on)
                meshes.append(mesh)
                piece_fine.append(fine)
                for a, b in missing:  # the next boundary sample between a and b (finest piece numbering)
                    loop = mf.boundary_loop
                    ia, ib = np.nonzero(loop == a)[0][0], np.nonzero(loop == b)[0][0]
                    between = loop[(np.arange(ia + 1, ia + (ib - ia) % len(loop))) % len(loop)]
                    ids = self.finest.current_of[self.offsets[i] + between]
                    if len(ids):
                        grow.append(ids[np.argmin(self.born[ids])])
                    else:  # an edge of the finest outline: the vertices in its diametral disk give way
                        p, q = mf.uv[a], mf.uv[b]
                        near = np.linalg.norm(mf.uv - 0.5 * (p + q), axis=1) <= 0.5 * np.linalg.norm(q - p) * (1 + 1e-6)
                        near[[a, b]] = False
                        ids = self.finest.current_of[self.offsets[i] + np.nonzero(near)[0]]
                        drop.extend(ids[~self.start.active[ids]])
                drop.extend(self.finest.current_of[self.offsets[i] + outside])
            if not grow and not drop:
                break
            active = active.copy()
            active[np.asarray(grow, np.int64)] = True
            active[np.asarray(drop, np.int64)] = False
        else:
            raise RuntimeError("internal error: local refinement found no outline-conforming mesh")
        g = self.mg.plan.assemble(meshes)
        merged, _, _, current_of = merge_seams(g.data, g, g.data.positions, np.zeros_like(g.data.positions))
        fine_of = np.zeros(merged.n_particles, np.int64)
        fine_of[current_of] = self.finest.current_of[np.concatenate([f + o for f, o in zip(piece_fine,
                                                                                              self.offsets)])]
        return LocalMesh(GarmentLevel(g, merged, current_of), active, fine_of, piece_fine)

    def _prolongation(self, new: LocalMesh) -> Level:
        """Tables from the current mesh to `new`: a vertex both have copies itself; a new one takes the barycentric
        weights of the current pattern triangle it lies in (of the piece of its first member)."""
        cur = self.current
        n = new.level.merged.n_particles
        index_of = np.full(len(self.born), -1, np.int64)
        index_of[cur.fine_of] = np.arange(len(cur.fine_of))
        parents = np.full((n, 3), -1, np.int64)
        weights = np.zeros((n, 3))
        old = index_of[new.fine_of]
        parents[old >= 0, 0] = old[old >= 0]
        weights[old >= 0, 0] = 1.0
        first = np.full(n, -1, np.int64)
        first[new.level.current_of[::-1]] = np.arange(len(new.level.current_of))[::-1]
        g_new, g_cur = new.level.garment, cur.level.garment
        piece_of = np.searchsorted(g_new.offsets, first, side="right") - 1
        for i, m in enumerate(g_new.meshes):
            rows = np.nonzero((old < 0) & (piece_of == i))[0]
            if not len(rows):
                continue
            mc = g_cur.meshes[i]
            t, w = locate(mc.uv, mc.triangles, m.uv[first[rows] - g_new.offsets[i]])
            parents[rows] = cur.level.current_of[g_cur.offsets[i] + mc.triangles[t]]
            weights[rows] = w
        # no uv: a merged vertex's pattern point is in one piece only (the pieces' meshes hold them)
        return Level(np.zeros((n, 2)), new.level.merged.triangles, parents, weights, np.full((n, 4), -1, np.int64))


def _points_in_triangles(uv: np.ndarray, triangles: np.ndarray, points: np.ndarray, chunk: int = 256):
    """The points (k, 2) in each closed triangle (uv (n, 2), triangles (t, 3)): yields (row, (j,) int64 indices of
    the points in triangle `row`) for the triangles that hold any."""
    tol = 1e-9
    for s in range(0, len(triangles), chunk):
        P = uv[triangles[s:s + chunk]]  # (c, 3, 2)
        lo, hi = P.min(axis=1), P.max(axis=1)
        a, b, c = P[:, 0, None], P[:, 1, None], P[:, 2, None]
        q = points[None]
        det = (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])
        l1 = ((q[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (q[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0]))
        l2 = ((b[..., 0] - a[..., 0]) * (q[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (q[..., 0] - a[..., 0]))
        l1, l2 = l1 / det, l2 / det
        inside = (l1 >= -tol) & (l2 >= -tol) & (1 - l1 - l2 >= -tol)
        inside &= np.all((q >= lo[:, None] - 1e-12) & (q <= hi[:, None] + 1e-12), axis=2)
        for r in range(len(P)):
            j = np.nonzero(inside[r])[0]
            if len(j):
                yield s + r, j


def _triangulate(mf: PieceMesh, on: np.ndarray):
    """The Delaunay mesh of the active vertices `on` ((n_F,) bool) of the finest piece mesh `mf`, its outline the
    active boundary samples. Returns (PieceMesh, (n,) int64 finest vertex of each vertex, missing outline edges
    [(a, b)] in finest numbering, (k,) int64 finest vertices left outside the outline)."""
    fine = np.nonzero(on)[0]
    local = np.full(mf.n_vertices, -1, np.int64)
    local[fine] = np.arange(len(fine))
    uv = mf.uv[fine]
    loop = mf.boundary_loop[on[mf.boundary_loop]]
    # a ring of points far outside: no vertex of the piece is on the hull, where collinear boundary samples
    # (a straight outline) would give flat triangles
    centre, size = 0.5 * (uv.min(axis=0) + uv.max(axis=0)), float(np.ptp(uv, axis=0).max())
    ring = centre + 10 * size * np.stack([np.cos(np.arange(8) * np.pi / 4), np.sin(np.arange(8) * np.pi / 4)], 1)
    tris = Delaunay(np.concatenate([uv, ring])).simplices.astype(np.int64)
    tris = tris[np.all(tris < len(uv), axis=1)]
    tris = tris[inside_polygon(uv[tris].mean(axis=1), uv[local[loop]])]
    area = _orient(uv, tris)
    tris[area < 0] = tris[area < 0][:, [0, 2, 1]]
    edges = {(min(a, b), max(a, b)) for t in tris for a, b in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
    ll = local[loop]
    missing = [(int(loop[k]), int(loop[(k + 1) % len(loop)])) for k in range(len(loop))
               if (min(ll[k], ll[(k + 1) % len(ll)]), max(ll[k], ll[(k + 1) % len(ll)])) not in edges]
    used = np.zeros(len(fine), bool)
    used[tris.ravel()] = True
    outside = fine[~used] if not missing else np.zeros(0, np.int64)
    segments = [local[s[on[s]]] for s in mf.boundary_segments]
    mesh = PieceMesh(mf.piece, uv, tris, segments, local[loop], mesh_quality(uv, tris), mf.hierarchy, mf.level)
    return mesh, fine, missing, outside


def _orient(uv: np.ndarray, tris: np.ndarray) -> np.ndarray:
    p = uv[tris]
    a, b = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]


def fold_marks(x: np.ndarray, triangles: np.ndarray, angle: float) -> np.ndarray:
    """(t,) bool: the triangles (t, 3) with a dihedral angle above `angle` [deg] across any of their edges
    shared with one other triangle, at positions x (n, 3) [m]."""
    n = np.cross(x[triangles[:, 1]] - x[triangles[:, 0]], x[triangles[:, 2]] - x[triangles[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    e = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(len(triangles)), 3)
    order = np.lexsort((e[:, 1], e[:, 0]))
    e, owner = e[order], owner[order]
    same = np.all(e[1:] == e[:-1], axis=1)
    a, b = owner[:-1][same], owner[1:][same]
    bent = np.degrees(np.arccos(np.clip((n[a] * n[b]).sum(axis=1), -1.0, 1.0))) > angle
    marked = np.zeros(len(triangles), bool)
    marked[a[bent]] = marked[b[bent]] = True
    return marked
