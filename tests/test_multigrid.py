"""Multigrid over the 4-8 levels (multilevel/multigrid.py) for the approximate-implicit system
(M + h^2 L) dv = rhs: agreement with a sparse direct solve, a level-independent V-cycle rate where Jacobi
stalls, pins, coarser active levels, and no recompiles. Problem: a 1 m square, base (4, 4), springs of
k = 2000 N/m on the triangle edges, 0.2 kg/m^2 area-lumped."""
import numpy as np
import pytest
import taichi as ti

import taichi_cloth as tc
from multilevel.hierarchy import Hierarchy48
from multilevel.multigrid import LevelOperator, MultigridSolver, edge_operator, prolongation_matrix

K = 2000.0      # [N/m]
RHO = 0.2       # [kg/m^2]
G = np.array([0.0, -9.81, 0.0])


def problem(levels: int):
    hier = Hierarchy48.rectangle((1.0, 1.0), (4, 4), levels)
    return hier, [edge_operator(lv, RHO, K) for lv in hier.levels]


def load(level, op, h, seed=0):
    """rhs (n, 3) [kg m/s]: h m (g + a smooth load) plus a little noise: smooth enough that Jacobi stalls."""
    x, y = level.uv[:, 0], level.uv[:, 1]
    smooth = np.stack([np.sin(np.pi * x) * np.cos(np.pi * y), 3 * np.cos(2 * np.pi * x), 0.5 * x * y], 1)
    noise = 0.1 * np.random.default_rng(seed).standard_normal((op.n, 3))
    return h * op.mass[:, None] * (G + smooth + noise)


def put(field, values):
    full = np.zeros((field.shape[0], 3))
    full[:len(values)] = values
    field.from_numpy(full.astype(np.float32 if field.dtype == ti.f32 else np.float64))


def get(field, n):
    return field.to_numpy()[:n].astype(np.float64)


def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


class Case:
    """A solver with its hierarchy, operators and a pair of rhs/dv fields sized for the finest level."""

    def __init__(self, levels, fp, **kw):
        self.hier, self.ops = problem(levels)
        self.mg = MultigridSolver(self.hier.levels, self.ops, fp=fp, **kw)
        n = self.ops[-1].n
        self.rhs = ti.Vector.field(3, fp, n)
        self.dv = ti.Vector.field(3, fp, n)

    def restore(self, krylov=True):
        self.mg.krylov = krylov
        self.mg.set_active_level(len(self.ops) - 1)
        for lv, op in enumerate(self.ops):
            self.mg.set_pinned(lv, np.zeros(op.n, bool))

    def run(self, level, b, h, cycles, guess=None):
        self.mg.set_active_level(level)
        put(self.rhs, b)
        put(self.dv, np.zeros_like(b) if guess is None else guess)
        self.mg.solve(self.rhs, self.dv, h, cycles)
        return get(self.dv, len(b))

    def factors(self, level, b, h, cycles):
        """Residual after 0..cycles iterations: one call per plain V-cycle, or one PCG run of k iterations."""
        self.mg.set_active_level(level)
        put(self.rhs, b)
        self.dv.fill(0)
        res = [self.mg.residual_norm(self.rhs, self.dv, h)]
        for k in range(1, cycles + 1):
            if self.mg.krylov:
                self.dv.fill(0)
            self.mg.solve(self.rhs, self.dv, h, k if self.mg.krylov else 1)
            res.append(self.mg.residual_norm(self.rhs, self.dv, h))
        return np.array(res)


@pytest.fixture(scope="module")
def f64():
    case = Case(7, ti.f64)  # finest 33 x 33
    yield case


@pytest.fixture(scope="module")
def f32():
    case = Case(5, ti.f32)  # finest 17 x 17
    yield case


def test_the_coarse_lumped_mass_is_the_restricted_fine_mass():
    hier, ops = problem(5)
    for lv in range(1, 5):
        P = prolongation_matrix(hier[lv], ops[lv - 1].n)
        assert np.allclose(P.T @ ops[lv].mass, ops[lv - 1].mass, rtol=1e-12, atol=0)
    assert np.isclose(ops[-1].mass.sum(), RHO * 1.0)


