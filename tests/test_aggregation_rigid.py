"""The aggregation multigrid's rigid-body coarse space (taichi_cloth.linear.aggregation): rotations are in it, a
garment's preconditioned solve equals scipy's direct solve of the filtered system built from the BlockSystem's
blocks, its cycle is the same operator run in one thread or level by level in parallel, and its CG count stays
bounded as the garment's spacing halves."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spl

from conftest import damping_matrix, sliding_normals
from taichi_cloth.linear.aggregation import AggregationMultigrid
from taichi_cloth.runtime import OneThreadLoops
from taichi_cloth.stability import stiffness_matrix
from test_implicit_multigrid import GAMMA, H, assert_symmetric_positive, dense_level, prolongation, sewn_pair


@pytest.fixture(scope="module")
def pair():
    """The sewn pair at 2 cm, float64, aggregation-preconditioned: one scene (its kernels compiled once) that each
    test resets to its start."""
    return sewn_pair(0.02)


def filtered_matrix(integ):
    """A~ = S A S + M' (I - S) (scipy CSR, float64) and S, from the BlockSystem's spring blocks B_s = axial u u^T +
    iso I, the masses times mass_scale plus the sliding contacts' friction dashpots (extra_mass) and the filter (pins,
    contacts held by static friction, sliding contacts)."""
    m, sy = integ.model, integ.system
    n, ns = m.data.n_particles, m.n_springs[None]
    u = sy.u.to_numpy()[:ns]
    B = sy.axial.to_numpy()[:ns, None, None] * np.einsum("si,sj->sij", u, u) \
        + sy.iso.to_numpy()[:ns, None, None] * np.eye(3)
    a, b = m.spring_a.to_numpy()[:ns], m.spring_b.to_numpy()[:ns]
    mass = m.mass.to_numpy()[:n] * sy.mass_scale[None]
    held = m.inv_mass.to_numpy()[:n] == 0
    S = np.repeat(np.eye(3)[None], n, 0)
    if integ.contacts is not None:
        normal = sliding_normals(integ.contacts, n)
        for i in np.nonzero(np.einsum("ij,ij->i", normal, normal) > 0)[0]:
            nn = normal[i] / np.linalg.norm(normal[i])
            S[i] = np.eye(3) - np.outer(nn, nn)
        held |= integ.contacts.stuck.to_numpy()[:n] != 0
    S[held] = 0
    r, c = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    rows, cols, vals = [], [], []
    drag = sy.extra_mass.to_numpy()[:n]
    for i, j, blk in ((np.arange(n), np.arange(n), (mass + drag)[:, None, None] * np.eye(3)), (a, a, B), (b, b, B),
                      (a, b, -B), (b, a, -B)):
        rows.append((3 * i[:, None, None] + r).ravel())
        cols.append((3 * j[:, None, None] + c).ravel())
        vals.append(blk.ravel())
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, 3 * n))
    Sm = sp.block_diag(list(S), format="csr")
    return (Sm @ A @ Sm + sp.diags(np.repeat(mass, 3)) @ (sp.identity(3 * n) - Sm)).tocsr(), Sm


def test_a_rigid_motion_is_reproduced_exactly_by_the_prolongation_from_every_coarse_level(pair):
    """v_i = t + theta x (x_i - p) (a small rotation about an arbitrary axis through an arbitrary point, and a
    translation) is P_1 ... P_l of the coarse vertices' (t + theta x (c - p), theta), on every level l, with the lever
    arms the cycle computed from the current positions (the Galerkin test of test_implicit_multigrid checks that the
    cycle's coarse operators are P^T A~ P with this P). A translation-only coarse space misses it by |theta| |x - c|."""
    sc = pair
    sc.reset()
    sc.step(6)  # off the flat start
    integ = sc.integrator
    mg = integ.policy.current
    assert isinstance(mg, AggregationMultigrid) and len(mg.sizes) >= 3, integ.detail
    integ.system.set_step(H, GAMMA)
    integ._assemble(H, H * GAMMA, 1)
    mg.prepare(integ.system, integ.filter)
    x = sc.positions()
    rng = np.random.default_rng(3)
    axis = rng.standard_normal(3)
    theta, t, p = 0.01 * axis / np.linalg.norm(axis), rng.standard_normal(3), rng.standard_normal(3)
    v = (t + np.cross(theta, x - p)).reshape(-1)
    vb = mg.vbound.to_numpy()
    centre = mg.centre.to_numpy()
    np.testing.assert_allclose(mg.arm.to_numpy()[:len(x)], x - centre[mg.agg.to_numpy()[:len(x)] - vb[1]],
                               rtol=0, atol=1e-12)
    P = np.eye(3 * len(x))
    for level in range(1, len(mg.sizes)):
        P = P @ prolongation(mg, level)
        c = centre[vb[level] - vb[1]:vb[level + 1] - vb[1]]
        coarse = np.concatenate([t + np.cross(theta, c - p), np.repeat(theta[None], len(c), 0)], 1).reshape(-1)
        np.testing.assert_allclose(P @ coarse, v, rtol=0, atol=1e-12 * np.abs(v).max())
        translations = coarse.reshape(-1, 6) * [1, 1, 1, 0, 0, 0]
        assert np.abs(P @ translations.reshape(-1) - v).max() > 1e-4  # the rotation is what it needs


def test_a_garment_solve_preconditioned_by_the_cycle_equals_the_direct_solve(pair):
    """The aggregation-preconditioned CG solution of a Newton system of the sewn pair lying partly on the ball (pins,
    contacts held and sliding) equals scipy's direct solve of A~ x = S b, A~ built from the BlockSystem's blocks, to
    1e-8 of its largest component (CG to a relative 1e-12, float64)."""
    sc = pair
    sc.reset()
    sc.step(12)
    integ = sc.integrator
    n = sc.model.data.n_particles
    touching = np.linalg.norm(sc.contacts.normal.to_numpy()[:n], axis=1) > 0
    assert 4 < touching.sum() < n - 10, touching.sum()
    integ.system.set_step(H, GAMMA)
    integ._begin()
    integ._assemble(H, H * GAMMA, 1)
    mg = integ.policy.current
    assert isinstance(mg, AggregationMultigrid)
    mg.prepare(integ.system, integ.filter)
    integ.pcg.x.fill(0)
    integ.pcg.solve(integ.system, integ.filter, mg, 1e-12, 2000)
    its = integ.pcg.iterations[None]
    A, S = filtered_matrix(integ)
    b = S @ integ.b.to_numpy()[:n].reshape(-1)
    expected = spl.spsolve(A.tocsc(), b)
    got = integ.pcg.x.to_numpy()[:n].reshape(-1)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-8 * np.abs(expected).max())
    assert 0 < its < 200, its
    # the cycle as a GPU runs it (a kernel per level, no loop in one thread: the coarsest factored a column per
    # launch and solved by its inverse) is the same operator as the CPU's one-thread cycle, to round-off
    r = np.random.default_rng(5).standard_normal(integ.pcg.r.shape + (3,))
    integ.pcg.r.from_numpy(r)
    mg.apply(integ.pcg.r, integ.pcg.z)
    serial = integ.pcg.z.to_numpy()[:n]
    assert mg.serial and np.abs(serial).max() > 0
    with OneThreadLoops() as seen:
        gpu = AggregationMultigrid(integ.model.capacity[:2], fp=integ.model.fp, serial=False)
        gpu.rebuild(integ.model.data.springs, n, integ.model.data.kind)
        assert gpu.sizes == mg.sizes
        gpu.prepare(integ.system, integ.filter)
        integ.pcg.r.from_numpy(r)
        gpu.apply(integ.pcg.r, integ.pcg.z)
    assert seen.sites == set()
    np.testing.assert_allclose(integ.pcg.z.to_numpy()[:n], serial, rtol=0, atol=1e-10 * np.abs(serial).max())


