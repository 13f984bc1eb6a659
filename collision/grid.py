"""A uniform voxel grid over a triangle mesh, built in Taichi kernels (count, prefix sum, fill).

Each triangle is binned into every cell its bounding box, inflated by `pad`, overlaps (docs/algorithms.md, collision:
Teschner 2003 finds the best cell size near the mean primitive size). Dense mode covers the mesh's bounds
plus `margin` with a fixed number of cells, so rebuilding after the mesh moves or morphs refills the same
fields (no reallocation, no recompile) while the mesh stays within the allocated extent. Hashed mode
(Teschner et al. 2003: hash(i,j,k) = (73856093 i ^ 19349663 j ^ 83492791 k) mod a prime) has no bounds, for a
mesh that travels (the cloth itself, for self-collision); cells sharing a bucket only add candidates. With
`vertices_start` the boxes span each triangle's start and end positions (swept over a step). With `bounds` a dense
grid covers a region known in advance (a mesh sequence's every frame) once, and is never re-centred.

`build` rebuilds from the host and checks the capacity at once (one read). A grid rebuilt on the device without a
read (self-collision: `build_pass` inside a kernel, or the `rebuild` launches) follows its 0-d `active` flag (0: its
loops run over nothing) and keeps in `needed` the most (triangle, cell) pairs a rebuild asked for; pairs beyond the
capacity are dropped, and its owner reports `needed` with the frame's measurement (`check_capacity`).
"""
import math

import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock


#: cells per block of the parallel prefix sum (VoxelGrid._scan)
SCAN_BLOCK = 256


