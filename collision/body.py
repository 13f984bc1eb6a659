"""Cloth particles against a triangle body: voxel grid + fuzzy-ranked continuous collision (Hsiao 2006 section 2.3).

Per step, each particle's motion segment p (start of step) -> q (after the integrator) gathers the triangles of
the voxels its box (inflated by the thickness) touches. Each candidate gets the collision possibility
mu = clamp(-(q - p).n / |q - p|, 0, 1) (docs/algorithms.md, collision), set to 0 when the motion cannot reach the face's plane
this step; triangles it moves along or away from, or cannot reach (mu = 0), are never crossing-tested. The rest are tested with the Fan et al. 1998 eq. (15) segment test:
  mode "fuzzy" (Hsiao 2006's): in descending mu, accept the first hit;
  mode "exact":              test every mu > 0 candidate and take the earliest hit.
Whatever mu is, a proximity test keeps resting contact: a particle closer than the thickness to its nearest
candidate face (closest point on the triangle, so edges and vertices count) is pushed away from that point
to the thickness; only a point projecting into a face can be found behind it. A crossing puts the end point at the thickness above the crossed face's plane. Then the
inward normal velocity is removed (restitution 0) and Coulomb friction scales the tangential velocity
(Bridson et al. 2002). Counters record the crossing tests done and the tests that
testing every candidate would have cost.
"""
import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock
from clothbase.meshes import validate_triangle_mesh

from .base import BAND_HELD, ParticleCollider
from .geometry import (barycentric, carry_point, closest_point_on_triangle, collision_possibility, inside_triangle,
                       segment_triangle, solid_angle)
from .grid import VoxelGrid, pairs_bound

MODES = ("fuzzy", "exact")
_CANDIDATES, _TESTS, _HITS, _CONTACTS, _OVERFLOW, _QUERIES = range(6)
COUNTER_NAMES = ("candidates", "crossing_tests", "crossings", "proximity_contacts", "candidate_overflows",
                 "queries")