def test_an_aggregation_v_cycle_is_symmetric_and_positive_and_its_levels_are_galerkin(pair):
    """The aggregation cycle is the symmetric positive definite operator CG needs, and every coarse level is
    P^T A~ P of the level above (P the aggregates' rigid-body prolongation: level 0's S_i [I, -[x_i - c]_x], a coarse
    vertex's [[I, -[c_G - c_K]_x], [0, I]]): checked on the sewn pair against the blocks of the filtered operator
    A~ = S A S + M' (I - S) built here."""
    sc = pair
    sc.reset()
    sc.step(12)
    integ = sc.integrator
    mg = integ.policy.current
    integ.system.set_step(H, GAMMA)
    integ._assemble(H, H * GAMMA, 1)  # the Newton system's springs at the current state
    mg.prepare(integ.system, integ.filter)
    n = sc.model.data.n_particles
    assert_symmetric_positive(mg, np.random.default_rng(7), np.ones(n, bool))  # every row: A~ has no zero rows

    def dense(level):
        return dense_level(mg, level)

    # level 0 is A~ of the formulas
    d, x = sc.model.data, sc.positions()
    K = stiffness_matrix(x, d.springs, d.stiffness, d.rest_length)
    D = damping_matrix(d, x)
    drag = integ.system.extra_mass.to_numpy()[:n].astype(np.float64)  # the sliding contacts' friction
    A = np.diag(np.repeat(d.mass, 3) * (1 + H * GAMMA) + np.repeat(drag, 3)) + H * D + H * H * K
    normals = sliding_normals(sc.contacts, n)
    held = sc.model.pinned | (sc.contacts.stuck.to_numpy()[:n] != 0)
    S = np.zeros((3 * n, 3 * n))
    for i in range(n):
        nn = normals[i] @ normals[i]
        Si = np.zeros((3, 3)) if held[i] else np.eye(3) - (np.outer(normals[i], normals[i]) / nn if nn > 0 else 0)
        S[3 * i:3 * i + 3, 3 * i:3 * i + 3] = Si
    M = np.diag(np.repeat(d.mass, 3) * (1 + H * GAMMA))
    At = S @ A @ S + M @ (np.eye(3 * n) - S)
    np.testing.assert_allclose(dense(0), At, rtol=0, atol=1e-12 * np.abs(At).max())
    for level in range(1, len(mg.sizes)):
        fine, coarse = dense(level - 1), dense(level)
        P = prolongation(mg, level, S)
        np.testing.assert_allclose(coarse, P.T @ fine @ P, rtol=0, atol=1e-12 * np.abs(fine).max())


