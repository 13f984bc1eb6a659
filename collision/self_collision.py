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

The passes keep the layers a thickness apart but guarantee nothing: a fast or crowded contact can still cross
within a step. So the step ends with the continuous stage (`continuous`, on by default), which keeps a step that
starts intersection-free intersection-free:
  1. every gathered pair (point-triangle, edge-edge) is tested along the straight-line motion from the start of
     the step by additive CCD (collision.ccd): a pair closes if it would come closer than FLOOR thicknesses plus
     SEPARATION times the rest of its starting distance. A pair that was not gathered cannot touch while every
     particle stays inside the reach it was gathered for (_gather: the boxes of the pair's two sides do not
     meet), so a particle that a push carried outside its reach makes the stage gather the candidates again,
     from the motion as it is then;
  2. a closing pair loses the approaching part of its relative motion along the normal between its closest points
     at the time of contact, as an inelastic impulse would remove it (Bridson, Fedkiw and Anderson 2002 section
     7.2), pair after pair in one thread (the list is short, and sorted, so that a run repeats itself); the motion
     along the contact plane is kept, so layers still slide. The test and the response repeat (IMPULSE_PASSES at
     most);
  3. the particles of the pairs still closing are merged into impact zones (Provot 1997; Bridson, Fedkiw and
     Anderson 2002 section 7.4; Harmon et al. 2008), each zone the connected set of the pairs found so far in this
     step, and every zone moves as one rigid translation from the start of the step: the mass-weighted mean of its
     particles' motions and velocities (an inelastic collision: momentum is kept), or, where a pin is in the zone,
     the pinned particles' mean motion (the pin carries the zone). A zone's own pairs then keep their starting
     distances; the test repeats with the moved zones (ZONE_PASSES at most), merging zones that meet.
