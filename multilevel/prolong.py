"""Prolongation of per-vertex state to a refined level, in a Taichi kernel, in place.

A level switch keeps the fields (allocated at the finest capacity) and refills them: the new vertex k
gets x[k] = sum_j w[k, j] x_old[p[k, j]] (midpoints: (x_a + x_b) / 2, which keeps the 3D shape exactly
and adds no strain), and the same for velocities. Velocity is also the history of the position
schemes (Verlet and central difference keep d = x - x_prev = h v), so prolonging v prolongs x_prev.
The tables are refilled from the host per switch; the kernel compiles once for all levels.
"""

import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock

from .hierarchy import Level


@ti.data_oriented
class Prolongation:
    """parent: (P, 3) i32 (-1 unused), weight: (P, 3) fp, scratch_x / scratch_v: (P,) vec3 fp.

    P is the capacity (the finest level's vertex count)."""

    def __init__(self, capacity: int, fp=ti.f32, serial: bool = False):
        self.capacity = int(capacity)
        self.fp = fp
        self.serial = bool(serial)  # loops in one thread (small cloths on the CPU)
        blk = FieldBlock()
        self.parent = blk.scalar(ti.i32, (self.capacity, 3))
        self.weight = blk.scalar(fp, (self.capacity, 3))
        self.scratch_x = blk.vector(3, fp, self.capacity)
        self.scratch_v = blk.vector(3, fp, self.capacity)
        blk.finalize(self)

    def apply(self, level: Level, x, v, n_old: int) -> None:
        """Refill x, v ((P,) vec3 fields; n_old live entries) with the prolonged values of `level`'s
        vertices, using its tables (parents index the n_old vertices of the level above)."""
        n_new = level.n_vertices
        if n_new > self.capacity:
            raise ValueError(f"level has {n_new} vertices, above the capacity {self.capacity}")
        if level.parents.max(initial=-1) >= n_old:
            raise ValueError("prolongation table refers to a vertex the level above does not have")
        parents = np.full((self.capacity, 3), -1, np.int32)
        weights = np.zeros((self.capacity, 3), np.float32 if self.fp == ti.f32 else np.float64)
        parents[:n_new] = level.parents
        weights[:n_new] = level.weights
        self.parent.from_numpy(parents)
        self.weight.from_numpy(weights)
        self._apply(x, v, n_old, n_new)

    @ti.kernel
    def _apply(self, x: ti.template(), v: ti.template(), n_old: ti.i32, n_new: ti.i32):
        ti.loop_config(serialize=self.serial)
        for i in range(n_old):
            self.scratch_x[i] = x[i]
            self.scratch_v[i] = v[i]
        ti.loop_config(serialize=self.serial)
        for k in range(n_new):
            px = ti.Vector.zero(self.fp, 3)
            pv = ti.Vector.zero(self.fp, 3)
            for j in ti.static(range(3)):
                p = self.parent[k, j]
                if p >= 0:
                    px += self.weight[k, j] * self.scratch_x[p]
                    pv += self.weight[k, j] * self.scratch_v[p]
            x[k] = px
            v[k] = pv
