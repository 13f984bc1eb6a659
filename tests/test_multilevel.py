"""Multilevel 4-8 meshes: exact hierarchy facts, level switches that keep shape, mass and momentum, the same
material at every level, no recompiles, and a coarse-to-fine drape that ends where the fine one does."""
import numpy as np
import pytest

import taichi_cloth as tc
from multilevel.hierarchy import (Hierarchy48, boundary_vertices, edge_use, hanging_vertices, signed_areas,
                                  valences)
from taichi_cloth.errors import SceneError
from taichi_cloth.multilevel_cloth import multilevel_grid
from taichi_cloth.scenefile import load_scene
from conftest import current_level, refine
from test_recording_and_cli import rows_by_entity

W, H, NX, NY, LEVELS = 1.2, 0.8, 3, 2, 6


@pytest.fixture(scope="module")
def hierarchy():
    return Hierarchy48.rectangle((W, H), (NX, NY), LEVELS)


def expected_counts(level: int) -> tuple[int, int]:
    """(vertices, triangles) of level `level` (0-based) for the NX x NY base."""
    m = level // 2
    grid = (NX * 2**m + 1) * (NY * 2**m + 1)
    centres = NX * NY * 4**m if level % 2 else 0
    return grid + centres, 2 * NX * NY * 2**level


def test_levels_are_conforming_4_8_meshes_with_exact_counts(hierarchy):
    for k, L in enumerate(hierarchy.levels):
        n, t = L.n_vertices, L.n_triangles
        assert (n, t) == expected_counts(k)
        # right isosceles, counter-clockwise, tiling the rectangle exactly
        area = signed_areas(L.uv, L.triangles)
        assert area.min() > 0 and abs(area.sum() - W * H) < 1e-12
        p = L.uv[L.triangles]
        hyp = np.linalg.norm(p[:, 1] - p[:, 0], axis=1)
        legs = np.linalg.norm(p[:, 2][:, None] - p[:, [0, 1]], axis=2)
        assert np.allclose(legs[:, 0], legs[:, 1], rtol=1e-12) and np.allclose(hyp, np.sqrt(2) * legs[:, 0], rtol=1e-12)
        # conforming: no hanging vertex, no edge with 3+ triangles, single-use edges only on the outline
        assert len(hanging_vertices(L.uv, L.triangles)) == 0
        edges, count = edge_use(L.triangles)
        assert count.max() == 2
        ends = L.uv[edges[count == 1]]
        on_outline = (np.isclose(np.abs(ends[..., 0]), W / 2) | np.isclose(np.abs(ends[..., 1]), H / 2)).all(axis=1)
        assert on_outline.all()
        inner = ~boundary_vertices(L.triangles, n)
        assert set(np.unique(valences(L.triangles, n)[inner])) == {4, 8}
        # edge length shrinks by 1/sqrt(2) per level
        assert np.isclose(legs.min(), (W / NX) / np.sqrt(2) ** k)


def test_vertices_are_nested_and_midpoints_have_parent_and_diamond_tables(hierarchy):
    for prev, L in zip(hierarchy.levels, hierarchy.levels[1:]):
        n = prev.n_vertices
        assert np.array_equal(L.uv[:n], prev.uv)
        a, b = L.parents[n:, 0], L.parents[n:, 1]
        assert np.array_equal(L.uv[n:], 0.5 * (prev.uv[a] + prev.uv[b]))
        assert np.allclose(L.weights.sum(axis=1), 1.0)
        # each midpoint's diamond: 2 apexes inside, 1 on the outline; apexes are equidistant from the midpoint
        apex = L.diamonds[n:, 2:]
        inside = apex[:, 1] >= 0
        d0 = np.linalg.norm(L.uv[n:] - prev.uv[apex[:, 0]], axis=1)
        d1 = np.linalg.norm(L.uv[n:][inside] - prev.uv[apex[inside, 1]], axis=1)
        assert np.allclose(d0[inside], d1) and np.allclose(d0, 0.5 * np.linalg.norm(prev.uv[a] - prev.uv[b], axis=1))
        outline = (np.isclose(np.abs(L.uv[n:, 0]), W / 2) | np.isclose(np.abs(L.uv[n:, 1]), H / 2))
        assert np.array_equal(~inside, outline)