@ti.data_oriented
class MeshCollider(ParticleCollider):
    """A triangle body (e.g. the mannequin) that cloth particles cannot pass.

    vertices (V,3) [m] and triangles (T,3) with outward-facing winding; thickness [m]: the cloth keeps this
    distance from the surface; friction: Coulomb coefficient; cell_size [m]: voxel edge (default 1.5 x the
    mean edge length, 2 x for a deforming body); max_step [m]: the largest particle motion per step the grid margin allows for; mode:
    "fuzzy" or "exact"; max_candidates: per-particle candidate list length (a particle with more has its cells
    scanned unranked instead, and counted as overflows); passes: detection passes per step (a particle moved
    out of a crossing is checked again); reach_gate: also give mu = 0 to faces whose plane the motion cannot reach this step (off:
    the direction alone decides, for measuring what the gate saves); repulsion: None, or Repulsion keyword
    arguments (stiffness, distance, max_force) to add Fan et al. 1998's repulsion force; motion: a scripted rigid
    motion of the body (clothbase.keyframes.RigidMotion: its tests run in the body's frame as built, on each
    particle's motion relative to it, so the grid is never rebuilt), or None; sequence: a deforming body
    (clothbase.sequences.MeshSequence, whose first frame `vertices` and `triangles` are), posed on the device
    before every step from `start` [s] (or "sewn": once `ready()` is true), or None. A deforming body's grid bins
    each triangle's box over a window of frames, refilled on the device when a step leaves it; each particle's
    start point is carried with each candidate triangle (geometry.carry_point), so the tests run on its motion
    relative to the surface there, and a contact takes the surface's velocity at its closest point.

    Fields: vertices (V,) vec3 f32 (a deforming body: at the end of the step; vertices_start at its start),
    triangles (T,) ivec3, normals (T,) unit vec3 f32, counters (6,) i64.
    """

    def __init__(self, vertices, triangles, thickness: float = 0.003, friction: float = 0.3,
                 cell_size: float | None = None, max_step: float = 0.05, mode: str = "fuzzy",
                 max_candidates: int = 256, passes: int = 2, reach_gate: bool = True, repulsion: dict | None = None,
                 source: str = "body", motion=None, sequence=None, start=0.0):
        v = np.asarray(vertices, dtype=np.float64)
        t = np.asarray(triangles, dtype=np.int64)
        validate_triangle_mesh(v, t, source)
        if mode not in MODES:
            raise ValueError(f"collision mode must be one of {', '.join(MODES)}, got {mode!r}")
        if not thickness > 0:
            raise ValueError(f"collision thickness must be > 0 m, got {thickness}")
        if friction < 0:
            raise ValueError(f"friction must be >= 0, got {friction}")
        if (motion is not None or sequence is not None) and repulsion:
            raise ValueError(f"{source}: a moving body has no repulsion force (give it keyframes or repulsion)")
        if motion is not None and sequence is not None:
            raise ValueError(f"{source}: a mesh sequence moves itself: give it no keyframes or rotation")
        if sequence is not None and (sequence.frames.shape[1] != len(v) or not np.array_equal(sequence.triangles, t)):
            raise ValueError(f"{source}: the vertices and triangles must be the sequence's first frame")
        if start != "sewn" and not (isinstance(start, (int, float)) and start >= 0):
            raise ValueError(f"{source}: start must be a time >= 0 s or 'sewn', got {start!r}")
        self.source, self.mode, self.motion = source, mode, motion
        self.sequence, self.start, self.ready = sequence, start, None
        self.begin = None if start == "sewn" else float(start)  # [s] the run time at which the sequence starts
        self.deforming = sequence is not None
        self.thickness, self.friction, self.passes = float(thickness), float(friction), int(passes)
        self.max_candidates = int(max_candidates)
        self.reach_gate = bool(reach_gate)
        self.n_vertices, self.n_tri = len(v), len(t)
        self.triangles_np = t
        edges = np.linalg.norm(v[t] - v[t[:, [1, 2, 0]]], axis=2)
        self.mean_edge = float(edges.mean())
        # a deforming body refills its grid as it moves: larger cells (fewer to scan and fill) pay for the few more
        # candidates they hold (the mannequin's clip: 1.3 instead of 2.0 ms a step posing, 1.4 instead of 1.3 colliding)
        self.cell_size = float(cell_size) if cell_size else (2.0 if sequence is not None else 1.5) * self.mean_edge
        blk = FieldBlock()
        self.vertices = blk.vector(3, ti.f32, len(v))
        self.triangles = blk.vector(3, ti.i32, len(t))
        self.normals = blk.vector(3, ti.f32, len(t))
        self.n_triangles = blk.scalar(ti.i32, ())
        self.counters = blk.scalar(ti.i64, 6)
        self.vertices_start = self.frames = self.sweep = self.box_lo = self.box_hi = None
        if self.deforming:
            self.vertices_start = blk.vector(3, ti.f32, len(v))
            # each vertex's box over the frames of the window the grid was built for: lo, hi [m]
            self.box_lo = blk.vector(3, ti.f32, len(v))
            self.box_hi = blk.vector(3, ti.f32, len(v))
            self.frames = blk.vector(3, ti.f32, (sequence.n_frames, len(v)))
            self.sweep = blk.scalar(ti.f32, ())  # [m] the farthest a vertex moves in the step
        blk.finalize(self)
        self.vertices.from_numpy(v.astype(np.float32))
        self.triangles.from_numpy(t.astype(np.int32))
        self.n_triangles[None] = len(t)
        self._compute_normals()
        grid = {}
        if self.deforming:
            self.frames.from_numpy(sequence.frames.astype(np.float32))
            self.vertices_start.copy_from(self.vertices)
            self.box_lo.copy_from(self.vertices)
            self.box_hi.copy_from(self.vertices)
            travel = float(np.linalg.norm(np.diff(sequence.frames, axis=0), axis=2).max()) if len(sequence.frames) > 1 \
                else 0.0  # the most a vertex moves between two frames
            capacity = max(pairs_bound(f, t, self.cell_size, self.thickness, True, travel) for f in sequence.frames)
            grid = dict(vertices_start=self.box_lo, bounds=sequence.bounds(), capacity=int(capacity) + 64)
        # a deforming body bins its triangles over a window of its frames (box_lo..box_hi), refilled when a step
        # leaves it: with a sequence of 30 frames/s and steps of 1/120 s, every fourth step
        self.grid = VoxelGrid(self.box_hi if self.deforming else self.vertices, self.triangles, self.n_triangles,
                              self.cell_size, pad=self.thickness, margin=self.thickness + max_step, vertices_np=v,
                              triangles_np=t, **grid)
        self._vertices_np = v
        self._posed = None  # a deforming body: the (frame, weight) pair of the last pose
        self._window = (0, 0)  # the frames the grid's boxes span
        self._attached = False
        self.repulsion = Repulsion(self, **repulsion) if repulsion else None
        self._last_distance = None  # (vertices_np, points, signed distances) of the last signed_distance call

    # ------------------------------------------------------------------ body motion
    @property
    def vertices_np(self) -> np.ndarray:
        """The body's vertices now (V,3) float64 [m] (a deforming body: at the last step's end)."""
        if self.deforming and self._vertices_np is None:
            self._vertices_np = self.sequence.at(self.t_pose)
        return self._vertices_np

    @property
    def animated(self) -> bool:
        return self.motion is not None or self.deforming

    def set_vertices(self, vertices) -> None:
        """Move or morph the body (same topology) [m]: refreshes normals and rebuilds the grid."""
        if self.deforming:
            raise ValueError(f"{self.source}: a mesh sequence poses itself (its frames give the vertices)")
        v = np.asarray(vertices, dtype=np.float64)
        if v.shape != (self.n_vertices, 3):
            raise ValueError(f"{self.source}: expected {self.n_vertices} vertices, got {v.shape}")
        self._vertices_np = v
        self.vertices.from_numpy(v.astype(np.float32))
        self._compute_normals()
        self.grid.build(v)

    def move(self, t0: float, t1: float) -> None:
        """The poses of a step from t0 to t1 [s]: a rigid motion's (ParticleCollider.move), or a deforming body's
        frames at both ends, interpolated on the device, its normals and its grid refilled (no read)."""
        if not self.deforming:
            super().move(t0, t1)
            return
        if self.begin is None and t1 > t0 and (self.ready is None or self.ready()):
            self.begin = t0
        s0, s1 = (t0 - self.begin, t1 - self.begin) if self.begin is not None else (0.0, 0.0)
        self.t_pose = s1
        key = (self.sequence.position(s0), self.sequence.position(s1))
        if key == self._posed:
            return  # held: nothing moves (before the start, after the end)
        self._posed = key
        self._vertices_np = None
        (k0, w0), (k1, w1) = key
        self._pose(k0, w0, k1, w1, 1.0 / (t1 - t0) if t1 > t0 else 0.0)
        window = (k0, min(k1 + 1, self.sequence.n_frames - 1) if w1 > 0 else k1)
        if not (self._window[0] <= window[0] and window[1] <= self._window[1]):
            self._window = window
            self._bin_window(*window)
            self.grid.rebuild()

    def rewind(self) -> None:
        """Back to t = 0: the body where it starts (a deforming body waits for its start again)."""
        if self.deforming:
            self.begin = None if self.start == "sewn" else float(self.start)
            self._posed = None
            self._window = (-1, -1)  # binned again
        self.move(0.0, 0.0)

    @ti.kernel
    def _pose(self, k0: ti.i32, w0: ti.f32, k1: ti.i32, w1: ti.f32, inv_dt: ti.f64):
        """A deforming body at the start (frame k0 and the next, weight w0) and the end (k1, w1) of the step; inv_dt
        [1/s] of the step (surface velocities)."""
        self.inv_dt[None] = inv_dt
        self.sweep[None] = 0.0
        last = self.frames.shape[0] - 1
        for v in range(self.n_vertices):
            a = (1.0 - w0) * self.frames[k0, v] + w0 * self.frames[ti.min(k0 + 1, last), v]
            b = (1.0 - w1) * self.frames[k1, v] + w1 * self.frames[ti.min(k1 + 1, last), v]
            self.vertices_start[v] = a
            self.vertices[v] = b
            ti.atomic_max(self.sweep[None], (b - a).norm())  # a maximum: the same whatever the threads' order
        self.normals_pass()

    @ti.kernel
    def _bin_window(self, first: ti.i32, last: ti.i32):
        """Each vertex's box over frames first..last (the grid's triangle boxes; a vertex's path between two frames
        is the straight line between them, so the box of the frames holds every pose in between)."""
        for v in range(self.n_vertices):
            lo = self.frames[first, v]
            hi = lo
            for k in range(first + 1, last + 1):
                lo = ti.min(lo, self.frames[k, v])
                hi = ti.max(hi, self.frames[k, v])
            self.box_lo[v] = lo
            self.box_hi[v] = hi

    @ti.kernel
    def _compute_normals(self):
        self.normals_pass()

    @ti.func
    def normals_pass(self):
        ti.loop_config(serialize=self.serial)
        for t in range(self.n_triangles[None]):
            c = self.triangles[t]
            a = self.vertices[c[0]]
            self.normals[t] = (self.vertices[c[1]] - a).cross(self.vertices[c[2]] - a).normalized(1e-20)

    # ------------------------------------------------------------------ the cloth side
    def _on_attach(self) -> None:
        P = self.x.shape[0]
        blk = FieldBlock()
        self.cand = blk.scalar(ti.i32, (P, self.max_candidates))
        self.cand_mu = blk.scalar(ti.f32, (P, self.max_candidates))
        blk.finalize(self)

    def resolve(self, dt: float) -> None:
        """After the step: find crossings and contacts of every particle and respond (positions, velocities)."""
        self._resolve(self.thickness, self.friction)

    @property
    def report_slots(self) -> int:
        """A deforming body's grid reports the most (triangle, cell) pairs its rebuilds asked for with the frame's
        measurement (its one read)."""
        return 1 if self.deforming else 0

    def report(self, out, offset: int) -> None:
        self.grid.report(out, offset)

    def reported(self, values) -> None:
        self.grid.reported(values)

    def reset_counters(self) -> None:
        self.counters.fill(0)

    def counter_values(self) -> dict:
        return dict(zip(COUNTER_NAMES, (int(c) for c in self.counters.to_numpy())))

    @ti.func
    def _collect(self, i, p, q):
        """Candidates of particle i for segment p -> q into cand[i, :]; returns (count, overflowed)."""
        tau = ti.cast(self.thickness, self.x.dtype)
        lo = ti.min(p, q) - tau
        hi = ti.max(p, q) + tau
        cmin, cmax = self.grid.clamp_range(ti.cast(lo, ti.f32), ti.cast(hi, ti.f32))
        motion = ti.cast(q - p, ti.f32)
        n = 0
        overflow = 0
        for a, b, c in ti.ndrange((cmin[0], cmax[0] + 1), (cmin[1], cmax[1] + 1), (cmin[2], cmax[2] + 1)):
            cell = self.grid.cell_index(ti.Vector([a, b, c]))
            for e in range(self.grid.cell_start[cell], self.grid.cell_start[cell + 1]):
                t = self.grid.cell_triangles[e]
                seen = False
                for k in range(n):
                    if self.cand[i, k] == t:
                        seen = True
                        break
                if not seen:
                    if n < self.max_candidates:
                        nrm = self.normals[t]
                        start = self._carried(t, ti.cast(p, ti.f32))
                        height = (start - self.vertices[self.triangles[t][0]]).dot(nrm)
                        relative = motion
                        if ti.static(self.deforming):
                            relative = ti.cast(q, ti.f32) - start
                        self.cand[i, n] = t
                        self.cand_mu[i, n] = collision_possibility(height, relative, nrm, self.reach_gate)
                        n += 1
                    else:
                        overflow = 1
        return n, overflow

    @ti.func
    def _scan_all(self, p, q, reach):
        """Fallback when a candidate list overflowed: every triangle of the touched cells, unranked (duplicates
        across cells are tested again). Returns (crossed triangle or -1, contact triangle or -1, its signed gap,
        push direction, crossing tests, cell entries scanned)."""
        tau = ti.cast(self.thickness, self.x.dtype)
        cmin, cmax = self.grid.clamp_range(ti.cast(ti.min(p, q) - tau, ti.f32), ti.cast(ti.max(p, q) + tau, ti.f32))
        pf = ti.cast(p, ti.f32)
        qf = ti.cast(q, ti.f32)
        hit, best_t, tests, scanned = -1, 2.0, 0, 0
        contact, best_gap, best_dir = -1, ti.cast(1e30, ti.f32), ti.Vector.zero(ti.f32, 3)
        for a, b, c in ti.ndrange((cmin[0], cmax[0] + 1), (cmin[1], cmax[1] + 1), (cmin[2], cmax[2] + 1)):
            cell = self.grid.cell_index(ti.Vector([a, b, c]))
            for e in range(self.grid.cell_start[cell], self.grid.cell_start[cell + 1]):
                t = self.grid.cell_triangles[e]
                scanned += 1
                v0, v1, v2 = self._corners(t)
                nrm = self.normals[t]
                start = self._carried(t, pf)
                if collision_possibility((start - v0).dot(nrm), qf - start, nrm, self.reach_gate) > 0:
                    crossed, s = segment_triangle(start, qf, v0, v1, v2)
                    tests += 1
                    if crossed and s < best_t:
                        hit, best_t = t, s
                contact, best_gap, best_dir = self._proximity(t, qf, reach, contact, best_gap, best_dir)
        return hit, contact, best_gap, best_dir, tests, scanned

    @ti.func
    def _corners(self, t):
        c = self.triangles[t]
        return self.vertices[c[0]], self.vertices[c[1]], self.vertices[c[2]]

    @ti.func
    def _carried(self, t, p):
        """The step's start point p (f32) of a particle, carried with triangle t to the step's end (a deforming
        body; p itself for a body that keeps its shape): its motion relative to the triangle ends at q."""
        out = p
        if ti.static(self.deforming):
            c = self.triangles[t]
            out = carry_point(p, self.vertices_start[c[0]], self.vertices_start[c[1]], self.vertices_start[c[2]],
                              self.vertices[c[0]], self.vertices[c[1]], self.vertices[c[2]])
        return out

    @ti.func
    def _velocity_at(self, t, x):
        """A deforming body's velocity [m/s] over the step at the point of triangle t closest to x (f32): its
        corners' velocities by the barycentric weights of that point."""
        c = self.triangles[t]
        a, b, cc = self._corners(t)
        w = barycentric(closest_point_on_triangle(x, a, b, cc), a, b, cc)
        moved = w[0] * (a - self.vertices_start[c[0]]) + w[1] * (b - self.vertices_start[c[1]]) + \
            w[2] * (cc - self.vertices_start[c[2]])
        return ti.cast(moved, ti.f64) * self.inv_dt[None]

    @ti.func
    def _crossing(self, i, n, p, q):
        """The crossing of segment p -> q chosen by the mode among the n candidates: (triangle or -1, tests)."""
        pf = ti.cast(p, ti.f32)
        qf = ti.cast(q, ti.f32)
        best = -1
        best_t = 2.0
        tests = 0
        if ti.static(self.mode == "exact"):
            for k in range(n):
                if self.cand_mu[i, k] > 0:
                    t = self.cand[i, k]
                    a, b, c = self._corners(t)
                    hit, s = segment_triangle(self._carried(t, pf), qf, a, b, c)
                    tests += 1
                    if hit and s < best_t:
                        best, best_t = t, s
        else:
            # the published fuzzy order: repeatedly take the most likely untested candidate, stop at the first hit
            for _ in range(n):
                kmax = -1
                mu_max = 0.0
                for k in range(n):
                    if self.cand_mu[i, k] > mu_max:
                        kmax, mu_max = k, self.cand_mu[i, k]
                if kmax < 0:
                    break
                self.cand_mu[i, kmax] = -1.0  # tested
                t = self.cand[i, kmax]
                a, b, c = self._corners(t)
                hit, s = segment_triangle(self._carried(t, pf), qf, a, b, c)
                tests += 1
                if hit:
                    best = t
                    break
        return best, tests

    @ti.func
    def _proximity(self, t, qf, reach, best, best_gap, best_dir):
        """Update the closest contact with triangle t. Its closest point c to q gives the gap |q - c| and the push
        direction (q - c) / |q - c|. Only a point projecting into the face's interior can be behind it (negative
        gap, pushed along the face normal); an edge or vertex closest point counts as outside, since crossings
        into the body are caught by the segment test (a point behind a face's plane near a convex edge is
        usually in front of the neighbouring face)."""
        v0, v1, v2 = self._corners(t)
        nrm = self.normals[t]
        plane = (qf - v0).dot(nrm)
        # the gap is at least the plane distance: far planes are culled before the closest-point computation. The
        # nearest face decides, in front of it or behind: a point just above a thin plate is also behind the plate's
        # underside, and taking that for "inside" pushed it through (a 1 cm slab crossed by every glide)
        if ti.abs(plane) < reach + BAND_HELD * ti.cast(self.thickness, ti.f32):  # reach: at least the thickness
            gap = plane
            direction = nrm
            if not inside_triangle(qf, v0, v1, v2, nrm):
                offset = qf - closest_point_on_triangle(qf, v0, v1, v2)
                gap = offset.norm()
                if gap > 1e-9:
                    direction = offset / gap
            if ti.abs(gap) < ti.abs(best_gap):
                best, best_gap, best_dir = t, gap, direction
        return best, best_gap, best_dir

    @ti.func
    def _nearest_contact(self, i, n, q, reach):
        """Among the n candidates, the closest one to q, in front or behind (within `reach` of its plane):
        (triangle or -1, signed gap [m], push direction)."""
        qf = ti.cast(q, ti.f32)
        best, best_gap, best_dir = -1, ti.cast(1e30, ti.f32), ti.Vector.zero(ti.f32, 3)
        for k in range(n):
            best, best_gap, best_dir = self._proximity(self.cand[i, k], qf, reach, best, best_gap, best_dir)
        return best, best_gap, best_dir

    @ti.kernel
    def _resolve(self, thickness: ti.f64, friction: ti.f64):
        # counters accumulate in kernel locals (reduced per thread), not in contended global atomics
        queries, candidates, overflows, tests_done, crossings, contacts = 0, 0, 0, 0, 0, 0
        ti.loop_config(serialize=self.serial)
        for i in range(self.n_particles[None]):
            if self.inv_mass[i] != 0:
                p = self.x_start[i]
                if ti.static(self.moving):  # the particle's motion relative to the body, in its frame as built
                    p = ti.cast(self.to_rest(0, self.x_start[i]), self.x.dtype)
                for _ in range(self.passes):
                    q = self.x[i]
                    if ti.static(self.moving):
                        q = ti.cast(self.to_rest(1, self.x[i]), self.x.dtype)
                    n, overflow = self._collect(i, p, q)
                    queries += 1
                    candidates += n
                    overflows += overflow
                    if n == 0:
                        break
                    reach = ti.cast(thickness, ti.f32) + ti.cast((q - p).norm(), ti.f32)
                    if ti.static(self.deforming):  # the surface may have come towards the particle too
                        reach += self.sweep[None]
                    hit, tests, near, gap, direction = -1, 0, -1, ti.cast(0.0, ti.f32), ti.Vector.zero(ti.f32, 3)
                    if overflow:
                        scanned = 0
                        hit, near, gap, direction, tests, scanned = self._scan_all(p, q, reach)
                        candidates += scanned - n  # the baseline is every entry
                    else:
                        hit, tests = self._crossing(i, n, p, q)
                        if hit < 0:
                            near, gap, direction = self._nearest_contact(i, n, q, reach)
                    tests_done += tests
                    push = ti.Vector.zero(ti.f32, 3)
                    if hit >= 0:
                        # crossed: the end point goes to the thickness above the crossed face's plane
                        crossings += 1
                        a, b, c = self._corners(hit)
                        direction = self.normals[hit]
                        push = (ti.cast(thickness, ti.f32) - (ti.cast(q, ti.f32) - a).dot(direction)) * direction
                    elif near >= 0 and gap < ti.cast(thickness, ti.f32):
                        # too close: away from the closest point of the surface, to the thickness
                        contacts += 1
                        push = (ti.cast(thickness, ti.f32) - gap) * direction
                    elif near >= 0 and gap < (1 + self.band(i)) * ti.cast(thickness, ti.f32):
                        # within the contact band: a contact for the solve (its friction), nothing to push
                        band_normal = ti.cast(direction, self.x.dtype)
                        resting = ti.Vector.zero(self.x.dtype, 3)  # the body's velocity there
                        if ti.static(self.moving):
                            band_normal = ti.cast(self.turn(1, direction), self.x.dtype)
                            resting = ti.cast(self.surface_velocity(q), self.x.dtype)
                        if ti.static(self.deforming):
                            resting = ti.cast(self._velocity_at(near, ti.cast(q, ti.f32)), self.x.dtype)
                        self.record_contact(i, band_normal, ti.cast(friction, self.x.dtype), resting)
                        break
                    else:
                        break
                    nrm = ti.cast(direction, self.x.dtype)
                    self.x[i] = q + ti.cast(push, self.x.dtype)
                    surface = ti.Vector.zero(self.x.dtype, 3)  # the body's velocity where the particle ends
                    if ti.static(self.moving):
                        end = q + ti.cast(push, self.x.dtype)
                        self.x[i] = ti.cast(self.to_world(1, end), self.x.dtype)
                        nrm = ti.cast(self.turn(1, direction), self.x.dtype)
                        surface = ti.cast(self.surface_velocity(end), self.x.dtype)
                    if ti.static(self.deforming):
                        touched = hit if hit >= 0 else near
                        surface = ti.cast(self._velocity_at(touched, ti.cast(self.x[i], ti.f32)), self.x.dtype)
                    crossed = hit >= 0
                    self.record_contact(i, nrm, ti.cast(friction, self.x.dtype), surface)
                    self.respond(i, nrm, surface, ti.cast(friction, self.x.dtype))
                    if not crossed:
                        break  # a proximity push is local: only a crossing response needs checking again
        self.counters[_QUERIES] += queries
        self.counters[_CANDIDATES] += candidates
        self.counters[_OVERFLOW] += overflows
        self.counters[_TESTS] += tests_done
        self.counters[_HITS] += crossings
        self.counters[_CONTACTS] += contacts

    # ------------------------------------------------------------------ exact queries (tests, metrics)
    def signed_distance(self, points) -> np.ndarray:
        """Signed distance [m] of points (N,3) to the body surface, negative inside: exact point-triangle
        distance, sign from the generalised winding number. Brute force O(N T) in one kernel, for tests and
        end-of-run metrics, never per step: 1.6 s for 5,000 points on the mannequin's 26,756 triangles on the 2-core
        CPU. The last answer is kept, so the end of a run, which asks for the same positions twice (the run
        summary's agreement of stretch limit and body, the garment's quality table), pays once."""
        pts = np.ascontiguousarray(self.rest_points(points), dtype=np.float64).reshape(-1, 3)
        last = self._last_distance
        if last is not None and last[0] is self.vertices_np and np.array_equal(last[1], pts):
            return last[2].copy()
        out = np.zeros(len(pts), np.float64)
        if len(pts):
            self._signed_distance(pts, out)
        self._last_distance = (self.vertices_np, pts.copy(), out.copy())  # set_vertices replaces vertices_np
        return out

    @ti.kernel
    def _signed_distance(self, pts: ti.types.ndarray(dtype=ti.math.vec3, ndim=1),
                         out: ti.types.ndarray(dtype=ti.f64, ndim=1)):
        # parallel whatever the cloth's size: each point is a pass over every triangle of the body
        for k in range(pts.shape[0]):
            p = ti.cast(pts[k], ti.f64)
            best = ti.cast(1e30, ti.f64)
            winding = ti.cast(0.0, ti.f64)
            for t in range(self.n_triangles[None]):
                c = self.triangles[t]
                a = ti.cast(self.vertices[c[0]], ti.f64)
                b = ti.cast(self.vertices[c[1]], ti.f64)
                cc = ti.cast(self.vertices[c[2]], ti.f64)
                best = ti.min(best, (closest_point_on_triangle(p, a, b, cc) - p).norm())
                winding += solid_angle(p, a, b, cc)
            out[k] = -best if winding > 2.0 * 3.141592653589793 else best  # winding number > 1/2

    def describe(self) -> dict:
        """What a recorder needs to draw the body."""
        return {"kind": "mesh", "vertices": self.vertices_np, "triangles": self.triangles_np, "name": self.source}


