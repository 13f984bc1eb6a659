"""Cloth self-collision: point-triangle and edge-edge proximity through a hashed voxel grid, for a cloth whose
triangles may change (a seam merge, a 4-8 level switch).

Each step the triangles are binned by their boxes swept from the start to the end of the step (the cloth moves,
so the grid is hashed and rebuilt every step), and every particle and every edge gathers the triangles near its own
swept box once. Then up to `passes` Jacobi passes over the gathered pairs (until one finds no contact):
  point-triangle: particle p and a triangle not incident to it, p's closest point c on the triangle within half a
    thickness of the triangle's outline in its plane, and d0, d1 = p's height above the triangle's plane at the
    start and the end of the step. The side is d0's (the layers' order before the step); a pair closer than the
    thickness on that side, or one that changed sides (it crossed within the step), is a contact, if the relative
    motion could have carried it there (|d0|, |d1| within the thickness plus the relative motion).
  edge-edge: two edges that share no vertex, with closest points at parameters (s, t) inside both; the side is
    the direction between the closest points at the start of the step, the gap the end separation along it.
A contact moves its four particles apart along the side's normal until the gap is the thickness, each by its
inverse mass and barycentric weight (the point and the triangle's point, or the two edges' points, move apart by
the missing gap and momentum is conserved: Bridson, Fedkiw and Anderson 2002 section 7.1), and an inelastic
impulse removes the approaching relative normal velocity, with Coulomb friction on the tangential part. The
corrections of all the contacts of a particle are averaged (Jacobi), so a few passes settle a stack of layers.
The bodies resolve first: a particle they hold (a contact recorded this step) is not pushed into the body here, so
a layer on a layer on the body moves away from the body, never into it.
While the pieces of a garment are apart, a seam particle ignores the triangles and edges of the other seam
particles, so that the seams can close.
"""
import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock, fill_prefix
from clothbase.meshes import edges_of

from .base import ParticleCollider
from .geometry import barycentric, closest_point_on_triangle, closest_segment_params
from .grid import VoxelGrid

#: the point-triangle test reaches this fraction of the thickness beyond the triangle's outline (so that a particle
#: right above a shared edge or vertex is caught by the triangles around it, whatever the round-off)
OUTLINE_SLACK = 0.5