@pytest.mark.parametrize("krylov", [True, False], ids=["mg-pcg", "v-cycle"])
def test_agrees_with_a_sparse_direct_solve(f64, f32, krylov):
    h = 1 / 120
    for case, cycles, tol in ((f64, 10, 1e-9), (f32, 6, 2e-5)):
        case.restore(krylov)
        top = len(case.ops) - 1
        b = load(case.hier[top], case.ops[top], h)
        exact = case.ops[top].reference_solve(b, h)
        dv = case.run(top, b, h, cycles)
        assert rel(dv, exact) < tol, (case.mg.fp, rel(dv, exact))


def test_vcycle_rate_is_level_independent_where_jacobi_stalls(f64):
    """h = 1/60 s: h^2 k / m = 267 (level 2) .. 4267 (level 6). Jacobi: 20 sweeps (more work than one V(2,2)
    cycle, ~12 sweeps) remove < 10 % of the residual; a V-cycle removes > 80 % per cycle at every depth."""
    case, h = f64, 1 / 60
    case.restore(krylov=False)
    worst = []
    for level in range(2, 7):
        op = case.ops[level]
        b = load(case.hier[level], op, h)
        assert 1e2 < h * h * K / np.median(op.mass) < 1e4
        put(case.rhs, b)
        case.dv.fill(0)
        case.mg.set_active_level(level)
        case.mg.jacobi(case.rhs, case.dv, h, 20)
        assert case.mg.residual_norm(case.rhs, case.dv, h) > 0.9
        res = case.factors(level, b, h, 6)
        per_cycle = res[1:] / res[:-1]
        worst.append(per_cycle.max())
        assert per_cycle.max() < 0.2, (level, per_cycle)
    assert max(worst) < 2.5 * min(worst), worst  # roughly independent of the depth (0.07 .. 0.14 measured)
    case.restore()


def test_point_pins_need_the_krylov_wrapper(f64):
    """Two pinned corners (the hanging sheet): the plain V-cycle slows to ~0.5 per cycle (the coarse levels
    misjudge a point pin), MG-PCG keeps ~0.1-0.2 per iteration and reaches the direct solution."""
    case, h = f64, 1 / 120
    top = len(case.ops) - 1
    uv = case.hier[top].uv
    pins = np.isclose(uv[:, 1], 0.5) & np.isclose(np.abs(uv[:, 0]), 0.5)
    op = case.ops[top]
    b = load(case.hier[top], op, h)
    exact = LevelOperator(op.mass, op.springs, op.stiffness, pins).reference_solve(b, h)
    rates = {}
    for krylov in (False, True):
        case.restore(krylov)
        case.mg.set_pinned(top, pins)
        res = case.factors(top, b, h, 8)
        rates[krylov] = (res[8] / res[3]) ** (1 / 5)
    assert rates[False] > 0.3 and rates[True] < 0.25, rates
    assert rel(get(case.dv, op.n), exact) < 1e-6  # after 8 MG-PCG iterations
    case.restore()


def test_pinned_rows_stay_at_zero(f64):
    """Top edge pinned on every level, plus a midpoint vertex pinned only on the finest level: dv = 0 there even
    from a non-zero guess and a non-zero rhs on those rows, and the free rows match the reduced direct solve
    (MG-PCG, the default)."""
    case, h = f64, 1 / 120
    case.restore()
    top = len(case.ops) - 1
    for lv, level in enumerate(case.hier.levels):
        case.mg.set_pinned(lv, np.isclose(level.uv[:, 1], 0.5))
    pins = np.isclose(case.hier[top].uv[:, 1], 0.5)
    lone = case.ops[top - 1].n + 7  # a vertex that the coarser levels do not have
    pins[lone] = True
    case.mg.set_pinned(top, pins)
    op = case.ops[top]
    ref = LevelOperator(op.mass, op.springs, op.stiffness, pins)
    b = load(case.hier[top], op, h)
    dv = case.run(top, b, h, 10, guess=np.ones_like(b))
    assert np.all(dv[pins] == 0.0)
    assert rel(dv, ref.reference_solve(b, h)) < 1e-8
    # the level below inherits the pinned vertices it shares, plus the two parents of the pinned midpoint
    expect = pins[:case.ops[top - 1].n].copy()
    expect[case.hier[top].parents[lone, :2]] = True
    assert np.array_equal(case.mg.effective_pins(top - 1), expect)
    case.restore()