def test_level_springs_come_from_2d_rest_coordinates_and_masses_are_conserved():
    cloth = multilevel_grid((W, H), (NX, NY), LEVELS, "denim", center=(0.1, 1.0, -0.2), plane="xz")
    density = tc.MATERIALS["denim"].density
    for d, L in zip(cloth.levels, cloth.hierarchy.levels):
        uv_len = np.linalg.norm(L.uv[d.springs[:, 1]] - L.uv[d.springs[:, 0]], axis=1)
        assert np.allclose(d.rest_length, uv_len, rtol=1e-14, atol=0)
        assert abs(d.mass.sum() - density * W * H) < 1e-14
        assert d.count(tc.SpringKind.STRUCTURAL) + d.count(tc.SpringKind.SHEAR) == len(edge_use(L.triangles)[0])
        assert d.count(tc.SpringKind.SHEAR) == len(np.unique(np.sort(L.triangles[:, :2], axis=1), axis=0))


def test_every_level_is_the_same_isotropic_material():
    """Stretch test per level: the elastic energy of a small affine strain, per area, is that of an isotropic
    sheet with Young's modulus material.sheet_modulus and Poisson's ratio 1/3 (C11 = 9/8 E, C66 = 3/8 E),
    on even (axis-aligned) and odd (45-degree) levels alike."""
    mat = tc.MATERIALS["cotton"]
    cloth = multilevel_grid((1.0, 1.0), (4, 4), 5, mat)
    eps = 1e-5
    for d in cloth.levels:
        in_plane = d.kind != tc.SpringKind.BEND
        for F, expected in ((np.diag([1 + eps, 1, 1]), 9 / 8), (np.array([[1, eps, 0], [eps, 1, 0], [0, 0, 1]]), 4 * 3 / 8)):
            x = d.positions @ F.T
            s = d.springs[in_plane]
            length = np.linalg.norm(x[s[:, 1]] - x[s[:, 0]], axis=1)
            energy = (0.5 * d.stiffness[in_plane] * (length - d.rest_length[in_plane]) ** 2).sum()
            assert energy / (0.5 * eps**2) / mat.sheet_modulus == pytest.approx(expected, rel=1e-4)


CORNERS = dict(near=[[-0.5, 1, -0.5], [0.5, 1, -0.5]])
EDGE = dict(box=((-0.6, 0.99, -0.51), (0.6, 1.01, -0.49)))


def hanging(start_level=0, levels=4, pins=CORNERS, **schedule):
    cloth = multilevel_grid((1.0, 1.0), (4, 4), levels, "cotton", center=(0, 1, 0), plane="xz", start_level=start_level)
    return tc.Scene(cloth, integrator="implicit", dt=1 / 120, precision="f64", air_damping=1.0, pins=[pins],
                    multilevel=schedule or None)


def test_a_refinement_keeps_the_shape_and_the_momentum_exactly():
    sc = hanging(refine=False)
    sc.step(30)
    for _ in range(3):
        x, v, m = sc.positions(), sc.velocities(), sc.model.data.mass
        n = len(x)
        level = sc.model.data
        refine(sc)
        L = sc.controller("refiner").cloth.hierarchy.levels[current_level(sc)]
        x2, v2, m2 = sc.positions(), sc.velocities(), sc.model.data.mass
        assert len(x2) == L.n_vertices > n and sc.model.n_particles[None] == L.n_vertices
        assert np.array_equal(x2[:n], x) and np.array_equal(v2[:n], v)
        a, b = L.parents[n:, 0], L.parents[n:, 1]
        assert np.abs(x2[n:] - 0.5 * (x[a] + x[b])).max() < 1e-15  # on the old surface: distance 0
        assert m2.sum() == pytest.approx(m.sum(), rel=1e-14)
        p, p2 = (m[:, None] * v).sum(0), (m2[:, None] * v2).sum(0)
        assert np.abs(p2 - p).max() <= 1e-13 * np.abs(p).max()
        assert np.abs((m2[:, None] * x2).sum(0) - (m[:, None] * x).sum(0)).max() < 1e-13
        # the old level's springs are still at the same strain where they survive as the first halves
        assert sc.model.data is not level
        sc.step(5)


