"""The implicit integrator's multigrid preconditioners (taichi_cloth.linear.level_cycle, .aggregation): a
multigrid-preconditioned CG solve equals a direct sparse solve of the same filtered Newton system of backward Euler
(scipy, float64), with pins and with contacts; it equals the Jacobi-preconditioned step; a V-cycle is the
symmetric operator CG needs; the scene picks the preconditioner the cloth allows and says which."""
import dataclasses

import numpy as np
import pytest
import taichi as ti

import taichi_cloth as tc
from conftest import current_level, damping_matrix, sliding_normals, spring_forces
from taichi_cloth.linear import ConstraintFilter
from taichi_cloth.linear.aggregation import AggregationMultigrid
from taichi_cloth.linear.level_cycle import copies
from taichi_cloth.linear.policy import AGGREGATION_FROM
from taichi_cloth.multilevel_cloth import multilevel_grid
from taichi_cloth.stability import stiffness_matrix

H, GAMMA = 1 / 60, 0.3
EDGE = {"box": ((-0.26, 0.59, -0.26), (0.26, 0.61, -0.24))}  # the back edge of the sheet below
BALL = {"type": "sphere", "center": [0.0, 0.3, 0.05], "radius": 0.25, "friction": 0.8}


def sheet_on_a_ball(preconditioner: str, tolerance: float = 1e-12, levels: int = 5, steps: int = 12, **options):
    """A 0.5 m cotton sheet (4-8 levels from a 2 x 2 base), held by its back edge, dropped onto a ball: after 12
    steps part of it lies on the ball (contacts, sliding) and part hangs free; after 42 in one Newton iteration a
    step, some contacts stick (4 of 17, the others slide; 41-43 steps: 4-10 stick, 13-7 slide)."""
    cloth = multilevel_grid((0.5, 0.5), (2, 2), levels, "cotton", center=(0, 0.6, 0), plane="xz",
                            start_level=levels - 1)
    sc = tc.Scene(cloth, dt=H, air_damping=GAMMA, precision="f64", pins=[EDGE], colliders=[BALL],
                  multilevel={"refine": False},
                  integrator_options={"preconditioner": preconditioner, "cg_tolerance": tolerance,
                                      "cg_max_iterations": 2000, **options})
    sc.step(steps)
    return sc


def filtered_solve(sc) -> np.ndarray:
    """dv of the first Newton iteration of a backward-Euler step of `sc` now (the Baraff-Witkin system), by scipy:
    the free directions Q (pins and contacts held by static friction: none, other contacts: the two tangents, a
    contact the step releases: all three),
    dv = Q (Q^T A Q)^-1 Q^T b, with A and b built from the formulas, not from the engine's kernels (but for the
    sliding contacts' friction dashpots h c_i, read from the engine: test_friction checks what they do); then a released
    contact that dv moves into the body is held (its new normal velocity removed: the step's active set). The step's
    friction, which changes velocities before the solve, is applied first (by the engine) and switched off for the
    step itself (solve_after_friction)."""
    sc.integrator._contact_friction(sc.dt)
    d = sc.model.data
    x, v = sc.positions(), sc.velocities()
    f, _ = spring_forces(d, x, v)
    f += d.mass[:, None] * np.array([0.0, -9.81, 0.0]) - GAMMA * d.mass[:, None] * v
    K = stiffness_matrix(x, d.springs, d.stiffness, d.rest_length)
    D = damping_matrix(d, x)
    drag = sc.integrator.system.extra_mass.to_numpy()[: d.n_particles].astype(np.float64)
    A = np.diag(np.repeat(d.mass, 3) * (1 + H * GAMMA) + np.repeat(drag, 3)) + H * D + H * H * K
    surface = sc.contacts.velocity.to_numpy()[: d.n_particles].astype(np.float64)
    rhs = H * f.reshape(-1) - H * H * K @ v.reshape(-1) - (drag[:, None] * (v - surface)).reshape(-1)
    normals = sliding_normals(sc.contacts, d.n_particles)
    stuck = sc.contacts.stuck.to_numpy()[: d.n_particles] != 0
    columns = []
    for i in range(d.n_particles):
        if sc.model.pinned[i] or stuck[i]:
            continue
        n = normals[i]
        if n @ n > 0:
            t1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
            t1 /= np.linalg.norm(t1)
            basis = [t1, np.cross(n, t1)]
        else:
            basis = np.eye(3)
        for e in basis:
            col = np.zeros(3 * d.n_particles)
            col[3 * i: 3 * i + 3] = e
            columns.append(col)
    Q = np.array(columns).T
    y = np.linalg.solve(Q.T @ A @ Q, Q.T @ rhs)
    dv = (Q @ y).reshape(-1, 3)
    contact = sc.contacts.normal.to_numpy()[: d.n_particles].astype(np.float64)
    for i in np.flatnonzero(sc.contacts.released.to_numpy()[: d.n_particles] != 0):
        n = contact[i] / np.linalg.norm(contact[i])
        dv[i] -= min((v[i] + dv[i]) @ n, 0.0) * n
    return dv


