"""An algebraic multigrid preconditioner for the backward-Euler spring system of any cloth (a mesh file, a sewn
garment, a locally refined cloth): levels by aggregation of neighbouring particles, coarse operators by Galerkin
projection (after Tamstorf, Jones and McCormick 2015, "Smoothed aggregation multigrid for cloth simulation", without
the smoothing of the prolongation).

The system the implicit integrator solves (linear.system gives its blocks) is filtered: S A S dv = S b
with S_i = 0 at a pin and I - n n^T at a contact. The cycle approximates the inverse of

    A~ = S A S + M' (I - S),   M' = M (1 + h gamma),

which is block diagonal over range(S) + null(S), so S A~^-1 S is exactly the filtered system's solution: a
preconditioner for A~ needs no pin or contact logic of its own. A~ is stored as 3x3 blocks: D_i on the diagonal
and O_e = A~(a, b) per edge e = (a, b) (level 0: the cloth's springs, O_s = -S_a B_s S_b).

Aggregation (host, once per topology): a greedy pass over the spring graph makes every particle whose neighbours are
all free the root of an aggregate with them; a second pass adds each particle left to a neighbour's aggregate. The
prolongation P is piecewise constant (P[i, agg(i)] = I), so the Galerkin operator P^T A~ P is again diagonal blocks
plus edge blocks, summed from the level above without any matrix product:

    D_G = sum over members i of D_i + sum over edges e inside G of (O_e + O_e^T)
    O_(G,H) = sum over edges e = (a, b) from G to H of O_e (O_e^T for an edge from H to G)

Levels are built until at most COARSE_TARGET vertices remain; the coarsest is factored (Cholesky, float64) in every
prepare. A V(1,1) cycle with weighted block-Jacobi smoothing is symmetric, as CG needs.

Iteration counts and timings against Jacobi: docs/performance.md, preconditioners.

House rules: the levels are packed into fields sized once from the cloth's capacity (coarse levels hold at most as
many vertices and edges as the cloth), the level bounds are runtime values, so a rebuild after a topology change (a
seam merge, a level switch) loads new tables and compiles nothing.
"""

import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock

from ..model import csr
from .dense import cholesky, cholesky_solve
from .system import filtered_block, spring_block

#: the most levels (the cloth itself included); a 256 x 256 sheet needs 5
MAX_LEVELS = 6
#: aggregate until at most this many vertices remain (the coarsest level is factored densely at every step)
COARSE_TARGET = 32
#: the largest coarsest level accepted when aggregation stalls [vertices]
COARSE_MAX = 128
#: block-Jacobi weight (the scipy prototype: 0.67 and 0.8 equal, 0.5 needs 10 % more iterations)
DEFAULT_OMEGA = 0.67


def aggregate(n: int, ends: np.ndarray) -> np.ndarray:
    """(n,) int64 aggregate of every vertex of a graph with n vertices and (E, 2) edges `ends` (numbered from 0)."""
    ends = np.asarray(ends, np.int64).reshape(-1, 2)
    both = np.concatenate([ends, ends[:, ::-1]])
    both = both[np.argsort(both[:, 1], kind="stable")]  # every vertex's neighbours in increasing order
    ptr, nbr = csr(both[:, 0], n, both[:, 1])
    agg = np.full(n, -1, np.int64)
    count = 0
    for i in range(n):  # roots: a free vertex with all its neighbours free takes them all
        if agg[i] < 0:
            nb = nbr[ptr[i]:ptr[i + 1]]
            if not (agg[nb] >= 0).any():
                agg[i] = count
                agg[nb] = count
                count += 1
    for i in range(n):  # the rest joins a neighbour's aggregate (or, isolated, makes its own)
        if agg[i] < 0:
            nb = nbr[ptr[i]:ptr[i + 1]]
            taken = nb[agg[nb] >= 0]
            if len(taken):
                agg[i] = agg[taken[0]]
            else:
                agg[i] = count
                count += 1
    return agg