def test_pins_hold_through_level_switches_and_are_reselected_on_each_level():
    cloth = multilevel_grid((1.0, 0.5), (2, 1), 4, "cotton", center=(0, 1, 0))
    sc = tc.Scene(cloth, integrator="approx-implicit", dt=1 / 240, multilevel={"refine": False},
                  pins=[dict(box=((-0.6, 1.24, -0.1), (0.6, 1.26, 0.1)))])
    for level in range(4):
        top = np.isclose(sc.model.data.positions[:, 1], 1.25)
        assert np.array_equal(sc.model.pinned, top)
        sc.step(10)
        assert np.allclose(sc.positions()[top], sc.model.data.positions[top], atol=1e-6)
        if level < 3:
            refine(sc)
    with pytest.raises(ValueError, match="finest"):
        refine(sc)


def test_level_switches_compile_nothing():
    sc = hanging(refine=False, levels=4)
    sc.step(2)
    refine(sc)
    sc.step(2)  # the prolongation kernel compiles at the first switch
    with tc.CompileCounter() as cc:
        refine(sc)
        sc.step(2)
        refine(sc)
        sc.step(2)
        sc.reset()
        sc.step(2)
    assert cc.total == 0, cc.compiled


def test_a_scene_without_multilevel_builds_none_of_it():
    with tc.CompileCounter() as cc:
        sc = tc.Scene(tc.ClothBuilder.grid((0.5, 0.5), (6, 6)), integrator="approx-implicit", dt=0.005)
        sc.step(2)
    assert sc.controller("refiner") is None and [c.name for c in sc.controllers] == []
    assert not any(name.startswith("Prolongation") for name in cc.names())
    with pytest.raises(SceneError, match="multilevel"):
        tc.Scene(tc.ClothBuilder.grid((0.5, 0.5), (6, 6)), multilevel={})


@pytest.mark.slow
def test_coarse_to_fine_drape_ends_where_the_fine_drape_does():
    """A cloth held by one edge, released horizontally, swings down: refined from level 1 to level 4 as it
    settles, its rest shape is within 1 % of the cloth size of the same cloth run at level 4 from the start.
    (Held by two corners instead, the slack cloth folds, and fold patterns depend on the path: there the
    two rest shapes may legitimately differ by several cm.)"""
    settle = dict(max_speed=0.003, energy_change=1e-6, window=10, max_time=20.0)
    finals = []
    for start in (0, 3):
        sc = hanging(start_level=start, levels=4, pins=EDGE, **settle)
        frames = 0
        while not (sc.controller("refiner").at_finest and sc.controller("refiner").settled) and frames < 1500:
            sc.run(5, progress=False)  # a run's summary costs more than a frame: 5 at a time, the last ones at rest
            frames += 5
        assert sc.controller("refiner").settled, f"start level {start + 1} did not settle in {frames} frames"
        assert [s.level for s in sc.controller("refiner").switches] == list(range(start, 4))
        finals.append(sc.positions())
    d = np.linalg.norm(finals[0] - finals[1], axis=1)
    assert d.max() < 0.01, d.max()


def test_scene_file_multilevel_runs_records_the_levels_and_rejects_bad_tables(tmp_path):
    text = """
name = "ml"
frames = 40
[cloth.grid]
size = [0.6, 0.6]
center = [0.0, 1.0, 0.0]
plane = "xz"
[integrator]
name = "approx-implicit"
dt = 0.005
[[pins]]
near = [[-0.3, 1.0, -0.3]]
[multilevel]
levels = 3
base_cells = [2, 2]
[multilevel.settle]
max_time = 0.2
"""
    path = tmp_path / "ml.toml"
    path.write_text(text)
    loaded = load_scene(path)
    sc = loaded.scene
    assert current_level(sc) == 0 and sc.model.data.n_particles == 9
    rec = tc.Recorder(tmp_path / "ml.rrd")
    summary = sc.run(loaded.frames, recorder=rec, progress=False)
    rec.close()
    assert [s.level for s in sc.controller("refiner").switches] == [0, 1, 2] and summary.n_particles == 25
    assert [e.split(" at ")[0] for e in summary.events] == ["level 2", "level 3"]
    assert "level 2 at t = 0.200 s: 13 particles" in summary.format()
    got = rows_by_entity(tmp_path / "ml.rrd")
    static, frames, _ = got["/cloth/mesh"]
    assert static == 0 and len(frames) >= 41  # topology on the timeline, not static
    assert len(got["/metrics/cloth/level"][1]) == 41
    assert len(got["/cloth/events"][1]) == 2  # one event per switch
    for bad, message in ((text.replace("levels = 3", "levels = 0"), "levels"),
                         (text.replace("base_cells = [2, 2]", "base_cells = [2, 2]\nrefine = \"adaptive\""), "refine"),
                         (text.replace("plane = \"xz\"", "plane = \"xz\"\nresolution = [5, 5]"), "resolution"),
                         (text.replace("max_time = 0.2", "max_time = -1"), "max_time"),
                         (text.replace("[multilevel]\n", "[multilevel]\nstart_level = 4\n"), "start_level"),
                         (text.replace("[multilevel]\nlevels = 3\nbase_cells = [2, 2]\n[multilevel.settle]\nmax_time = 0.2\n", ""),
                          "resolution")):
        path.write_text(bad)
        with pytest.raises(SceneError, match=message):
            load_scene(path)


