"""Geometric multigrid over the 4-8 levels for the approximate-implicit system (docs/algorithms.md).

The system, per particle i and identical for the x, y and z components of dv:

    (m_i + h^2 sum_j k_ij) dv_i - h^2 sum_j k_ij dv_j = rhs_i,     i.e.  A = M + h^2 L,

M the lumped masses [kg], L the spring-weighted graph Laplacian [N/m], h the time step [s]; rhs [kg m/s]
(h f, plus h^2 J~ v with the jv_term), dv [m/s]. Pinned particles have dv_i = 0 and their rows are left out.

The paper's smoother, and why it is not enough: a Jacobi sweep damps only the high frequencies; a smooth error
(uniform free fall is the extreme) loses a fraction m / (m + h^2 sum k) per sweep, ~1e-4 on a stiff
129 x 129 sheet. Multigrid moves the smooth error to the coarser 4-8 levels, where it is rough again.

Method (a V(pre, post) cycle over the levels 0..active, by default inside preconditioned CG):
  * smoother: weighted Jacobi, dv_i += omega (rhs - A dv)_i / A_ii, written in the difference form
    A dv = m dv_i + h^2 sum k_ij (dv_i - dv_j) so that float32 does not cancel on smooth fields. omega = 0.9:
    on these meshes the eigenvalues of diag(A)^-1 A reach ~1.6, so even omega = 1 smooths
    (|1 - omega mu| <= 0.6 at the top); 0.9 was measured slightly best (0.121 vs 0.126 residual factor per
    V(2,2) cycle on the stiff 129 x 129 case, 0.6: 0.142);
  * restriction R = P^T (a gather from a precomputed transpose table of the prolongation, no atomics),
    the restricted residual is 0 on pinned rows; prolongation = the hierarchy's own tables (parents, weights);
  * coarse operators by rediscretisation: each level's own masses and springs (LevelOperator). For the 4-8
    rectangle the area-lumped coarse mass is exactly P^T m_fine and the constant-k edge Laplacian has the
    same energy density 2 k |grad u|^2 on every level, so A_c ~ P^T A_f P (benchmarks/multigrid_solver.py
    measures the difference);
  * coarsest level: solved exactly by default (coarse_sweeps = 0). Jacobi cannot do it, whatever the level
    is small: its slowest mode is the rigid translation, governed by the mass alone, with the Jacobi factor
    1 - m/(m + h^2 sum k) per sweep (~0.999 on the 17 x 17 base of the stiff benchmark). The exact solve uses
    the generalised eigenpairs L q = lambda M q of the free rows, computed once on the host per pin set:
    A^-1 = G diag(1/(1 + h^2 lambda)) G^T with G = M^-1/2 Q, so h may change every step without host work.
    It is dense (n0^2 entries); coarse_direct_max bounds n0.
  * pins: a level's own mask (LevelOperator.pinned, set_pinned) applies when it is the active level. The
    coarser levels, used as correction spaces, inherit the pins of the level above: a coarse vertex is fixed
    iff it is a prolongation parent of a pinned fine vertex (the same vertex, or a hypotenuse end of a
    pinned midpoint), so that a prolonged correction vanishes at the fine pins by construction. Merely
    zeroing the prolonged correction on pinned rows is not enough: with one pinned midpoint that the coarse
    level does not know, the coarse correction is a free-fall one and the V-cycle diverged (measured).
  * Krylov acceleration (krylov = True, the default): each iteration is one CG step preconditioned by one
    V-cycle (symmetric: pre = post sweeps, R = P^T, exact or Jacobi coarse solve). Reason: POINT pins
    (two pinned corners, a pinned midpoint) hold the stiff sheet by a log-singular dip whose strength
    depends on the mesh spacing, so a rediscretised coarse level misjudges it; the plain V-cycle then drops
    from ~0.12 to ~0.5 (corners) or ~0.8 (a central point) residual factor per cycle, while MG-PCG stays
    at ~0.05-0.2 (measured; Galerkin coarse operators would recover ~0.17 on the corners). Line pins
    (a pinned edge) and free sheets converge at ~0.12 per plain V-cycle either way. Each PCG iteration
    costs one V-cycle plus one fine operator application and two reductions (kept on the device).

House rules: every level is packed into the same concatenated fields (per-level vertex offsets, one CSR
adjacency over global indices, one transpose table), so each kernel is compiled once and takes the level's
offsets and counts as arguments: 5 or 9 levels compile the same kernels, switching the active level or
changing h, omega or the pins compiles nothing. The per-level CSR is built on the host (numpy) at
construction. Fields are allocated through clothbase.fields.FieldBlock.
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock

from .hierarchy import Level, edge_use

# Weighted-Jacobi factor: measured on the 4-8 rectangles (benchmarks/multigrid_solver.py, omega sweep).
DEFAULT_OMEGA = 0.9


@dataclass
class LevelOperator:
    """The approximate-implicit operator of one level, as numpy arrays.

    mass:      (n,) float64 [kg]    lumped particle masses (> 0 on every unpinned particle)
    springs:   (s, 2) int64         particle indices (of this level) of each spring's two ends
    stiffness: (s,) float64 [N/m]   spring constants k (the isotropic J~ of the approximate implicit step,
                                    docs/algorithms.md)
    pinned:    (n,) bool            True where dv = 0 (the row is left out of the system)
    """

    mass: np.ndarray
    springs: np.ndarray
    stiffness: np.ndarray
    pinned: np.ndarray

    def __post_init__(self):
        self.mass = np.asarray(self.mass, np.float64).reshape(-1)
        self.springs = np.asarray(self.springs, np.int64).reshape(-1, 2)
        self.stiffness = np.broadcast_to(np.asarray(self.stiffness, np.float64), (len(self.springs),)).copy()
        pinned = np.zeros(len(self.mass), bool) if self.pinned is None else np.asarray(self.pinned, bool)
        self.pinned = pinned.reshape(-1)
        n = len(self.mass)
        if len(self.pinned) != n:
            raise ValueError(f"pinned has {len(self.pinned)} entries for {n} particles")
        if len(self.springs) and (self.springs.min() < 0 or self.springs.max() >= n):
            raise ValueError("a spring end lies outside 0..n-1")
        if np.any(self.springs[:, 0] == self.springs[:, 1]):
            raise ValueError("a spring joins a particle to itself")
        if np.any(self.stiffness < 0) or not np.all(np.isfinite(self.stiffness)):
            raise ValueError("spring stiffness must be finite and >= 0 [N/m]")
        if np.any(self.mass[~self.pinned] <= 0) or not np.all(np.isfinite(self.mass)):
            raise ValueError("every unpinned particle needs a finite mass > 0 [kg]")

    @property
    def n(self) -> int:
        return len(self.mass)

    def stiffness_sum(self) -> np.ndarray:
        """(n,) sum of the stiffness of the springs at each particle [N/m]."""
        return (np.bincount(self.springs[:, 0], self.stiffness, self.n)
                + np.bincount(self.springs[:, 1], self.stiffness, self.n))

    def laplacian(self):
        """The spring Laplacian L (n, n) as a scipy.sparse CSR matrix [N/m] (scipy is imported here only)."""
        import scipy.sparse as sp

        a, b, k = self.springs[:, 0], self.springs[:, 1], self.stiffness
        off = sp.coo_matrix((np.concatenate([-k, -k]), (np.concatenate([a, b]), np.concatenate([b, a]))),
                            shape=(self.n, self.n))
        return (off + sp.diags(self.stiffness_sum())).tocsr()

    def matrix(self, h: float):
        """A = M + h^2 L (n, n), scipy.sparse CSR [kg], pins ignored."""
        import scipy.sparse as sp

        return (sp.diags(self.mass) + h * h * self.laplacian()).tocsr()

    def reference_solve(self, rhs: np.ndarray, h: float) -> np.ndarray:
        """Exact solution (scipy spsolve, float64) of A dv = rhs on the free rows, dv = 0 on pinned rows.
        rhs: (n,) or (n, 3) [kg m/s]; returns the same shape [m/s]."""
        from scipy.sparse.linalg import spsolve

        rhs = np.asarray(rhs, np.float64)
        free = ~self.pinned
        out = np.zeros_like(rhs)
        if free.any():
            A = self.matrix(h)[free][:, free].tocsc()
            sol = spsolve(A, rhs[free])
            out[free] = sol.reshape(out[free].shape)
        return out


def edge_operator(level: Level, density: float, stiffness: float, pinned: np.ndarray | None = None) -> LevelOperator:
    """The operator of a 4-8 level with one spring of constant k [N/m] on every triangle edge and masses
    lumped from area (m_i = density * sum over the triangles at i of area/3; density [kg/m^2])."""
    edges, _ = edge_use(level.triangles)
    uv, t = level.uv, level.triangles
    e1, e2 = uv[t[:, 1]] - uv[t[:, 0]], uv[t[:, 2]] - uv[t[:, 0]]
    area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    mass = density * np.bincount(t.reshape(-1), np.repeat(area / 3.0, 3), level.n_vertices)
    return LevelOperator(mass, edges, np.full(len(edges), float(stiffness)),
                         np.zeros(level.n_vertices, bool) if pinned is None else pinned)


def prolongation_matrix(level: Level, n_coarse: int):
    """P (n_fine, n_coarse) of a level's prolongation tables as scipy.sparse CSR (value_fine = P value_coarse)."""
    import scipy.sparse as sp

    live = level.parents >= 0
    rows = np.nonzero(live)[0]
    return sp.csr_matrix((level.weights[live], (rows, level.parents[live])), shape=(level.n_vertices, n_coarse))