@ti.data_oriented
class SelfCollision(ParticleCollider):
    """The cloth against its own triangles, which may change during a run (a seam merge, a level switch).

    triangles:      the cloth's (T,) ivec3 i32 field (capacity-sized) and n_triangles its 0-d i32 live count;
                    the grid reads them every step, so it follows the model's refills
    shapes:         (positions (P,3) [m], triangles (T,3)) of every mesh the cloth can take, the one in use
                    first (its levels, or the garment as placed): the grid and the edge fields are sized for the
                    largest
    thickness [m]:  default a quarter of the mean rest edge of the mesh in use; a level switch re-derives it
    seam_particles: (k,) particle ids that sewing pulls together: while the pieces are apart (the first shape's
                    particle count), pairs with seam particles on both sides are skipped
    friction:       Coulomb coefficient between layers; cell_size [m] (default 1.5 x the finest mesh's mean rest
                    edge); max_candidates: triangles gathered per particle, edges per edge (more are ignored and
                    counted); passes: Jacobi passes per step at most
    """

    def __init__(self, triangles, n_triangles, shapes, thickness: float | None = None, friction: float = 0.1,
                 cell_size: float | None = None, max_candidates: int = 96, passes: int = 3, seam_particles=()):
        shapes = [(np.asarray(x, dtype=np.float64), np.asarray(t, dtype=np.int64)) for x, t in shapes]
        if not shapes or any(len(t) == 0 for _, t in shapes):
            raise ValueError("self-collision needs a cloth with triangles")
        if thickness is not None and not thickness > 0:
            raise ValueError(f"self-collision thickness must be > 0 m, got {thickness}")
        if not friction >= 0:
            raise ValueError(f"self-collision friction must be >= 0, got {friction}")
        self.fixed_thickness = None if thickness is None else float(thickness)
        self.friction, self.passes = float(friction), int(passes)
        self.max_candidates = int(max_candidates)
        self.triangles, self.n_triangles = triangles, n_triangles
        self.shapes = shapes
        self.thickness = self._thickness_for(*shapes[0])
        self.cell_size = float(cell_size) if cell_size else 1.5 * min(_mean_edge(x, t) for x, t in shapes)
        self.seam_particles = np.asarray(seam_particles, dtype=np.int64)
        self.edge_capacity = max(len(edges_of(t)[0]) for _, t in shapes)
        blk = FieldBlock()
        # vertex-triangle candidates, edge candidates, point-triangle contacts, edge-edge contacts, overflows
        self.counters = blk.scalar(ti.i64, 5)
        self.tau = blk.scalar(ti.f32, ())
        self.n_edges = blk.scalar(ti.i32, ())
        self.pass_contacts = blk.scalar(ti.i32, ())
        blk.finalize(self)
        self.tau[None] = self.thickness

    def _thickness_for(self, x: np.ndarray, t: np.ndarray) -> float:
        return self.fixed_thickness if self.fixed_thickness is not None else 0.25 * _mean_edge(x, t)

    def _on_attach(self) -> None:
        # cloth-cloth contacts are not handed to the solver: contact_normal holds the bodies' contacts, read only
        P, E, T, K = self.x.shape[0], self.edge_capacity, self.triangles.shape[0], self.max_candidates
        blk = FieldBlock()
        self.cand = blk.scalar(ti.i32, (P, K))  # triangles near each particle
        self.n_cand = blk.scalar(ti.i32, P)
        self.edge_cand = blk.scalar(ti.i32, (E, K))  # edges near each edge (with a higher id)
        self.n_edge_cand = blk.scalar(ti.i32, E)
        self.edges = blk.vector(2, ti.i32, E)
        self.triangle_edges = blk.vector(3, ti.i32, T)
        self.box_lo = blk.vector(3, ti.f32, T)  # the triangles' padded swept boxes [m] of this step
        self.box_hi = blk.vector(3, ti.f32, T)
        self.on_seam = blk.scalar(ti.i8, P)
        self.dx = blk.vector(3, self.x.dtype, P)
        self.dv = blk.vector(3, self.x.dtype, P)
        self.hits = blk.scalar(ti.i32, P)
        blk.finalize(self)
        self.topology_changed(*self.shapes[0])
        # sized by the shape with the most (triangle, cell) pairs; built on boxes swept from x_start to x
        x_np, t_np = max(self.shapes, key=lambda s: len(s[1]) * _mean_edge(*s) ** 2)
        self.grid = VoxelGrid(self.x, self.triangles, self.n_triangles, self.cell_size,
                              pad=max(self._thickness_for(x, t) for x, t in self.shapes), margin=0.0,
                              vertices_np=x_np, triangles_np=t_np, hashed=True, vertices_start=self.x_start,
                              serial=self.serial)

    def topology_changed(self, positions: np.ndarray, triangles: np.ndarray) -> None:
        """The cloth took another mesh ((P,3) rest positions [m], (T,3) triangles): its edges, the seam flags (set
        only while the pieces are apart) and the default thickness follow."""
        t = np.asarray(triangles, dtype=np.int64)
        edges, face_edge, _ = edges_of(t)
        if len(edges) > self.edge_capacity:
            raise ValueError(f"self-collision: the cloth has {len(edges)} edges, capacity {self.edge_capacity} "
                             "(give every mesh the cloth can take in `shapes`)")
        fill_prefix(self.edges, edges.astype(np.int32))
        fill_prefix(self.triangle_edges, face_edge.astype(np.int32))
        self.n_edges[None] = len(edges)
        flags = np.zeros(self.x.shape[0], dtype=np.int8)
        if len(positions) == len(self.shapes[0][0]) and len(self.seam_particles):
            flags[self.seam_particles] = 1
        self.on_seam.from_numpy(flags)
        self.thickness = self._thickness_for(np.asarray(positions, dtype=np.float64), t)
        self.tau[None] = self.thickness

    def resolve(self, dt: float) -> None:
        self.grid.build()
        self._gather()
        for _ in range(self.passes):
            if self._pass() == 0:  # nothing touched: the later passes would find nothing either
                break

    def counter_values(self) -> dict:
        names = ("candidates", "edge candidates", "point-triangle contacts", "edge-edge contacts",
                 "candidate_overflows")
        return dict(zip(names, (int(c) for c in self.counters.to_numpy())))

    # ------------------------------------------------------------------ candidates
    @ti.func
    def _add(self, cand: ti.template(), row, n, item):
        """Append `item` to cand[row, :n] unless it is there; returns the new count (overflows are counted)."""
        seen = False
        for k in range(n):
            if cand[row, k] == item:
                seen = True
                break
        out = n
        if not seen:
            if n < self.max_candidates:
                cand[row, n] = item
                out = n + 1
            else:
                ti.atomic_add(self.counters[4], 1)
        return out

    @ti.func
    def _collect(self, lo, hi, row, cand: ti.template(), skip_a, skip_b, edges: ti.template()):
        """Gather into cand[row, :] the triangles whose padded swept boxes meet box [lo, hi] and have neither vertex
        skip_a nor skip_b, or with `edges`, the edges above `row` of those triangles; returns how many."""
        cmin, cmax = self.grid.clamp_range(lo, hi)
        n = 0
        for a, b, c in ti.ndrange((cmin[0], cmax[0] + 1), (cmin[1], cmax[1] + 1), (cmin[2], cmax[2] + 1)):
            cell = self.grid.cell_index(ti.Vector([a, b, c]))
            for e in range(self.grid.cell_start[cell], self.grid.cell_start[cell + 1]):
                t = self.grid.cell_triangles[e]
                tri = self.triangles[t]
                # hash collisions and cell corners bring far ones
                if (all(self.box_lo[t] <= hi) and all(lo <= self.box_hi[t]) and tri[0] != skip_a
                        and tri[1] != skip_a and tri[2] != skip_a and tri[0] != skip_b and tri[1] != skip_b
                        and tri[2] != skip_b):
                    if ti.static(edges):
                        for j in ti.static(range(3)):
                            f = self.triangle_edges[t][j]
                            if f > row:  # each pair once
                                n = self._add(cand, row, n, f)
                    else:
                        n = self._add(cand, row, n, t)
        return n

    @ti.kernel
    def _gather(self):
        # in parallel even on a small cloth: a few milliseconds of work, against a dispatch of ~0.1 ms
        tau = ti.cast(self.tau[None], ti.f32)
        for t in range(self.n_triangles[None]):
            self.box_lo[t], self.box_hi[t] = self.grid.triangle_box(t)
        for i in range(self.n_particles[None]):
            p0, p1 = ti.cast(self.x_start[i], ti.f32), ti.cast(self.x[i], ti.f32)
            n = self._collect(ti.min(p0, p1) - tau, ti.max(p0, p1) + tau, i, self.cand, i, i, False)
            self.n_cand[i] = n
            ti.atomic_add(self.counters[0], n)
        for e in range(self.n_edges[None]):
            # edges within one ring of the edge's ends are its neighbours, not its contacts
            ab = self.edges[e]
            lo = ti.min(self.x_start[ab[0]], self.x_start[ab[1]], self.x[ab[0]], self.x[ab[1]])
            hi = ti.max(self.x_start[ab[0]], self.x_start[ab[1]], self.x[ab[0]], self.x[ab[1]])
            n = self._collect(ti.cast(lo, ti.f32) - tau, ti.cast(hi, ti.f32) + tau, e, self.edge_cand, ab[0], ab[1],
                              True)
            self.n_edge_cand[e] = n
            ti.atomic_add(self.counters[1], n)

    # ------------------------------------------------------------------ the response
    @ti.func
    def _mobility(self, i, push):
        """Particle i's inverse mass for a response that pushes it along `push`: 0 when a body collider holds it
        this step and `push` heads into that body (a layer on a layer on the body moves away from the body; the
        body's contact stays)."""
        out = ti.cast(self.inv_mass[i], self.x.dtype)
        if ti.static(self.records_contacts):
            if push.dot(ti.cast(self.contact_normal[i], self.x.dtype)) < 0:
                out = 0.0
        return out

    @ti.func
    def _push(self, ids, w, n, depth, friction):
        """Move particles ids (4,) with weights w (4,) (the point of contact on each side is sum w_k x_k, w > 0 on
        the side that normal n points to, w < 0 on the other) apart along n by `depth`, and remove their
        approaching relative velocity along n (inelastic) with Coulomb friction on the rest."""
        im = ti.Vector([self._mobility(ids[k], w[k] * n) for k in ti.static(range(4))], self.x.dtype)
        # no particle moves more than the gap it closes: a contact whose only free particle has a small weight
        # (the rest held by a body or a pin) would otherwise throw it by depth / weight
        den = ti.max((w * w * im).sum(), (ti.abs(w) * im).max())
        if den > 0:
            lam = depth / den
            v_rel = ti.Vector.zero(self.x.dtype, 3)
            for k in ti.static(range(4)):
                v_rel += w[k] * self.v[ids[k]]
            vn = v_rel.dot(n)
            impulse = ti.Vector.zero(self.x.dtype, 3)
            if vn < 0:
                vt = v_rel - vn * n
                vt_len = vt.norm()
                impulse = -vn / den * n
                if vt_len > 0:
                    impulse -= ti.min(friction * (-vn), vt_len) / den * vt / vt_len
            for k in ti.static(range(4)):
                if w[k] != 0:
                    self.dx[ids[k]] += w[k] * im[k] * lam * n
                    self.dv[ids[k]] += w[k] * im[k] * impulse
                    ti.atomic_add(self.hits[ids[k]], 1)

    @ti.func
    def _seams_meet(self, a, b):
        """Whether a pair of features with seam particles on both sides is skipped (the pieces are apart)."""
        return a != 0 and b != 0

    @ti.func
    def _point_triangle(self, i, t, tau, friction):
        tri = self.triangles[t]
        p0, p1 = self.x_start[i], self.x[i]
        a0, b0, c0 = self.x_start[tri[0]], self.x_start[tri[1]], self.x_start[tri[2]]
        a1, b1, c1 = self.x[tri[0]], self.x[tri[1]], self.x[tri[2]]
        n0 = (b0 - a0).cross(c0 - a0).normalized(1e-20)
        n1 = (b1 - a1).cross(c1 - a1).normalized(1e-20)
        d0 = (p0 - a0).dot(n0)
        d1 = (p1 - a1).dot(n1)
        side = 1.0 if d0 >= 0 else -1.0
        if ti.abs(d0) < 1e-12:
            side = 1.0 if d1 >= 0 else -1.0
        # only a particle the relative motion could have carried to the plane counts: a far one can change sides
        # just because the triangle turned
        reach = tau + ((p1 - p0) - (a1 + b1 + c1 - a0 - b0 - c0) / 3.0).norm()
        if side * d1 < tau and ti.abs(d0) <= reach and ti.abs(d1) <= reach:
            c = closest_point_on_triangle(p1, a1, b1, c1)
            off = (p1 - c) - (p1 - c).dot(n1) * n1
            if off.norm() <= OUTLINE_SLACK * tau:
                bary = barycentric(c, a1, b1, c1)
                ids = ti.Vector([i, tri[0], tri[1], tri[2]])
                w = ti.Vector([1.0, -bary[0], -bary[1], -bary[2]], self.x.dtype)
                self._push(ids, w, side * n1, tau - side * d1, friction)
                ti.atomic_add(self.counters[2], 1)
                ti.atomic_add(self.pass_contacts[None], 1)

    @ti.func
    def _edge_edge(self, e, f, tau, friction):
        pa, pb = self.edges[e]
        qa, qb = self.edges[f]
        s, u = closest_segment_params(self.x[pa], self.x[pb], self.x[qa], self.x[qb])
        inner = 1e-3
        if s > inner and s < 1 - inner and u > inner and u < 1 - inner:
            x0, x1 = ti.static(self.x_start, self.x)
            start = (1 - u) * x0[qa] + u * x0[qb] - (1 - s) * x0[pa] - s * x0[pb]
            end = (1 - u) * x1[qa] + u * x1[qb] - (1 - s) * x1[pa] - s * x1[pb]
            dist0 = start.norm()
            if dist0 > 1e-9:
                n = start / dist0
                gap = end.dot(n)
                reach = tau + (end - start).norm()
                if gap < tau and dist0 <= reach and end.norm() <= reach:
                    ids = ti.Vector([qa, qb, pa, pb])
                    w = ti.Vector([1 - u, u, -(1 - s), -s], self.x.dtype)
                    self._push(ids, w, n, tau - gap, friction)
                    ti.atomic_add(self.counters[3], 1)
                    ti.atomic_add(self.pass_contacts[None], 1)

    @ti.kernel
    def _pass(self) -> ti.i32:
        """One Jacobi pass over the gathered pairs; returns how many contacts it found."""
        tau = ti.cast(self.tau[None], self.x.dtype)
        friction = ti.cast(self.friction, self.x.dtype)
        self.pass_contacts[None] = 0
        ti.loop_config(serialize=self.serial)
        for i in range(self.n_particles[None]):
            self.dx[i] = ti.Vector.zero(self.x.dtype, 3)
            self.dv[i] = ti.Vector.zero(self.x.dtype, 3)
            self.hits[i] = 0
        ti.loop_config(serialize=self.serial)
        for i in range(self.n_particles[None]):
            for k in range(self.n_cand[i]):
                t = self.cand[i, k]
                tri = self.triangles[t]
                seams = self.on_seam[tri[0]] + self.on_seam[tri[1]] + self.on_seam[tri[2]]
                if not self._seams_meet(self.on_seam[i], seams):
                    self._point_triangle(i, t, tau, friction)
        ti.loop_config(serialize=self.serial)
        for e in range(self.n_edges[None]):
            ab = self.edges[e]
            for k in range(self.n_edge_cand[e]):
                f = self.edge_cand[e, k]
                cd = self.edges[f]
                if not self._seams_meet(self.on_seam[ab[0]] + self.on_seam[ab[1]],
                                        self.on_seam[cd[0]] + self.on_seam[cd[1]]):
                    self._edge_edge(e, f, tau, friction)
        ti.loop_config(serialize=self.serial)
        for i in range(self.n_particles[None]):
            if self.hits[i] > 0:
                self.x[i] += self.dx[i] / self.hits[i]
                self.v[i] += self.dv[i] / self.hits[i]
        return self.pass_contacts[None]

    def describe(self) -> dict:
        return {"kind": "self"}


def _mean_edge(x: np.ndarray, t: np.ndarray) -> float:
    """Mean edge length [m] of triangles t (T,3) over positions x (P,3)."""
    return float(np.linalg.norm(x[t] - x[t[:, [1, 2, 0]]], axis=2).mean())

