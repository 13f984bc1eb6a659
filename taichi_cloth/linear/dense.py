"""Dense Cholesky factorisation and solve in Taichi functions, for the coarsest level of a multigrid cycle (a few
hundred unknowns, factored in one thread at every step; float64 fields)."""

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
