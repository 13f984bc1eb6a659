"""An algebraic multigrid preconditioner for the backward-Euler spring system of any cloth (a mesh file, a sewn
garment, a locally refined cloth): levels by aggregation of neighbouring particles, the rigid-body modes of every
aggregate as its coarse unknowns, coarse operators by Galerkin projection (Tamstorf, Jones and McCormick 2015,
"Smoothed aggregation multigrid for cloth simulation", without the smoothing of the prolongation: see
docs/performance.md, preconditioners, for why).

The system the implicit integrator solves (linear.system gives its blocks) is filtered: S A S dv = S b
with S_i = 0 at a pin and I - n n^T at a contact. The cycle approximates the inverse of

    A~ = S A S + M' (I - S),   M' = M (1 + h gamma),

which is block diagonal over range(S) + null(S), so S A~^-1 S is exactly the filtered system's solution: a
preconditioner for A~ needs no pin or contact logic of its own. Level 0 (the cloth) stores A~ as 3x3 blocks: D_i on
the diagonal and O_e = A~(a, b) per edge e = (a, b) (the cloth's springs, O_s = -S_a B_s S_b).

Aggregation (host, once per topology): a greedy pass over the spring graph makes every particle whose neighbours are
all free the root of an aggregate with them; a second pass adds each particle left to a neighbour's aggregate.

The constraints in the coarse space (Tamstorf, Jones and McCormick 2015, section 4): level 0's prolongation is
filtered, S_i T_i, so that a coarse correction never moves a pinned or held particle nor a sliding one along its
normal, and the Galerkin blocks see S A S alone (the mass M' (I - S) that keeps A~ invertible on null(S) would
otherwise tie every aggregate with a constrained member to it). The restriction is its transpose, T_i^T S_i.

The coarse space: a coarse vertex G (an aggregate) carries 6 unknowns, a translation t [m/s] and a small rotation
theta [rad/s] about its centroid c_G (the mean position of its particles, from the CURRENT positions, recomputed in
every prepare). Folding cloth's slow modes are local rotations, which piecewise-constant (translation-only)
aggregates cannot represent. The prolongation of a member i of G on level 0 is the 3x6 block

    T_i = [I, -[x_i - c_G]_x]        (v_i = t + theta x (x_i - c_G)),

and of a coarse vertex G inside the aggregate K of the next level the 6x6 block [[I, -[c_G - c_K]_x], [0, I]],
which reproduces every rigid motion exactly on every level. The Galerkin operator P^T A~ P is again diagonal blocks
plus edge blocks (6x6), summed from the level above without any matrix product beyond the blocks':

    D_G = sum over members i of T_i^T D_i T_i + sum over edges e = (a, b) inside G of (T_a^T O_e T_b + its transpose)
    O_(G,H) = sum over edges e = (a, b) from G to H of T_a^T O_e T_b (its transpose for an edge from H to G)

An aggregate of one or two particles, or of collinear ones, cannot see some of its rotations (its rotational block
is singular: a single particle's is exactly 0). The Galerkin blocks are kept as they are (so that the next level is
still P^T A~ P); only the copies that are inverted (the smoother's 6x6 blocks, the coarsest level's dense matrix) get
a relative regularisation of their diagonal, REGULARISATION times each diagonal entry, and an exactly zero diagonal
entry becomes 1: its row and column are zero and so is the restricted residual there (the rotation's lever arms are
0), so that unknown comes out 0 whatever the value.

Levels are built until at most COARSE_TARGET vertices remain; the coarsest is factored (Cholesky, float64) in every
prepare. A V(1,1) cycle with weighted block-Jacobi smoothing is symmetric, as CG needs.

Iteration counts and timings: docs/performance.md, preconditioners.

House rules: the levels are packed into fields sized once from the cloth's capacity (coarse levels hold at most as
many vertices and edges as the cloth), the level bounds are runtime values, so a rebuild after a topology change (a
seam merge, a level switch) loads new tables and compiles nothing.
"""

import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock

from ..cloth import SpringKind
from ..model import csr
from .dense import PIVOT_FLOOR, cholesky, cholesky_solve, factor_in_parallel
from .system import filtered_block, spring_block