def solve_after_friction(sc) -> None:
    """One step of the integrator alone (the collider would change v afterwards), its friction already applied by
    filtered_solve."""
    sc.integrator._contact_friction = lambda dt: None
    try:
        sc.integrator.step(sc.state, sc.contacts, sc.dt)
    finally:
        del sc.integrator._contact_friction


@pytest.mark.parametrize("preconditioner", ["multigrid", "jacobi"])
def test_a_step_equals_the_direct_solve_of_the_filtered_system(preconditioner):
    sc = sheet_on_a_ball(preconditioner, steps=42, newton_iterations=1, line_search=False)
    assert sc.model.pinned.sum() > 0
    touching = np.linalg.norm(sc.contacts.normal.to_numpy()[: sc.model.data.n_particles], axis=1) > 0
    assert 4 < touching.sum() < sc.model.data.n_particles - 10  # some particles on the ball, most free
    expected = filtered_solve(sc)
    stuck = sc.contacts.stuck.to_numpy()[: sc.model.data.n_particles] != 0
    assert stuck.sum() >= 1 and (touching & ~stuck).sum() >= 4  # held by static friction, and sliding
    assert (sc.integrator.system.extra_mass.to_numpy()[: sc.model.data.n_particles] > 0).sum() >= 4  # friction
    v = sc.velocities()
    solve_after_friction(sc)
    np.testing.assert_allclose(sc.velocities() - v, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    assert (sc.integrator.policy.current is not sc.integrator.policy.jacobi) == (preconditioner == "multigrid")


def test_multigrid_and_jacobi_give_the_same_step_and_multigrid_needs_far_fewer_iterations():
    steps = {}
    for preconditioner in ("multigrid", "jacobi"):
        sc = sheet_on_a_ball(preconditioner, tolerance=1e-10)
        it0 = sc.integrator.stats["cg_iterations"]
        sc.step(3)
        steps[preconditioner] = (sc.positions(), (sc.integrator.stats["cg_iterations"] - it0) / 3)
    (xm, itm), (xj, itj) = steps["multigrid"], steps["jacobi"]
    # to a few float32 ulps: the ball pushes out in float32 (0.19 m has an ulp of 1.5e-8 m)
    np.testing.assert_allclose(xm, xj, rtol=0, atol=1e-7)
    assert itm < 0.6 * itj, (itm, itj)  # 48 against 87 over the 3 steps (block Jacobi on the filtered system)


def test_a_v_cycle_is_symmetric_and_positive_on_the_free_rows():
    """CG needs a symmetric positive definite preconditioner: z = V(r) is linear, <V r1, r2> = <r1, V r2>, and
    <V r, r> > 0 on the free rows (the pinned ones, and the ones static friction holds, come out 0; a sliding
    contact's row has no component along its normal)."""
    sc = sheet_on_a_ball("multigrid", steps=42, newton_iterations=1, line_search=False)
    mg = sc.integrator.policy.current
    system = sc.integrator.system
    system.set_step(H, GAMMA)
    mg.prepare(system, ConstraintFilter(sc.model))
    free = ~sc.model.pinned
    z1 = assert_symmetric_positive(mg, np.random.default_rng(5), free)
    assert np.abs(z1[~free]).max() == 0
    # with the contacts: particles held by static friction are held by the cycle as pins are (what the filtered
    # system does), and a sliding contact's normal is left out: the cycle's output has no component along it
    stuck = sc.contacts.stuck.to_numpy()[: sc.model.data.n_particles] != 0
    assert stuck.sum() >= 1
    n = sliding_normals(sc.contacts, sc.model.data.n_particles)
    sliding = free & ~stuck & (np.linalg.norm(n, axis=1) > 0)
    assert sliding.sum() >= 4
    mg.prepare(system, sc.integrator.filter)
    z1 = assert_symmetric_positive(mg, np.random.default_rng(6), free & ~stuck)
    assert np.abs(z1[~free | stuck]).max() == 0
    along = np.einsum("ij,ij->i", z1[sliding], n[sliding]) / np.linalg.norm(n[sliding], axis=1)
    assert np.abs(along).max() <= 1e-12 * np.abs(z1).max() and np.abs(z1[sliding]).max() > 0


def assert_symmetric_positive(mg, rng, rows) -> np.ndarray:
    """Checks that the cycle z = V(r) of `mg` is linear, symmetric (<V r1, r2> = <r1, V r2>) and positive on the
    rows (particles) selected by the boolean mask `rows`, for two random r (other rows 0); returns V(r1)."""
    n = len(rows)
    src, out = ti.Vector.field(3, ti.f64, n), ti.Vector.field(3, ti.f64, n)

    def V(r):
        src.from_numpy(r)
        mg.apply(src, out)
        return out.to_numpy()

    r1, r2 = (rng.standard_normal((n, 3)) * rows[:, None] for _ in range(2))
    z1, z2 = V(r1), V(r2)
    assert abs((z1 * r2).sum() - (r1 * z2).sum()) <= 1e-10 * abs((z1 * r2).sum())
    np.testing.assert_allclose(V(2 * r1 - 3 * r2), 2 * z1 - 3 * z2, rtol=0, atol=1e-10 * np.abs(z1).max())
    assert (z1 * r1).sum() > 0 and (z2 * r2).sum() > 0
    return z1


def without_last_particle(cloth):
    """ClothData `cloth` less its last particle, with the springs and triangles that use it (no grid shape)."""
    last = cloth.n_particles - 1
    keep = np.all(cloth.springs != last, axis=1)
    return dataclasses.replace(cloth, positions=cloth.positions[:last], mass=cloth.mass[:last],
                               springs=cloth.springs[keep], rest_length=cloth.rest_length[keep],
                               stiffness=cloth.stiffness[keep], damping=cloth.damping[keep], kind=cloth.kind[keep],
                               triangles=cloth.triangles[np.all(cloth.triangles != last, axis=1)], grid_shape=None)


def test_the_scene_picks_the_preconditioner_the_cloth_allows_and_says_which():
    ml = tc.Scene(multilevel_grid((0.5, 0.5), (2, 2), 3, "cotton", center=(0, 1, 0)), dt=H,
                  multilevel={"refine": False})
    assert ml.integrator.policy.current is ml.integrator.policy.levels
    assert "V-cycles over 3 4-8 levels" in ml.run(0, progress=False).format()
    grid = tc.Scene(tc.ClothBuilder.grid((0.5, 0.5), (6, 6)), dt=H)
    assert grid.integrator.policy.current is grid.integrator.policy.jacobi
    assert "Jacobi-preconditioned CG" in grid.run(0, progress=False).format()
    # `auto` aggregates a cloth off 4-8 levels from AGGREGATION_FROM = 2,000 particles on: a 40 x 50 grid has
    # exactly 2,000, and the same grid less its last particle (and that particle's springs and triangles) 1,999
    assert AGGREGATION_FROM == 2000
    sheet = tc.ClothBuilder.grid((1.0, 1.0), (40, 50))
    assert sheet.n_particles == 2000
    big = tc.Scene(sheet, dt=H)
    assert isinstance(big.integrator.policy.current, AggregationMultigrid)
    assert big.integrator.detail.startswith("CG preconditioned by V-cycles over ")
    assert "aggregation levels (2000 > " in big.integrator.detail
    below = tc.Scene(without_last_particle(sheet), dt=H)
    assert below.model.data.n_particles == 1999
    assert below.integrator.policy.current is below.integrator.policy.jacobi
    assert below.integrator.policy.apart is None  # the aggregation cycle not even built
    assert "Jacobi-preconditioned CG" in below.run(0, progress=False).format()
    asked = tc.Scene(tc.ClothBuilder.grid((0.5, 0.5), (6, 6)), dt=H, integrator_options={"preconditioner": "multigrid"})
    assert isinstance(asked.integrator.policy.current, AggregationMultigrid)
    assert "V-cycles over 2 aggregation levels (36 > 8)" in asked.run(0, progress=False).format()
    # 300 loose threads of one spring each: aggregated into 300 single vertices that do not coarsen further
    x = np.stack([np.repeat(np.arange(300) * 0.02, 2), np.zeros(600), np.tile([0.0, 0.01], 300)], 1)
    pairs = np.arange(600).reshape(300, 2)
    threads = tc.ClothData(x, np.full(600, 1e-3), pairs, np.full(300, 0.01), np.full(300, 50.0), np.zeros(300),
                           np.full(300, int(tc.SpringKind.STRUCTURAL)))
    with pytest.warns(UserWarning, match="aggregation failed: aggregation stopped at 300 vertices"):
        loose = tc.Scene(threads, dt=H, integrator_options={"preconditioner": "multigrid"})
    assert loose.integrator.policy.current is loose.integrator.policy.jacobi
    assert any("uses Jacobi instead" in w for w in loose.warnings)
    with pytest.raises(tc.SceneError, match="preconditioner"):
        tc.load_scene({"cloth": {"grid": {"size": [0.5, 0.5], "resolution": [4, 4]}},
                       "integrator": {"name": "implicit", "dt": 0.01, "preconditioner": "ilu"}})


def test_the_preconditioner_follows_level_switches_without_compiling():
    cloth = multilevel_grid((0.5, 0.5), (2, 2), 4, "cotton", center=(0, 0.6, 0), plane="xz")
    sc = tc.Scene(cloth, dt=H, pins=[EDGE], multilevel={"refine": False})
    sc.step(2)
    sc.apply(sc.controller("refiner").refine())
    sc.step(2)
    with tc.CompileCounter() as cc:
        for _ in range(2):
            sc.apply(sc.controller("refiner").refine())
            sc.step(3)
    assert cc.total == 0, cc.compiled
    assert current_level(sc) == 3 and sc.integrator.policy.current.active == 3
    assert sc.check().max_strain < 0.05


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


@pytest.mark.parametrize("preconditioner", ["multigrid", "jacobi"])
def test_a_step_of_a_sewn_garment_equals_the_direct_solve(preconditioner):
    sc = sewn_pair(0.02, preconditioner, cg_tolerance=1e-12, cg_max_iterations=2000, newton_iterations=1,
                   line_search=False)
    sc.step(12)
    n = sc.model.data.n_particles
    assert n == 2 * 11 * 11 - 11 and sc.model.pinned.sum() == 21
    touching = np.linalg.norm(sc.contacts.normal.to_numpy()[:n], axis=1) > 0
    assert 4 < touching.sum() < n - 10, touching.sum()
    mg = sc.integrator.policy.current
    if preconditioner == "multigrid":
        assert isinstance(mg, AggregationMultigrid) and len(mg.sizes) >= 2, sc.integrator.detail
    else:
        assert mg is sc.integrator.policy.jacobi
    expected = filtered_solve(sc)
    v = sc.velocities()
    solve_after_friction(sc)
    np.testing.assert_allclose(sc.velocities() - v, expected, rtol=0, atol=1e-9 * np.abs(expected).max())


def cross_matrix(d) -> np.ndarray:
    """-[d]_x: -[d]_x theta = theta x d."""
    return np.array([[0.0, d[2], -d[1]], [-d[2], 0.0, d[0]], [d[1], -d[0], 0.0]])


def dense_level(mg, level) -> np.ndarray:
    """The aggregation cycle's operator on `level` as a dense matrix (3 unknowns per vertex on level 0, 6 above)."""
    vb, eb = mg.vbound.to_numpy(), mg.ebound.to_numpy()
    lo, hi = vb[level:level + 2]
    elo, ehi = eb[level:level + 2]
    if level == 0:
        k, diag, off, v0, e0 = 3, mg.diag.to_numpy(), mg.off.to_numpy(), 0, 0
    else:
        k, diag, off, v0, e0 = 6, mg.diag6.to_numpy(), mg.off6.to_numpy(), vb[1], eb[1]
    A = np.zeros((k * (hi - lo), k * (hi - lo)))
    ea, eb_ = mg.end_a.to_numpy() - lo, mg.end_b.to_numpy() - lo
    for g in range(hi - lo):
        A[k * g:k * g + k, k * g:k * g + k] = diag[lo + g - v0]
    for q in range(elo, ehi):
        a, b = ea[q], eb_[q]
        A[k * a:k * a + k, k * b:k * b + k] += off[q - e0]
        A[k * b:k * b + k, k * a:k * a + k] += off[q - e0].T
    return A


def prolongation(mg, level, S=None) -> np.ndarray:
    """The dense prolongation from `level` to `level - 1`, built here from the aggregates and the lever arms the
    cycle keeps (x_i - c on level 0, c_G - c_K above); S: level 0's filter (3n x 3n), applied to its rows."""
    vb = mg.vbound.to_numpy()
    agg, arm = mg.agg.to_numpy(), mg.arm.to_numpy()
    kf = 3 if level == 1 else 6
    nf, nc = mg.sizes[level - 1], mg.sizes[level]
    P = np.zeros((kf * nf, 6 * nc))
    for i in range(nf):
        c = agg[vb[level - 1] + i] - vb[level]
        W = cross_matrix(arm[vb[level - 1] + i])
        if level == 1:
            P[3 * i:3 * i + 3, 6 * c:6 * c + 6] = np.hstack([np.eye(3), W])
        else:
            P[6 * i:6 * i + 6, 6 * c:6 * c + 6] = np.block([[np.eye(3), W], [np.zeros((3, 3)), np.eye(3)]])
    return S @ P if S is not None and level == 1 else P


def test_aggregation_levels_follow_the_seam_merge_without_compiling():
    from taichi_cloth.garment.garment import build_garment
    from test_garment import two_squares

    g = build_garment(two_squares())
    sc = tc.Scene(g, dt=1 / 240, gravity=(0, 0, 0), sewing=dict(close_speed=0.5, epsilon=0.002),
                  integrator_options={"preconditioner": "multigrid"})
    sc.run(2, progress=False)
    mg = sc.integrator.policy.current
    assert mg.sizes[0] == g.data.n_particles
    with tc.CompileCounter() as cc:
        sc.run(58, progress=False)
    assert sc.controller("sewing").joined
    assert mg.sizes[0] == sc.model.data.n_particles == g.data.n_particles - len(g.seam_pairs)
    # the merge reloads the level tables: only Taichi's own numpy transfers compile (cc.taichi_own), no kernel of
    # the engine
    assert not cc.compiled, cc.compiled
    assert sc.integrator.last_residual <= 1e-3


def test_a_garment_on_its_4_8_levels_uses_them_once_merged_and_a_step_equals_the_direct_solve(monkeypatch):
    """One hierarchy, two uses: a garment sewn coarse to fine (taichi_cloth.garment.levels) is preconditioned by
    V-cycles over the same levels the refiner switches between, from the seam merge on (its pieces apart are on no
    level: aggregation levels before). Its levels are nested by their tables, not by index
    (taichi_cloth.linear.level_cycle.copies), and a step on level 2 of 3 equals the direct solve of the filtered system.
    The policy uses them only with GARMENT_LEVELS (off: the aggregation cycle serves a garment's levels, `auto` from
    AGGREGATION_FROM particles, Jacobi below)."""
    from taichi_cloth.garment.levels import multilevel_garment
    from taichi_cloth.linear import policy
    from test_multilevel_garment import SPHERE, two_squares

    monkeypatch.setattr(policy, "GARMENT_LEVELS", True)

    mg = multilevel_garment(two_squares(), start_level=0)
    sc = tc.Scene(mg, dt=H, air_damping=GAMMA, precision="f64", colliders=[SPHERE], multilevel={"refine": False},
                  integrator_options={"preconditioner": "multigrid", "cg_tolerance": 1e-12, "cg_max_iterations": 2000,
                                      "newton_iterations": 1, "line_search": False})
    integ, sewing = sc.integrator, sc.controller("sewing")
    levels, apart = integ.policy.levels, integ.policy.current
    assert isinstance(apart, AggregationMultigrid) and levels.n_levels == 3  # the pieces apart (242 particles)
    assert any(not np.array_equal(c, np.arange(len(c))) for c in copies(mg.cloth.hierarchy.levels))
    frames = 0
    while not sewing.joined and frames < 60:
        sc.run(1, progress=False)
        frames += 1
    assert sewing.joined and integ.policy.current is levels and levels.active == 0
    assert "V-cycles over 3 4-8 levels once on them (before: aggregation levels)" in integ.detail
    sc.apply(sc.controller("refiner").refine())
    assert levels.active == 1 and sc.model.data.n_particles == mg.levels[1].merged.n_particles
    sc.run(12, progress=False)  # on the sphere (contacts), the seams merged
    n = sc.model.data.n_particles
    touching = np.linalg.norm(sc.contacts.normal.to_numpy()[:n], axis=1) > 0
    assert 4 < touching.sum() < n - 10, touching.sum()
    expected = filtered_solve(sc)
    v = sc.velocities()
    solve_after_friction(sc)
    np.testing.assert_allclose(sc.velocities() - v, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    integ.system.set_step(H, GAMMA)
    levels.prepare(integ.system, ConstraintFilter(sc.model))
    assert_symmetric_positive(levels, np.random.default_rng(11), np.ones(n, bool))
    # level 1's springs point where their ends' copies on level 2 (simulated) are
    copy = copies(mg.cloth.hierarchy.levels)[0]
    n0, s0 = levels.sizes[0], levels.spring_counts[0]
    assert np.array_equal(levels.at.to_numpy()[:n0], copy)
    ends = mg.cloth.levels[0].springs
    d = sc.positions()[copy[ends[:, 1]]] - sc.positions()[copy[ends[:, 0]]]
    np.testing.assert_allclose(levels.u.to_numpy()[:s0], d / np.linalg.norm(d, axis=1, keepdims=True), atol=1e-12)
    sc.reset()  # the pieces apart again: off the levels
    assert integ.policy.current is apart and sc.model.data.n_particles == mg.garment.data.n_particles
    monkeypatch.setattr(policy, "GARMENT_LEVELS", False)
    small = tc.Scene(mg, dt=H, colliders=[SPHERE])
    assert small.integrator.policy.levels is None
    assert small.integrator.policy.current is small.integrator.policy.jacobi  # 242 particles: below AGGREGATION_FROM
    named = tc.Scene(mg, dt=H, colliders=[SPHERE], integrator_options={"preconditioner": "multigrid"})
    assert named.integrator.policy.levels is None
    assert isinstance(named.integrator.policy.current, AggregationMultigrid)