@pytest.mark.slow
def test_an_outline_hierarchy_drapes_through_its_levels_with_its_mass():
    """A pattern piece with a curved outline (taichi_cloth.garment.outline): every level carries the same mass, and a
    switch places each new particle by the level's prolongation table (barycentric inside, arc midpoints on
    the boundary, so that seam partners stay paired)."""
    from taichi_cloth.garment.outline import outline_hierarchy
    from taichi_cloth.multilevel_cloth import multilevel_cloth

    t = np.linspace(0.0, 2 * np.pi, 200)
    ellipse = np.stack([0.4 * np.cos(t), 0.25 * np.sin(t)], 1)
    ellipse[-1] = ellipse[0]
    cloth = multilevel_cloth(outline_hierarchy([ellipse], 3, 0.1), "cotton", center=(0, 1, 0), plane="xz")
    mass = [d.mass.sum() for d in cloth.levels]
    assert np.allclose(mass, mass[-1], rtol=1e-13, atol=0)
    sc = tc.Scene(cloth, integrator="implicit", dt=1 / 120, precision="f64", pins=[dict(near=[[-0.4, 1, 0]])],
                  multilevel={"refine": False})
    for _ in range(2):
        sc.step(10)
        x = sc.positions()
        refine(sc)
        L = cloth.hierarchy.levels[current_level(sc)]
        assert np.abs(sc.positions() - L.prolong(x)).max() < 1e-13
        assert sc.check().max_strain < 0.05


@pytest.mark.slow
def test_local_refinement_follows_the_drape_and_stays_conforming():
    """refine = "local": only triangles bent by more than `angle` across their hypotenuse, or touching the
    ball, are bisected (with the 4-8 forced splits). The mesh stays conforming, keeps its mass, ends with
    fewer particles than the global finest level, and its finest triangles lie where the cloth meets the ball."""
    cloth = multilevel_grid((1.0, 1.0), (4, 4), 5, "cotton", center=(0, 0.6, 0), plane="xz")
    ball = np.array([0.0, 0.3, 0.0])
    sc = tc.Scene(cloth, integrator="implicit", dt=1 / 120, colliders=[dict(type="sphere", center=ball, radius=0.25)],
                  multilevel=dict(refine="local", max_time=0.4, angle=15.0))
    sc.run(120, progress=False)
    r = sc.controller("refiner")
    assert [s.level for s in r.switches] == [0, 1, 2, 3, 4]
    mesh = r.mesh
    assert len(hanging_vertices(mesh.uv, mesh.triangles)) == 0 and edge_use(mesh.triangles)[1].max() == 2
    assert abs(signed_areas(mesh.uv, mesh.triangles).sum() - 1.0) < 1e-12
    assert cloth.levels[1].n_particles < sc.model.data.n_particles < cloth.levels[-1].n_particles
    assert sc.model.data.mass.sum() == pytest.approx(0.15, rel=1e-13)
    gap = np.abs(np.linalg.norm(sc.positions() - ball, axis=1) - 0.25)[mesh.triangles].mean(axis=1)
    assert gap[r.depth == r.depth.max()].mean() < 0.5 * gap[r.depth == r.depth.min()].mean()
