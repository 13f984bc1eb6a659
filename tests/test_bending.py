"""The quadratic bending model (taichi_cloth.bending): zero at rest and under rigid motion, the continuum energy on an
isometric bend, a force of first order in the bend, and its pairs rebuilt across a merged seam."""
import numpy as np
import pytest

from taichi_cloth.bending import bending_energy, quadratic_bending
from taichi_cloth.cloth import SpringKind, mesh_cloth
from taichi_cloth.material import Material

B = 2.0e-5  # [N m]


def equilateral_lattice(n: int, a: float):
    """(positions (P,2) [m], triangles) of an n x n rhombus of equilateral triangles of side a [m]."""
    P = np.array([[a * (i + 0.5 * j), a * j * np.sqrt(3) / 2] for j in range(n + 1) for i in range(n + 1)])
    idx = lambda i, j: j * (n + 1) + i  # noqa: E731
    T = [t for j in range(n) for i in range(n)
         for t in ([idx(i, j), idx(i + 1, j), idx(i, j + 1)], [idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)])]
    return P, np.array(T)


def right_grid(n: int, a: float):
    """(positions, triangles) of an n x n square grid of spacing a [m], the squares cut along alternating diagonals
    (the 4-8 pattern of the 4-8 levels and of the pattern mesher's interior)."""
    P = np.array([[a * i, a * j] for i in range(n + 1) for j in range(n + 1)])
    idx = lambda i, j: i * (n + 1) + j  # noqa: E731
    T = []
    for i in range(n):
        for j in range(n):
            c00, c10, c11, c01 = idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)
            T += [[c00, c10, c11], [c00, c11, c01]] if (i + j) % 2 == 0 else [[c00, c10, c01], [c10, c11, c01]]
    return P, np.array(T)


def area(P, T):
    a, b = P[T[:, 1]] - P[T[:, 0]], P[T[:, 2]] - P[T[:, 0]]
    return float(0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum())


def rolled(P, radius: float, degrees: float):
    """The flat points P (n,2) [m] rolled isometrically onto a cylinder of `radius` [m] whose axis makes `degrees`
    with the second coordinate axis."""
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    q = P - P.mean(axis=0)
    u, v = c * q[:, 0] + s * q[:, 1], -s * q[:, 0] + c * q[:, 1]
    return np.stack([radius * np.sin(u / radius), v, radius * (1.0 - np.cos(u / radius))], axis=1)


def test_the_energy_is_zero_flat_and_under_a_rigid_motion():
    P, T = equilateral_lattice(8, 0.02)
    pairs, k = quadratic_bending(T, P[T], B)
    assert np.all(pairs[:, 0] < pairs[:, 1]) and len(np.unique(pairs, axis=0)) == len(pairs)
    assert (k < 0).any() and (k > 0).any()  # the pair constants have both signs
    x = np.c_[P, np.zeros(len(P))]
    theta = 0.7
    R = np.array([[np.cos(theta), 0, np.sin(theta)], [0, 1, 0], [-np.sin(theta), 0, np.cos(theta)]])
    scale = B * 0.5 / 0.1**2 * area(P, T)  # the energy of a 10 cm radius bend, for scale
    assert abs(bending_energy(x, pairs, k)) < 1e-12 * scale
    assert abs(bending_energy(x @ R.T + [0.3, -1.0, 2.0], pairs, k)) < 1e-12 * scale


@pytest.mark.parametrize("degrees", [0.0, 30.0, 45.0, 90.0])
def test_a_cylindrical_bend_holds_the_continuum_energy_on_equilateral_triangles(degrees):
    """B / 2 kappa^2 x area, in every direction; the lattice's boundary edges (no hinge) lose under 2 %."""
    P, T = equilateral_lattice(60, 0.005)
    pairs, k = quadratic_bending(T, P[T], B)
    radius = 0.2
    ratio = bending_energy(rolled(P, radius, degrees), pairs, k) / (0.5 * B / radius**2 * area(P, T))
    assert 0.98 < ratio < 1.0, ratio


def test_on_a_right_triangle_grid_the_bend_is_exact_along_the_axes_and_stiffer_along_the_diagonals():
    """The hinge energy's anisotropy on the pattern mesher's grids, as the module documents it."""
    P, T = right_grid(60, 0.005)
    pairs, k = quadratic_bending(T, P[T], B)
    radius = 0.2
    ratio = {d: bending_energy(rolled(P, radius, d), pairs, k) / (0.5 * B / radius**2 * area(P, T))
             for d in (0.0, 90.0, 45.0, -45.0)}
    assert 0.98 < ratio[0.0] < 1.0 and 0.98 < ratio[90.0] < 1.0, ratio
    assert 1.40 < min(ratio[45.0], ratio[-45.0]) and max(ratio[45.0], ratio[-45.0]) < 1.55, ratio