@ti.data_oriented
class VoxelGrid:
    """Cells of edge `cell_size` [m] over the AABB of `vertices` (a (V,) vec3 field) plus `margin` [m].

    cell_start: (C+1,) i32 CSR offsets; cell_triangles: (pair capacity,) i32 triangle ids; origin: 0-d vec3 [m];
    dims: the grid size in cells (fixed). `triangles` is a (T,) ivec3 field, `n_triangles` a 0-d i32 field.
    `grow` leaves room for the mesh to grow by that factor in extent and in (triangle, cell) pairs; `bounds` (lo,
    hi) [m]: the box the mesh stays in for its whole life (the grid covers it plus `margin`, fixed); `capacity`:
    the (triangle, cell) pairs to hold, when the caller knows better (a deforming mesh).
    """

    def __init__(self, vertices, triangles, n_triangles, cell_size: float, pad: float, margin: float,
                 vertices_np: np.ndarray, triangles_np: np.ndarray, grow: float = 1.25, hashed: bool = False,
                 vertices_start=None, serial: bool = False, bounds=None, capacity: int | None = None):
        if not cell_size > 0:
            raise ValueError(f"voxel cell size must be > 0 m, got {cell_size}")
        self.vertices, self.triangles, self.n_triangles = vertices, triangles, n_triangles
        self.serial = bool(serial)  # loops in one thread (a grid rebuilt every step over a small cloth)
        self.vertices_start = vertices_start
        self.swept = vertices_start is not None
        self.cell_size, self.pad, self.margin, self.hashed = float(cell_size), float(pad), float(margin), hashed
        pairs = self._count_pairs_np(vertices_np, triangles_np)
        if hashed:
            self.dims = (0, 0, 0)
            self.n_cells = _prime_at_least(int(hashed_cells(pairs, grow)))
        else:
            lo, hi = (vertices_np.min(0), vertices_np.max(0)) if bounds is None else map(np.asarray, bounds)
            lo, hi = lo - margin, hi + margin
            self.dims = tuple(int(math.ceil(grow * (h - a) / cell_size)) + 2 for a, h in zip(lo, hi))
            self.n_cells = self.dims[0] * self.dims[1] * self.dims[2]
        n_cells = self.n_cells
        if capacity is not None:
            self.pair_capacity = int(capacity)
        elif hashed or self.swept:
            # a moving mesh (cloth folding, moving fast): room for every triangle turned any way
            self.pair_capacity = self._pairs_bound_np(vertices_np, triangles_np) + 64
        else:
            self.pair_capacity = max(int(grow * grow * pairs) + 64, 64)
        blk = FieldBlock()
        self.origin = blk.vector(3, ti.f32, ())
        self.cell_count = blk.scalar(ti.i32, n_cells)
        self.cell_start = blk.scalar(ti.i32, n_cells + 1)
        self.block_count = blk.scalar(ti.i32, -(-n_cells // SCAN_BLOCK))  # cells of each scan block (parallel scan)
        self.cell_triangles = blk.scalar(ti.i32, self.pair_capacity)
        self.active = blk.scalar(ti.i32, ())  # 0: a rebuild on the device does nothing (the mesh did not move enough)
        self.total = blk.scalar(ti.i32, ())  # the (triangle, cell) pairs of the last rebuild
        self.needed = blk.scalar(ti.i32, ())  # the most pairs a rebuild asked for since check_capacity
        blk.finalize(self)
        self.active[None] = 1
        self.n_pairs = 0
        self.fixed = bounds is not None and not hashed
        if self.fixed:
            self.origin[None] = (0.5 * (lo + hi) - 0.5 * np.array(self.dims) * self.cell_size).tolist()
        self.build(vertices_np)

    def _count_pairs_np(self, v, t) -> int:
        lo = v[t].min(1) - self.pad
        hi = v[t].max(1) + self.pad
        span = np.floor(hi / self.cell_size) - np.floor(lo / self.cell_size) + 1
        return int(span.prod(1).sum())

    def _pairs_bound_np(self, v, t) -> int:
        return int(pairs_bound(v, t, self.cell_size, self.pad, self.swept))

    def build(self, vertices_np: np.ndarray | None = None) -> int:
        """(Re)bin every triangle; call after the mesh moved. The grid is re-centred on the mesh bounds (from
        `vertices_np` if given, else read back). Returns the number of (triangle, cell) pairs."""
        if not self.hashed and not self.fixed:
            v = self.vertices.to_numpy() if vertices_np is None else vertices_np
            centre = 0.5 * (v.min(0) + v.max(0))
            extent = np.array(self.dims) * self.cell_size
            if np.any(v.max(0) - v.min(0) + 2 * self.margin > extent - 2 * self.cell_size):
                raise ValueError("the mesh outgrew its voxel grid; build the collider again with a larger margin")
            self.origin[None] = (centre - 0.5 * extent).tolist()
        self.rebuild()
        total = int(self.total[None])
        self.check_capacity(total)
        self.n_pairs = total
        return total

    def rebuild(self) -> None:
        """Bin every triangle again where `active` is set, with no read (the capacity: check_capacity)."""
        self._count()
        self._scan()
        self._fill()
        if not self.serial:
            self._sort_cells()

    @ti.kernel
    def report(self, out: ti.template(), offset: ti.i32):
        """Put the most (triangle, cell) pairs a rebuild asked for since the last report in out[offset] (the frame's
        one read), and count afresh."""
        out[offset] = ti.cast(self.needed[None], ti.f64)
        self.needed[None] = 0

    def reported(self, values) -> None:
        """The frame's read is back: values[0] is what report put there."""
        self.check_capacity(int(values[0]))

    def check_capacity(self, needed: int) -> None:
        """Raise if a rebuild asked for more (triangle, cell) pairs than the grid holds."""
        if needed > self.pair_capacity:
            raise ValueError(f"voxel grid needs {needed} triangle-cell pairs, capacity {self.pair_capacity}: "
                             "build the collider again (or use a larger cell size)")

    @ti.func
    def gate(self, n):
        """n while a rebuild is on (active), else 0: the range of the rebuild's loops."""
        return ti.select(self.active[None] != 0, n, 0)

    @ti.func
    def build_pass(self):
        """The whole rebuild (count, prefix sum, fill) inside a kernel; in a loop in one thread on a serial grid."""
        self.count_pass()
        self.scan_pass()
        self.fill_pass()

    @ti.func
    def cell_coord(self, p):
        """Integer cell coordinates of point p (not clamped)."""
        return ti.floor((p - self.origin[None]) / self.cell_size, ti.i32)

    @ti.func
    def cell_index(self, c):
        out = 0
        if ti.static(self.hashed):
            h = (c[0] * 73856093) ^ (c[1] * 19349663) ^ (c[2] * 83492791)
            out = (h % self.n_cells + self.n_cells) % self.n_cells
        else:
            out = (c[2] * self.dims[1] + c[1]) * self.dims[0] + c[0]
        return out

    @ti.func
    def clamp_range(self, lo, hi):
        """Cell coordinate ranges covering the box [lo, hi] [m], clipped to a dense grid (empty when outside)."""
        cmin = self.cell_coord(lo)
        cmax = self.cell_coord(hi)
        if ti.static(not self.hashed):
            cmin = ti.max(cmin, 0)
            cmax = ti.min(cmax, ti.Vector([self.dims[0] - 1, self.dims[1] - 1, self.dims[2] - 1]))
        return cmin, cmax

    @ti.func
    def triangle_box(self, t):
        tri = self.triangles[t]
        a, b, c = self.vertices[tri[0]], self.vertices[tri[1]], self.vertices[tri[2]]
        lo = ti.min(a, b, c)
        hi = ti.max(a, b, c)
        if ti.static(self.swept):
            a0, b0, c0 = self.vertices_start[tri[0]], self.vertices_start[tri[1]], self.vertices_start[tri[2]]
            lo = ti.min(lo, a0, b0, c0)
            hi = ti.max(hi, a0, b0, c0)
        return ti.cast(lo, ti.f32) - self.pad, ti.cast(hi, ti.f32) + self.pad

    @ti.kernel
    def _count(self):
        self.count_pass()

    @ti.func
    def count_pass(self):
        ti.loop_config(serialize=self.serial)
        for c in range(self.gate(self.n_cells)):
            self.cell_count[c] = 0
        ti.loop_config(serialize=self.serial)
        for t in range(self.gate(self.n_triangles[None])):
            lo, hi = self.triangle_box(t)
            cmin, cmax = self.clamp_range(lo, hi)
            for i, j, k in ti.ndrange((cmin[0], cmax[0] + 1), (cmin[1], cmax[1] + 1), (cmin[2], cmax[2] + 1)):
                ti.atomic_add(self.cell_count[self.cell_index(ti.Vector([i, j, k]))], 1)

    @ti.kernel
    def _scan(self):
        self.scan_pass()

    @ti.func
    def scan_pass(self):
        """cell_start = the exclusive prefix sum of cell_count (clipped to the capacity); total its sum (and needed
        the largest). Serial: one
        thread, ~1e5 additions once per build. Parallel (no loop in one thread: a GPU): each block of SCAN_BLOCK
        cells sums itself, then starts after the sum of the blocks before it (each block adds those up itself: a
        few hundred additions each) and scans its own cells."""
        if ti.static(self.serial):
            total = 0
            ti.loop_config(serialize=True)
            for c in range(self.gate(self.n_cells)):
                self.cell_start[c] = ti.min(total, self.pair_capacity)
                total += self.cell_count[c]
            if self.active[None] != 0:
                self.total[None] = total
                self.cell_start[self.n_cells] = ti.min(total, self.pair_capacity)
        else:
            B, NB = ti.static(SCAN_BLOCK), ti.static(-(-self.n_cells // SCAN_BLOCK))
            for b in range(self.gate(NB)):
                acc = 0
                for c in range(b * B, ti.min((b + 1) * B, self.n_cells)):
                    acc += self.cell_count[c]
                self.block_count[b] = acc
            for b in range(self.gate(NB)):
                start = 0
                for a in range(b):
                    start += self.block_count[a]
                for c in range(b * B, ti.min((b + 1) * B, self.n_cells)):
                    self.cell_start[c] = ti.min(start, self.pair_capacity)
                    start += self.cell_count[c]
                if b == NB - 1:
                    self.total[None] = start
                    self.cell_start[self.n_cells] = ti.min(start, self.pair_capacity)
        if self.active[None] != 0:
            self.needed[None] = ti.max(self.needed[None], self.total[None])

    @ti.kernel
    def _fill(self):
        self.fill_pass()

    @ti.func
    def fill_pass(self):
        ti.loop_config(serialize=self.serial)
        for c in range(self.gate(self.n_cells)):
            self.cell_count[c] = 0  # reused as the fill cursor
        ti.loop_config(serialize=self.serial)
        for t in range(self.gate(self.n_triangles[None])):
            lo, hi = self.triangle_box(t)
            cmin, cmax = self.clamp_range(lo, hi)
            for i, j, k in ti.ndrange((cmin[0], cmax[0] + 1), (cmin[1], cmax[1] + 1), (cmin[2], cmax[2] + 1)):
                cell = self.cell_index(ti.Vector([i, j, k]))
                slot = self.cell_start[cell] + ti.atomic_add(self.cell_count[cell], 1)
                if slot < self.pair_capacity:  # beyond: the rebuild asked for too many (needed says how many)
                    self.cell_triangles[slot] = t

    @ti.kernel
    def _sort_cells(self):
        """Each cell's triangles in ascending index: a parallel fill appends them in the order threads arrive, and
        the collision stage's ranked tests visit candidates in list order, so without this two runs of one scene
        differ (insertion sort: a cell holds a few triangles)."""
        for c in range(self.gate(self.n_cells)):
            begin, end = self.cell_start[c], self.cell_start[c + 1]
            for a in range(begin + 1, end):
                t = self.cell_triangles[a]
                b = a - 1
                while b >= begin:
                    if self.cell_triangles[b] <= t:
                        break
                    self.cell_triangles[b + 1] = self.cell_triangles[b]
                    b -= 1
                self.cell_triangles[b + 1] = t


def pairs_bound(v: np.ndarray, t: np.ndarray, cell_size: float, pad: float, swept: bool = True,
                travel: float = 0.0) -> float:
    """(triangle, cell) pairs of mesh (v (V,3) [m], t (T,3)) in any pose that keeps its edge lengths, each triangle's
    box widened by `pad` [m] and (swept) moved by up to a cell, or by `travel` [m] more, in a step: a box of extent
    e along an axis meets at most floor(e / cell) + 2 cells, and e is at most the longest edge plus twice the pad.
    A float: a tiny cell can make it too large for an integer."""
    longest = np.linalg.norm(v[t] - v[t[:, [1, 2, 0]]], axis=2).max(1)
    per_axis = np.floor((longest + 2 * pad + travel) / cell_size) + (3 if swept else 2)
    return float((per_axis ** 3).sum())


def hashed_cells(pairs: float, grow: float = 1.25) -> float:
    """The cells of a hashed grid sized for `pairs` (triangle, cell) pairs (VoxelGrid; a prime near this)."""
    return 2 * grow * grow * pairs + 1031


def _prime_at_least(n: int) -> int:
    def is_prime(k):
        return k > 1 and all(k % d for d in range(2, int(k ** 0.5) + 1))

    while not is_prime(n):
        n += 1
    return n
