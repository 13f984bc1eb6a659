"""The implicit integrator's multigrid preconditioner (multilevel.spring_multigrid): a multigrid-preconditioned CG
solve equals a direct sparse solve of the same filtered Newton system of backward Euler (scipy, float64), with pins
and with contacts; it equals the Jacobi-preconditioned step; a V-cycle is the symmetric operator CG needs; the scene
picks the preconditioner the cloth allows and says which."""
import numpy as np
import pytest
import taichi as ti

import taichi_cloth as tc
from conftest import current_level, spring_forces
from taichi_cloth.multilevel_cloth import multilevel_grid
from taichi_cloth.stability import stiffness_matrix

H, GAMMA = 1 / 60, 0.3
EDGE = {"box": ((-0.26, 0.59, -0.26), (0.26, 0.61, -0.24))}  # the back edge of the sheet below
BALL = {"type": "sphere", "center": [0.0, 0.3, 0.05], "radius": 0.25}


def sheet_on_a_ball(preconditioner: str, tolerance: float = 1e-12, levels: int = 5, **options):
    """A 0.5 m cotton sheet (4-8 levels from a 2 x 2 base), held by its back edge, dropped onto a ball: after 12
    steps part of it lies on the ball (contacts) and part hangs free."""
    cloth = multilevel_grid((0.5, 0.5), (2, 2), levels, "cotton", center=(0, 0.6, 0), plane="xz",
                            start_level=levels - 1)
    sc = tc.Scene(cloth, dt=H, air_damping=GAMMA, precision="f64", pins=[EDGE], colliders=[BALL],
                  multilevel={"refine": False},
                  integrator_options={"preconditioner": preconditioner, "cg_tolerance": tolerance,
                                      "cg_max_iterations": 2000, **options})
    sc.step(12)
    return sc


def filtered_solve(sc) -> np.ndarray:
    """dv of the first Newton iteration of a backward-Euler step of `sc` now (the Baraff-Witkin system), by scipy:
    the free directions Q (pins: none, contacts: the two tangents), dv = Q (Q^T A Q)^-1 Q^T b, with A and b built
    from the formulas, not from the engine's kernels."""
    d = sc.model.data
    x, v = sc.positions(), sc.velocities()
    f, _ = spring_forces(d, x, v)
    length = np.linalg.norm(x[d.springs[:, 1]] - x[d.springs[:, 0]], axis=1)
    f += d.mass[:, None] * np.array([0.0, -9.81, 0.0]) - GAMMA * d.mass[:, None] * v
    K = stiffness_matrix(x, d.springs, d.stiffness, d.rest_length)
    D = stiffness_matrix(x, d.springs, d.damping, length)  # rest = current length: only the kd u u^T term
    A = np.diag(np.repeat(d.mass, 3) * (1 + H * GAMMA)) + H * D + H * H * K
    rhs = H * f.reshape(-1) - H * H * K @ v.reshape(-1)
    normals = sc.state.contacts.normal.to_numpy()[: d.n_particles]
    columns = []
    for i in range(d.n_particles):
        if sc.model.pinned[i]:
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
    return (Q @ y).reshape(-1, 3)


@pytest.mark.parametrize("preconditioner", ["multigrid", "jacobi"])
def test_a_step_equals_the_direct_solve_of_the_filtered_system(preconditioner):
    sc = sheet_on_a_ball(preconditioner, newton_iterations=1, line_search=False)
    assert sc.model.pinned.sum() > 0
    touching = np.linalg.norm(sc.state.contacts.normal.to_numpy()[: sc.model.data.n_particles], axis=1) > 0
    assert 4 < touching.sum() < sc.model.data.n_particles - 10  # some particles on the ball, most free
    expected = filtered_solve(sc)
    v = sc.velocities()
    sc.integrator.step(sc.dt)  # the integrator alone: the collider would change v afterwards
    np.testing.assert_allclose(sc.velocities() - v, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    assert (sc.integrator.multigrid is not None) == (preconditioner == "multigrid")


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
    assert itm < 0.4 * itj, (itm, itj)  # 71 against 242 per Newton iteration (Jacobi warm-started)


def test_a_v_cycle_is_symmetric_and_positive_on_the_free_rows():
    """CG needs a symmetric positive definite preconditioner: z = V(r) is linear, <V r1, r2> = <r1, V r2>, and
    <V r, r> > 0 on the free rows (the pinned ones come out 0)."""
    sc = sheet_on_a_ball("multigrid")
    mg = sc.integrator.multigrid
    mg.prepare(sc.state.x, sc.model.inv_mass, H, GAMMA)
    n = sc.model.data.n_particles
    free = ~sc.model.pinned
    rng = np.random.default_rng(5)
    src, out = ti.Vector.field(3, ti.f64, n), ti.Vector.field(3, ti.f64, n)

    def V(r):
        src.from_numpy(r)
        mg.apply(src, out)
        return out.to_numpy()

    r1, r2 = (rng.standard_normal((n, 3)) * free[:, None] for _ in range(2))
    z1, z2 = V(r1), V(r2)
    assert np.abs(z1[~free]).max() == 0
    assert abs((z1 * r2).sum() - (r1 * z2).sum()) <= 1e-10 * abs((z1 * r2).sum())
    np.testing.assert_allclose(V(2 * r1 - 3 * r2), 2 * z1 - 3 * z2, rtol=0, atol=1e-10 * np.abs(z1).max())
    assert (z1 * r1).sum() > 0 and (z2 * r2).sum() > 0


def test_the_scene_picks_the_preconditioner_the_cloth_allows_and_says_which():
    ml = tc.Scene(multilevel_grid((0.5, 0.5), (2, 2), 3, "cotton", center=(0, 1, 0)), dt=H,
                  multilevel={"refine": False})
    assert ml.integrator.multigrid is not None and "V-cycles over 3 4-8 levels" in ml.run(1, progress=False).format()
    grid = tc.Scene(tc.ClothBuilder.grid((0.5, 0.5), (6, 6)), dt=H)
    assert grid.integrator.multigrid is None and "Jacobi-preconditioned CG" in grid.run(1, progress=False).format()
    with pytest.warns(UserWarning, match="multigrid preconditioner needs a multilevel cloth"):
        asked = tc.Scene(tc.ClothBuilder.grid((0.5, 0.5), (6, 6)), dt=H,
                         integrator_options={"preconditioner": "multigrid"})
    assert asked.integrator.multigrid is None and any("uses Jacobi instead" in w for w in asked.warnings)
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
    assert current_level(sc) == 3 and sc.integrator.multigrid.active == 3
    assert sc.check().max_strain < 0.05