A zone holding pins that move apart (a twist) cannot move rigidly with all of them; its pairs that still close
after the last pass are counted as unresolved. Rotations are not kept (Bridson's zones keep angular momentum), and a
zone stops the sliding inside it: the zones are a last resort. The stage does not untangle a cloth that starts
crossed (the run reports that, taichi_cloth.self_intersection).
"""
import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock, fill_prefix
from clothbase.fixedpoint import from_fixed, to_fixed
from clothbase.meshes import edges_of

from .base import ParticleCollider
from .ccd import additive_ccd
from .geometry import barycentric, closest_point_on_triangle, closest_segment_params
from .grid import VoxelGrid

#: the point-triangle test reaches this fraction of the thickness beyond the triangle's outline (so that a particle
#: right above a shared edge or vertex is caught by the triangles around it, whatever the round-off)
OUTLINE_SLACK = 0.5
#: the continuous stage keeps every pair at least FLOOR thicknesses plus SEPARATION times the rest of its distance
#: at the start of the step apart (the floor keeps the gaps it tests far above round-off)
SEPARATION, FLOOR = 0.1, 0.05
#: passes that stop the approach of the closing pairs, then impact-zone passes, per step at most
IMPULSE_PASSES, ZONE_PASSES = 16, 32
#: the candidates gathered in a step serve the next steps while every particle stays within this many thicknesses
#: of its motion in the step they were gathered (a calm cloth then skips the grid rebuild and the gathering)
REUSE_MARGIN = 0.25
#: how many steps' impact zones a SelfCollision remembers (zones_in_last)
RECENT_STEPS = 1000
#: additive CCD iterations per pair at most (a pair sliding past at its contact distance takes ~ l_p / 0.9 d)
CCD_ITERATIONS = 256


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
                 cell_size: float | None = None, max_candidates: int = 96, passes: int = 3, seam_particles=(),
                 continuous: bool = True):
        shapes = [(np.asarray(x, dtype=np.float64), np.asarray(t, dtype=np.int64)) for x, t in shapes]
        if not shapes or any(len(t) == 0 for _, t in shapes):
            raise ValueError("self-collision needs a cloth with triangles")
        if thickness is not None and not thickness > 0:
            raise ValueError(f"self-collision thickness must be > 0 m, got {thickness}")
        if not friction >= 0:
            raise ValueError(f"self-collision friction must be >= 0, got {friction}")
        self.fixed_thickness = None if thickness is None else float(thickness)
        self.friction, self.passes, self.continuous = float(friction), int(passes), bool(continuous)
        self.max_candidates = int(max_candidates)
        self.triangles, self.n_triangles = triangles, n_triangles
        self.shapes = shapes
        self.thickness = self._thickness_for(*shapes[0])
        self.cell_size = float(cell_size) if cell_size else 1.5 * min(_mean_edge(x, t) for x, t in shapes)
        self.seam_particles = np.asarray(seam_particles, dtype=np.int64)
        self.edge_capacity = max(len(edges_of(t)[0]) for _, t in shapes)
        blk = FieldBlock()
        # vertex-triangle candidates, edge candidates, point-triangle contacts, edge-edge contacts, overflows,
        # the continuous stage's closing pairs (summed over its passes), impact zones (summed over the passes),
        # pairs still closing after the last pass, particles found outside their boxes (gathered again)
        self.counters = blk.scalar(ti.i64, 9)
        self.tau = blk.scalar(ti.f32, ())
        self.n_edges = blk.scalar(ti.i32, ())
        self.pass_contacts = blk.scalar(ti.i32, ())
        blk.finalize(self)
        self.tau[None] = self.thickness

    def _thickness_for(self, x: np.ndarray, t: np.ndarray) -> float:
        return self.fixed_thickness if self.fixed_thickness is not None else default_thickness(x, t)

    def _on_attach(self) -> None:
        # cloth-cloth contacts are not handed to the solver: contact_normal holds the bodies' contacts, read only
        P, E, T, K = self.x.shape[0], self.edge_capacity, self.triangles.shape[0], self.max_candidates
        blk = FieldBlock()
        self.cand = blk.scalar(ti.i32, (P, K))  # triangles near each particle
        self.n_cand = blk.scalar(ti.i32, P)
        self.edge_cand = blk.scalar(ti.i32, (E, K))  # edges near each edge (with a higher id)
        self.n_edge_cand = blk.scalar(ti.i32, E)
        self.full = blk.scalar(ti.i8, P)  # 1 where a particle's candidates overflowed this step
        self.edge_full = blk.scalar(ti.i8, E)
        self.edges = blk.vector(2, ti.i32, E)
        self.triangle_edges = blk.vector(3, ti.i32, T)
        self.box_lo = blk.vector(3, ti.f32, T)  # the boxes of the triangles' vertices' reaches [m] (_gather)
        self.box_hi = blk.vector(3, ti.f32, T)
        self.on_seam = blk.scalar(ti.i8, P)
        # the pass's pushes on each particle [m] and [m/s], summed in fixed point: the same in any order
        self.dx = blk.vector(3, ti.i64, P)
        self.dv = blk.vector(3, ti.i64, P)
        self.hits = blk.scalar(ti.i32, P)
        self.reach_lo = blk.vector(3, ti.f32, P)  # each particle's reach [m] while its candidates hold
        self.reach_hi = blk.vector(3, ti.f32, P)
        self.closing = blk.vector(4, ti.i32, 4 * P)  # the particles of the pairs that close this pass
        self.closing_kind = blk.scalar(ti.i8, 4 * P)
        self.n_closing = blk.scalar(ti.i32, ())
        self.stale = blk.scalar(ti.i32, ())  # 1: the triangles changed, the candidates name the old ones
        self.pass_live = blk.scalar(ti.i32, ())  # 1 while the proximity passes find contacts
        # the impact zones (_zone_pass): a union-find forest over the particles of the step's closing pairs, the
        # motion [m] and velocity [m/s] of each at the start of the zone passes, and each zone's sums at its root
        self.parent = blk.scalar(ti.i32, P)
        self.member = blk.scalar(ti.i32, P)
        self.zone_motion = blk.vector(3, ti.f64, P)
        self.zone_velocity = blk.vector(3, ti.f64, P)
        self.zone_count = blk.scalar(ti.i32, P)
        self.zone_held = blk.scalar(ti.i32, P)  # pinned particles
        self.zone_mass = blk.scalar(ti.f64, P)  # [kg] of the free ones
        self.zone_pin_motion = blk.vector(3, ti.f64, P)  # summed over the pinned [m]
        self.zone_momentum = blk.vector(3, ti.f64, P)  # mass-weighted motion [kg m] and velocity [kg m/s]
        self.zone_impulse = blk.vector(3, ti.f64, P)
        self.step_zones = blk.scalar(ti.i32, ())  # impact zones made in this step
        self.zone_log = blk.vector(2, ti.f64, RECENT_STEPS)  # (dt [s], impact zones) of the last steps, a ring
        self.zone_steps = blk.scalar(ti.i64, ())
        blk.finalize(self)
        self.topology_changed(*self.shapes[0])  # also marks the candidates stale: the first step gathers
        # sized by the shape with the most (triangle, cell) pairs; built on boxes swept from x_start to x
        x_np, t_np = max(self.shapes, key=lambda s: len(s[1]) * _mean_edge(*s) ** 2)
        self.grid = VoxelGrid(self.x, self.triangles, self.n_triangles, self.cell_size,
                              pad=(1 + REUSE_MARGIN) * max(self._thickness_for(x, t) for x, t in self.shapes),
                              margin=0.0,
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
        self.stale[None] = 1  # the candidates name the old triangles and edges

    def resolve(self, dt: float) -> None:
        """After a step of dt [s]: gather the candidates again if a particle left its reach, the proximity passes,
        then the continuous stage (module docstring). Decided on the device: a serial cloth takes it all in one
        launch in one thread (no read); a parallel one launches the stages, and reads the count of closing pairs
        after each test of the continuous stage (once a step at rest)."""
        if self.serial:
            self._resolve_in_thread(1.0 / dt, dt)
            return
        self._begin_step()
        self._regather(0)
        for _ in range(self.passes):
            self._pass()
        if self.continuous:
            it = 0
            while True:
                self._regather(1)
                self._closing_pass()
                if self.n_closing[None] == 0:
                    break
                if it < IMPULSE_PASSES:
                    self._respond(1.0 / dt)
                elif it < IMPULSE_PASSES + ZONE_PASSES:
                    self._zone(int(it == IMPULSE_PASSES), dt)
                else:
                    self._give_up()
                    break
                it += 1
        self._log_zones(dt)

    def _regather(self, counted: int) -> None:
        """The grid and the candidates again, where a particle left its reach (or the triangles changed)."""
        self._check_reach(counted)
        self.grid.rebuild()
        self._gather()

    @ti.kernel
    def _resolve_in_thread(self, inv_dt: ti.f64, dt: ti.f64):
        """The whole of `resolve` in one thread (a serial cloth): the same stages, decided in the same order."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            self._begin_pass()
            phase, it = 0, 0  # phase 0: the proximity passes; then the continuous stage's tests
            while True:
                self._check_reach_pass(phase)
                self.grid.build_pass()
                self._gather_pass()
                if phase == 0:
                    for _p in range(self.passes):
                        self._proximity_pass()
                    phase = 1
                    if ti.static(not self.continuous):
                        break
                else:
                    self._closing_test()
                    n = self.n_closing[None]
                    if n == 0:
                        break
                    if it < IMPULSE_PASSES:
                        self._respond_pass(ti.cast(inv_dt, self.x.dtype))
                    elif it < IMPULSE_PASSES + ZONE_PASSES:
                        self._zone_pass(it == IMPULSE_PASSES, dt)
                    else:
                        self.counters[7] += n
                        break
                    it += 1
            self._log_zones_pass(dt)

    @ti.kernel
    def _begin_step(self):
        self._begin_pass()

    @ti.func
    def _begin_pass(self):
        self.pass_live[None] = 1
        self.n_closing[None] = 0
        self.step_zones[None] = 0

    @ti.kernel
    def _give_up(self):
        """The pairs still closing after the last zone pass: counted as unresolved."""
        self.counters[7] += self.n_closing[None]

    @ti.kernel
    def _log_zones(self, dt: ti.f64):
        self._log_zones_pass(dt)

    @ti.func
    def _log_zones_pass(self, dt):
        """Append (dt [s], the step's impact zones) to the ring of the last RECENT_STEPS steps."""
        k = self.zone_steps[None]
        self.zone_log[ti.cast(k % RECENT_STEPS, ti.i32)] = ti.Vector([dt, ti.cast(self.step_zones[None], ti.f64)])
        self.zone_steps[None] = k + 1

    def recent_zones(self, seconds: float) -> list[int]:
        """The impact zones made by each of the last `seconds` [s] of steps, newest first (at most the last
        RECENT_STEPS steps)."""
        steps, log = int(self.zone_steps[None]), self.zone_log.to_numpy()
        out, span = [], 0.0
        for k in range(steps - 1, max(steps - RECENT_STEPS, 0) - 1, -1):
            if span >= seconds:
                break
            dt, zones = log[k % RECENT_STEPS]
            out.append(int(zones))
            span += dt
        return out

    def zones_in_last(self, seconds: float) -> int:
        """The impact zones made in the last `seconds` [s] of steps (at most the last RECENT_STEPS steps)."""
        return sum(self.recent_zones(seconds))

    # ------------------------------------------------------------------ reported with the frame's measurement
    report_slots = 1  # the most (triangle, cell) pairs a grid rebuild asked for since the last frame

    def report(self, out, offset: int) -> None:
        self.grid.report(out, offset)

    def reported(self, values) -> None:
        self.grid.reported(values)

    def counter_values(self) -> dict:
        names = ("candidates", "edge candidates", "point-triangle contacts", "edge-edge contacts",
                 "candidate_overflows", "closing pairs", "impact zones", "unresolved pairs", "gathered again")
        return dict(zip(names, (int(c) for c in self.counters.to_numpy())))

    # ------------------------------------------------------------------ candidates
    @ti.func
    def _add(self, cand: ti.template(), full: ti.template(), row, n, item):
        """Append `item` to cand[row, :n] unless it is there; returns the new count (an overflow is counted and
        marks the row full: the continuous stage then walks the grid for it)."""
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
                full[row] = ti.cast(1, ti.i8)
                ti.atomic_add(self.counters[4], 1)
        return out

    @ti.func
    def _near(self, t, lo, hi, skip_a, skip_b):
        """Triangle t's box (its vertices' reaches) meets box [lo, hi] and t has neither vertex skip_a nor skip_b
        (the grid's cells also hold far triangles: hash collisions, cell corners, the grid's wider padding)."""
        tri = self.triangles[t]
        return (all(self.box_lo[t] <= hi) and all(lo <= self.box_hi[t]) and tri[0] != skip_a and tri[1] != skip_a
                and tri[2] != skip_a and tri[0] != skip_b and tri[1] != skip_b and tri[2] != skip_b)

    @ti.func
    def _edge_near(self, f, lo, hi):
        """Edge f's reach box (its ends' reaches) meets box [lo, hi]."""
        q = self.edges[f]
        return (all(ti.min(self.reach_lo[q[0]], self.reach_lo[q[1]]) <= hi)
                and all(lo <= ti.max(self.reach_hi[q[0]], self.reach_hi[q[1]])))

    @ti.func
    def _collect(self, lo, hi, row, cand: ti.template(), full: ti.template(), skip_a, skip_b, edges: ti.template()):
        """Gather into cand[row, :] the triangles whose padded swept boxes meet box [lo, hi] and have neither vertex
        skip_a nor skip_b, or with `edges`, the edges above `row` of those triangles; returns how many."""
        cmin, cmax = self.grid.clamp_range(lo, hi)
        n = 0
        full[row] = ti.cast(0, ti.i8)
        for a, b, c in ti.ndrange((cmin[0], cmax[0] + 1), (cmin[1], cmax[1] + 1), (cmin[2], cmax[2] + 1)):
            cell = self.grid.cell_index(ti.Vector([a, b, c]))
            for e in range(self.grid.cell_start[cell], self.grid.cell_start[cell + 1]):
                t = self.grid.cell_triangles[e]
                if self._near(t, lo, hi, skip_a, skip_b):
                    if ti.static(edges):
                        for j in ti.static(range(3)):
                            f = self.triangle_edges[t][j]
                            if f > row and self._edge_near(f, lo, hi):  # each pair once
                                n = self._add(cand, full, row, n, f)
                    else:
                        n = self._add(cand, full, row, n, t)
        return n

    @ti.kernel
    def _gather(self):
        self._gather_pass()

    @ti.func
    def _gather_pass(self):
        """Gather the candidates (the grid is built; nothing while it is not `active`): each particle's reach is its
        motion over the step (start to now) grown by REUSE_MARGIN thicknesses, a triangle's box the box of its
        vertices' reaches; a particle gathers the triangles whose boxes meet its reach padded by the thickness, an
        edge the edges whose reach boxes meet its own so padded (found through the grid, whose cells hold the
        triangles' swept boxes padded by (1 + REUSE_MARGIN) thicknesses: the triangles' boxes and more). While every
        particle stays in its reach, every pair within a thickness of each other is among the candidates. In
        parallel when launched alone (`_gather`), in one thread inside `_resolve_in_thread`."""
        tau = ti.cast(self.tau[None], ti.f32)
        margin = ti.cast(REUSE_MARGIN, ti.f32) * tau
        for i in range(self.grid.gate(self.n_particles[None])):
            p0, p1 = ti.cast(self.x_start[i], ti.f32), ti.cast(self.x[i], ti.f32)
            self.reach_lo[i], self.reach_hi[i] = ti.min(p0, p1) - margin, ti.max(p0, p1) + margin
        for t in range(self.grid.gate(self.n_triangles[None])):
            tri = self.triangles[t]
            self.box_lo[t] = ti.min(self.reach_lo[tri[0]], self.reach_lo[tri[1]], self.reach_lo[tri[2]])
            self.box_hi[t] = ti.max(self.reach_hi[tri[0]], self.reach_hi[tri[1]], self.reach_hi[tri[2]])
        for i in range(self.grid.gate(self.n_particles[None])):
            n = self._collect(self.reach_lo[i] - tau, self.reach_hi[i] + tau, i, self.cand, self.full, i, i, False)
            self.n_cand[i] = n
            ti.atomic_add(self.counters[0], n)
        for e in range(self.grid.gate(self.n_edges[None])):
            # edges within one ring of the edge's ends are its neighbours, not its contacts
            ab = self.edges[e]
            lo = ti.min(self.reach_lo[ab[0]], self.reach_lo[ab[1]])
            hi = ti.max(self.reach_hi[ab[0]], self.reach_hi[ab[1]])
            n = self._collect(lo - tau, hi + tau, e, self.edge_cand, self.edge_full, ab[0], ab[1], True)
            self.n_edge_cand[e] = n
            ti.atomic_add(self.counters[1], n)
        if self.grid.active[None] != 0:
            self.stale[None] = 0

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
                    self.dx[ids[k]] += to_fixed(w[k] * im[k] * lam * n)
                    self.dv[ids[k]] += to_fixed(w[k] * im[k] * impulse)
                    ti.atomic_add(self.hits[ids[k]], 1)

    @ti.func
    def _seams_meet(self, a, b):
        """Whether a pair of features with seam particles on both sides is skipped (the pieces are apart)."""
        return a != 0 and b != 0

    @ti.func
    def _swept_apart(self, ids, edge_edge: ti.template(), gap):
        """Whether the boxes the two sides of pair ids (4,) (point | triangle, or edge | edge) sweep over the step
        are more than `gap` [m] apart along an axis: then the pair never comes within `gap` (a cheap test that
        spares most candidates the exact one)."""
        x0, x1 = ti.static(self.x_start, self.x)
        lo_a, hi_a = ti.min(x0[ids[0]], x1[ids[0]]), ti.max(x0[ids[0]], x1[ids[0]])
        lo_b, hi_b = ti.min(x0[ids[3]], x1[ids[3]]), ti.max(x0[ids[3]], x1[ids[3]])
        for k in ti.static(range(1, 3)):
            if ti.static(edge_edge and k == 1):
                lo_a, hi_a = ti.min(lo_a, x0[ids[k]], x1[ids[k]]), ti.max(hi_a, x0[ids[k]], x1[ids[k]])
            else:
                lo_b, hi_b = ti.min(lo_b, x0[ids[k]], x1[ids[k]]), ti.max(hi_b, x0[ids[k]], x1[ids[k]])
        return any(lo_a - hi_b > gap) or any(lo_b - hi_a > gap)

    @ti.func
    def _point_triangle(self, i, t, tau, friction):
        tri = self.triangles[t]
        if not self._swept_apart(ti.Vector([i, tri[0], tri[1], tri[2]]), False, tau):
            self._point_triangle_near(i, tri, tau, friction)

    @ti.func
    def _point_triangle_near(self, i, tri, tau, friction):
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
        if not self._swept_apart(ti.Vector([pa, pb, qa, qb]), True, tau):
            self._edge_edge_near(pa, pb, qa, qb, tau, friction)

    @ti.func
    def _edge_edge_near(self, pa, pb, qa, qb, tau, friction):
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
    def _pass(self):
        self._proximity_pass()

    @ti.func
    def _proximity_pass(self):
        """One Jacobi pass over the gathered pairs, while the pass before found a contact (pass_live)."""
        tau = ti.cast(self.tau[None], self.x.dtype)
        friction = ti.cast(self.friction, self.x.dtype)
        self.pass_contacts[None] = 0
        live = self.pass_live[None] != 0
        ti.loop_config(serialize=self.serial)
        for i in range(ti.select(live, self.n_particles[None], 0)):
            self.dx[i] = ti.Vector.zero(ti.i64, 3)
            self.dv[i] = ti.Vector.zero(ti.i64, 3)
            self.hits[i] = 0
        ti.loop_config(serialize=self.serial)
        for i in range(ti.select(live, self.n_particles[None], 0)):
            for k in range(self.n_cand[i]):
                t = self.cand[i, k]
                tri = self.triangles[t]
                seams = self.on_seam[tri[0]] + self.on_seam[tri[1]] + self.on_seam[tri[2]]
                if not self._seams_meet(self.on_seam[i], seams):
                    self._point_triangle(i, t, tau, friction)
        ti.loop_config(serialize=self.serial)
        for e in range(ti.select(live, self.n_edges[None], 0)):
            ab = self.edges[e]
            for k in range(self.n_edge_cand[e]):
                f = self.edge_cand[e, k]
                cd = self.edges[f]
                if not self._seams_meet(self.on_seam[ab[0]] + self.on_seam[ab[1]],
                                        self.on_seam[cd[0]] + self.on_seam[cd[1]]):
                    self._edge_edge(e, f, tau, friction)
        ti.loop_config(serialize=self.serial)
        for i in range(ti.select(live, self.n_particles[None], 0)):
            if self.hits[i] > 0:
                self.x[i] += from_fixed(self.dx[i], self.x.dtype) / self.hits[i]
                self.v[i] += from_fixed(self.dv[i], self.x.dtype) / self.hits[i]
        # nothing touched: the later passes would find nothing either
        self.pass_live[None] = ti.select(self.pass_contacts[None] > 0, 1, 0)

    # ------------------------------------------------------------------ the continuous stage
    @ti.kernel
    def _check_reach(self, counted: ti.i32):
        self._check_reach_pass(counted)

    @ti.func
    def _check_reach_pass(self, counted):
        """Turn the grid's rebuild (and the gathering) on where the triangles changed or a particle lies outside the
        reach it gathered its candidates for (_gather): while none does, a pair that was not gathered cannot touch,
        since the boxes of its two sides do not meet. counted: the continuous stage's check (a response carried a
        particle out; rare, since a push is shorter than the reach's margin), counted as gathered again."""
        left = 0
        ti.loop_config(serialize=self.serial)
        for i in range(self.n_particles[None]):
            p, q = ti.cast(self.x_start[i], ti.f32), ti.cast(self.x[i], ti.f32)
            lo, hi = self.reach_lo[i], self.reach_hi[i]
            if any(ti.min(p, q) < lo) or any(ti.max(p, q) > hi):
                left += 1
        if counted != 0:
            self.counters[8] += left
        self.grid.active[None] = ti.select(left > 0 or self.stale[None] != 0, 1, 0)

    @ti.func
    def _closes(self, ids, kind):
        """Record the pair of particles ids (4,) as closing (kind 0: point-triangle, 1: edge-edge)."""
        k = ti.atomic_add(self.n_closing[None], 1)
        if k < self.closing.shape[0]:
            self.closing[k] = ids
            self.closing_kind[k] = ti.cast(kind, ti.i8)

    @ti.func
    def _pair_toi(self, ids, edge_edge: ti.template(), s, xi):
        """The fraction of the step pair ids (4,) (point, triangle or edge, edge) can safely take (collision.ccd):
        1 at once where the boxes its two sides sweep never meet (they cannot touch)."""
        x0, x1 = ti.static(self.x_start, self.x)
        out = x0[ids[0]][0] * 0.0 + 1.0
        if not self._swept_apart(ids, edge_edge, 0.0):
            a, b, c, d = ids[0], ids[1], ids[2], ids[3]
            out = additive_ccd(x0[a], x0[b], x0[c], x0[d], x1[a] - x0[a], x1[b] - x0[b], x1[c] - x0[c],
                               x1[d] - x0[d], s, xi, CCD_ITERATIONS, edge_edge)
        return out

    @ti.func
    def _stop_approach(self, ids, edge_edge: ti.template(), toi, rate):
        """The inelastic response of a pair that closes at fraction toi of the step (Bridson, Fedkiw and Anderson
        2002 section 7.2): its particles ids (4,) lose the approaching part of their relative motion along the
        normal between the pair's closest points at toi, by mass and barycentric weight, and their velocities the
        matching change (rate = 1/dt [1/s]); the motion along the contact plane is kept, so layers still slide."""
        x0, x1 = ti.static(self.x_start, self.x)
        p = [x0[ids[k]] + toi * (x1[ids[k]] - x0[ids[k]]) for k in ti.static(range(4))]
        w = ti.Vector.zero(self.x.dtype, 4)
        n = p[0] - p[0]
        if ti.static(edge_edge):
            u, v = closest_segment_params(p[0], p[1], p[2], p[3])
            n = ((p[0] + u * (p[1] - p[0])) - (p[2] + v * (p[3] - p[2]))).normalized(1e-20)
            w = ti.Vector([1.0 - u, u, v - 1.0, -v], self.x.dtype)
        else:
            q = closest_point_on_triangle(p[0], p[1], p[2], p[3])
            bary = barycentric(q, p[1], p[2], p[3])
            n = (p[0] - q).normalized(1e-20)
            w = ti.Vector([1.0, -bary[0], -bary[1], -bary[2]], self.x.dtype)
        im = ti.Vector([self._mobility(ids[k], w[k] * n) for k in ti.static(range(4))], self.x.dtype)
        approach = n.dot(n) * 0.0
        for k in ti.static(range(4)):
            approach += w[k] * (x1[ids[k]] - x0[ids[k]]).dot(n)
        den = (w * w * im).sum()
        if approach < 0 and den > 0:
            lam = -approach / den
            for k in ti.static(range(4)):
                x1[ids[k]] += w[k] * im[k] * lam * n
                self.v[ids[k]] += w[k] * im[k] * lam * rate * n

    @ti.func
    def _point_triangle_ccd(self, i, t, s, xi):
        tri = self.triangles[t]
        seams = self.on_seam[tri[0]] + self.on_seam[tri[1]] + self.on_seam[tri[2]]
        if not self._seams_meet(self.on_seam[i], seams):
            ids = ti.Vector([i, tri[0], tri[1], tri[2]])
            if self._pair_toi(ids, False, s, xi) < 1:
                self._closes(ids, 0)

    @ti.func
    def _edge_edge_ccd(self, e, f, s, xi):
        pa, pb = self.edges[e]
        qa, qb = self.edges[f]
        if not self._seams_meet(self.on_seam[pa] + self.on_seam[pb], self.on_seam[qa] + self.on_seam[qb]):
            ids = ti.Vector([pa, pb, qa, qb])
            if self._pair_toi(ids, True, s, xi) < 1:
                self._closes(ids, 1)

    @ti.kernel
    def _respond(self, inv_dt: ti.f64):
        ti.loop_config(serialize=True)
        for _ in range(1):
            self._respond_pass(ti.cast(inv_dt, self.x.dtype))

    @ti.func
    def _respond_pass(self, rate):
        """Put the recorded closing pairs in a fixed order (the parallel test records them in any order), then stop
        their approach one after the other (Gauss-Seidel: each sees the corrections before it, so a stack of layers
        settles in a few passes; the list is short, one thread). rate = 1/dt [1/s]."""
        s = ti.cast(SEPARATION, self.x.dtype)
        xi = ti.cast(FLOOR * self.tau[None], self.x.dtype)
        n = ti.min(self.n_closing[None], self.closing.shape[0])
        self._sort_closing(n)
        for k in range(n):
            ids = self.closing[k]
            if self.closing_kind[k] == 0:
                toi = self._pair_toi(ids, False, s, xi)
                if toi < 1:
                    self._stop_approach(ids, False, toi, rate)
            else:
                toi = self._pair_toi(ids, True, s, xi)
                if toi < 1:
                    self._stop_approach(ids, True, toi, rate)

    @ti.func
    def _closing_before(self, a, b):
        """Whether closing pair a sorts before pair b: by kind, then by the particles' ids."""
        ka, kb = self.closing_kind[a], self.closing_kind[b]
        out = ka < kb
        if ka == kb:
            pa, pb = self.closing[a], self.closing[b]
            decided = False
            for j in ti.static(range(4)):
                if not decided and pa[j] != pb[j]:
                    out = pa[j] < pb[j]
                    decided = True
        return out

    @ti.func
    def _swap_closing(self, a, b):
        self.closing[a], self.closing[b] = self.closing[b], self.closing[a]
        self.closing_kind[a], self.closing_kind[b] = self.closing_kind[b], self.closing_kind[a]

    @ti.func
    def _sift_closing(self, root, end):
        """Restore the max-heap of closing[:end] below `root`."""
        r = root
        while 2 * r + 1 < end:
            child = 2 * r + 1
            if child + 1 < end and self._closing_before(child, child + 1):
                child += 1
            if self._closing_before(r, child):
                self._swap_closing(r, child)
                r = child
            else:
                break

    @ti.func
    def _sort_closing(self, n):
        """Sort closing[:n] (heap sort, one thread: O(n log n) for any list)."""
        for k in range(n // 2):
            self._sift_closing(n // 2 - 1 - k, n)
        for k in range(n - 1):
            self._swap_closing(0, n - 1 - k)
            self._sift_closing(0, n - 1 - k)

    @ti.func
    def _zone_root(self, p):
        r = p
        while self.parent[r] != r:
            r = self.parent[r]
        return r

    @ti.kernel
    def _zone(self, first: ti.i32, dt: ti.f64):
        ti.loop_config(serialize=True)
        for _ in range(1):
            self._zone_pass(first, dt)

    @ti.func
    def _zone_pass(self, first, dt):
        """One pass of impact zones (module docstring, step 3), in one thread (zones are rare and small; the sums
        then run in a fixed order). first: the stage's first pass, which takes each particle's motion and velocity
        as they are now. Merges the particles of the recorded closing pairs into zones (the connected sets of all
        the pairs found by the passes so far: a union-find forest, joined to the smaller root), and moves every
        free particle of a zone by the zone's rigid translation from the start of the step (module docstring)."""
        P = self.n_particles[None]
        if first:
            for p in range(P):
                self.parent[p] = p
                self.member[p] = 0
                self.zone_motion[p] = ti.cast(self.x[p], ti.f64) - ti.cast(self.x_start[p], ti.f64)
                self.zone_velocity[p] = ti.cast(self.v[p], ti.f64)
        for k in range(ti.min(self.n_closing[None], self.closing.shape[0])):
            ids = self.closing[k]
            for j in ti.static(range(4)):
                self.member[ids[j]] = 1
            for j in ti.static(range(1, 4)):
                a, b = self._zone_root(ids[0]), self._zone_root(ids[j])
                if a != b:
                    self.parent[ti.max(a, b)] = ti.min(a, b)
        for p in range(P):
            if self.member[p] != 0:
                r = self._zone_root(p)
                self.parent[p] = r
                self.zone_count[r] = 0
                self.zone_held[r] = 0
                self.zone_mass[r] = 0.0
                self.zone_pin_motion[r] = ti.Vector.zero(ti.f64, 3)
                self.zone_momentum[r] = ti.Vector.zero(ti.f64, 3)
                self.zone_impulse[r] = ti.Vector.zero(ti.f64, 3)
        for p in range(P):
            if self.member[p] != 0:
                r = self.parent[p]
                self.zone_count[r] += 1
                if self.inv_mass[p] == 0:
                    self.zone_held[r] += 1
                    self.zone_pin_motion[r] += self.zone_motion[p]
                else:
                    m = 1.0 / ti.cast(self.inv_mass[p], ti.f64)
                    self.zone_mass[r] += m
                    self.zone_momentum[r] += m * self.zone_motion[p]
                    self.zone_impulse[r] += m * self.zone_velocity[p]
        made = 0
        for p in range(P):
            if self.member[p] != 0:
                r = self.parent[p]
                if r == p and self.zone_count[p] > 1:
                    made += 1
                if self.inv_mass[p] != 0:
                    # a zone holding a pin moves with the pins' mean motion (the pin carries the zone)
                    shift = self.zone_momentum[r] / self.zone_mass[r]
                    drift = self.zone_impulse[r] / self.zone_mass[r]
                    if self.zone_held[r] > 0:
                        shift = self.zone_pin_motion[r] / self.zone_held[r]
                        drift = shift / dt
                    self.x[p] = ti.cast(ti.cast(self.x_start[p], ti.f64) + shift, self.x.dtype)
                    self.v[p] = ti.cast(drift, self.x.dtype)
        self.counters[6] += made
        self.step_zones[None] += made

    @ti.func
    def _walk_ccd(self, row, lo, hi, skip_a, skip_b, edges: ti.template(), s, xi):
        """The continuous test of particle `row` against the triangles near box [lo, hi] (with `edges`, of edge
        `row` against the edges above it there), found through the grid: for a row whose candidates overflowed. A
        triangle in several cells is tested again: harmless."""
        cmin, cmax = self.grid.clamp_range(lo, hi)
        for a, b, c in ti.ndrange((cmin[0], cmax[0] + 1), (cmin[1], cmax[1] + 1), (cmin[2], cmax[2] + 1)):
            cell = self.grid.cell_index(ti.Vector([a, b, c]))
            for m in range(self.grid.cell_start[cell], self.grid.cell_start[cell + 1]):
                t = self.grid.cell_triangles[m]
                if self._near(t, lo, hi, skip_a, skip_b):
                    if ti.static(edges):
                        for j in ti.static(range(3)):
                            f = self.triangle_edges[t][j]
                            if f > row and self._edge_near(f, lo, hi):
                                self._edge_edge_ccd(row, f, s, xi)
                    else:
                        self._point_triangle_ccd(row, t, s, xi)

    @ti.kernel
    def _closing_pass(self):
        self._closing_test()

    @ti.func
    def _closing_test(self):
        """Test every gathered pair along the step's straight-line motion and record the pairs that close (n_closing
        of them, counted as closing pairs). A row whose candidates overflowed walks the grid instead of its list, so
        no pair is missed."""
        s = ti.cast(SEPARATION, self.x.dtype)
        xi = ti.cast(FLOOR * self.tau[None], self.x.dtype)
        tau = ti.cast(self.tau[None], ti.f32)
        self.n_closing[None] = 0
        ti.loop_config(serialize=self.serial)
        for i in range(self.n_particles[None]):
            if self.full[i] == 0:
                for k in range(self.n_cand[i]):
                    self._point_triangle_ccd(i, self.cand[i, k], s, xi)
            else:
                self._walk_ccd(i, self.reach_lo[i] - tau, self.reach_hi[i] + tau, i, i, False, s, xi)
        ti.loop_config(serialize=self.serial)
        for e in range(self.n_edges[None]):
            if self.edge_full[e] == 0:
                for k in range(self.n_edge_cand[e]):
                    self._edge_edge_ccd(e, self.edge_cand[e, k], s, xi)
            else:
                ab = self.edges[e]
                lo = ti.min(self.reach_lo[ab[0]], self.reach_lo[ab[1]]) - tau
                hi = ti.max(self.reach_hi[ab[0]], self.reach_hi[ab[1]]) + tau
                self._walk_ccd(e, lo, hi, ab[0], ab[1], True, s, xi)
        self.counters[5] += self.n_closing[None]

    def describe(self) -> dict:
        return {"kind": "self"}


def default_thickness(x: np.ndarray, t: np.ndarray) -> float:
    """The default thickness [m] of a cloth (P,3) [m] with triangles t (T,3): a quarter of its mean edge."""
    return 0.25 * _mean_edge(np.asarray(x, dtype=np.float64), np.asarray(t, dtype=np.int64))


def _mean_edge(x: np.ndarray, t: np.ndarray) -> float:
    """Mean edge length [m] of triangles t (T,3) over positions x (P,3)."""
    return float(np.linalg.norm(x[t] - x[t[:, [1, 2, 0]]], axis=2).mean())