@ti.data_oriented
class Repulsion:
    """Fan et al. 1998 eq. (5), f_r = c_r exp(1/D) N for D <= d, in a form that neither overflows nor jumps
    (docs/algorithms.md, collision warns that the published form is unit dependent, overflows float32 below 1.1 cm and is
    discontinuous at d). Ours, with D the particle's distance to the nearest face of the body:

        f = min(max_force, stiffness (exp(d / max(D, d/10)) - e)) along the outward direction, for D < d

    so it is 0 at D = d (continuous), unit free (d/D is dimensionless) and bounded (exp(10) at D <= d/10, then
    max_force). A particle found inside the body gets max_force along the face normal. stiffness and max_force
    are in N per particle, distance in m. It acts as a force source: every integrator sees it explicitly (it
    is not in the stable-step bound, so keep it soft: it only supplements the position response)."""

    def __init__(self, body: "MeshCollider", stiffness: float = 1e-3, distance: float = 0.01, max_force: float = 0.05):
        if not (stiffness >= 0 and distance > 0 and max_force > 0):
            raise ValueError(f"repulsion needs stiffness >= 0, distance > 0, max_force > 0; got {stiffness}, "
                             f"{distance}, {max_force}")
        if distance > body.grid.margin:
            raise ValueError(f"repulsion distance {distance} m exceeds the body grid margin {body.grid.margin} m")
        self.body = body
        self.stiffness, self.distance, self.max_force = float(stiffness), float(distance), float(max_force)

    def prepare(self, t: float) -> None:
        pass

    @ti.func
    def force(self, i, xi, vi):
        b = self.body
        x = ti.cast(xi, ti.f32)
        d = ti.cast(self.distance, ti.f32)
        cmin, cmax = b.grid.clamp_range(x - d, x + d)
        best = d
        direction = ti.Vector.zero(ti.f32, 3)
        for a, bb, c in ti.ndrange((cmin[0], cmax[0] + 1), (cmin[1], cmax[1] + 1), (cmin[2], cmax[2] + 1)):
            cell = b.grid.cell_index(ti.Vector([a, bb, c]))
            for e in range(b.grid.cell_start[cell], b.grid.cell_start[cell + 1]):
                t = b.grid.cell_triangles[e]
                v0, v1, v2 = b._corners(t)
                near = closest_point_on_triangle(x, v0, v1, v2)
                gap = (x - near).norm()
                if gap < best:
                    best = gap
                    direction = (x - near) / ti.max(gap, 1e-12)
                    if (x - near).dot(b.normals[t]) < 0:  # inside the body
                        best = 0.0
                        direction = b.normals[t]
        f = ti.Vector.zero(b.x.dtype, 3)
        if best < d:
            e = 2.718281828459045
            mag = ti.min(self.max_force, self.stiffness * (ti.exp(d / ti.max(best, 0.1 * d)) - e))
            f = ti.cast(mag * direction, b.x.dtype)
        return f