@ti.data_oriented
class AggregationMultigrid:
    """V-cycles over aggregation levels for the implicit spring system of a cloth (see the module docstring).

    capacity:  (particles, springs) of the cloth's model: the fields are sized from it once
    fp:        ti.f32 or ti.f64, the precision of the fields and kernels (the coarse factor is float64)
    serial:    run every loop in one thread (the CPU: every level is a few thousand vertices at most per core)
    omega:     the block-Jacobi weight
    Call rebuild(springs, n_particles) before the first prepare, and again whenever the cloth's topology changes.
    """

    #: applied by its own kernels between CG's (linear.pcg), from a zero start
    inline = False
    warm_start = False

    def __init__(self, capacity: tuple[int, int], fp=ti.f32, serial: bool = True, omega: float = DEFAULT_OMEGA):
        P, S = int(capacity[0]), int(max(capacity[1], 1))
        self.fp, self.serial = fp, bool(serial)
        self.capacity = (P, S)
        V, E = 2 * P + 1, 2 * S + 1  # the cloth + every coarse level: each level at most half the one above
        C = 3 * COARSE_MAX
        blk = FieldBlock()
        self.diag = blk.matrix(3, 3, fp, V)       # diagonal blocks of A~ [kg]
        self.dinv = blk.matrix(3, 3, fp, V)       # their inverses [1/kg]
        self.off = blk.matrix(3, 3, fp, E)        # A~(a, b) of every edge [kg]
        self.b = blk.vector(3, fp, V)             # right-hand side per level [kg m/s]
        self.x = blk.vector(3, fp, V)             # iterate per level [m/s]
        self.r = blk.vector(3, fp, V)             # residual per level [kg m/s]
        self.end_a = blk.scalar(ti.i32, E)        # edge ends, global vertex indices
        self.end_b = blk.scalar(ti.i32, E)
        self.adj_ptr = blk.scalar(ti.i32, V + 1)  # per vertex: its edges, the other end, whether it is end a
        self.adj_edge = blk.scalar(ti.i32, 2 * E)
        self.adj_other = blk.scalar(ti.i32, 2 * E)
        self.adj_is_a = blk.scalar(ti.i32, 2 * E)
        self.agg = blk.scalar(ti.i32, V)          # the coarse vertex of every vertex (-1 on the coarsest level)
        self.mem_ptr = blk.scalar(ti.i32, V + 1)  # per coarse vertex: its members on the level above
        self.mem = blk.scalar(ti.i32, V)
        self.in_ptr = blk.scalar(ti.i32, V + 1)   # per coarse vertex: the edges inside it on the level above
        self.inner = blk.scalar(ti.i32, E)
        self.ce_ptr = blk.scalar(ti.i32, E + 1)   # per coarse edge: the edges it sums, and whether transposed
        self.ce = blk.scalar(ti.i32, E)
        self.ce_flip = blk.scalar(ti.i32, E)
        self.vbound = blk.scalar(ti.i32, MAX_LEVELS + 1)  # level l: vertices vbound[l]..vbound[l+1]-1
        self.ebound = blk.scalar(ti.i32, MAX_LEVELS + 1)  # and edges ebound[l]..ebound[l+1]-1
        self.n_levels = blk.scalar(ti.i32, ())
        self.chol = blk.scalar(ti.f64, (C, C))    # the coarsest level's Cholesky factor (lower)
        self.work = blk.scalar(ti.f64, C)
        self.weight = blk.scalar(fp, ())
        blk.finalize(self)
        self.weight[None] = float(omega)
        self.sizes: list[int] = []
        self.edge_counts: list[int] = []

    # ------------------------------------------------------------------ host side
    def rebuild(self, springs: np.ndarray, n_particles: int) -> None:
        """Aggregate the cloth whose (S, 2) spring ends (particle indices) are `springs`, and load the level tables.
        Raises ValueError when the cloth exceeds the capacity or aggregation stalls above COARSE_MAX vertices."""
        P, S = self.capacity
        ends = np.asarray(springs, np.int64).reshape(-1, 2)
        n = int(n_particles)
        if n > P or len(ends) > S:
            raise ValueError(f"a cloth of {n} particles and {len(ends)} springs exceeds the multigrid's capacity "
                             f"{self.capacity}")
        if n < 1:
            raise ValueError("the aggregation multigrid needs at least one particle")
        sizes, edges, aggs = [n], [ends], []
        while sizes[-1] > COARSE_TARGET and len(sizes) < MAX_LEVELS:
            agg = aggregate(sizes[-1], edges[-1])
            nc = int(agg.max()) + 1
            if 2 * nc > sizes[-1]:  # stalls: fewer than two vertices per aggregate
                break
            ca, cb = agg[edges[-1][:, 0]], agg[edges[-1][:, 1]]
            keep = ca != cb
            pairs = np.unique(np.sort(np.stack([ca[keep], cb[keep]], 1), axis=1), axis=0).reshape(-1, 2)
            aggs.append(agg)
            sizes.append(nc)
            edges.append(pairs)
        if sizes[-1] > COARSE_MAX:
            raise ValueError(f"aggregation stopped at {sizes[-1]} vertices, more than {COARSE_MAX} for the coarsest "
                             "level's dense factorisation")
        self.sizes, self.edge_counts = sizes, [len(e) for e in edges]
        L = len(sizes)
        vb = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        eb = np.concatenate([[0], np.cumsum(self.edge_counts)]).astype(np.int64)
        V, E = self.diag.shape[0], self.off.shape[0]
        if vb[-1] > V or eb[-1] > E:
            raise ValueError("the aggregation levels exceed the multigrid's capacity")
        g_ends = np.concatenate([e + vb[l] for l, e in enumerate(edges)]).reshape(-1, 2)
        end_a, end_b = np.zeros(E, np.int32), np.zeros(E, np.int32)
        end_a[:eb[-1]], end_b[:eb[-1]] = g_ends[:, 0], g_ends[:, 1]
        # adjacency over every level
        rows = np.concatenate([g_ends[:, 0], g_ends[:, 1]])
        edge = np.concatenate([np.arange(eb[-1])] * 2)
        other = np.concatenate([g_ends[:, 1], g_ends[:, 0]])
        is_a = np.concatenate([np.ones(eb[-1], np.int64), np.zeros(eb[-1], np.int64)])
        adj_ptr, edge, other, is_a = csr(rows, V, edge, other, is_a)
        pad = lambda a, size: np.concatenate([a, np.zeros(size - len(a), np.int64)]).astype(np.int32)  # noqa: E731
        # aggregates, members, inner edges and coarse edges of every coarse level
        agg_all = np.full(V, -1, np.int64)
        mem_keys, mem_vals, in_keys, in_vals, ce_keys, ce_vals, ce_flip = [], [], [], [], [], [], []
        for l, agg in enumerate(aggs):
            fine = np.arange(sizes[l]) + vb[l]
            coarse = agg + vb[l + 1]
            agg_all[fine] = coarse
            mem_keys.append(coarse)
            mem_vals.append(fine)
            ca, cb = agg[edges[l][:, 0]], agg[edges[l][:, 1]]
            fe = np.arange(len(edges[l])) + eb[l]
            inside = ca == cb
            in_keys.append(ca[inside] + vb[l + 1])
            in_vals.append(fe[inside])
            lo, hi = np.minimum(ca, cb)[~inside], np.maximum(ca, cb)[~inside]
            # the coarse edge of (lo, hi): its row in the sorted unique pairs of level l + 1
            cidx = np.searchsorted(edges[l + 1][:, 0] * sizes[l + 1] + edges[l + 1][:, 1], lo * sizes[l + 1] + hi)
            ce_keys.append(cidx + eb[l + 1])
            ce_vals.append(fe[~inside])
            ce_flip.append((ca > cb)[~inside])
        cat = lambda parts: np.concatenate(parts) if parts else np.zeros(0, np.int64)  # noqa: E731
        mem_ptr, mem = csr(cat(mem_keys), V, cat(mem_vals))
        in_ptr, inner = csr(cat(in_keys), V, cat(in_vals))
        ce_ptr, ce, flip = csr(cat(ce_keys), E, cat(ce_vals), cat(ce_flip).astype(np.int64))
        self.end_a.from_numpy(end_a)
        self.end_b.from_numpy(end_b)
        self.adj_ptr.from_numpy(adj_ptr.astype(np.int32))
        self.adj_edge.from_numpy(pad(edge, 2 * E))
        self.adj_other.from_numpy(pad(other, 2 * E))
        self.adj_is_a.from_numpy(pad(is_a, 2 * E))
        self.agg.from_numpy(agg_all.astype(np.int32))
        self.mem_ptr.from_numpy(mem_ptr.astype(np.int32))
        self.mem.from_numpy(pad(mem, V))
        self.in_ptr.from_numpy(in_ptr.astype(np.int32))
        self.inner.from_numpy(pad(inner, E))
        self.ce_ptr.from_numpy(ce_ptr.astype(np.int32))
        self.ce.from_numpy(pad(ce, E))
        self.ce_flip.from_numpy(pad(flip, E))
        self.vbound.from_numpy(np.concatenate([vb, np.full(MAX_LEVELS - L, vb[-1])]).astype(np.int32))
        self.ebound.from_numpy(np.concatenate([eb, np.full(MAX_LEVELS - L, eb[-1])]).astype(np.int32))
        self.n_levels[None] = L

    @property
    def omega(self) -> float:
        return float(self.weight[None])

    @omega.setter
    def omega(self, value: float) -> None:
        self.weight[None] = float(value)

    @property
    def detail(self) -> str:
        return f"V-cycles over {len(self.sizes)} aggregation levels ({' > '.join(str(n) for n in self.sizes)})"

    def prepare(self, system, filt) -> None:
        """Once per Newton system: the level operators of A~ from the system's diagonal blocks and spring blocks
        (linear.BlockSystem) and the filter S (linear.ConstraintFilter). One kernel launch."""
        self._prepare(system, filt)

    def apply(self, r, z) -> None:
        """z = V-cycle(r): r, z are (P,) vec3 fields of the cloth [kg m/s], [m/s]. One kernel launch."""
        self._cycle(r, z)

    # ------------------------------------------------------------------ helpers of the kernels
    @ti.func
    def _apply_A(self, g):
        """(A~ x)_g on g's level, from the current iterate x."""
        out = self.diag[g] @ self.x[g]
        for e in range(self.adj_ptr[g], self.adj_ptr[g + 1]):
            q = self.adj_edge[e]
            xo = self.x[self.adj_other[e]]
            if self.adj_is_a[e] != 0:
                out += self.off[q] @ xo
            else:
                out += self.off[q].transpose() @ xo
        return out

    @ti.func
    def _smooth(self, lo, hi, from_zero: ti.template()):
        """One weighted block-Jacobi sweep on the vertices lo..hi-1 (from_zero: the iterate is 0, so x = w D^-1 b)."""
        w = self.weight[None]
        if ti.static(from_zero):
            ti.loop_config(serialize=self.serial)
            for g in range(lo, hi):
                self.x[g] = w * (self.dinv[g] @ self.b[g])
        else:
            ti.loop_config(serialize=self.serial)
            for g in range(lo, hi):
                self.r[g] = self.b[g] - self._apply_A(g)
            ti.loop_config(serialize=self.serial)
            for g in range(lo, hi):
                self.x[g] += w * (self.dinv[g] @ self.r[g])

    # ------------------------------------------------------------------ the kernels
    @ti.kernel
    def _prepare(self, system: ti.template(), filt: ti.template()):
        ms = system.mass_scale[None]
        # the cloth: D_i = S_i (M' + sum B_s) S_i + M' (I - S_i), O_s = -S_a B_s S_b
        ti.loop_config(serialize=self.serial)
        for i in range(self.vbound[1]):
            self.diag[i] = filtered_block(filt.projector(i), system.diagonal(i, ms), system.model.mass[i] * ms)
        ti.loop_config(serialize=self.serial)
        for q in range(self.ebound[1]):
            B = spring_block(system.u[q], system.axial[q], system.iso[q])
            self.off[q] = -(filt.projector(self.end_a[q]) @ B @ filt.projector(self.end_b[q]))
        # the coarse levels, each summed from the one above (Galerkin with piecewise-constant prolongation)
        for l in ti.static(range(1, MAX_LEVELS)):
            ti.loop_config(serialize=self.serial)
            for g in range(self.vbound[l], self.vbound[l + 1]):
                D = ti.Matrix.zero(self.fp, 3, 3)
                for e in range(self.mem_ptr[g], self.mem_ptr[g + 1]):
                    D += self.diag[self.mem[e]]
                for e in range(self.in_ptr[g], self.in_ptr[g + 1]):
                    O = self.off[self.inner[e]]
                    D += O + O.transpose()
                self.diag[g] = D
            ti.loop_config(serialize=self.serial)
            for q in range(self.ebound[l], self.ebound[l + 1]):
                O = ti.Matrix.zero(self.fp, 3, 3)
                for e in range(self.ce_ptr[q], self.ce_ptr[q + 1]):
                    Of = self.off[self.ce[e]]
                    if self.ce_flip[e] != 0:
                        O += Of.transpose()
                    else:
                        O += Of
                self.off[q] = O
        ti.loop_config(serialize=self.serial)
        for g in range(self.vbound[self.n_levels[None]]):
            self.dinv[g] = self.diag[g].inverse()
        # the coarsest level: assembled densely and factored L L^T in one thread
        ti.loop_config(serialize=True)
        for _ in range(1):
            lc = self.n_levels[None] - 1
            v0, v1 = self.vbound[lc], self.vbound[lc + 1]
            C = 3 * (v1 - v0)
            for i in range(C):
                for j in range(C):
                    self.chol[i, j] = 0.0
            for g in range(v0, v1):
                D = ti.cast(self.diag[g], ti.f64)
                for c in ti.static(range(3)):
                    for d in ti.static(range(3)):
                        self.chol[3 * (g - v0) + c, 3 * (g - v0) + d] = D[c, d]
            for q in range(self.ebound[lc], self.ebound[lc + 1]):
                O = ti.cast(self.off[q], ti.f64)
                a, b = self.end_a[q] - v0, self.end_b[q] - v0
                for c in ti.static(range(3)):
                    for d in ti.static(range(3)):
                        self.chol[3 * a + c, 3 * b + d] = O[c, d]
                        self.chol[3 * b + d, 3 * a + c] = O[c, d]
            cholesky(self.chol, C)

    @ti.kernel
    def _cycle(self, r: ti.template(), z: ti.template()):
        nl = self.n_levels[None]
        ti.loop_config(serialize=self.serial)
        for i in range(self.vbound[1]):
            self.b[i] = ti.cast(r[i], self.fp)
        # down: smooth from zero, residual, restrict to the level below
        for l in ti.static(range(MAX_LEVELS - 1)):
            lo = self.vbound[l]
            hi = ti.select(l < nl - 1, self.vbound[l + 1], lo)  # the coarsest and the unused levels: nothing
            self._smooth(lo, hi, True)
            ti.loop_config(serialize=self.serial)
            for g in range(lo, hi):
                self.r[g] = self.b[g] - self._apply_A(g)
            chi = ti.select(l < nl - 1, self.vbound[l + 2], hi)
            ti.loop_config(serialize=self.serial)
            for g in range(hi, chi):
                acc = ti.Vector.zero(self.fp, 3)
                for e in range(self.mem_ptr[g], self.mem_ptr[g + 1]):
                    acc += self.r[self.mem[e]]
                self.b[g] = acc
        # the coarsest level: x = (L L^T)^-1 b, in one thread
        ti.loop_config(serialize=True)
        for _ in range(1):
            lc = nl - 1
            v0, v1 = self.vbound[lc], self.vbound[lc + 1]
            C = 3 * (v1 - v0)
            for g in range(v0, v1):
                for c in ti.static(range(3)):
                    self.work[3 * (g - v0) + c] = ti.cast(self.b[g][c], ti.f64)
            cholesky_solve(self.chol, self.work, C)
            for g in range(v0, v1):
                k = 3 * (g - v0)
                self.x[g] = ti.Vector([self.work[k], self.work[k + 1], self.work[k + 2]], self.fp)
        # up: add the coarse correction, smooth
        for k in ti.static(range(MAX_LEVELS - 1)):
            l = ti.static(MAX_LEVELS - 2 - k)
            lo = self.vbound[l]
            hi = ti.select(l < nl - 1, self.vbound[l + 1], lo)
            ti.loop_config(serialize=self.serial)
            for g in range(lo, hi):
                self.x[g] += self.x[self.agg[g]]
            self._smooth(lo, hi, False)
        ti.loop_config(serialize=self.serial)
        for i in range(self.vbound[1]):
            z[i] = ti.cast(self.x[i], z.dtype)