#: the most levels (the cloth itself included); a 256 x 256 sheet needs 5
MAX_LEVELS = 6
#: aggregate until at most this many vertices remain (the coarsest level, 6 unknowns per vertex, is factored densely
#: at every step)
COARSE_TARGET = 16
#: the largest coarsest level accepted when aggregation stalls [vertices]
COARSE_MAX = 128
#: block-Jacobi weight (the scipy prototype: 0.67 and 0.8 equal, 0.5 needs 10 % more iterations)
DEFAULT_OMEGA = 0.67
#: the relative regularisation of the inverted coarse blocks (see the module docstring)
REGULARISATION = 1e-6


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


@ti.func
def cross_matrix(d):
    """-[d]_x (3x3, d's precision): -[d]_x theta = theta x d, a rotation theta's velocity at the lever arm d."""
    z = 0.0 * d[0]
    return ti.Matrix([[z, d[2], -d[1]], [-d[2], z, d[0]], [d[1], -d[0], z]])


@ti.func
def block(fp: ti.template(), M, r: ti.template(), c: ti.template()):
    """The 3x3 block (r, c) (0 or 1) of a 6x6 matrix of precision fp."""
    B = ti.Matrix.zero(fp, 3, 3)
    for i, j in ti.static(ti.ndrange(3, 3)):
        B[i, j] = M[3 * r + i, 3 * c + j]
    return B


@ti.func
def blocks6(fp: ti.template(), A, B, C, D):
    """The 6x6 matrix [[A, B], [C, D]] of 3x3 blocks, precision fp."""
    M = ti.Matrix.zero(fp, 6, 6)
    for i, j in ti.static(ti.ndrange(3, 3)):
        M[i, j] = A[i, j]
        M[i, j + 3] = B[i, j]
        M[i + 3, j] = C[i, j]
        M[i + 3, j + 3] = D[i, j]
    return M


@ti.func
def fine_galerkin(fp: ti.template(), O, wa, wb):
    """T_a^T O T_b (6x6) for a 3x3 block O between level-0 vertices with T = [I, W], W = -[arm]_x (wa, wb)."""
    Ob = O @ wb
    return blocks6(fp, O, Ob, wa.transpose() @ O, wa.transpose() @ Ob)


@ti.func
def coarse_galerkin(fp: ti.template(), X, wa, wb):
    """R_a^T X R_b (6x6) for a 6x6 block X between coarse vertices with R = [[I, W], [0, I]], W = -[arm]_x."""
    X11, X12, X21, X22 = block(fp, X, 0, 0), block(fp, X, 0, 1), block(fp, X, 1, 0), block(fp, X, 1, 1)
    top = X11 @ wb + X12
    return blocks6(fp, X11, top, wa.transpose() @ X11 + X21, wa.transpose() @ top + X21 @ wb + X22)


@ti.func
def regularised(D, eps: ti.template()):
    """D (6x6 float64) with eps times each diagonal entry added, and a zero diagonal entry made 1 (see the module
    docstring: an aggregate's rotation it cannot see)."""
    for j in ti.static(range(6)):
        D[j, j] = ti.select(D[j, j] > 0, D[j, j] * (1.0 + eps), 1.0)
    return D


@ti.func
def spd_inverse6(A):
    """The inverse of a symmetric positive definite 6x6 float64 matrix, by its Cholesky factor L: L^-T L^-1 (a pivot
    below PIVOT_FLOOR of its diagonal entry is raised to that: a bounded inverse of a nearly singular block)."""
    L = ti.Matrix.zero(ti.f64, 6, 6)
    for j in ti.static(range(6)):
        s = A[j, j]
        floor = ti.max(PIVOT_FLOOR * ti.abs(A[j, j]), 1e-300)  # see linear.dense
        for k in ti.static(range(j)):
            s -= L[j, k] * L[j, k]
        djj = ti.sqrt(ti.max(s, floor))
        L[j, j] = djj
        for i in ti.static(range(j + 1, 6)):
            t = A[i, j]
            for k in ti.static(range(j)):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / djj
    Li = ti.Matrix.zero(ti.f64, 6, 6)
    for j in ti.static(range(6)):
        Li[j, j] = 1.0 / L[j, j]
        for i in ti.static(range(j + 1, 6)):
            t = ti.cast(0.0, ti.f64)
            for k in ti.static(range(j, i)):
                t -= L[i, k] * Li[k, j]
            Li[i, j] = t / L[i, i]
    return Li.transpose() @ Li


