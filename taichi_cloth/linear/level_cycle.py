"""V-cycles over the cloth's nested 4-8 levels: a preconditioner of the implicit step's block system (linear.system).

Every level l has the system of linear.system with its own masses and springs: every 4-8 level of a cloth is
built from the same material (taichi_cloth.multilevel_cloth), so the coarse operators are rediscretisations of the
fine one. Every vertex of level l has a copy on level l + 1 (a vertex whose prolongation row is that one vertex with
weight 1): the same index on a 4-8 rectangle, where the levels are nested by index, another one on a garment's
levels, nested by their tables (taichi_cloth.garment.levels). Following the copies up to the level simulated
gives every coarser level its geometry from the simulated positions: the coarse springs point where the cloth is.

A V(nu, nu) cycle (the preconditioner, symmetric as CG needs):
  * smoother: block Jacobi, dv_i += omega D_i^-1 (b - A dv)_i with D_i the 3x3 diagonal block of A;
  * restriction R = P^T (a gather from the transpose of the prolongation table), prolongation P = the
    hierarchy's tables, applied to each component;
  * the coarsest level is solved exactly: its 3 n0 x 3 n0 matrix is assembled and factored (linear.dense,
    float64) once per system, in one thread (n0 = 25 for the usual 4 x 4 base);
  * contacts, on the simulated level: a particle that static friction holds is fixed as a pin is, and a sliding
    one has its smoother block, its residual and its coarse correction filtered (S = I - n n^T: the block
    S D S + m'(I - S)), so that the cycle smooths the filtered system CG solves; the sliding friction's dashpot
    (the system's extra_mass) is on its diagonal, as in A;
  * pins: a particle of the simulated level with inverse mass 0 is fixed; a coarser vertex is fixed iff it is a
    prolongation parent of a fixed vertex of the level above, so that a prolonged correction vanishes at the
    pins by construction (zeroing the correction afterwards is not enough: with one pinned midpoint the coarse
    level does not know, the coarse correction is a free-fall one and the cycle diverges).
    Both are decided on the device at every prepare, so pins that move between levels need no host work.
The caller (linear.pcg) filters what the cycle does not know: z = S V(S r) stays symmetric on the free subspace.
Iteration counts and timings against Jacobi: docs/performance.md, preconditioners.

House rules: every level is packed into the same fields (per-level offsets), each kernel compiles once per
solver and takes a level's offsets as arguments, so switching the active level compiles nothing.
"""

import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock
from multilevel.hierarchy import Level

from ..model import csr
from ..runtime import one_thread_loops
from .dense import cholesky, cholesky_solve, factor_in_parallel
from .system import diagonal_block, filtered_block, spring_block, spring_coefficients, spring_row

#: block-Jacobi weight; a scipy prototype measured 0.67 best among 0.5, 0.67 and 0.8 for V(1,1) cycles
DEFAULT_OMEGA = 0.67
#: the largest coarsest level [vertices] factored densely at every step (3 n0 unknowns, serial)
COARSE_MAX = 128
#: levels with fewer vertices run their loops in one thread: on a CPU a parallel loop's dispatch costs more than a
#: serial pass over them (docs/performance.md, preconditioners)
SERIAL_BELOW = 1 << 30


def copies(levels: list[Level]) -> list[np.ndarray]:
    """Per level l but the finest, (n_l,) int64: the index on level l + 1 of each vertex's copy (the vertex whose
    prolongation row is that vertex alone, with weight 1). ValueError when a vertex has none (tables that are not a
    nested hierarchy)."""
    out = []
    for l, (prev, lv) in enumerate(zip(levels, levels[1:])):
        live = (lv.parents >= 0) & (lv.weights != 0)
        single = (live.sum(1) == 1) & live[:, 0] & (lv.weights[:, 0] == 1.0)
        copy = np.full(prev.n_vertices, -1, np.int64)
        fine = np.nonzero(single)[0]
        coarse, first = np.unique(lv.parents[fine, 0], return_index=True)  # the first copy where there are several
        copy[coarse] = fine[first]
        if (copy < 0).any():
            raise ValueError(f"level {l + 1} has {int((copy < 0).sum())} vertices without a copy on level {l + 2}: "
                             "the spring multigrid needs nested levels")
        out.append(copy)
    return out