def hinge_force(bending: str, theta: float) -> float:
    """The force [N] the bending springs put on one apex of two equilateral triangles (side 2 cm) folded by theta
    [rad] about their shared edge, along the fold's normal."""
    a = 0.02
    h = a * np.sqrt(3) / 2
    flat = np.array([[0, 0, 0], [a, 0, 0], [a / 2, h, 0], [a / 2, -h, 0]], float)
    tris = np.array([[0, 1, 2], [1, 0, 3]])
    cloth = mesh_cloth(flat, tris, Material(density=0.1, stretch=1000.0, shear=0.0, bend=B, bending=bending))
    x = flat.copy()
    x[3] = [a / 2, -h * np.cos(theta), h * np.sin(theta)]
    bend = np.isin(cloth.kind, [SpringKind.BEND, SpringKind.QUADRATIC_BEND])
    force = np.zeros(3)
    for (i, j), k, L0 in zip(cloth.springs[bend], cloth.stiffness[bend], cloth.rest_length[bend]):
        if 3 in (i, j):
            d = x[i if j == 3 else j] - x[3]
            force += k * (np.linalg.norm(d) - L0) * d / np.linalg.norm(d)
    return float(force @ np.array([0.0, -np.sin(theta), -np.cos(theta)]))  # back toward flat


def test_the_quadratic_bend_resists_to_first_order_and_the_bend_spring_to_third():
    """Folding by 1/10 the angle takes 1/10 the restoring force with the quadratic energy, 1/1000 with a bend spring
    (its tension grows as theta^2, and it pulls almost in the sheet's plane, theta of it against the fold): why a
    calibrated bend spring had to be 10^2-10^3 x the measured rigidity."""
    small, large = 0.01, 0.1
    q = hinge_force("quadratic", large) / hinge_force("quadratic", small)
    s = hinge_force("springs", large) / hinge_force("springs", small)
    assert q == pytest.approx(10.0, rel=1e-2) and s == pytest.approx(1000.0, rel=2e-2)
    assert hinge_force("quadratic", small) > 0 and hinge_force("springs", small) > 0


def test_a_merged_seam_is_bent_across_and_flat_at_rest():
    """Two squares sewn edge to edge and merged, with quadratic bending: the merged sheet laid flat holds no
    bending energy, and folded 90 degrees along the seam it holds B x sum over the seam's hinges of |e|^2 / (A0 + A1)
    (K x = 2 sin 45 degrees x |e| at each)."""
    from taichi_cloth.garment.garment import FreePlacement, GarmentSpec, build_garment
    from taichi_cloth.garment.seams import Seam, SeamSide
    from taichi_cloth.garment.sewing import merge_seams
    from test_garment import square

    mat = Material(density=0.1, stretch=1000.0, shear=10.0, bend=B, damping=2e-5, bending="quadratic")
    seam = Seam("middle", SeamSide("A", "br", "tr"), SeamSide("B", "bl", "tl"))
    flat = {"v_axis": (0.0, 0.0, 1.0)}
    g = build_garment(GarmentSpec("sewn pair", [square("A"), square("B")], [seam],
                                  {"A": FreePlacement((-0.2, 0.6, -0.1), **flat),
                                   "B": FreePlacement((0.0, 0.6, -0.1), **flat)}, spacing=0.02, material=mat))
    x = g.data.positions
    data, mx, _, _ = merge_seams(g.data, g, x, np.zeros_like(x))
    q = data.kind == SpringKind.QUADRATIC_BEND
    assert q.sum() > 0 and np.all(data.rest_length[q] == 0.0)
    pairs, k = data.springs[q], data.stiffness[q]
    scale = B * 0.5 / 0.1**2 * 0.08
    assert abs(bending_energy(mx, pairs, k)) < 1e-10 * scale
    # fold piece B's side (x > seam) up by 90 degrees about the seam line x = 0, y = 0.6
    seam_x = 0.0
    folded = mx.copy()
    right = mx[:, 0] > seam_x + 1e-9
    folded[right, 1] = 0.6 + (mx[right, 0] - seam_x)
    folded[right, 0] = seam_x
    on_seam = np.abs(mx[:, 0] - seam_x) < 1e-9
    seam_edges = [t for t in data.triangles if on_seam[t].sum() == 2]
    assert len(seam_edges) > 0
    expected = 0.0
    tris = data.triangles
    corners = mx[tris]
    areas = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    edge_area: dict = {}
    for t, A in zip(tris, areas):
        ends = tuple(sorted(int(p) for p in t if on_seam[p]))
        if len(ends) == 2:
            edge_area.setdefault(ends, []).append(A)
    for (i, j), As in edge_area.items():
        assert len(As) == 2
        expected += B * np.sum((mx[i] - mx[j]) ** 2) / (As[0] + As[1])
    assert bending_energy(folded, pairs, k) == pytest.approx(expected, rel=1e-9)


