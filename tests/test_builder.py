"""Exact counts and geometry of the cloth builders, and clear errors for bad meshes."""
import numpy as np
import pytest

import taichi_cloth as tc
from taichi_cloth.cloth import SpringKind
from clothbase.meshes import edges_of, interior_edge_opposites


@pytest.mark.parametrize("nu,nv", [(2, 2), (5, 3), (16, 16)])
def test_grid_counts_are_exact(nu, nv):
    d = tc.ClothBuilder.grid((1.0, 0.6), (nu, nv))
    assert d.n_particles == nu * nv
    assert d.count(SpringKind.STRUCTURAL) == nu * (nv - 1) + nv * (nu - 1)
    assert d.count(SpringKind.SHEAR) == 2 * (nu - 1) * (nv - 1)
    assert d.count(SpringKind.BEND) == nv * max(nu - 2, 0) + nu * max(nv - 2, 0)
    assert len(d.triangles) == 2 * (nu - 1) * (nv - 1)


def test_grid_mass_rest_lengths_and_stiffness():
    mat = tc.MATERIALS["cotton"]
    d = tc.ClothBuilder.grid((1.2, 0.8), (13, 9), mat, center=(0.0, 2.0, 0.0))
    assert d.mass.sum() == pytest.approx(mat.density * 1.2 * 0.8, rel=1e-12)
    du, dv = 1.2 / 12, 0.8 / 8
    L = np.linalg.norm(d.positions[d.springs[:, 1]] - d.positions[d.springs[:, 0]], axis=1)
    np.testing.assert_allclose(d.rest_length, L)
    expected = {SpringKind.SHEAR: np.hypot(du, dv)}
    np.testing.assert_allclose(d.rest_length[d.kind == SpringKind.SHEAR], expected[SpringKind.SHEAR])
    # a square grid gives structural springs k = stretch inside and stretch/2 on the boundary strips
    sq = tc.ClothBuilder.grid((1.0, 1.0), (11, 11), mat)
    k = sq.stiffness[sq.kind == SpringKind.STRUCTURAL]
    assert set(np.round(k, 9)) == {mat.stretch, mat.stretch / 2}
    assert np.count_nonzero(np.isclose(k, mat.stretch / 2)) == 4 * 10  # 2 boundary rows + 2 columns, 10 springs each
    np.testing.assert_allclose(sq.stiffness[sq.kind == SpringKind.SHEAR], mat.shear)
    np.testing.assert_allclose(sq.damping, mat.damping * sq.stiffness)


def test_grid_triangles_face_one_way_and_cover_the_area():
    d = tc.ClothBuilder.grid((1.0, 0.5), (7, 4), plane="xy")
    p = d.positions[d.triangles]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert np.all(n[:, 2] > 0)  # +u x +v = +z
    assert 0.5 * n[:, 2].sum() == pytest.approx(0.5)


def _cube():
    import trimesh

    m = trimesh.creation.box()
    return np.asarray(m.vertices), np.asarray(m.faces)


def test_triangle_mesh_springs_from_edges_and_opposite_vertices():
    v, f = _cube()
    d = tc.ClothBuilder.triangle_mesh(v, f, "silk")
    edges, _, counts = edges_of(f)
    assert d.count(SpringKind.STRUCTURAL) == len(edges) == 18
    assert d.count(SpringKind.BEND) == len(interior_edge_opposites(f))
    assert d.count(SpringKind.SHEAR) == 0
    assert d.mass.sum() == pytest.approx(tc.MATERIALS["silk"].density * 6.0)  # unit cube area 6
    # bend pairs are the two vertices opposite an interior edge: never joined by that edge
    pairs = interior_edge_opposites(f)
    assert len(pairs) > 0 and np.all(pairs[:, 0] != pairs[:, 1])


def test_model_adjacency_lists_every_spring_twice():
    d = tc.ClothBuilder.grid((1.0, 1.0), (6, 5))
    m = tc.Model(d)
    off = m.adj_offset.to_numpy()
    spring = m.adj_spring.to_numpy()[: 2 * d.n_springs]
    other = m.adj_other.to_numpy()[: 2 * d.n_springs]
    assert off[-1] == 2 * d.n_springs
    assert np.all(np.bincount(spring, minlength=d.n_springs) == 2)
    owner = np.repeat(np.arange(d.n_particles), np.diff(off))
    a, b = d.springs[spring, 0], d.springs[spring, 1]
    assert np.all(((owner == a) & (other == b)) | ((owner == b) & (other == a)))


@pytest.mark.parametrize("case,message", [
    ("empty", "no vertices"),
    ("nan", "NaN"),
    ("degenerate", "degenerate"),
    ("nonmanifold", "non-manifold"),
])
def test_bad_meshes_get_one_clear_error(case, message):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], float)
    f = np.array([[0, 1, 2]])
    if case == "empty":
        v, f = np.zeros((0, 3)), np.zeros((0, 3), int)
    elif case == "nan":
        v[1, 0] = np.nan
    elif case == "degenerate":
        f = np.array([[0, 1, 1]])
    elif case == "nonmanifold":
        f = np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4]])
    with pytest.raises(tc.MeshError, match=message):
        tc.ClothBuilder.triangle_mesh(v, f, source="bad.obj")


def test_mesh_file_round_trip(tmp_path):
    import trimesh

    path = tmp_path / "flag.obj"
    trimesh.creation.box().export(path)
    d = tc.ClothBuilder.mesh_file(path, scale=2.0)
    assert d.n_particles == 8
    assert np.ptp(d.positions, axis=0) == pytest.approx([2.0, 2.0, 2.0])
    with pytest.raises(tc.MeshError, match="no such mesh file"):
        tc.ClothBuilder.mesh_file(tmp_path / "missing.obj")


def test_a_grid_the_machine_cannot_hold_is_refused_by_the_builder_before_it_allocates():
    """The memory guard is the builder's (taichi_cloth.guards.check_grid): in Python too a huge grid gets one
    SceneError naming the resolution and the estimate, not numpy's _ArrayMemoryError traceback (the scene-file reader
    calls the same guard before Taichi starts)."""
    with pytest.raises(tc.SceneError, match=r"^ClothBuilder.grid resolution 100000 x 100000: 10,000,000,000 particles "
                                            r"need about 55.9 TiB of memory \(estimate, 6 KiB a particle\) and this "
                                            r"machine has .* available; use a coarser resolution$"):
        tc.ClothBuilder.grid((1, 1), (100000, 100000))
    with pytest.raises(tc.SceneError, match=r"^ClothBuilder.multilevel_grid base_cells 40 x 40, levels 20: "
                                            r"1,762,656,256 particles need about .*; use fewer levels$"):
        tc.ClothBuilder.multilevel_grid((1, 1), (40, 40), 20)