def test_a_coarser_active_level_solves_that_level(f64):
    case, h = f64, 1 / 120
    case.restore()
    n_top = case.ops[-1].n
    for level, cycles, tol in ((2, 10, 1e-9), (0, 1, 1e-10)):  # level 0 alone: the exact coarse solve
        op = case.ops[level]
        b = load(case.hier[level], op, h, seed=level)
        case.mg.set_active_level(level)
        garbage = np.full((n_top, 3), 7.0)
        garbage[:op.n] = b
        put(case.rhs, garbage)  # entries beyond n_level are ignored ...
        guess = np.full((n_top, 3), 5.0)
        guess[:op.n] = 0.0
        put(case.dv, guess)
        case.mg.solve(case.rhs, case.dv, h, cycles)
        out = case.dv.to_numpy()
        assert np.all(out[op.n:] == 5.0)  # ... and left alone
        assert rel(out[:op.n].astype(np.float64), op.reference_solve(b, h)) < tol
    case.restore()


def test_jacobi_is_the_papers_smoother(f32):
    """Two sweeps from 0 with omega = 1 give the paper's dv_i = (rhs_i + h^2 sum_j k_ij dv~_j) / (m_i + h^2 sum_j k_ij),
    dv~ = rhs / diag."""
    case, h = f32, 1 / 120
    case.restore()
    top = len(case.ops) - 1
    op = case.ops[top]
    b = load(case.hier[top], op, h)
    put(case.rhs, b)
    case.dv.fill(0)
    case.mg.jacobi(case.rhs, case.dv, h, 2)
    diag = op.mass + h * h * op.stiffness_sum()
    off = diag[:, None] * (b / diag[:, None]) - op.matrix(h) @ (b / diag[:, None])  # h^2 sum_j k_ij dv~_j
    seed = (b + off) / diag[:, None]
    assert rel(get(case.dv, op.n), seed) < 1e-5


def test_no_recompiles_for_levels_pins_or_step():
    """Each solver kernel compiles once for all levels: solving on every level, switching pins, h and omega
    compiles nothing after the first solve."""
    with tc.CompileCounter() as first:
        case = Case(4, ti.f32)
        b = load(case.hier[3], case.ops[3], 0.01)
        case.run(3, b, 0.01, 1)
        case.mg.krylov = False
        case.run(3, b, 0.01, 1)
        case.mg.jacobi(case.rhs, case.dv, 0.01, 3)
        case.mg.residual_norm(case.rhs, case.dv, 0.01)
    own = {k: v for k, v in first.compiled.items() if k.startswith("MultigridSolver.")}
    assert own and all(v == 1 for v in own.values()), own
    with tc.CompileCounter() as again:
        for level in (3, 2, 1, 0, 3):
            op = case.ops[level]
            case.run(level, load(case.hier[level], op, 1 / 60), 1 / 60, 2)
            case.mg.residual_norm(case.rhs, case.dv, 1 / 30)
            case.mg.jacobi(case.rhs, case.dv, 1 / 90, 2)
        case.mg.set_pinned(3, np.isclose(case.hier[3].uv[:, 1], 0.5))
        case.mg.omega = 0.7
        case.mg.krylov = True
        case.run(3, b, 0.02, 2)
    assert again.total == 0, again.compiled


def test_bad_input_is_refused():
    hier, ops = problem(2)
    with pytest.raises(ValueError):
        MultigridSolver(hier.levels, ops[:1])
    with pytest.raises(ValueError):
        MultigridSolver(hier.levels, ops, coarse_direct_max=10)
    with pytest.raises(ValueError):
        MultigridSolver(hier.levels, ops, pre_sweeps=1, post_sweeps=2)  # CG needs a symmetric V-cycle
    with pytest.raises(ValueError):
        LevelOperator(np.zeros(3), np.array([[0, 1]]), np.array([1.0]), np.zeros(3, bool))  # massless free particle
