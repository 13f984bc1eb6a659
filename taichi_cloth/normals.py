"""Vertex normals of the cloth surface, computed in a Taichi kernel (used by wind and the recorder)."""
import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock


@ti.data_oriented
class VertexNormals:
    """normal: (P,) vec3 fp. After compute(False), for vertex i the sum over its triangles of (area vector)/3
    [m^2]: its length is the vertex's share of the deformed area, its direction the area-weighted normal.
    After compute(True), the same normalised to unit length (zero where a vertex has no area)."""

    def __init__(self, model, state):
        self.model, self.state = model, state
        blk = FieldBlock()
        self.normal = blk.vector(3, model.fp, model.capacity[0])
        self.triangle_area = blk.vector(3, model.fp, max(model.capacity[2], 1))  # area vectors [m^2]
        blk.finalize(self)

    @ti.func
    def triangle_area_vector(self, t):
        c = self.model.triangles[t]
        p0 = self.state.x[c[0]]
        return 0.5 * (self.state.x[c[1]] - p0).cross(self.state.x[c[2]] - p0)

    @ti.func
    def vertex_normal(self, i, unit: ti.template()):
        """Sum of the area vectors of vertex i's triangles / 3 (after the triangle pass), or its unit vector."""
        m = self.model
        n = ti.Vector.zero(m.fp, 3)
        for e in range(m.tri_offset[i], m.tri_offset[i + 1]):
            n += self.triangle_area[m.tri_list[e]]
        n /= 3.0
        if ti.static(unit):
            length = n.norm()
            n = n / length if length > 0 else ti.Vector.zero(m.fp, 3)
        return n

    @ti.kernel
    def compute(self, unit: ti.template()):
        ti.loop_config(serialize=self.model.serial)
        for t in range(self.model.n_triangles[None]):
            self.triangle_area[t] = self.triangle_area_vector(t)
        ti.loop_config(serialize=self.model.serial)
        for i in range(self.model.n_particles[None]):
            self.normal[i] = self.vertex_normal(i, unit)

    @ti.kernel
    def _snapshot(self, positions: ti.types.ndarray(dtype=ti.math.vec3, ndim=1),
                  normals: ti.types.ndarray(dtype=ti.math.vec3, ndim=1)):
        ti.loop_config(serialize=self.model.serial)
        for t in range(self.model.n_triangles[None]):
            self.triangle_area[t] = self.triangle_area_vector(t)
        ti.loop_config(serialize=self.model.serial)
        for i in range(self.model.n_particles[None]):
            normals[i] = ti.cast(self.vertex_normal(i, True), ti.f32)
            positions[i] = ti.cast(self.state.x[i], ti.f32)

    def snapshot(self) -> tuple[np.ndarray, np.ndarray]:
        """Fresh (P,3) float32 arrays of the positions [m] and unit normals, filled by one kernel launch
        (what the recorder logs each frame)."""
        P = self.model.data.n_particles
        positions = np.empty((P, 3), np.float32)
        normals = np.empty((P, 3), np.float32)
        self._snapshot(positions, normals)
        return positions, normals