def test_a_reset_scene_runs_again_as_it_ran_from_its_start(pair):
    """Scene.reset() forgets the contacts too: the sewn pair lying on the ball, reset and run again, retraces its
    first run (a stale contact held by static friction would keep its particle still in the first step: about
    h^2 g = 2.7 mm off)."""
    pair.reset()
    pair.step(12)
    first = pair.positions()
    assert (pair.contacts.stuck.to_numpy() != 0).any() or (pair.integrator.system.extra_mass.to_numpy() > 0).any()
    pair.reset()
    assert not pair.contacts.normal.to_numpy().any() and not pair.contacts.stuck.to_numpy().any()
    pair.step(12)
    np.testing.assert_allclose(pair.positions(), first, rtol=0, atol=1e-9)


#: CG iterations per Newton iteration the aggregation cycle may add from 2 cm to 1 cm spacing
MARGIN = 6


def test_the_cg_count_stays_bounded_as_the_spacing_halves():
    """CG iterations per Newton iteration of the sewn pair falling onto the ball over 12 steps (cg_tolerance 1e-3,
    float32 as the demos run) at 2 and 1 cm spacing: the finer takes at most MARGIN more than the coarser.
    Jacobi-preconditioned CG on the same Newton systems (the 12th step's, its contacts off) needs more than MARGIN
    more (figures: docs/performance.md, preconditioners): the test tells a preconditioner that does not scale."""
    its, jacobi = {}, {}
    for spacing in (0.02, 0.01):
        sc = sewn_pair(spacing, precision="f32", cg_tolerance=1e-3)
        sc.step(12)
        integ = sc.integrator
        its[spacing] = integ.stats["cg_iterations"] / integ.stats["newton_iterations"]
        # the next step's first Newton system without its contacts (how many the ball holds by friction decides
        # how well Jacobi does; that number varies with the path), solved from zero by each preconditioner
        sc.contacts.reset()
        integ.system.set_step(H, GAMMA)
        integ._begin()
        integ._assemble(H, H * GAMMA, 1)
        counts = []
        for preconditioner in (integ.policy.current, integ.policy.jacobi):
            preconditioner.prepare(integ.system, integ.filter)
            integ.pcg.x.fill(0)
            integ.pcg.solve(integ.system, integ.filter, preconditioner, 1e-3, 2000)
            counts.append(integ.pcg.iterations[None])
        assert isinstance(integ.policy.current, AggregationMultigrid) and counts[0] < counts[1], counts
        jacobi[spacing] = counts[1]
    assert its[0.01] <= its[0.02] + MARGIN, its
    assert jacobi[0.01] > jacobi[0.02] + MARGIN, jacobi


@pytest.mark.filterwarnings("ignore:.*Taichi matrices/vectors with 6x6")  # the engine's own 6x6 blocks, on purpose
def test_a_nearly_singular_block_gets_a_bounded_inverse_and_factor():
    """A 6x6 block that is positive semidefinite in exact arithmetic but slightly indefinite in its entries (an
    aggregate that cannot see one of its rotations, in float32) is inverted (the smoother's blocks) and factored (the
    coarsest level's dense factor) to finite numbers: with a pivot floor of 1e-300 both overflowed to inf and NaN,
    and CG stopped at once with every later step of the 1 cm skirt left explicit."""
    import taichi as ti

    from taichi_cloth.linear.aggregation import spd_inverse6
    from taichi_cloth.linear.dense import cholesky, cholesky_solve

    rng = np.random.default_rng(2)
    B = rng.standard_normal((6, 3))
    A = B @ B.T - 1e-9 * np.eye(6)  # rank 3, nudged below semidefinite
    assert np.linalg.eigvalsh(A).min() < 0
    M = ti.Matrix.field(6, 6, ti.f64, ())
    out = ti.Matrix.field(6, 6, ti.f64, ())
    dense = ti.field(ti.f64, (6, 6))
    y = ti.field(ti.f64, 6)

    @ti.kernel
    def run():
        out[None] = spd_inverse6(M[None])
        for _ in range(1):
            cholesky(dense, 6)
            cholesky_solve(dense, y, 6)

    M[None] = A.tolist()
    dense.from_numpy(A)
    y.from_numpy(np.ones(6))
    run()
    assert np.isfinite(out[None].to_numpy()).all() and np.isfinite(y.to_numpy()).all()