@ti.data_oriented
class SpringMultigrid:
    """V-cycles over nested 4-8 levels for the implicit spring system (see the module docstring).

    levels:      the hierarchy's levels (0 = coarsest), nested (see `copies`)
    springs:     per level, (s_l, 2) int64 vertex indices of each spring on its level
    stiffness, damping, rest_length: per level, (s_l,) float64 [N/m], [N s/m], [m]
    mass:        per level, (n_l,) float64 [kg]
    viscous:     per level, (s_l,) float64 [N s/m]: the isotropic dashpot of each spring (None: none)
    fp:          ti.f32 or ti.f64, the precision of the fields and kernels (the coarse factor is float64)
    sweeps:      block-Jacobi sweeps before and after each coarse correction (fixed per solver)
    omega:       the Jacobi weight (a runtime attribute: changing it compiles nothing)
    serial_below: levels with fewer vertices run their loops in one thread
    one_thread_coarsest: the coarsest level factored and solved in one thread (default: on the CPU only; elsewhere
                 by linear.dense.factor_in_parallel and its inverse)
    """

    #: applied by its own kernels between CG's (linear.pcg), from a zero start
    inline = False
    warm_start = False

    def __init__(self, levels: list[Level], springs, stiffness, damping, rest_length, mass, fp=ti.f32,
                 sweeps: int = 1, omega: float = DEFAULT_OMEGA, serial_below: int = SERIAL_BELOW, viscous=None,
                 one_thread_coarsest: bool | None = None):
        L = len(levels)
        if viscous is None:
            viscous = [np.zeros(len(s)) for s in springs]
        if L < 1 or not all(len(a) == L for a in (springs, stiffness, damping, rest_length, mass, viscous)):
            raise ValueError("need springs, stiffness, damping, rest_length and mass for every level")
        copy = copies(levels)
        if levels[0].n_vertices > COARSE_MAX:
            raise ValueError(f"the coarsest level has {levels[0].n_vertices} vertices, more than {COARSE_MAX} for "
                             "its dense factorisation: build the cloth on a smaller base")
        if sweeps < 1:
            raise ValueError("need at least one smoothing sweep")
        self.fp, self.sweeps = fp, int(sweeps)
        self.serial_below = int(serial_below)
        self.one_thread = one_thread_loops() if one_thread_coarsest is None else bool(one_thread_coarsest)
        self.n_levels = L
        self.sizes = [lv.n_vertices for lv in levels]
        self.spring_counts = [len(s) for s in springs]
        self.offsets = np.concatenate([[0], np.cumsum(self.sizes)]).astype(np.int64)
        self.spring_offsets = np.concatenate([[0], np.cumsum(self.spring_counts)]).astype(np.int64)
        N, Ns = int(self.offsets[-1]), int(self.spring_offsets[-1])

        # ---- host tables
        ends = []
        rows, adj_other, adj_spring = [], [], []
        for l, s in enumerate(springs):
            s = np.asarray(s, np.int64).reshape(-1, 2)
            if len(s) and (s.min() < 0 or s.max() >= self.sizes[l]):
                raise ValueError(f"level {l}: a spring end lies outside 0..{self.sizes[l] - 1}")
            g = s + self.offsets[l]
            ends.append(g)
            q = np.arange(len(s)) + self.spring_offsets[l]
            rows += [g[:, 0], g[:, 1]]
            adj_other += [g[:, 1], g[:, 0]]
            adj_spring += [q, q]
        adj_ptr, adj_other, adj_spring = csr(np.concatenate(rows), N, np.concatenate(adj_other),
                                             np.concatenate(adj_spring))
        up = np.full(N, -1, np.int64)  # the copy of each vertex on the next level, as a packed index
        for l, c in enumerate(copy):
            up[self.offsets[l]:self.offsets[l + 1]] = c + self.offsets[l + 1]
        par = np.full((N, 3), -1, np.int64)
        pw = np.zeros((N, 3))
        r_rows, r_cols, r_w = [], [], []
        for l in range(1, L):
            lv = levels[l]
            o, oc = self.offsets[l], self.offsets[l - 1]
            live = lv.parents >= 0
            par[o:o + lv.n_vertices] = np.where(live, lv.parents + oc, -1)
            pw[o:o + lv.n_vertices] = np.where(live, lv.weights, 0.0)
            fi, fj = np.nonzero(live & (lv.weights != 0))
            r_rows.append(lv.parents[fi, fj] + oc)
            r_cols.append(fi + o)
            r_w.append(lv.weights[fi, fj])
        if r_rows:
            r_ptr, rc, rw = csr(np.concatenate(r_rows), N, np.concatenate(r_cols), np.concatenate(r_w))
        else:
            r_ptr, rc, rw = np.zeros(N + 1, np.int64), np.zeros(1, np.int64), np.zeros(1)

        # ---- fields
        n0 = self.sizes[0]
        C = 3 * n0
        blk = FieldBlock()
        self.mass = blk.scalar(fp, N)                     # [kg]
        self.pin = blk.scalar(ti.i32, N)                  # 1: dv fixed at 0 on this level
        self.dinv = blk.matrix(3, 3, fp, N)               # inverse 3x3 diagonal blocks [1/kg]
        self.b = blk.vector(3, fp, N)                     # right-hand side per level [kg m/s]
        self.x = blk.vector(3, fp, N)                     # iterate per level [m/s]
        self.r = blk.vector(3, fp, N)                     # residual per level [kg m/s]
        self.adj_ptr = blk.scalar(ti.i32, N + 1)
        self.adj_other = blk.scalar(ti.i32, max(len(adj_other), 1))
        self.adj_spring = blk.scalar(ti.i32, max(len(adj_spring), 1))
        self.end_a = blk.scalar(ti.i32, max(Ns, 1))       # spring ends, packed indices
        self.end_b = blk.scalar(ti.i32, max(Ns, 1))
        self.up = blk.scalar(ti.i32, N)                   # each vertex's copy on the next level (packed; -1 finest)
        self.at = blk.scalar(ti.i32, N)                   # each vertex's particle on the simulated level
        self.k = blk.scalar(fp, max(Ns, 1))               # [N/m]
        self.kd = blk.scalar(fp, max(Ns, 1))              # [N s/m]
        self.c = blk.scalar(fp, max(Ns, 1))               # [N s/m] isotropic dashpot
        self.rest = blk.scalar(fp, max(Ns, 1))            # [m]
        self.u = blk.vector(3, fp, max(Ns, 1))            # unit direction at the current positions
        self.axial = blk.scalar(fp, max(Ns, 1))           # h kd + h^2 k (1 - g) [kg]
        self.iso = blk.scalar(fp, max(Ns, 1))             # h^2 k g + h c [kg]
        self.par = blk.vector(3, ti.i32, N)
        self.pw = blk.vector(3, fp, N)
        self.r_ptr = blk.scalar(ti.i32, N + 1)
        self.r_child = blk.scalar(ti.i32, max(len(rc), 1))
        self.r_w = blk.scalar(fp, max(len(rw), 1))
        self.chol = blk.scalar(ti.f64, (C, C))            # the coarsest level's Cholesky factor (lower)
        self.work = blk.scalar(ti.f64, C)
        if not self.one_thread:  # the parallel factor's diagonal, the inverse, the product
            self.pivots, self.inverse, self.solution = blk.scalar(ti.f64, C), blk.scalar(ti.f64, (C, C)), \
                blk.scalar(ti.f64, C)
        self.mass_scale = blk.scalar(fp, ())              # 1 + h gamma of the current step
        self.level = blk.scalar(ti.i32, ())               # the active level
        self.weight = blk.scalar(fp, ())                  # omega
        self.proj = blk.matrix(3, 3, fp, N)               # the contact filter S (simulated level; I elsewhere)
        self.extra = blk.scalar(fp, N)                    # the system's extra_mass (simulated level), or 0 [kg]
        blk.finalize(self)
        self.omega = float(omega)

        npf = np.float32 if fp == ti.f32 else np.float64
        cat = lambda arrays: np.concatenate([np.asarray(a, np.float64).reshape(-1) for a in arrays])  # noqa: E731
        self.mass.from_numpy(cat(mass).astype(npf))
        self.adj_ptr.from_numpy(adj_ptr.astype(np.int32))
        if len(adj_other):
            self.adj_other.from_numpy(adj_other.astype(np.int32))
            self.adj_spring.from_numpy(adj_spring.astype(np.int32))
        if Ns:
            e = np.concatenate(ends)
            self.end_a.from_numpy(e[:, 0].astype(np.int32))
            self.end_b.from_numpy(e[:, 1].astype(np.int32))
            self.k.from_numpy(cat(stiffness).astype(npf))
            self.kd.from_numpy(cat(damping).astype(npf))
            self.c.from_numpy(cat(viscous).astype(npf))
            self.rest.from_numpy(cat(rest_length).astype(npf))
        self.up.from_numpy(up.astype(np.int32))
        self.par.from_numpy(par.astype(np.int32))
        self.pw.from_numpy(pw.astype(npf))
        self.r_ptr.from_numpy(r_ptr.astype(np.int32))
        self.r_child.from_numpy(rc.astype(np.int32))
        self.r_w.from_numpy(rw.astype(npf))
        self.set_active_level(L - 1)

    # ------------------------------------------------------------------ host side
    @property
    def active(self) -> int:
        return self._active

    def set_active_level(self, level: int) -> None:
        """The level simulated now (coarse-to-fine simulation): cycles use levels 0..level."""
        level = int(level)
        if not 0 <= level < self.n_levels:
            raise ValueError(f"level must lie in 0..{self.n_levels - 1}, got {level}")
        self._active = level
        self.level[None] = level

    @property
    def omega(self) -> float:
        return self._omega

    @omega.setter
    def omega(self, value: float) -> None:
        self._omega = float(value)
        self.weight[None] = self._omega

    @property
    def detail(self) -> str:
        return f"V-cycles over {self.n_levels} 4-8 levels"

    def prepare(self, system, filt) -> None:
        """Once per system, before the cycles: every level's springs at the positions system.x (the simulated
        level's (P,) vec3 field [m]) for its step system.h [s] and system.h_gamma, the pins (the simulated level's
        inverse masses 0, and their parents), the block inverses and the coarsest factor. filt
        (linear.ConstraintFilter): a particle its contacts' static friction holds is fixed as a pin is, a sliding
        one's normal is left out on the simulated level (its smoother and its transfers work on the filtered system
        there). One kernel launch."""
        self._prepare(system, filt, system.h, system.h_gamma, int(self.spring_offsets[self._active + 1]))
        if not self.one_thread:
            factor_in_parallel(self.chol, self.pivots, self.inverse, 3 * self.sizes[0], system.live)

    def apply(self, r, z) -> None:
        """z = V-cycle(r) on the active level: r, z are (P,) vec3 fields of the simulated level [kg m/s], [m/s]
        (pinned rows of z come out 0). One kernel launch."""
        self._cycle(r, z)

    # ------------------------------------------------------------------ helpers of the kernels
    @ti.func
    def _count(self, l: ti.template()):
        """Vertices of level l if it takes part in the cycles (l <= the active level), else 0."""
        return ti.select(l <= self.level[None], ti.static(self.sizes[l]), 0)

    @ti.func
    def _block(self, g, mass_scale):
        return diagonal_block(self.fp, self.mass[g], mass_scale, self.adj_ptr[g], self.adj_ptr[g + 1],
                              self.adj_spring, self.u, self.axial, self.iso) \
            + ti.Matrix.identity(self.fp, 3) * self.extra[g]

    @ti.func
    def _filtered(self, g, vec):
        """S vec: vec without its components along vertex g's sliding-contact normals (none off the simulated
        level)."""
        return self.proj[g] @ vec

    @ti.func
    def _apply_A(self, g):
        """(A x)_g on g's level, from the current iterate x."""
        return spring_row((self.mass[g] * self.mass_scale[None] + self.extra[g]) * self.x[g], g, self.adj_ptr[g],
                          self.adj_ptr[g + 1],
                          self.adj_spring, self.adj_other, self.u, self.axial, self.iso, self.x)

    # ------------------------------------------------------------------ the kernels
    @ti.kernel
    def _prepare(self, system: ti.template(), filt: ti.template(), h: ti.f64, h_gamma: ti.f64, n_springs: ti.i32):
        L = ti.static(self.n_levels)
        hh = ti.cast(h, self.fp)
        mass_scale = 1.0 + ti.cast(h_gamma, self.fp)
        self.mass_scale[None] = mass_scale
        active = self.level[None]
        # every vertex's particle on the simulated level: its own, then from the finest down, its copy's
        for l in ti.static(range(L)):
            ti.loop_config(serialize=ti.static(self.sizes[l] < self.serial_below))
            for i in range(system.gated(ti.select(l == active, ti.static(self.sizes[l]), 0))):
                self.at[ti.static(int(self.offsets[l])) + i] = i
        for k in ti.static(range(L - 1)):
            l = ti.static(L - 2 - k)
            ti.loop_config(serialize=ti.static(self.sizes[l] < self.serial_below))
            for i in range(system.gated(ti.select(l < active, ti.static(self.sizes[l]), 0))):
                g = ti.static(int(self.offsets[l])) + i
                self.at[g] = self.at[self.up[g]]
        # the springs of every level up to the active one, at the positions of the simulated level
        ti.loop_config(serialize=ti.static(int(self.spring_offsets[-1]) < self.serial_below))
        for q in range(system.gated(n_springs)):
            d = ti.cast(system.x[self.at[self.end_b[q]]] - system.x[self.at[self.end_a[q]]], self.fp)
            u, axial, iso = spring_coefficients(d, hh, self.k[q], self.kd[q], self.c[q], self.rest[q])
            self.u[q] = u
            self.axial[q] = axial
            self.iso[q] = iso
        # pins: the simulated level's own (inverse mass 0), then every coarser level inherits them
        for l in ti.static(range(L)):
            ti.loop_config(serialize=ti.static(self.sizes[l] < self.serial_below))
            for i in range(system.gated(self._count(l))):
                g = ti.static(int(self.offsets[l])) + i
                fixed = 0
                S = ti.Matrix.identity(self.fp, 3)
                extra = ti.cast(0.0, self.fp)
                if l == active:
                    fixed = ti.select(filt.model.inv_mass[i] == 0, 1, 0)
                    extra = ti.cast(system.extra_mass[i], self.fp)
                    if ti.static(filt.has_contacts):
                        if filt.contacts.stuck[i] != 0:
                            fixed = 1
                        else:
                            S = ti.cast(filt.contacts.projector(i), self.fp)
                self.pin[g] = fixed
                self.proj[g] = S
                self.extra[g] = extra
        for k in ti.static(range(L - 1)):
            l = ti.static(L - 1 - k)  # from the finest down: level l marks the parents on level l - 1
            ti.loop_config(serialize=ti.static(self.sizes[l] < self.serial_below))
            for i in range(system.gated(self._count(l))):
                g = ti.static(int(self.offsets[l])) + i
                if self.pin[g] != 0:
                    for j in ti.static(range(3)):
                        p = self.par[g][j]
                        if p >= 0 and self.pw[g][j] != 0:
                            self.pin[p] = 1
        # block inverses of every level
        for l in ti.static(range(L)):
            ti.loop_config(serialize=ti.static(self.sizes[l] < self.serial_below))
            for i in range(system.gated(self._count(l))):
                g = ti.static(int(self.offsets[l])) + i
                inv = ti.Matrix.zero(self.fp, 3, 3)
                if self.pin[g] == 0:
                    # on a sliding contact the block of the filtered system: S D S + m'(I - S)
                    inv = filtered_block(self.proj[g], self._block(g, mass_scale), self.mass[g] * mass_scale).inverse()
                self.dinv[g] = inv
        # the coarsest level's matrix (pinned rows: identity), each vertex its three rows; factored L L^T in one
        # thread on the CPU (elsewhere: prepare, by factor_in_parallel)
        n0 = ti.static(self.sizes[0])
        C = ti.static(3 * self.sizes[0])
        ti.loop_config(serialize=ti.static(self.one_thread))
        for i, j in ti.ndrange(system.gated(C), C):
            self.chol[i, j] = 0.0
        ti.loop_config(serialize=ti.static(self.one_thread))
        for v in range(system.gated(n0)):
            if self.pin[v] != 0:
                for c in ti.static(range(3)):
                    self.chol[3 * v + c, 3 * v + c] = 1.0
            else:
                D = ti.cast(self._block(v, mass_scale), ti.f64)
                for c in ti.static(range(3)):
                    for d in ti.static(range(3)):
                        self.chol[3 * v + c, 3 * v + d] = D[c, d]
                for e in range(self.adj_ptr[v], self.adj_ptr[v + 1]):
                    w = self.adj_other[e]
                    if self.pin[w] == 0:
                        q = self.adj_spring[e]
                        B = spring_block(ti.cast(self.u[q], ti.f64), ti.cast(self.axial[q], ti.f64),
                                         ti.cast(self.iso[q], ti.f64))
                        for c in ti.static(range(3)):
                            for d in ti.static(range(3)):
                                self.chol[3 * v + c, 3 * w + d] -= B[c, d]
        if ti.static(self.one_thread):
            ti.loop_config(serialize=True)
            for _ in range(system.gated(1)):
                cholesky(self.chol, C)

    @ti.func
    def _residual(self, l: ti.template()):
        """r = S (b - A x) on level l (0 at its fixed vertices)."""
        ti.loop_config(serialize=ti.static(self.sizes[l] < self.serial_below))
        for i in range(self._count(l)):
            g = ti.static(int(self.offsets[l])) + i
            res = ti.Vector.zero(self.fp, 3)
            if self.pin[g] == 0:
                res = self._filtered(g, self.b[g] - self._apply_A(g))
            self.r[g] = res

    @ti.func
    def _smooth(self, l: ti.template(), from_zero: ti.template()):
        """`sweeps` weighted block-Jacobi sweeps on level l, from its current iterate; `from_zero`: the iterate is
        0, so the first sweep's residual is b itself (one operator application saved per level and cycle)."""
        off = ti.static(int(self.offsets[l]))
        w = self.weight[None]
        for k in ti.static(range(self.sweeps)):
            if ti.static(from_zero and k == 0):
                ti.loop_config(serialize=ti.static(self.sizes[l] < self.serial_below))
                for i in range(self._count(l)):
                    g = off + i
                    self.x[g] = w * (self.dinv[g] @ self.b[g])
            else:
                self._residual(l)
                ti.loop_config(serialize=ti.static(self.sizes[l] < self.serial_below))
                for i in range(self._count(l)):
                    g = off + i
                    self.x[g] += w * (self.dinv[g] @ self.r[g])

    @property
    def in_thread(self) -> bool:
        """Whether a CG iteration may run the cycle inside its own one-thread kernel (every loop serial)."""
        return self.serial_below > max(max(self.sizes), int(self.spring_offsets[-1]))

    @ti.kernel
    def _cycle(self, r: ti.template(), z: ti.template()):
        self.cycle_in_thread(r, z)

    @ti.func
    def cycle_in_thread(self, r: ti.template(), z: ti.template()):
        """z = V-cycle(r) (the body of apply's one launch; callable from a one-thread loop when in_thread)."""
        L = ti.static(self.n_levels)
        active = self.level[None]
        # load the right-hand side on the active level, zero iterate
        for l in ti.static(range(L)):
            ti.loop_config(serialize=ti.static(self.sizes[l] < self.serial_below))
            for i in range(ti.select(l == active, ti.static(self.sizes[l]), 0)):
                g = ti.static(int(self.offsets[l])) + i
                rhs = ti.Vector.zero(self.fp, 3)
                if self.pin[g] == 0:
                    rhs = self._filtered(g, ti.cast(r[i], self.fp))
                self.b[g] = rhs
                self.x[g] = ti.Vector.zero(self.fp, 3)
        # down: smooth, residual, restrict to the level below (whose iterate starts at zero)
        for k in ti.static(range(L - 1)):
            l = ti.static(L - 1 - k)
            coff = ti.static(int(self.offsets[l - 1]))
            self._smooth(l, True)
            self._residual(l)
            ti.loop_config(serialize=ti.static(self.sizes[l - 1] < self.serial_below))
            for c in range(ti.select(l <= active, ti.static(self.sizes[l - 1]), 0)):
                gc = coff + c
                acc = ti.Vector.zero(self.fp, 3)
                if self.pin[gc] == 0:
                    for e in range(self.r_ptr[gc], self.r_ptr[gc + 1]):
                        acc += self.r_w[e] * self.r[self.r_child[e]]
                self.b[gc] = acc
                self.x[gc] = ti.Vector.zero(self.fp, 3)
        # the coarsest level: x_0 = (L L^T)^-1 b_0, in one thread on the CPU, else as the product with the inverse
        n0 = ti.static(self.sizes[0])
        C = ti.static(3 * self.sizes[0])
        if ti.static(self.one_thread):
            ti.loop_config(serialize=True)
            for _ in range(1):
                for v in range(n0):
                    for c in ti.static(range(3)):
                        self.work[3 * v + c] = ti.cast(self.b[v][c], ti.f64)
                cholesky_solve(self.chol, self.work, C)
                for v in range(n0):
                    out = ti.Vector.zero(self.fp, 3)
                    if self.pin[v] == 0:
                        out = ti.Vector([self.work[3 * v], self.work[3 * v + 1], self.work[3 * v + 2]], self.fp)
                    self.x[v] = out
        else:
            for v in range(n0):
                for c in ti.static(range(3)):
                    self.work[3 * v + c] = ti.cast(self.b[v][c], ti.f64)
            for i in range(C):
                acc = ti.cast(0.0, ti.f64)
                for j in range(C):
                    acc += self.inverse[i, j] * self.work[j]
                self.solution[i] = acc
            for v in range(n0):
                out = ti.Vector.zero(self.fp, 3)
                if self.pin[v] == 0:
                    out = ti.Vector([self.solution[3 * v], self.solution[3 * v + 1], self.solution[3 * v + 2]],
                                    self.fp)
                self.x[v] = out
        # up: add the prolonged correction (not on pinned rows), smooth
        for l in ti.static(range(1, L)):
            off = ti.static(int(self.offsets[l]))
            ti.loop_config(serialize=ti.static(self.sizes[l] < self.serial_below))
            for i in range(self._count(l)):
                g = off + i
                if self.pin[g] == 0:
                    corr = ti.Vector.zero(self.fp, 3)
                    for j in ti.static(range(3)):
                        p = self.par[g][j]
                        if p >= 0:
                            corr += self.pw[g][j] * self.x[p]
                    self.x[g] += self._filtered(g, corr)
            self._smooth(l, False)
        # store the active level's iterate
        for l in ti.static(range(L)):
            ti.loop_config(serialize=ti.static(self.sizes[l] < self.serial_below))
            for i in range(ti.select(l == active, ti.static(self.sizes[l]), 0)):
                z[i] = ti.cast(self.x[ti.static(int(self.offsets[l])) + i], z.dtype)
