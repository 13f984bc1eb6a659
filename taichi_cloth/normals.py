"""Vertex normals of the cloth surface, computed in a Taichi kernel (used by wind and the recorder)."""
import numpy as np
import taichi as ti


@ti.data_oriented
class VertexNormals:
    """normal: (P,) vec3 fp. After compute(False), for vertex i the sum over its triangles of (area vector)/3
    [m^2]: its length is the vertex's share of the deformed area, its direction the area-weighted normal.
    After compute(True), the same normalised to unit length (zero where a vertex has no area)."""

    def __init__(self, model, state):
        self.model, self.state = model, state
        self.normal = ti.Vector.field(3, model.fp, model.capacity[0])
        self.triangle_area = ti.Vector.field(3, model.fp, max(model.capacity[2], 1))  # area vectors [m^2]

    @ti.kernel
    def compute(self, unit: ti.template()):
        m, s = self.model, self.state
        for t in range(m.n_triangles[None]):
            c = m.triangles[t]
            p0 = s.x[c[0]]
            self.triangle_area[t] = 0.5 * (s.x[c[1]] - p0).cross(s.x[c[2]] - p0)
        for i in range(m.n_particles[None]):
            n = ti.Vector.zero(m.fp, 3)
            for e in range(m.tri_offset[i], m.tri_offset[i + 1]):
                n += self.triangle_area[m.tri_list[e]]
            n /= 3.0
            if ti.static(unit):
                length = n.norm()
                n = n / length if length > 0 else ti.Vector.zero(m.fp, 3)
            self.normal[i] = n

    @ti.kernel
    def _snapshot(self, positions: ti.types.ndarray(dtype=ti.math.vec3, ndim=1),
                  normals: ti.types.ndarray(dtype=ti.math.vec3, ndim=1)):
        m, s = self.model, self.state
        for t in range(m.n_triangles[None]):
            c = m.triangles[t]
            p0 = s.x[c[0]]
            self.triangle_area[t] = 0.5 * (s.x[c[1]] - p0).cross(s.x[c[2]] - p0)
        for i in range(m.n_particles[None]):
            n = ti.Vector.zero(m.fp, 3)
            for e in range(m.tri_offset[i], m.tri_offset[i + 1]):
                n += self.triangle_area[m.tri_list[e]]
            length = n.norm()
            normals[i] = ti.cast(n / length if length > 0 else ti.Vector.zero(m.fp, 3), ti.f32)
            positions[i] = ti.cast(s.x[i], ti.f32)

    def snapshot(self) -> tuple[np.ndarray, np.ndarray]:
        """Fresh (P,3) float32 arrays of the positions [m] and unit normals, filled by one kernel launch
        (what the recorder logs each frame)."""
        P = self.model.data.n_particles
        positions = np.empty((P, 3), np.float32)
        normals = np.empty((P, 3), np.float32)
        self._snapshot(positions, normals)
        return positions, normals
