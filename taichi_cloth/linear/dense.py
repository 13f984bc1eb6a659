"""Dense Cholesky factorisation and solve, for the coarsest level of a multigrid cycle (a few hundred unknowns,
factored at every Newton iteration; float64 fields): on the CPU in one thread (Taichi functions called from a
one-thread loop), elsewhere column by column in parallel launches and solved by the inverse (factor_in_parallel)."""

import taichi as ti

#: the smallest pivot of a factor, relative to its diagonal entry: a matrix that is positive semidefinite in exact
#: arithmetic but not in its float32 entries (an aggregate that cannot see one of its rotations) gets a pivot of
#: this size in that direction instead of one of 1e-300, whose factor overflowed to inf and NaN
PIVOT_FLOOR = 1e-6


@ti.func
def cholesky(A: ti.template(), C):
    """A's leading C x C block (symmetric positive definite) becomes its Cholesky factor L (A = L L^T) in place,
    column by column, in the lower triangle (the upper one is left as it was). Call it from one thread."""
    for j in range(C):
        s = A[j, j]
        floor = ti.max(PIVOT_FLOOR * ti.abs(A[j, j]), 1e-300)
        for k in range(j):
            s -= A[j, k] * A[j, k]
        djj = ti.sqrt(ti.max(s, floor))
        A[j, j] = djj
        for i in range(j + 1, C):
            t = A[i, j]
            for k in range(j):
                t -= A[i, k] * A[j, k]
            A[i, j] = t / djj


@ti.func
def cholesky_solve(L: ti.template(), y: ti.template(), C):
    """y = (L L^T)^-1 y in place, for the factor `cholesky` left in L's leading C x C block. One thread."""
    for i in range(C):
        t = y[i]
        for k in range(i):
            t -= L[i, k] * y[k]
        y[i] = t / L[i, i]
    for ii in range(C):
        i = C - 1 - ii
        t = y[i]
        for k in range(i + 1, C):
            t -= L[k, i] * y[k]
        y[i] = t / L[i, i]


# ---------------------------------------------------------------------- the same without a one-thread loop
# A GPU runs no loop in one thread (a one-thread factor of a 384-unknown level is some ten million dependent steps
# of one GPU thread at every Newton iteration): there the factor takes one launch per column, its rows in parallel,
# the inverse one launch, a column of it per thread, and a solve is the product with the inverse, its rows in
# parallel.

@ti.kernel
def factor_column(A: ti.template(), diag: ti.template(), j: ti.i32, C: ti.i32, live: ti.template()):
    """Column j of the Cholesky factor of A's leading C x C block, its rows in parallel; the columns before j are
    done (earlier launches). The factor's diagonal goes to diag (A[j, j] stays A's: every row of the column reads
    it), its lower triangle into A's. Nothing when live[None] is 0."""
    for i in range(j, ti.select(live[None] != 0, C, j)):
        s = A[j, j]
        floor = ti.max(PIVOT_FLOOR * ti.abs(A[j, j]), 1e-300)
        for k in range(j):
            s -= A[j, k] * A[j, k]
        djj = ti.sqrt(ti.max(s, floor))
        if i == j:
            diag[j] = djj
        else:
            t = A[i, j]
            for k in range(j):
                t -= A[i, k] * A[j, k]
            A[i, j] = t / djj


@ti.kernel
def invert_factor(A: ti.template(), diag: ti.template(), inverse: ti.template(), C: ti.i32, live: ti.template()):
    """inverse = (L L^T)^-1 for the factor of factor_column (lower triangle of A, diagonal diag), one column per
    thread: two triangular solves with a unit vector. Nothing when live[None] is 0."""
    for c in range(ti.select(live[None] != 0, C, 0)):
        for i in range(C):
            t = ti.cast(ti.select(i == c, 1.0, 0.0), ti.f64)
            for k in range(c, i):
                t -= A[i, k] * inverse[k, c]
            inverse[i, c] = t / diag[i]
        for ii in range(C):
            i = C - 1 - ii
            t = inverse[i, c]
            for k in range(i + 1, C):
                t -= A[k, i] * inverse[k, c]
            inverse[i, c] = t / diag[i]


def factor_in_parallel(A, diag, inverse, C: int, live) -> None:
    """A's leading C x C block factored and inverted without a one-thread loop (C + 1 launches; live: a 0-d int
    field, nothing is done while it is 0)."""
    for j in range(C):
        factor_column(A, diag, j, C, live)
    invert_factor(A, diag, inverse, C, live)