def test_the_engine_holds_a_small_cantilever_where_the_direct_solve_of_the_bending_energy_does():
    """A 10 x 4 cm strip meshed by the garment mesher, clamped on a 2 cm ledge, with quadratic bending (B = 1e-2
    N m: a tip sag near 1 mm, the linear regime): after a second of the implicit step its sag is that of the linear
    solve K z = -m g of the bending springs alone (the structural springs act at second order), within 1 %."""
    import taichi_cloth as tc
    from taichi_cloth.garment.mesh import mesh_piece
    from taichi_cloth.garment.pattern import PatternPiece

    spacing, length, width = 0.01, 0.10, 0.04
    piece = PatternPiece.from_polygon("strip", [[-2 * spacing, 0], [length, 0], [length, width], [-2 * spacing, width]])
    m = mesh_piece(piece, spacing)
    x0 = np.c_[m.uv[:, 0], np.full(len(m.uv), 1.0), m.uv[:, 1]]
    mat = Material(density=0.1, stretch=5000.0, shear=50.0, bend=1e-2, damping=2e-5, bending="quadratic")
    cloth = mesh_cloth(x0, m.triangles, mat, source="strip", stiffness_rule="isotropic")
    held = m.uv[:, 0] <= 1e-9
    q = cloth.kind == SpringKind.QUADRATIC_BEND
    n = cloth.n_particles
    K = np.zeros((n, n))
    for (a, b), k in zip(cloth.springs[q], cloth.stiffness[q]):
        K[a, a] += k
        K[b, b] += k
        K[a, b] -= k
        K[b, a] -= k
    free = ~held
    sag = np.zeros(n)
    sag[free] = np.linalg.solve(K[np.ix_(free, free)], -9.81 * cloth.mass[free])
    tip = m.uv[:, 0] >= length - 1e-9
    assert -2e-3 < sag[tip].mean() < -0.5e-3, sag[tip].mean()

    scene = tc.Scene(cloth, integrator="implicit", dt=1.0 / 120.0, air_damping=2.0,
                     integrator_options={"cg_tolerance": 1e-8}, pins=[{"indices": np.nonzero(held)[0].tolist()}],
                     precision="f64")
    scene.run(60, progress=False)
    engine = scene.positions()[:, 1] - 1.0
    assert engine[tip].mean() == pytest.approx(sag[tip].mean(), rel=1e-2)


def test_a_material_names_its_bending_model():
    with pytest.raises(ValueError, match="bending must be one of springs, quadratic"):
        Material(density=0.1, stretch=1.0, shear=1.0, bend=1.0, bending="shells")
    P, T = equilateral_lattice(3, 0.02)
    x = np.c_[P, np.zeros(len(P))]
    cloth = mesh_cloth(x, T, Material(density=0.1, stretch=100.0, shear=1.0, bend=B, damping=1e-3,
                                      viscosity=0.0, bending="quadratic"))
    q = cloth.kind == SpringKind.QUADRATIC_BEND
    # the bending pairs are damped isotropically (ratio x k, the energy's Hessian), never along their direction
    assert np.all(cloth.axial_damping()[q] == 0.0)
    assert np.allclose(cloth.viscous_damping()[q], 1e-3 * cloth.stiffness[q])
    assert np.array_equal(cloth.axial_damping()[~q], cloth.damping[~q])


def test_a_scene_file_names_the_bending_model_in_its_material_table():
    from taichi_cloth.errors import SceneError
    from taichi_cloth.scenefile import parse_scene
    from taichi_cloth.schema import material_of

    def scene(material):
        return {"cloth": {"grid": {"size": [0.2, 0.2], "resolution": [5, 5]}, "material": material},
                "integrator": {"name": "implicit", "dt": 0.01}}

    cfg = parse_scene(scene({"preset": "silk", "bending": "quadratic", "bend": 2.94e-6}))
    mat = material_of(cfg["cloth"]["material"])
    assert mat.bending == "quadratic" and mat.bend == 2.94e-6 and mat.density == 0.06
    with pytest.raises(SceneError, match="bending"):
        parse_scene(scene({"preset": "silk", "bending": "shells"}))