def _csr(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray, n_rows: int):
    """Row pointer (n_rows + 1), columns and values sorted by row (stable)."""
    order = np.argsort(rows, kind="stable")
    ptr = np.zeros(n_rows + 1, np.int64)
    np.cumsum(np.bincount(rows, minlength=n_rows), out=ptr[1:])
    return ptr, cols[order], vals[order]


@ti.data_oriented
class MultigridSolver:
    """V-cycles over the packed 4-8 levels for (M + h^2 L) dv = rhs, by default as the preconditioner of CG
    (see the module docstring). Also works on non-nested tables (multilevel.outline: barycentric parents).

    levels:       the hierarchy's levels (0 = coarsest); level l > 0 prolongs from level l-1 by its tables.
    operators:    one LevelOperator per level (the same particle numbering as the level).
    fp:           ti.f32 (default) or ti.f64, the precision of every field and kernel.
    pre_sweeps, post_sweeps: weighted-Jacobi sweeps before/after the coarse correction (unrolled in the
                  kernels, so fixed per solver).
    omega:        the Jacobi weight (DEFAULT_OMEGA = 0.9, see the module docstring). A runtime attribute:
                  changing it compiles nothing.
    coarse_sweeps: 0 (default) = exact dense solve on the coarsest level; k > 0 = k Jacobi sweeps there
                  instead (kept to measure why that is a bad idea on free cloth).
    coarse_direct_max: the largest coarsest level [particles] for the dense solve (n0^2 entries are stored).
    krylov:       True (default): solve() runs V-cycle-preconditioned CG; False: plain V-cycles. A runtime
                  attribute (both paths live in one solver; each compiles its kernels on first use).

    Capacity: rhs and dv passed to solve/residual_norm/jacobi are Taichi Vector(3) fields with at least
    n_active entries; the copy kernels take them as templates, so each distinct field pair compiles the
    copy kernels once (an integrator passes the same fields every step).
    """

    def __init__(self, levels: list[Level], operators: list[LevelOperator], fp=ti.f32, pre_sweeps: int = 2,
                 post_sweeps: int = 2, omega: float = DEFAULT_OMEGA, coarse_sweeps: int = 0,
                 coarse_direct_max: int = 2048, krylov: bool = True):
        if not levels or len(levels) != len(operators):
            raise ValueError(f"need one operator per level, got {len(levels)} levels and {len(operators)} operators")
        if fp not in (ti.f32, ti.f64):
            raise ValueError("fp must be ti.f32 or ti.f64")
        if pre_sweeps < 0 or post_sweeps < 0 or pre_sweeps + post_sweeps == 0:
            raise ValueError("need pre_sweeps, post_sweeps >= 0 and at least one sweep per cycle")
        if krylov and pre_sweeps != post_sweeps:
            raise ValueError("krylov (CG) needs a symmetric V-cycle: pre_sweeps == post_sweeps")
        if not 0 < omega <= 1.5:
            raise ValueError(f"omega must lie in (0, 1.5], got {omega}")
        if coarse_sweeps < 0:
            raise ValueError("coarse_sweeps must be >= 0 (0 = exact coarse solve)")
        self.fp = fp
        self.pre_sweeps, self.post_sweeps = int(pre_sweeps), int(post_sweeps)
        self.omega = float(omega)
        self.coarse_sweeps = int(coarse_sweeps)
        self.krylov = bool(krylov)
        self.n_levels = len(levels)
        self.sizes = [op.n for op in operators]
        for lv, (level, op) in enumerate(zip(levels, operators)):
            if level.n_vertices != op.n:
                raise ValueError(f"level {lv}: {level.n_vertices} vertices but the operator has {op.n} particles")
        if self.coarse_sweeps == 0 and self.sizes[0] > coarse_direct_max:
            raise ValueError(f"the coarsest level has {self.sizes[0]} particles, more than coarse_direct_max = "
                             f"{coarse_direct_max} for the dense coarse solve: use a smaller base or set coarse_sweeps")
        self.offsets = np.concatenate([[0], np.cumsum(self.sizes)]).astype(np.int64)
        N = int(self.offsets[-1])
        self.n_total = N
        self.active = self.n_levels - 1
        self._own_pins = [op.pinned.copy() for op in operators]
        self._mass_np = [op.mass.copy() for op in operators]
        self._lap_np = None

        # ---- host tables (numpy), global indices
        rows, cols, ks = [], [], []
        for lv, op in enumerate(operators):
            o = self.offsets[lv]
            a, b = op.springs[:, 0] + o, op.springs[:, 1] + o
            rows += [a, b]
            cols += [b, a]
            ks += [op.stiffness, op.stiffness]
        rows, cols, ks = np.concatenate(rows), np.concatenate(cols), np.concatenate(ks)
        row_ptr, adj_j, adj_k = _csr(rows, cols, ks, N)
        ksum = np.bincount(rows, ks, N)
        mass = np.concatenate([op.mass for op in operators])
        par = np.full((N, 3), -1, np.int64)
        pw = np.zeros((N, 3))
        r_rows, r_cols, r_w = [], [], []
        self._links = [None]  # level l: (fine index, coarse parent index) pairs with a non-zero weight
        for lv in range(1, self.n_levels):
            level, nc = levels[lv], self.sizes[lv - 1]
            p, w = np.asarray(level.parents, np.int64), np.asarray(level.weights, np.float64)
            if p.shape != (self.sizes[lv], 3) or w.shape != p.shape:
                raise ValueError(f"level {lv}: prolongation tables must be ({self.sizes[lv]}, 3)")
            if p.max() >= nc:
                raise ValueError(f"level {lv}: a parent index lies outside level {lv - 1}")
            live = p >= 0
            o, oc = self.offsets[lv], self.offsets[lv - 1]
            par[o:o + self.sizes[lv]] = np.where(live, p + oc, -1)
            pw[o:o + self.sizes[lv]] = np.where(live, w, 0.0)
            fi, fj = np.nonzero(live)
            r_rows.append(p[fi, fj] + oc)   # coarse row gathers ...
            r_cols.append(fi + o)           # ... from its fine children
            r_w.append(w[fi, fj])
            keep = w[fi, fj] != 0
            self._links.append((fi[keep], p[fi, fj][keep]))
        if r_rows:
            r_ptr, r_child, r_wt = _csr(np.concatenate(r_rows), np.concatenate(r_cols), np.concatenate(r_w), N)
        else:
            r_ptr, r_child, r_wt = np.zeros(N + 1, np.int64), np.zeros(1, np.int64), np.zeros(1)

        # ---- fields (one SNode tree)
        n0 = self.sizes[0]
        direct = self.coarse_sweeps == 0
        blk = FieldBlock()
        self.mass = blk.scalar(fp, N)                 # [kg]
        self.ksum = blk.scalar(fp, N)                 # sum_j k_ij [N/m]
        self.pin = blk.scalar(ti.i32, N)              # effective pins (1 = dv fixed at 0)
        self.row_ptr = blk.scalar(ti.i32, N + 1)      # CSR over global indices
        self.adj_j = blk.scalar(ti.i32, max(len(adj_j), 1))
        self.adj_k = blk.scalar(fp, max(len(adj_k), 1))  # [N/m]
        self.par = blk.vector(3, ti.i32, N)           # prolongation parents (global, -1 = none)
        self.pw = blk.vector(3, fp, N)                # prolongation weights
        self.r_ptr = blk.scalar(ti.i32, N + 1)        # restriction = P^T as a gather table
        self.r_child = blk.scalar(ti.i32, max(len(r_child), 1))
        self.r_w = blk.scalar(fp, max(len(r_wt), 1))
        self.b = blk.vector(3, fp, N)                 # right-hand side per level [kg m/s]
        self.r = blk.vector(3, fp, N)                 # residual [kg m/s]
        self.xs = blk.vector(3, fp, (2, N))           # iterate (row 0) and Jacobi ping-pong (row 1) [m/s]
        self.acc = blk.scalar(ti.f64, 2)              # reductions
        self.G = blk.scalar(fp, n0 * n0 if direct else 1)   # coarse eigenvectors M^-1/2 Q, row-major [kg^-1/2]
        self.lam = blk.scalar(fp, n0 if direct else 1)      # coarse eigenvalues of M^-1 L [1/s^2]; -1 = unused
        self.y = blk.vector(3, fp, n0 if direct else 1)     # modal coefficients
        nmax = max(self.sizes)
        self.cg_x = blk.vector(3, fp, nmax)           # PCG iterate [m/s] (active level, local indices)
        self.cg_r = blk.vector(3, fp, nmax)           # PCG residual [kg m/s]
        self.cg_p = blk.vector(3, fp, nmax)           # search direction [m/s]
        self.cg_q = blk.vector(3, fp, nmax)           # A p [kg m/s]
        self.cg_s = blk.scalar(ti.f64, 3)             # r.z (previous), p.q, r.z (new)
        blk.finalize(self)

        npf = np.float32 if fp == ti.f32 else np.float64
        self.mass.from_numpy(mass.astype(npf))
        self.ksum.from_numpy(ksum.astype(npf))
        self.row_ptr.from_numpy(row_ptr.astype(np.int32))
        if len(adj_j):
            self.adj_j.from_numpy(adj_j.astype(np.int32))
            self.adj_k.from_numpy(adj_k.astype(npf))
        self.par.from_numpy(par.astype(np.int32))
        self.pw.from_numpy(pw.astype(npf))
        self.r_ptr.from_numpy(r_ptr.astype(np.int32))
        self.r_child.from_numpy(r_child.astype(np.int32))
        self.r_w.from_numpy(r_wt.astype(npf))
        self._npf = npf
        self._coarse_key = None
        self._coarse_ops = operators[0] if direct else None
        self._update_pins()

    # ------------------------------------------------------------------ host-side state
    def set_active_level(self, level: int) -> None:
        """Make `level` the finest level used now (coarse-to-fine simulation); levels above it are ignored."""
        level = int(level)
        if not 0 <= level < self.n_levels:
            raise ValueError(f"level must lie in 0..{self.n_levels - 1}, got {level}")
        if level != self.active:
            self.active = level
            self._update_pins()

    def set_pinned(self, level: int, pinned: np.ndarray) -> None:
        """Replace a level's own pin mask ((n_level,) bool; True = dv fixed at 0). Compiles nothing."""
        pinned = np.asarray(pinned, bool).reshape(-1)
        if pinned.shape != (self.sizes[level],):
            raise ValueError(f"level {level} has {self.sizes[level]} particles, got a mask of {pinned.shape}")
        if np.any(self._mass_np[level][~pinned] <= 0):
            raise ValueError("every unpinned particle needs a mass > 0")
        self._own_pins[level] = pinned.copy()
        self._update_pins()

    def effective_pins(self, level: int) -> np.ndarray:
        """(n_level,) bool: the pins a level uses in the current cycles: its own if it is the active level,
        inherited from the level above if coarser (see the module docstring), its own if finer (unused)."""
        return self._eff[level].copy()

    def _update_pins(self) -> None:
        eff = [p.copy() for p in self._own_pins]
        for c in range(self.active - 1, -1, -1):
            fine, coarse = self._links[c + 1]
            e = np.zeros(self.sizes[c], bool)
            e[coarse[eff[c + 1][fine]]] = True
            eff[c] = e
        self._eff = eff
        self.pin.from_numpy(np.concatenate(eff).astype(np.int32))
        if self.coarse_sweeps == 0:
            self._update_coarse(eff[0])

    def _update_coarse(self, pinned0: np.ndarray) -> None:
        """Eigenpairs of the coarsest level for the exact solve; recomputed only when its pins change."""
        key = pinned0.tobytes()
        if key == self._coarse_key:
            return
        op, n0 = self._coarse_ops, self.sizes[0]
        free = np.nonzero(~pinned0)[0]
        G = np.zeros((n0, n0))
        lam = np.full(n0, -1.0)
        if len(free):
            L = op.laplacian().toarray()[np.ix_(free, free)]
            s = 1.0 / np.sqrt(op.mass[free])
            S = s[:, None] * L * s[None, :]
            evals, Q = np.linalg.eigh(0.5 * (S + S.T))
            G[free, :len(free)] = s[:, None] * Q
            lam[:len(free)] = np.maximum(evals, 0.0)
        self.G.from_numpy(G.reshape(-1).astype(self._npf))
        self.lam.from_numpy(lam.astype(self._npf))
        self._coarse_key = key

    # ------------------------------------------------------------------ public solve
    def _check(self, rhs, dv, h) -> tuple[int, int]:
        n = self.sizes[self.active]
        for name, f in (("rhs", rhs), ("dv", dv)):
            if f.shape[0] < n:
                raise ValueError(f"{name} holds {f.shape[0]} entries, the active level {self.active} needs {n}")
        if not h > 0:
            raise ValueError(f"h must be > 0 [s], got {h}")
        return int(self.offsets[self.active]), n

    def solve(self, rhs, dv, h: float, cycles: int) -> None:
        """`cycles` iterations on the active level, each costing one V-cycle: preconditioned CG steps if
        self.krylov (the default), plain V-cycles otherwise. rhs [kg m/s], dv [m/s]: Vector(3) fields with
        >= n_active entries (the rest is ignored); dv holds the initial guess and receives the result (0 on
        pinned rows). h: the time step [s]. No host synchronisation inside (fixed iteration count)."""
        off, n = self._check(rhs, dv, h)
        h = float(h)
        self._load(rhs, dv, off, n)
        if self.krylov:
            if self.pre_sweeps != self.post_sweeps:
                raise ValueError("krylov needs a symmetric V-cycle: pre_sweeps == post_sweeps")
            self._cg_start(off, n, h)
            for k in range(int(cycles)):
                self._vcycle(h)
                self._cg_step(off, n, h, int(k == 0))
            self._cg_finish(off, n)
        else:
            for _ in range(int(cycles)):
                self._vcycle(h)
        self._store(dv, off, n)

    def jacobi(self, rhs, dv, h: float, sweeps: int, omega: float = 1.0) -> None:
        """The paper's smoother alone on the active level: `sweeps` Jacobi sweeps (omega = 1: the sweeps of
        taichi_cloth.integrators.approx_implicit) from the initial guess in dv. For comparisons."""
        off, n = self._check(rhs, dv, h)
        self._load(rhs, dv, off, n)
        self._jacobi(off, n, float(h), float(omega), int(sweeps))
        self._store(dv, off, n)

    def residual_norm(self, rhs, dv, h: float) -> float:
        """||rhs - A dv|| / ||rhs|| on the active level (L2 over the free rows and the 3 components);
        the absolute norm if rhs is 0 there. Overwrites the solver's scratch fields only."""
        off, n = self._check(rhs, dv, h)
        self._load(rhs, dv, off, n)
        self._norms(off, n, float(h))
        rr, bb = self.acc.to_numpy()
        return float(np.sqrt(rr / bb)) if bb > 0 else float(np.sqrt(rr))

    def _vcycle(self, h: float) -> None:
        o, s, w = self.offsets, self.sizes, self.omega
        for c in range(self.active, 0, -1):
            self._down(int(o[c]), s[c], int(o[c - 1]), s[c - 1], h, w)
        if self.coarse_sweeps == 0:
            self._coarse_direct(h)
        else:
            self._jacobi(0, s[0], h, w, self.coarse_sweeps)
        for c in range(1, self.active + 1):
            self._up(int(o[c]), s[c], h, w)

    def _jacobi(self, off: int, n: int, h: float, omega: float, sweeps: int) -> None:
        for k in range(sweeps):
            self._sweep(off, n, h, omega, k % 2)
        if sweeps % 2:
            self._copy_back(off, n)

    # ------------------------------------------------------------------ kernels
    @ti.func
    def _apply(self, g, src, hh):
        """(A x)_g = m x_g + h^2 sum_j k_gj (x_g - x_j), x = xs[src] (the difference form)."""
        xg = self.xs[src, g]
        acc = ti.Vector.zero(self.fp, 3)
        for e in range(self.row_ptr[g], self.row_ptr[g + 1]):
            acc += self.adj_k[e] * (xg - self.xs[src, self.adj_j[e]])
        return self.mass[g] * xg + hh * acc

    @ti.func
    def _sweep_loop(self, off, n, hh, w, src):
        for i in range(n):
            g = off + i
            out = ti.Vector.zero(self.fp, 3)
            if self.pin[g] == 0:
                r = self.b[g] - self._apply(g, src, hh)
                out = self.xs[src, g] + w * r / (self.mass[g] + hh * self.ksum[g])
            self.xs[1 - src, g] = out

    @ti.func
    def _sweeps(self, off, n, hh, w, count: ti.template()):
        for k in ti.static(range(count)):
            self._sweep_loop(off, n, hh, w, k % 2)
        if ti.static(count % 2 == 1):
            for i in range(n):
                self.xs[0, off + i] = self.xs[1, off + i]

    @ti.kernel
    def _sweep(self, off: ti.i32, n: ti.i32, h: ti.f64, omega: ti.f64, src: ti.i32):
        self._sweep_loop(off, n, ti.cast(h * h, self.fp), ti.cast(omega, self.fp), src)

    @ti.kernel
    def _copy_back(self, off: ti.i32, n: ti.i32):
        for i in range(n):
            self.xs[0, off + i] = self.xs[1, off + i]

    @ti.kernel
    def _down(self, off: ti.i32, n: ti.i32, coff: ti.i32, cn: ti.i32, h: ti.f64, omega: ti.f64):
        """Pre-smooth level (off, n), form its residual, restrict it to the coarser level (coff, cn), zero the
        coarse iterate."""
        hh = ti.cast(h * h, self.fp)
        self._sweeps(off, n, hh, ti.cast(omega, self.fp), self.pre_sweeps)
        for i in range(n):
            g = off + i
            r = ti.Vector.zero(self.fp, 3)
            if self.pin[g] == 0:
                r = self.b[g] - self._apply(g, 0, hh)
            self.r[g] = r
        for c in range(cn):
            gc = coff + c
            acc = ti.Vector.zero(self.fp, 3)
            if self.pin[gc] == 0:
                for e in range(self.r_ptr[gc], self.r_ptr[gc + 1]):
                    acc += self.r_w[e] * self.r[self.r_child[e]]
            self.b[gc] = acc
            self.xs[0, gc] = ti.Vector.zero(self.fp, 3)

    @ti.kernel
    def _up(self, off: ti.i32, n: ti.i32, h: ti.f64, omega: ti.f64):
        """Add the prolonged coarse correction to level (off, n) (not on pinned rows), then post-smooth."""
        for i in range(n):
            g = off + i
            if self.pin[g] == 0:
                corr = ti.Vector.zero(self.fp, 3)
                for j in ti.static(range(3)):
                    p = self.par[g][j]
                    if p >= 0:
                        corr += self.pw[g][j] * self.xs[0, p]
                self.xs[0, g] += corr
        self._sweeps(off, n, ti.cast(h * h, self.fp), ti.cast(omega, self.fp), self.post_sweeps)

    @ti.kernel
    def _coarse_direct(self, h: ti.f64):
        """x_0 = G diag(1/(1 + h^2 lambda)) G^T b_0 on the coarsest level (offset 0)."""
        n0 = self.y.shape[0]
        hh = ti.cast(h * h, self.fp)
        for p in range(n0):
            s = ti.Vector.zero(self.fp, 3)
            if self.lam[p] >= 0:
                for j in range(n0):
                    s += self.G[j * n0 + p] * self.b[j]
                s /= 1.0 + hh * self.lam[p]
            self.y[p] = s
        for i in range(n0):
            s = ti.Vector.zero(self.fp, 3)
            for p in range(n0):
                s += self.G[i * n0 + p] * self.y[p]
            self.xs[0, i] = s

    @ti.func
    def _apply_local(self, v: ti.template(), i, off, hh):
        """(A v)_i for a field v indexed locally on the level at offset off (the difference form)."""
        g = off + i
        vi = v[i]
        acc = ti.Vector.zero(self.fp, 3)
        for e in range(self.row_ptr[g], self.row_ptr[g + 1]):
            acc += self.adj_k[e] * (vi - v[self.adj_j[e] - off])
        return self.mass[g] * vi + hh * acc

    @ti.kernel
    def _cg_start(self, off: ti.i32, n: ti.i32, h: ti.f64):
        """x = the loaded guess, r = b - A x; the preconditioner's input b = r with a zero iterate."""
        hh = ti.cast(h * h, self.fp)
        for i in range(n):
            g = off + i
            r = ti.Vector.zero(self.fp, 3)
            if self.pin[g] == 0:
                r = self.b[g] - self._apply(g, 0, hh)
            self.cg_x[i] = self.xs[0, g]
            self.cg_r[i] = r
        for i in range(n):
            self.b[off + i] = self.cg_r[i]
            self.xs[0, off + i] = ti.Vector.zero(self.fp, 3)
        self.cg_s[0] = 0.0

    @ti.kernel
    def _cg_step(self, off: ti.i32, n: ti.i32, h: ti.f64, first: ti.i32):
        """One PCG step, z = xs[0] = V-cycle(r) already computed. Scalars stay on the device; a zero
        denominator (converged exactly) gives a zero step instead of NaN."""
        hh = ti.cast(h * h, self.fp)
        self.cg_s[2] = 0.0
        for i in range(n):
            self.cg_s[2] += ti.cast(self.cg_r[i].dot(self.xs[0, off + i]), ti.f64)
        beta = ti.cast(0.0, ti.f64)
        if first == 0 and self.cg_s[0] > 0:
            beta = self.cg_s[2] / self.cg_s[0]
        for i in range(n):
            self.cg_p[i] = self.xs[0, off + i] + ti.cast(beta, self.fp) * self.cg_p[i]
        self.cg_s[0] = self.cg_s[2]
        self.cg_s[1] = 0.0
        for i in range(n):
            q = ti.Vector.zero(self.fp, 3)
            if self.pin[off + i] == 0:
                q = self._apply_local(self.cg_p, i, off, hh)
            self.cg_q[i] = q
            self.cg_s[1] += ti.cast(self.cg_p[i].dot(q), ti.f64)
        alpha = ti.cast(0.0, ti.f64)
        if self.cg_s[1] > 0:
            alpha = self.cg_s[0] / self.cg_s[1]
        for i in range(n):
            a = ti.cast(alpha, self.fp)
            self.cg_x[i] += a * self.cg_p[i]
            r = self.cg_r[i] - a * self.cg_q[i]
            self.cg_r[i] = r
            self.b[off + i] = r
            self.xs[0, off + i] = ti.Vector.zero(self.fp, 3)

    @ti.kernel
    def _cg_finish(self, off: ti.i32, n: ti.i32):
        for i in range(n):
            self.xs[0, off + i] = self.cg_x[i]

    @ti.kernel
    def _load(self, rhs: ti.template(), dv: ti.template(), off: ti.i32, n: ti.i32):
        for i in range(n):
            g = off + i
            if self.pin[g] == 0:
                self.b[g] = ti.cast(rhs[i], self.fp)
                self.xs[0, g] = ti.cast(dv[i], self.fp)
            else:
                self.b[g] = ti.Vector.zero(self.fp, 3)
                self.xs[0, g] = ti.Vector.zero(self.fp, 3)

    @ti.kernel
    def _store(self, dv: ti.template(), off: ti.i32, n: ti.i32):
        for i in range(n):
            dv[i] = ti.cast(self.xs[0, off + i], dv.dtype)

    @ti.kernel
    def _norms(self, off: ti.i32, n: ti.i32, h: ti.f64):
        hh = ti.cast(h * h, self.fp)
        self.acc[0] = 0.0
        self.acc[1] = 0.0
        for i in range(n):
            g = off + i
            if self.pin[g] == 0:
                r = ti.cast(self.b[g] - self._apply(g, 0, hh), ti.f64)
                b = ti.cast(self.b[g], ti.f64)
                self.acc[0] += r.dot(r)
                self.acc[1] += b.dot(b)
