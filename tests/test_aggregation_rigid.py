"""The aggregation multigrid's rigid-body coarse space (taichi_cloth.linear.aggregation): rotations are in it, a
garment's preconditioned solve equals scipy's direct solve of the filtered system built from the BlockSystem's
blocks, its cycle is the same operator run in one thread or level by level in parallel, and its CG count stays
bounded as the garment's spacing halves."""
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl

import taichi_cloth as tc
from taichi_cloth.linear.aggregation import AggregationMultigrid
from test_implicit_multigrid import BALL, GAMMA, H, prolongation


def sewn_pair(spacing: float, preconditioner: str = "multigrid", precision: str = "f64", **options):
    """Two 0.2 m squares sewn into one 0.4 x 0.2 m sheet at `spacing` [m] (the seam merged: a garment's topology),
    held by its back edge above a ball."""
    from taichi_cloth.garment.garment import FreePlacement, GarmentSpec, build_garment
    from taichi_cloth.garment.seams import Seam, SeamSide
    from taichi_cloth.garment.sewing import merge_seams
    from test_garment import square

    seam = Seam("middle", SeamSide("A", "br", "tr"), SeamSide("B", "bl", "tl"))
    flat = {"v_axis": (0.0, 0.0, 1.0)}
    g = build_garment(GarmentSpec("sewn pair", [square("A"), square("B")], [seam],
                                  {"A": FreePlacement((-0.2, 0.6, -0.1), **flat),
                                   "B": FreePlacement((0.0, 0.6, -0.1), **flat)}, spacing=spacing))
    x = g.data.positions
    data, _, _, _ = merge_seams(g.data, g, x, np.zeros_like(x))
    back = {"box": ((-0.21, 0.59, -0.11), (0.21, 0.61, -0.09))}
    return tc.Scene(data, dt=H, air_damping=GAMMA, precision=precision, pins=[back], colliders=[BALL],
                    integrator_options={"preconditioner": preconditioner, **options})


def filtered_matrix(integ):
    """A~ = S A S + M' (I - S) (scipy CSR, float64) and S, from the BlockSystem's spring blocks B_s = axial u u^T +
    iso I, the masses times mass_scale and the filter (pins, contacts held by static friction, sliding contacts)."""
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
        normal = integ.contacts.normal.to_numpy()[:n]
        for i in np.nonzero(np.einsum("ij,ij->i", normal, normal) > 0)[0]:
            nn = normal[i] / np.linalg.norm(normal[i])
            S[i] = np.eye(3) - np.outer(nn, nn)
        held |= integ.contacts.stuck.to_numpy()[:n] != 0
    S[held] = 0
    r, c = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    rows, cols, vals = [], [], []
    for i, j, blk in ((np.arange(n), np.arange(n), mass[:, None, None] * np.eye(3)), (a, a, B), (b, b, B),
                      (a, b, -B), (b, a, -B)):
        rows.append((3 * i[:, None, None] + r).ravel())
        cols.append((3 * j[:, None, None] + c).ravel())
        vals.append(blk.ravel())
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * n, 3 * n))
    Sm = sp.block_diag(list(S), format="csr")
    return (Sm @ A @ Sm + sp.diags(np.repeat(mass, 3)) @ (sp.identity(3 * n) - Sm)).tocsr(), Sm


def test_a_rigid_motion_is_reproduced_exactly_by_the_prolongation_from_every_coarse_level():
    """v_i = t + theta x (x_i - p) (a small rotation about an arbitrary axis through an arbitrary point, and a
    translation) is P_1 ... P_l of the coarse vertices' (t + theta x (c - p), theta), on every level l, with the lever
    arms the cycle computed from the current positions (the Galerkin test of test_implicit_multigrid checks that the
    cycle's coarse operators are P^T A~ P with this P). A translation-only coarse space misses it by |theta| |x - c|."""
    sc = sewn_pair(0.02)
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


def test_a_garment_solve_preconditioned_by_the_cycle_equals_the_direct_solve():
    """The aggregation-preconditioned CG solution of a Newton system of the sewn pair lying partly on the ball (pins,
    contacts held and sliding) equals scipy's direct solve of A~ x = S b, A~ built from the BlockSystem's blocks, to
    1e-8 of its largest component (CG to a relative 1e-12, float64)."""
    sc = sewn_pair(0.02, cg_tolerance=1e-12, cg_max_iterations=2000)
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
    # the cycle as the CPU runs it (one thread, its levels a loop in one kernel) and as a GPU would (a kernel per
    # level, parallel loops) is the same operator: every vertex's sums run in the same order in both
    integ.pcg.r.from_numpy(np.random.default_rng(5).standard_normal(integ.pcg.r.shape + (3,)))
    mg.apply(integ.pcg.r, integ.pcg.z)
    serial = integ.pcg.z.to_numpy()[:n]
    assert mg.serial and np.abs(serial).max() > 0
    mg.serial = False
    try:
        mg.apply(integ.pcg.r, integ.pcg.z)
    finally:
        mg.serial = True
    np.testing.assert_allclose(integ.pcg.z.to_numpy()[:n], serial, rtol=0, atol=1e-12 * np.abs(serial).max())


#: CG iterations per Newton iteration the aggregation cycle may add from 2 cm to 1 cm spacing
MARGIN = 6


def test_the_cg_count_stays_bounded_as_the_spacing_halves():
    """CG iterations per Newton iteration of the sewn pair falling onto the ball over 12 steps (cg_tolerance 1e-3,
    float32 as the demos run) at 2, 1.4 and 1 cm spacing: the finest takes at most MARGIN more than the coarsest,
    where Jacobi's count grows by more (figures: docs/performance.md, preconditioners)."""
    its = {}
    runs = [("multigrid", 0.02), ("multigrid", 0.014), ("multigrid", 0.01), ("jacobi", 0.02), ("jacobi", 0.01)]
    for preconditioner, spacing in runs:  # (each scene compiles its kernels: Jacobi's 1.4 cm would say nothing new)
        sc = sewn_pair(spacing, preconditioner, precision="f32", cg_tolerance=1e-3)
        sc.step(12)
        stats = sc.integrator.stats
        its[preconditioner, spacing] = stats["cg_iterations"] / stats["newton_iterations"]
    assert max(its["multigrid", 0.014], its["multigrid", 0.01]) <= its["multigrid", 0.02] + MARGIN, its
    assert its["jacobi", 0.01] > its["jacobi", 0.02] + MARGIN, its  # it tells a preconditioner that does not scale