@ti.data_oriented
class AggregationMultigrid:
    """V-cycles over aggregation levels for the implicit spring system of a cloth (see the module docstring).

    capacity:  (particles, springs) of the cloth's model: the fields are sized from it once
    fp:        ti.f32 or ti.f64, the precision of the fields and kernels (the coarse factor is float64)
    serial:    run every loop in one thread (the CPU: every level is a few thousand vertices at most per core)
    omega:     the block-Jacobi weight
    Call rebuild(springs, n_particles) before the first prepare, and again whenever the cloth's topology changes.

    Vertices and edges are numbered over all levels (level l: vertices vbound[l]..vbound[l+1]-1, edges
    ebound[l]..ebound[l+1]-1); level 0's values live in 3x3 / vec3 fields indexed by that number, the coarse
    levels' in 6x6 / vec6 fields indexed by the number minus level 0's count (vertices) or spring count (edges).
    """

    #: applied by its own kernels between CG's (linear.pcg), from a zero start
    inline = False
    warm_start = False

    def __init__(self, capacity: tuple[int, int], fp=ti.f32, serial: bool = True, omega: float = DEFAULT_OMEGA):
        P, S = int(capacity[0]), int(max(capacity[1], 1))
        self.fp, self.serial = fp, bool(serial)
        self.capacity = (P, S)
        V, E = 2 * P + 1, 2 * S + 1  # the cloth + every coarse level: each level at most half the one above
        VC, EC = P + 1, S + 1         # the coarse levels alone
        C = 6 * COARSE_MAX
        blk = FieldBlock()
        # level 0: translations only
        self.diag = blk.matrix(3, 3, fp, P)       # diagonal blocks of A~ [kg]
        self.dinv = blk.matrix(3, 3, fp, P)       # their inverses [1/kg]
        self.off = blk.matrix(3, 3, fp, S)        # A~(a, b) of every spring [kg]
        self.b = blk.vector(3, fp, P)             # right-hand side [kg m/s]
        self.x = blk.vector(3, fp, P)             # iterate [m/s]
        self.r = blk.vector(3, fp, P)             # residual [kg m/s]
        self.proj = blk.matrix(3, 3, fp, P)       # the filter S_i: the prolongation is S_i T_i
        # the coarse levels: (t, theta) per vertex, so blocks mix [kg], [kg m] and [kg m^2]
        self.diag6 = blk.matrix(6, 6, fp, VC)     # Galerkin diagonal blocks
        self.dinv6 = blk.matrix(6, 6, fp, VC)     # the inverses of their regularised copies
        self.off6 = blk.matrix(6, 6, fp, EC)      # Galerkin edge blocks
        self.gal = blk.matrix(6, 6, fp, EC)       # R_a^T O_e R_b of every edge of the coarse level above one made
        self.b6 = blk.vector(6, fp, VC)           # right-hand side (force [kg m/s], torque [kg m^2/s])
        self.x6 = blk.vector(6, fp, VC)           # iterate (t [m/s], theta [1/s])
        self.r6 = blk.vector(6, fp, VC)
        self.centre = blk.vector(3, fp, VC)       # the aggregate's centroid [m]
        self.count = blk.scalar(fp, VC)           # the cloth particles it holds
        self.arm = blk.vector(3, fp, V)           # every vertex's position minus its aggregate's centroid [m]
        # tables
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
        if not self.serial:  # the parallel factor's diagonal, the inverse, the product (linear.dense)
            self.pivots, self.inverse, self.solution = blk.scalar(ti.f64, C), blk.scalar(ti.f64, (C, C)), \
                blk.scalar(ti.f64, C)
        self.weight = blk.scalar(fp, ())
        blk.finalize(self)
        self.weight[None] = float(omega)
        self.sizes: list[int] = []
        self.edge_counts: list[int] = []
        self._coarse_compiled = False

    # ------------------------------------------------------------------ host side
    def rebuild(self, springs: np.ndarray, n_particles: int, kinds: np.ndarray | None = None) -> None:
        """Aggregate the cloth whose (S, 2) spring ends (particle indices) are `springs`, and load the level tables.
        kinds: the (S,) SpringKind of every spring; where given, the cloth's particles are grouped along its
        structural and seam springs only (every spring still couples the coarse vertices). Raises ValueError when
        the cloth exceeds the capacity or aggregation stalls above COARSE_MAX vertices."""
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
            group = edges[-1]
            if len(sizes) == 1 and kinds is not None:
                # grouped over the bending and shear springs too, an aggregate spans two spacings each way and
                # bends inside, which its rigid motions cannot follow: smaller aggregates of the nearest neighbours
                # (docs/performance.md, preconditioners)
                kinds = np.asarray(kinds).reshape(-1)
                group = ends[(kinds == int(SpringKind.STRUCTURAL)) | (kinds == int(SpringKind.SEAM))]
            agg = aggregate(sizes[-1], group)
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
        V, E = self.arm.shape[0], self.end_a.shape[0]
        if vb[-1] > V or eb[-1] > E or vb[-1] - vb[1] > self.diag6.shape[0] or eb[-1] - eb[1] > self.off6.shape[0]:
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
        (linear.BlockSystem), its particles' positions (system.x, for the rotations' lever arms) and the filter S
        (linear.ConstraintFilter). A kernel launch per coarse level and one for the coarsest factor (one kernel
        for all levels unrolled the 6x6 block products once per level: docs/performance.md, compiling the cycle)."""
        self._prepare(system, filt)
        for level in range(2, len(self.sizes)):
            self._prepare_coarse(system, level)
        if not self._coarse_compiled and len(self.sizes) < 3:
            # compiled now, on a level with no vertices (the one past the coarsest), not at a later rebuild that
            # makes a third level: a seam merge or a level switch compiles nothing
            self._prepare_coarse(system, len(self.sizes))
        self._coarse_compiled = True
        self._factor(system)
        if not self.serial:
            unknowns = (3 if len(self.sizes) == 1 else 6) * self.sizes[-1]
            factor_in_parallel(self.chol, self.pivots, self.inverse, unknowns, system.live)

    def apply(self, r, z) -> None:
        """z = V-cycle(r): r, z are (P,) vec3 fields of the cloth [kg m/s], [m/s]. Serial (the CPU): one launch, the
        levels a loop in it. Parallel: a launch per level down and up and one for the coarsest, each loop over a
        level's vertices parallel. (Every level unrolled into one kernel multiplied its compile time; a launch per
        level costs the CPU more than the loops of a small level: docs/performance.md, compiling the cycle.)"""
        if self.serial:
            self._cycle_serial(r, z)
            return
        nl = len(self.sizes)
        self._descend_cloth_kernel(r)
        # a hierarchy of one or two levels launches one of each on no vertices, so that they are compiled now and
        # a later rebuild with more levels (a seam merge, a level switch) compiles nothing
        coarse = range(1, max(nl - 1, 2))
        for level in coarse:
            self._descend_kernel(level)
        self._solve_coarsest_kernel()
        for level in reversed(coarse):
            self._ascend_kernel(level)
        self._ascend_cloth_kernel(z)

    # ------------------------------------------------------------------ helpers of the kernels
    @ti.func
    def _apply_A(self, g):
        """(A~ x)_g on level 0, from the current iterate x."""
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
    def _apply_A6(self, g, n0, e0):
        """(A~ x)_g on a coarse level (g a global vertex index; n0, e0 level 0's vertex and edge counts)."""
        out = self.diag6[g - n0] @ self.x6[g - n0]
        for e in range(self.adj_ptr[g], self.adj_ptr[g + 1]):
            q = self.adj_edge[e] - e0
            xo = self.x6[self.adj_other[e] - n0]
            if self.adj_is_a[e] != 0:
                out += self.off6[q] @ xo
            else:
                out += self.off6[q].transpose() @ xo
        return out

    @ti.func
    def _smooth(self, lo, hi, from_zero: ti.template()):
        """One weighted block-Jacobi sweep on level 0's vertices lo..hi-1 (from_zero: the iterate is 0, so
        x = w D^-1 b)."""
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

    @ti.func
    def _smooth6(self, lo, hi, n0, e0, from_zero: ti.template()):
        """The same on a coarse level's vertices lo..hi-1 (global indices)."""
        w = self.weight[None]
        if ti.static(from_zero):
            ti.loop_config(serialize=self.serial)
            for g in range(lo, hi):
                self.x6[g - n0] = w * (self.dinv6[g - n0] @ self.b6[g - n0])
        else:
            ti.loop_config(serialize=self.serial)
            for g in range(lo, hi):
                self.r6[g - n0] = self.b6[g - n0] - self._apply_A6(g, n0, e0)
            ti.loop_config(serialize=self.serial)
            for g in range(lo, hi):
                self.x6[g - n0] += w * (self.dinv6[g - n0] @ self.r6[g - n0])

    @ti.func
    def _coarse_level(self, system: ti.template(), l, first: ti.template()):
        """Level l (a runtime value; first: l = 1, made from the cloth) from the one above: the aggregates'
        centroids and their members' lever arms, then the Galerkin blocks and the smoother's inverses."""
        nl = self.n_levels[None]
        n0, e0 = self.vbound[1], self.ebound[1]
        eps = ti.static(REGULARISATION)
        ti.loop_config(serialize=self.serial)
        for g in range(self.vbound[l], ti.select(system.live[None] != 0, self.vbound[l + 1], self.vbound[l])):
            c = ti.Vector.zero(self.fp, 3)
            w = ti.cast(0.0, self.fp)
            for e in range(self.mem_ptr[g], self.mem_ptr[g + 1]):
                m = self.mem[e]
                if ti.static(first):
                    c += ti.cast(system.x[m], self.fp)
                    w += 1.0
                else:
                    c += self.count[m - n0] * self.centre[m - n0]
                    w += self.count[m - n0]
            self.centre[g - n0] = c / w
            self.count[g - n0] = w
        hi = ti.select(l < nl, self.vbound[l], self.vbound[l - 1])  # the level above, when it has aggregates
        ti.loop_config(serialize=self.serial)
        for i in range(self.vbound[l - 1], ti.select(system.live[None] != 0, hi, self.vbound[l - 1])):
            if ti.static(first):
                self.arm[i] = ti.cast(system.x[i], self.fp) - self.centre[self.agg[i] - n0]
            else:
                self.arm[i] = self.centre[i - n0] - self.centre[self.agg[i] - n0]
        # from a coarse level, every edge's Galerkin block once (the diagonal sums the edges inside an aggregate,
        # the edge blocks those between two): one inlined copy of the 6x6 products, not two, compiles faster;
        # level 0's are cheap 3x3 products, and its many edges would cost memory traffic, so they are inlined
        ea = self.ebound[l - 1]
        if ti.static(not first):
            ti.loop_config(serialize=self.serial)
            for q in range(ea, self.ebound[l]):
                self.gal[q - ea] = self._edge_galerkin(q, e0, first)
        ti.loop_config(serialize=self.serial)
        for g in range(self.vbound[l], ti.select(system.live[None] != 0, self.vbound[l + 1], self.vbound[l])):
            D = ti.Matrix.zero(self.fp, 6, 6)
            for e in range(self.mem_ptr[g], self.mem_ptr[g + 1]):
                m = self.mem[e]
                W = cross_matrix(self.arm[m])
                if ti.static(first):  # (S T)^T A~ (S T) = T^T S D S T: the mass on null(S) drops out
                    S = self.proj[m]
                    D += fine_galerkin(self.fp, S @ self.diag[m] @ S, W, W)
                else:
                    D += coarse_galerkin(self.fp, self.diag6[m - n0], W, W)
            for e in range(self.in_ptr[g], self.in_ptr[g + 1]):
                X = self._galerkin_of(self.inner[e], ea, e0, first)
                D += X + X.transpose()
            self.diag6[g - n0] = D
            self.dinv6[g - n0] = ti.cast(spd_inverse6(regularised(ti.cast(D, ti.f64), eps)), self.fp)
        ti.loop_config(serialize=self.serial)
        for k in range(self.ebound[l], ti.select(system.live[None] != 0, self.ebound[l + 1], self.ebound[l])):
            O = ti.Matrix.zero(self.fp, 6, 6)
            for e in range(self.ce_ptr[k], self.ce_ptr[k + 1]):
                X = self._galerkin_of(self.ce[e], ea, e0, first)
                if self.ce_flip[e] != 0:
                    O += X.transpose()
                else:
                    O += X
            self.off6[k - e0] = O

    @ti.func
    def _galerkin_of(self, q, ea, e0, first: ti.template()):
        """Edge q's Galerkin block: computed from level 0, kept in gal from a coarse level (whose edges start at ea)."""
        X = ti.Matrix.zero(self.fp, 6, 6)
        if ti.static(first):
            X = self._edge_galerkin(q, e0, first)
        else:
            X = self.gal[q - ea]
        return X

    @ti.func
    def _edge_galerkin(self, q, e0, first: ti.template()):
        """The 6x6 Galerkin block T_a^T O_q T_b of edge q, from the level above's edge block (level 0's stored 3x3
        block when `first`, else the 6x6 block of a coarse level whose edges start at e0) and its ends' lever arms."""
        Wa, Wb = cross_matrix(self.arm[self.end_a[q]]), cross_matrix(self.arm[self.end_b[q]])
        X = ti.Matrix.zero(self.fp, 6, 6)
        if ti.static(first):
            X = fine_galerkin(self.fp, self.off[q], Wa, Wb)
        else:
            X = coarse_galerkin(self.fp, self.off6[q - e0], Wa, Wb)
        return X

    # ------------------------------------------------------------------ the kernels
    @ti.kernel
    def _prepare(self, system: ti.template(), filt: ti.template()):
        ms = system.mass_scale[None]
        n0, e0 = self.vbound[1], self.ebound[1]
        # the cloth: D_i = S_i (M' + sum B_s) S_i + M' (I - S_i), O_s = -S_a B_s S_b
        ti.loop_config(serialize=self.serial)
        for i in range(system.gated(n0)):
            S = filt.projector(i)
            D = filtered_block(S, system.diagonal(i, ms), system.model.mass[i] * ms)
            self.proj[i] = S
            self.diag[i] = D
            self.dinv[i] = D.inverse()
        ti.loop_config(serialize=self.serial)
        for q in range(system.gated(e0)):
            B = spring_block(system.u[q], system.axial[q], system.iso[q])
            self.off[q] = -(filt.projector(self.end_a[q]) @ B @ filt.projector(self.end_b[q]))
        # level 1 from the cloth (the deeper levels: _prepare_coarse, one launch each)
        self._coarse_level(system, 1, True)

    @ti.kernel
    def _prepare_coarse(self, system: ti.template(), l: ti.i32):
        self._coarse_level(system, l, False)

    @ti.kernel
    def _factor(self, system: ti.template()):
        nl = self.n_levels[None]
        n0, e0 = self.vbound[1], self.ebound[1]
        eps = ti.static(REGULARISATION)
        # the coarsest level: assembled densely (regularised as the module docstring says), 3 unknowns per vertex
        # when it is the cloth itself, else 6; factored L L^T in one thread on the CPU (elsewhere: prepare, by
        # factor_in_parallel)
        lc = nl - 1
        v0, v1 = self.vbound[lc], self.vbound[lc + 1]
        C = ti.select(lc == 0, 3, 6) * (v1 - v0)
        ti.loop_config(serialize=self.serial)
        for i, j in ti.ndrange(system.gated(C), C):
            self.chol[i, j] = 0.0
        ti.loop_config(serialize=self.serial)
        for g in range(v0, ti.select(system.live[None] != 0, v1, v0)):
            if lc == 0:
                D = ti.cast(self.diag[g], ti.f64)
                for c, d in ti.static(ti.ndrange(3, 3)):
                    self.chol[3 * g + c, 3 * g + d] = D[c, d]
            else:
                D = regularised(ti.cast(self.diag6[g - n0], ti.f64), eps)
                for c in ti.static(range(6)):
                    for d in ti.static(range(6)):
                        self.chol[6 * (g - v0) + c, 6 * (g - v0) + d] = D[c, d]
        ti.loop_config(serialize=self.serial)
        for q in range(self.ebound[lc], ti.select(system.live[None] != 0, self.ebound[lc + 1], self.ebound[lc])):
            if lc == 0:
                O = ti.cast(self.off[q], ti.f64)
                a, b = self.end_a[q], self.end_b[q]
                for c, d in ti.static(ti.ndrange(3, 3)):
                    self.chol[3 * a + c, 3 * b + d] = O[c, d]
                    self.chol[3 * b + d, 3 * a + c] = O[c, d]
            else:
                O = ti.cast(self.off6[q - e0], ti.f64)
                a, b = self.end_a[q] - v0, self.end_b[q] - v0
                for c in ti.static(range(6)):
                    for d in ti.static(range(6)):
                        self.chol[6 * a + c, 6 * b + d] = O[c, d]
                        self.chol[6 * b + d, 6 * a + c] = O[c, d]
        if ti.static(self.serial):
            ti.loop_config(serialize=True)
            for _ in range(system.gated(1)):
                cholesky(self.chol, C)

    @ti.func
    def _descend_cloth(self, r: ti.template()):
        """The cycle's first leg on the cloth: b = r, smooth from zero, residual, restrict to level 1 (R^T: a force
        and its torque about the aggregate's centroid)."""
        nl = self.n_levels[None]
        n0 = self.vbound[1]
        ti.loop_config(serialize=self.serial)
        for i in range(n0):
            self.b[i] = ti.cast(r[i], self.fp)
        h0 = ti.select(nl > 1, n0, 0)  # level 0 is smoothed here unless it is the coarsest
        self._smooth(0, h0, True)
        ti.loop_config(serialize=self.serial)
        for g in range(h0):
            self.r[g] = self.b[g] - self._apply_A(g)
        ti.loop_config(serialize=self.serial)
        for g in range(n0, ti.select(nl > 1, self.vbound[2], n0)):
            acc = ti.Vector.zero(self.fp, 6)
            for e in range(self.mem_ptr[g], self.mem_ptr[g + 1]):
                m = self.mem[e]
                f = self.proj[m] @ self.r[m]  # (S T)^T r: the transpose of the prolongation, as CG needs
                tq = self.arm[m].cross(f)
                acc += ti.Vector([f[0], f[1], f[2], tq[0], tq[1], tq[2]], self.fp)
            self.b6[g - n0] = acc

    @ti.func
    def _descend(self, l):
        """Coarse level l (1 <= l, above the coarsest; nothing on the coarsest): smooth from zero, residual,
        restrict to level l + 1."""
        nl = self.n_levels[None]
        n0, e0 = self.vbound[1], self.ebound[1]
        lo = self.vbound[l]
        hi = ti.select(l < nl - 1, self.vbound[l + 1], lo)
        self._smooth6(lo, hi, n0, e0, True)
        ti.loop_config(serialize=self.serial)
        for g in range(lo, hi):
            self.r6[g - n0] = self.b6[g - n0] - self._apply_A6(g, n0, e0)
        chi = ti.select(l < nl - 1, self.vbound[l + 2], hi)
        ti.loop_config(serialize=self.serial)
        for g in range(hi, chi):
            acc = ti.Vector.zero(self.fp, 6)
            for e in range(self.mem_ptr[g], self.mem_ptr[g + 1]):
                m = self.mem[e]
                rm = self.r6[m - n0]
                f = ti.Vector([rm[0], rm[1], rm[2]], self.fp)
                tq = self.arm[m].cross(f)
                acc += rm + ti.Vector([0.0, 0.0, 0.0, tq[0], tq[1], tq[2]], self.fp)
            self.b6[g - n0] = acc

    @ti.func
    def _solve_coarsest(self):
        """x = (L L^T)^-1 b on the coarsest level (loops that must run in one thread: call it from one)."""
        nl = self.n_levels[None]
        n0 = self.vbound[1]
        lc = nl - 1
        v0, v1 = self.vbound[lc], self.vbound[lc + 1]
        if lc == 0:
            for g in range(v0, v1):
                for c in ti.static(range(3)):
                    self.work[3 * g + c] = ti.cast(self.b[g][c], ti.f64)
            cholesky_solve(self.chol, self.work, 3 * v1)
            for g in range(v0, v1):
                self.x[g] = ti.Vector([self.work[3 * g], self.work[3 * g + 1], self.work[3 * g + 2]], self.fp)
        else:
            for g in range(v0, v1):
                for c in ti.static(range(6)):
                    self.work[6 * (g - v0) + c] = ti.cast(self.b6[g - n0][c], ti.f64)
            cholesky_solve(self.chol, self.work, 6 * (v1 - v0))
            for g in range(v0, v1):
                k = 6 * (g - v0)
                self.x6[g - n0] = ti.Vector([self.work[k], self.work[k + 1], self.work[k + 2], self.work[k + 3],
                                            self.work[k + 4], self.work[k + 5]], self.fp)

    @ti.func
    def _ascend(self, l):
        """Coarse level l (above the coarsest; nothing on the coarsest): add the correction of level l + 1 (R x:
        the aggregate's rigid motion at the member), smooth."""
        nl = self.n_levels[None]
        n0, e0 = self.vbound[1], self.ebound[1]
        lo = self.vbound[l]
        hi = ti.select(l < nl - 1, self.vbound[l + 1], lo)
        ti.loop_config(serialize=self.serial)
        for g in range(lo, hi):
            xc = self.x6[self.agg[g] - n0]
            th = ti.Vector([xc[3], xc[4], xc[5]], self.fp)
            v = th.cross(self.arm[g])
            self.x6[g - n0] += xc + ti.Vector([v[0], v[1], v[2], 0.0, 0.0, 0.0], self.fp)
        self._smooth6(lo, hi, n0, e0, False)

    @ti.func
    def _ascend_cloth(self, z: ti.template()):
        """The cycle's last leg on the cloth: add level 1's correction (filtered), smooth, z = x."""
        nl = self.n_levels[None]
        n0 = self.vbound[1]
        h0 = ti.select(nl > 1, n0, 0)
        ti.loop_config(serialize=self.serial)
        for g in range(h0):
            xc = self.x6[self.agg[g] - n0]
            v = ti.Vector([xc[0], xc[1], xc[2]], self.fp) + ti.Vector([xc[3], xc[4], xc[5]], self.fp).cross(self.arm[g])
            self.x[g] += self.proj[g] @ v
        self._smooth(0, h0, False)
        ti.loop_config(serialize=self.serial)
        for i in range(n0):
            z[i] = ti.cast(self.x[i], z.dtype)

    # ------------------------------------------------------------------ the kernels of the cycle
    @ti.kernel
    def _cycle_serial(self, r: ti.template(), z: ti.template()):
        """The whole V-cycle in one thread and one launch, its levels a runtime loop (the CPU)."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            self.cycle_in_thread(r, z)

    @property
    def in_thread(self) -> bool:
        """Whether a CG iteration may run the cycle inside its own one-thread kernel (cycle_in_thread)."""
        return self.serial

    @ti.func
    def cycle_in_thread(self, r: ti.template(), z: ti.template()):
        """z = V-cycle(r), called from a loop that runs in one thread (serial only)."""
        nl = self.n_levels[None]
        self._descend_cloth(r)
        for l in range(1, nl - 1):
            self._descend(l)
        self._solve_coarsest()
        for k in range(1, nl - 1):
            self._ascend(nl - 1 - k)
        self._ascend_cloth(z)

    @ti.kernel
    def _descend_cloth_kernel(self, r: ti.template()):
        self._descend_cloth(r)

    @ti.kernel
    def _descend_kernel(self, l: ti.i32):
        self._descend(l)

    @ti.kernel
    def _solve_coarsest_kernel(self):
        """The coarsest level's solve without a one-thread loop (the parallel cycle): the product with the inverse
        factor_in_parallel left, its rows in parallel."""
        nl = self.n_levels[None]
        n0 = self.vbound[1]
        lc = nl - 1
        v0, v1 = self.vbound[lc], self.vbound[lc + 1]
        k = ti.select(lc == 0, 3, 6)
        C = k * (v1 - v0)
        for g in range(v0, v1):
            if lc == 0:
                for c in ti.static(range(3)):
                    self.work[3 * g + c] = ti.cast(self.b[g][c], ti.f64)
            else:
                for c in ti.static(range(6)):
                    self.work[6 * (g - v0) + c] = ti.cast(self.b6[g - n0][c], ti.f64)
        for i in range(C):
            acc = ti.cast(0.0, ti.f64)
            for j in range(C):
                acc += self.inverse[i, j] * self.work[j]
            self.solution[i] = acc
        for g in range(v0, v1):
            if lc == 0:
                self.x[g] = ti.Vector([self.solution[3 * g + c] for c in ti.static(range(3))], self.fp)
            else:
                q = 6 * (g - v0)
                self.x6[g - n0] = ti.Vector([self.solution[q + c] for c in ti.static(range(6))], self.fp)

    @ti.kernel
    def _ascend_kernel(self, l: ti.i32):
        self._ascend(l)

    @ti.kernel
    def _ascend_cloth_kernel(self, z: ti.template()):
        self._ascend_cloth(z)
