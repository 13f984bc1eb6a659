"""Cloth self-collision: particle against the cloth's own triangles, through a hashed voxel grid.

Each step the triangles are binned by their boxes swept from the start to the end of the step (the cloth
moves, so the grid is hashed and rebuilt every step). For particle i and a triangle not incident to it, with
d0 = the particle's height above the triangle's plane at the start of the step and d1 at the end:
  crossing:  d0 and d1 differ in sign and the end point projects inside the triangle -> it crossed;
  proximity: |d1| < thickness on the side of d0 and projects inside -> too close.
Either way the particle goes back to its starting side at the thickness, and its velocity relative to the
triangle loses its approaching normal part (restitution 0) with Coulomb friction on the rest. Only the
particle moves (one-sided): simple and stable, not momentum-exact; a scene turns this on only when it needs it.
"""
import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock

from .base import ParticleCollider
from .geometry import inside_triangle
from .grid import VoxelGrid


@ti.data_oriented
class SelfCollision(ParticleCollider):
    """triangles (T,3) of the cloth and its rest positions (P,3) [m]; thickness [m] (default a quarter of the
    mean rest edge: with only particle-triangle tests, layers must keep apart by a good part of an edge or
    edges slip through each other); friction; cell_size [m] (default 1.5 x the mean rest edge);
    max_candidates per particle (more are ignored and counted)."""

    def __init__(self, triangles, rest_positions, thickness: float | None = None, friction: float = 0.1,
                 cell_size: float | None = None, max_candidates: int = 128, passes: int = 2):
        t = np.asarray(triangles, dtype=np.int64)
        x = np.asarray(rest_positions, dtype=np.float64)
        if len(t) == 0:
            raise ValueError("self-collision needs a cloth with triangles")
        mean_edge = float(np.linalg.norm(x[t] - x[t[:, [1, 2, 0]]], axis=2).mean())
        thickness = 0.25 * mean_edge if thickness is None else thickness
        if not thickness > 0:
            raise ValueError(f"self-collision thickness must be > 0 m, got {thickness}")
        self.thickness, self.friction, self.passes = float(thickness), float(friction), int(passes)
        self.max_candidates = int(max_candidates)
        self.triangles_np, self.rest_np = t, x
        self.cell_size = float(cell_size) if cell_size else 1.5 * mean_edge
        self.n_tri = len(t)
        blk = FieldBlock()
        self.counters = blk.scalar(ti.i64, 3)  # candidates, corrections, overflows
        blk.finalize(self)

    def _on_attach(self) -> None:
        # cloth-cloth contacts are not handed to the solver (contact_normal is left alone)
        blk = FieldBlock()
        self.triangles = blk.vector(3, ti.i32, self.n_tri)
        self.n_triangles = blk.scalar(ti.i32, ())
        self.cand = blk.scalar(ti.i32, (self.x.shape[0], self.max_candidates))
        blk.finalize(self)
        self.triangles.from_numpy(self.triangles_np.astype(np.int32))
        self.n_triangles[None] = self.n_tri
        # built at once, on boxes swept from x_start (= x now) to x
        self.grid = VoxelGrid(self.x, self.triangles, self.n_triangles, self.cell_size, pad=self.thickness,
                              margin=0.0, vertices_np=self.rest_np, triangles_np=self.triangles_np, hashed=True,
                              vertices_start=self.x_start, serial=self.serial)

    def resolve(self, dt: float) -> None:
        self.grid.build()
        self._resolve()

    def counter_values(self) -> dict:
        return dict(zip(("candidates", "corrections", "candidate_overflows"),
                        (int(c) for c in self.counters.to_numpy())))

    @ti.func
    def _plane(self, pos: ti.template(), t):
        c = self.triangles[t]
        a = ti.cast(pos[c[0]], ti.f32)
        b = ti.cast(pos[c[1]], ti.f32)
        cc = ti.cast(pos[c[2]], ti.f32)
        return a, b, cc, (b - a).cross(cc - a).normalized(1e-20)

    @ti.kernel
    def _resolve(self):
        tau = ti.cast(self.thickness, ti.f32)
        ti.loop_config(serialize=self.serial)
        for i in range(self.n_particles[None]):
            if self.inv_mass[i] != 0:
                p0 = ti.cast(self.x_start[i], ti.f32)
                for _ in range(self.passes):
                    p1 = ti.cast(self.x[i], ti.f32)
                    cmin, cmax = self.grid.clamp_range(ti.min(p0, p1) - tau, ti.max(p0, p1) + tau)
                    n = 0
                    for a, b, c in ti.ndrange((cmin[0], cmax[0] + 1), (cmin[1], cmax[1] + 1), (cmin[2], cmax[2] + 1)):
                        cell = self.grid.cell_index(ti.Vector([a, b, c]))
                        for e in range(self.grid.cell_start[cell], self.grid.cell_start[cell + 1]):
                            t = self.grid.cell_triangles[e]
                            tri = self.triangles[t]
                            if tri[0] != i and tri[1] != i and tri[2] != i:
                                seen = False
                                for k in range(n):
                                    if self.cand[i, k] == t:
                                        seen = True
                                        break
                                if not seen:
                                    if n < self.max_candidates:
                                        self.cand[i, n] = t
                                        n += 1
                                    else:
                                        ti.atomic_add(self.counters[2], 1)
                    ti.atomic_add(self.counters[0], n)
                    best = -1
                    best_fix = ti.cast(0.0, ti.f32)
                    best_n = ti.Vector.zero(ti.f32, 3)
                    for k in range(n):
                        t = self.cand[i, k]
                        a0, b0, c0, n0 = self._plane(self.x_start, t)
                        a1, b1, c1, n1 = self._plane(self.x, t)
                        d0 = (p0 - a0).dot(n0)
                        d1 = (p1 - a1).dot(n1)
                        # only a particle the relative motion could have carried to the plane counts: a far one
                        # can change sides just because the triangle turned
                        reach = tau + ((p1 - p0) - (a1 + b1 + c1 - a0 - b0 - c0) / 3.0).norm()
                        side = 1.0 if d0 >= 0 else -1.0
                        if ti.abs(d0) < 1e-12:
                            side = 1.0 if d1 >= 0 else -1.0
                        fix = side * tau - d1  # signed move along n1 that restores the side at the thickness
                        if (side * d1 < tau and ti.abs(d0) <= reach and ti.abs(d1) <= reach
                                and inside_triangle(p1, a1, b1, c1, n1) and ti.abs(fix) > ti.abs(best_fix)):
                            best, best_fix, best_n = t, fix, n1
                    if best < 0:
                        break
                    ti.atomic_add(self.counters[1], 1)
                    self.x[i] += ti.cast(best_fix * best_n, self.x.dtype)
                    tri = self.triangles[best]
                    v_tri = (self.v[tri[0]] + self.v[tri[1]] + self.v[tri[2]]) / 3.0
                    nrm = ti.cast(best_n * ti.math.sign(best_fix), self.x.dtype)
                    self.respond(i, nrm, v_tri, ti.cast(self.friction, self.x.dtype))

    def describe(self) -> dict:
        return {"kind": "self"}
