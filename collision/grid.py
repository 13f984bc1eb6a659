"""A uniform voxel grid over a triangle mesh, built in Taichi kernels (count, prefix sum, fill).

Each triangle is binned into every cell its bounding box, inflated by `pad`, overlaps (ALGORITHMS.md 3:
Teschner 2003 finds the best cell size near the mean primitive size). The grid covers the mesh's bounds
plus `margin`; its cell counts are fixed at construction, so rebuilding after the mesh moves or morphs
refills the same fields (no reallocation, no recompile) as long as the mesh stays within the allocated
extent.
"""
import math

import numpy as np
import taichi as ti


@ti.data_oriented
class VoxelGrid:
    """Cells of edge `cell_size` [m] over the AABB of `vertices` (a (V,) vec3 field) plus `margin` [m].

    cell_start: (C+1,) i32 CSR offsets; cell_triangles: (pair capacity,) i32 triangle ids; origin: 0-d vec3 [m];
    dims: the grid size in cells (fixed). `triangles` is a (T,) ivec3 field, `n_triangles` a 0-d i32 field.
    `grow` leaves room for the mesh to grow by that factor in extent and in (triangle, cell) pairs.
    """

    def __init__(self, vertices, triangles, n_triangles, cell_size: float, pad: float, margin: float,
                 vertices_np: np.ndarray, triangles_np: np.ndarray, grow: float = 1.25):
        if not cell_size > 0:
            raise ValueError(f"voxel cell size must be > 0 m, got {cell_size}")
        self.vertices, self.triangles, self.n_triangles = vertices, triangles, n_triangles
        self.cell_size, self.pad, self.margin = float(cell_size), float(pad), float(margin)
        lo, hi = vertices_np.min(0) - margin, vertices_np.max(0) + margin
        self.dims = tuple(int(math.ceil(grow * (h - l) / cell_size)) + 2 for l, h in zip(lo, hi))
        n_cells = self.dims[0] * self.dims[1] * self.dims[2]
        self.n_cells = n_cells
        pairs = self._count_pairs_np(vertices_np, triangles_np)
        self.pair_capacity = max(int(grow * grow * pairs) + 64, 64)
        self.origin = ti.Vector.field(3, ti.f32, ())
        self.cell_count = ti.field(ti.i32, n_cells)
        self.cell_start = ti.field(ti.i32, n_cells + 1)
        self.cell_triangles = ti.field(ti.i32, self.pair_capacity)
        self.n_pairs = 0
        self.build(vertices_np)

    def _count_pairs_np(self, v, t) -> int:
        lo = v[t].min(1) - self.pad
        hi = v[t].max(1) + self.pad
        span = np.floor(hi / self.cell_size) - np.floor(lo / self.cell_size) + 1
        return int(span.prod(1).sum())

    def build(self, vertices_np: np.ndarray | None = None) -> int:
        """(Re)bin every triangle; call after the mesh moved. The grid is re-centred on the mesh bounds (from
        `vertices_np` if given, else read back). Returns the number of (triangle, cell) pairs."""
        v = self.vertices.to_numpy() if vertices_np is None else vertices_np
        centre = 0.5 * (v.min(0) + v.max(0))
        extent = np.array(self.dims) * self.cell_size
        if np.any(v.max(0) - v.min(0) + 2 * self.margin > extent - 2 * self.cell_size):
            raise ValueError("the mesh outgrew its voxel grid; build the collider again with a larger margin")
        self.origin[None] = (centre - 0.5 * extent).tolist()
        self._count()
        total = self._scan()
        if total > self.pair_capacity:
            raise ValueError(f"voxel grid needs {total} triangle-cell pairs, capacity {self.pair_capacity}: "
                             "build the collider again (or use a larger cell size)")
        self._fill()
        self.n_pairs = total
        return total

    @ti.func
    def cell_coord(self, p):
        """Integer cell coordinates of point p (not clamped)."""
        return ti.floor((p - self.origin[None]) / self.cell_size, ti.i32)

    @ti.func
    def cell_index(self, c):
        return (c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]

    @ti.func
    def clamp_range(self, lo, hi):
        """Cell coordinate ranges covering the box [lo, hi] [m], clipped to the grid; empty when outside."""
        cmin = ti.max(self.cell_coord(lo), 0)
        cmax = ti.min(self.cell_coord(hi), ti.Vector([self.dims[0] - 1, self.dims[1] - 1, self.dims[2] - 1]))
        return cmin, cmax

    @ti.func
    def triangle_box(self, t):
        tri = self.triangles[t]
        a, b, c = self.vertices[tri[0]], self.vertices[tri[1]], self.vertices[tri[2]]
        return ti.min(a, b, c) - self.pad, ti.max(a, b, c) + self.pad

    @ti.kernel
    def _count(self):
        for c in range(self.n_cells):
            self.cell_count[c] = 0
        for t in range(self.n_triangles[None]):
            lo, hi = self.triangle_box(t)
            cmin, cmax = self.clamp_range(lo, hi)
            for i, j, k in ti.ndrange((cmin[0], cmax[0] + 1), (cmin[1], cmax[1] + 1), (cmin[2], cmax[2] + 1)):
                ti.atomic_add(self.cell_count[self.cell_index(ti.Vector([i, j, k]))], 1)

    @ti.kernel
    def _scan(self) -> ti.i32:
        # an exclusive prefix sum; serial, it is ~1e5 additions once per build
        ti.loop_config(serialize=True)
        total = 0
        for c in range(self.n_cells):
            self.cell_start[c] = total
            total += self.cell_count[c]
        self.cell_start[self.n_cells] = total
        return total

    @ti.kernel
    def _fill(self):
        for c in range(self.n_cells):
            self.cell_count[c] = 0  # reused as the fill cursor
        for t in range(self.n_triangles[None]):
            lo, hi = self.triangle_box(t)
            cmin, cmax = self.clamp_range(lo, hi)
            for i, j, k in ti.ndrange((cmin[0], cmax[0] + 1), (cmin[1], cmax[1] + 1), (cmin[2], cmax[2] + 1)):
                cell = self.cell_index(ti.Vector([i, j, k]))
                slot = ti.atomic_add(self.cell_count[cell], 1)
                self.cell_triangles[self.cell_start[cell] + slot] = t

    # ------------------------------------------------------------------ host-side inspection (tests)
    def triangles_in_box(self, lo, hi) -> np.ndarray:
        """Sorted unique triangle ids binned in the cells overlapping box [lo, hi] [m] (numpy, for tests)."""
        origin = self.origin.to_numpy()
        cmin = np.maximum(np.floor((np.asarray(lo) - origin) / self.cell_size).astype(int), 0)
        cmax = np.minimum(np.floor((np.asarray(hi) - origin) / self.cell_size).astype(int), np.array(self.dims) - 1)
        if np.any(cmin > cmax):
            return np.zeros(0, np.int64)
        start = self.cell_start.to_numpy()
        tris = self.cell_triangles.to_numpy()
        ii, jj, kk = np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(cmin, cmax)], indexing="ij")
        cells = ((kk * self.dims[1] + jj) * self.dims[0] + ii).ravel()
        if len(cells) == 0:
            return np.zeros(0, np.int64)
        return np.unique(np.concatenate([tris[start[c]:start[c + 1]] for c in cells]))
