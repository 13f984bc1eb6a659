"""A garment coarse to fine (Hsiao 2006 section 2.2; taichi_cloth.garment.levels): two squares sewn on level 1 (of
three; levels are 1-based here as in the scene files, 0-based in the code) over a sphere, merged, then refined to
level 3 by the refiner as the drape settles. Every switch keeps the seams closed, the mass and the momentum, and
the levels nested; no switch compiles a kernel; no particle ends inside the body."""
from pathlib import Path

import numpy as np
import pytest

import taichi_cloth as tc
from taichi_cloth.control import Controller
from taichi_cloth.errors import PatternError, SceneError
from taichi_cloth.garment.garment import FreePlacement, GarmentSpec
from taichi_cloth.garment.levels import multilevel_garment
from taichi_cloth.garment.pattern import PatternPiece
from taichi_cloth.garment.seams import Seam, SeamSide
from taichi_cloth.material import material as as_material
from taichi_cloth.scenefile import load_scene

SPHERE = dict(type="sphere", center=(0.0, 0.0, 0.0), radius=0.2)
DEMOS = Path(__file__).resolve().parents[1] / "demos"


def square(name, size=0.2):
    return PatternPiece.from_polygon(name, [[0, 0], [size, 0], [size, size], [0, size]],
                                     corner_names=["bl", "br", "tr", "tl"])


def two_squares(levels=3):
    """Two 0.2 m squares laid flat 0.1 m above the sphere's top, 0.1 m apart; A's right side sewn to B's left.
    Spacing 0.02 m on the finest of 3 levels: 0.04 m on levels 1 and 2."""
    seam = Seam("middle", SeamSide("A", "br", "tr"), SeamSide("B", "bl", "tl"))
    flat = dict(u_axis=(1.0, 0.0, 0.0), v_axis=(0.0, 0.0, 1.0))
    return GarmentSpec("two squares", [square("A"), square("B")], [seam],
                       {"A": FreePlacement((-0.25, 0.3, -0.1), **flat), "B": FreePlacement((0.05, 0.3, -0.1), **flat)},
                       spacing=0.02, levels=levels)


class SwitchProbe(Controller):
    """Keeps the state right after every level switch (the scene calls model_changed after the refill)."""

    name = "probe"

    def __init__(self, scene):
        self.scene, self.after = scene, []

    def model_changed(self, change, t, dt):
        if change.level is not None and change.prolong is not None:  # a switch (the merge names its level too)
            s = self.scene
            sewing = s.controller("sewing")  # it ran its own model_changed before this one
            self.after.append((change.level, s.positions(), s.velocities(), s.model.data, sewing.current_of,
                               sewing.gaps()))


def test_levels_are_built_merged_and_nested():
    mg = multilevel_garment(two_squares(), start_level=0)
    sizes = [(L.garment.data.n_particles, L.merged.n_particles, len(L.garment.seam_pairs)) for L in mg.levels]
    # 0.2 m sides: 5, 5 and 10 intervals on the seam, 6, 6 and 11 pairs; merging removes one particle per pair
    assert sizes == [(72, 66, 6), (102, 96, 6), (242, 231, 11)]
    assert mg.capacity == (231, mg.cloth.levels[-1].n_springs, len(mg.cloth.levels[-1].triangles))
    mass = [L.garment.data.mass.sum() for L in mg.levels] + [d.mass.sum() for d in mg.cloth.levels]
    assert np.allclose(mass, 2 * 0.2 * 0.2 * as_material("cotton").density, rtol=1e-13, atol=0)
    for k in (1, 2):
        L, coarse, fine = mg.cloth.hierarchy.levels[k], mg.levels[k - 1], mg.levels[k]
        assert L.n_vertices == fine.merged.n_particles and L.parents.max() == coarse.merged.n_particles - 1
        # a seam pair of the fine level is one merged particle, and so are its parents: the seam stays closed
        p = fine.current_of[fine.garment.seam_pairs]
        assert np.array_equal(p[:, 0], p[:, 1])
        # prolonging the coarse merged rest shape lands every inherited vertex on its parent exactly
        x = L.prolong(coarse.merged.positions)
        inherited = L.weights[:, 0] == 1.0
        assert inherited.sum() > coarse.merged.n_particles // 2
        assert np.array_equal(x[inherited], coarse.merged.positions[L.parents[inherited, 0]])
    with pytest.raises(PatternError, match="levels >= 2"):
        multilevel_garment(two_squares(levels=1))
    with pytest.raises(PatternError, match="start level 4 must lie in 1..3"):
        multilevel_garment(two_squares(), start_level=3)


def test_sewn_on_level_1_and_refined_to_level_3_keeps_seams_mass_momentum_and_nesting():
    mg = multilevel_garment(two_squares(), start_level=0)
    scene = tc.Scene(mg, integrator="implicit", dt=1 / 120, precision="f64", colliders=[SPHERE],
                     stretch_limit=dict(max_strain=0.1), multilevel=dict(max_time=0.25))
    refiner, sewing = scene.controller("refiner"), scene.controller("sewing")
    probe = SwitchProbe(scene)
    scene.add_controller(probe)
    before = []
    refine = refiner.refine

    def spy():  # the state right before every switch
        before.append((scene.positions(), scene.velocities(), scene.model.data))
        return refine()

    refiner.refine = spy
    frames = 0
    while len(refiner.switches) < 2 and frames < 120:  # sewing, the merge, then level 2
        scene.run(1, progress=False)
        frames += 1
    assert sewing.joined and refiner.level == 1
    # the refiner waited for the seams: level 1 ran at least max_time after the merge
    assert refiner.switches[1].t >= sewing.closed_at + 0.25 - 1e-9
    with tc.CompileCounter() as cc:  # level 2 to level 3 and on: nothing compiles
        summary = scene.run(60, progress=False)
    assert cc.total == 0, cc.compiled
    assert refiner.level == 2 and refiner.at_finest and [s.level for s in refiner.switches] == [0, 1, 2]
    assert sum("level 3 at t" in e for e in summary.events) == 1

    assert len(before) == len(probe.after) == 2
    for (x0, v0, d0), (level, x1, v1, d1, current_of, gaps) in zip(before, probe.after):
        L, fine = mg.cloth.hierarchy.levels[level], mg.levels[level]
        assert d1 is mg.cloth.levels[level] and len(x1) == fine.merged.n_particles
        assert d1.mass.sum() == pytest.approx(d0.mass.sum(), rel=1e-13)
        p0, p1 = (d0.mass[:, None] * v0).sum(0), (d1.mass[:, None] * v1).sum(0)
        assert np.abs(p1 - p0).max() <= 1e-12 * max(np.abs(p0).max(), 1e-9), (p0, p1)
        # nested: the new level's inherited vertices are where level k had them, the others on its surface
        inherited = L.weights[:, 0] == 1.0
        assert np.array_equal(x1[inherited], x0[L.parents[inherited, 0]])
        assert np.abs(x1 - L.prolong(x0)).max() < 1e-13
        # closed seams: every pair of the new level is one particle, and the sewing measures the new level's pairs
        assert np.array_equal(current_of, fine.current_of)
        assert gaps.max() == 0.0 and len(gaps) == len(fine.garment.seam_pairs)
    # on the sphere: no particle inside it, the seams closed, the strain within the stretch limit
    x = scene.positions()
    assert np.linalg.norm(x, axis=1).min() >= 0.2
    assert x[:, 1].max() < 0.25  # it fell onto the sphere
    assert sewing.gaps().max() == 0.0 and scene.check().max_strain < 0.12


def test_scene_file_runs_a_garment_coarse_to_fine_and_names_bad_tables(tmp_path):
    scene = {"cloth": {"garment": str(DEMOS / "garments" / "skirt.toml")},
             "integrator": {"name": "implicit", "dt": 1 / 120},
             "multilevel": {"levels": 2, "start_level": 1}, "colliders": [{"type": "mesh", "path": "mannequin"}]}
    loaded = load_scene(scene, out=tmp_path)
    sc = loaded.scene
    refiner, sewing = sc.controller("refiner"), sc.controller("sewing")
    assert refiner.level == 0 and refiner.cloth.n_levels == 2 and sewing.levels is not None
    assert sc.model.data is sewing.garment.data is sewing.levels.levels[0].garment.data
    local = load_scene(dict(scene, multilevel={"levels": 2, "start_level": 1, "refine": "local"}), out=tmp_path).scene
    ml = local.controller("sewing").levels
    t = ml.cloth.levels[-1].triangles
    assert local.controller("refiner").local.mg is ml  # a garment refines locally its own way
    edges = len(np.unique(np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1), axis=0))
    assert local.model.capacity == (ml.capacity[0], max(ml.capacity[1], 2 * edges), ml.capacity[2])
    with pytest.raises(SceneError, match=r"\[multilevel\] start_level: must be <= levels \(2\), got 3"):
        load_scene(dict(scene, multilevel={"levels": 2, "start_level": 3}), out=tmp_path)
    with pytest.raises(SceneError, match='coarse to fine needs join = "merge"'):
        load_scene(dict(scene, sewing={"join": "spring"}), out=tmp_path)
    with pytest.raises(SceneError, match="levels >= 2"):
        load_scene(dict(scene, multilevel={"levels": 1}), out=tmp_path)
    # a resolution preset: its spacing, and its levels where [multilevel] names none
    drafted = load_scene(dict(scene, multilevel={"start_level": 1}), resolution="draft", out=tmp_path).scene
    assert drafted.controller("refiner").cloth.n_levels == 3
    assert drafted.controller("sewing").garment.spec.spacing == 0.02
    with pytest.raises(SceneError, match="--resolution: is a garment's preset"):
        load_scene({"cloth": {"grid": {"size": [0.2, 0.2], "resolution": [3, 3]}},
                    "integrator": {"name": "explicit", "dt": 1e-3}}, resolution="fit", out=tmp_path)


def test_recording_and_self_collision_follow_the_switches(tmp_path):
    from test_recording_and_cli import rows_by_entity

    mg = multilevel_garment(two_squares(), start_level=0)
    scene = tc.Scene(mg, integrator="implicit", dt=1 / 120, colliders=[SPHERE], self_collision=True,
                     multilevel=dict(max_time=0.25))
    rec = tc.Recorder(tmp_path / "levels.rrd")
    summary = scene.run(100, recorder=rec, progress=False)
    rec.close()
    assert [s.level for s in scene.controller("refiner").switches] == [0, 1, 2]
    assert [e.split(" at t")[0] for e in summary.events] == ["seams closed", "level 2", "level 3"]
    got = rows_by_entity(tmp_path / "levels.rrd")
    assert len(got["/cloth/events"][1]) == 3  # the merge and one event per switch
    assert got["/cloth/mesh"][0] == 0  # the topology is on the timeline
    assert len(got["/metrics/cloth/level"][1]) == 101
    # the run ends on level 3 with self-collision on (it was given every level's mesh), nothing inside the sphere
    assert scene.model.n_particles[None] == mg.cloth.levels[2].n_particles
    assert np.linalg.norm(scene.positions(), axis=1).min() >= 0.2


def hanging_on_edges(uv, triangles):
    """Vertices lying strictly inside an edge of the 2D mesh (uv (n, 2), triangles (t, 3)): a non-conforming mesh
    has them (a refined side meets an unrefined one)."""
    from clothbase.meshes import edges_of

    edges = edges_of(triangles)[0]
    p, q = uv[edges[:, 0]][:, None], uv[edges[:, 1]][:, None]
    d, r = q - p, uv[None] - p
    length2 = (d ** 2).sum(2)
    t = (r * d).sum(2) / length2
    cross = d[..., 0] * r[..., 1] - d[..., 1] * r[..., 0]
    on = (np.abs(cross) <= 1e-9 * length2) & (t > 1e-9) & (t < 1 - 1e-9)
    return np.unique(np.nonzero(on)[1])


def test_local_refinement_refines_where_it_touches_and_stays_conforming_across_seams():
    """refine = "local" on the two squares over a smaller sphere (their outer parts hang free): two local steps
    (toward levels 2 and 3) where the cloth folds by more than 45 degrees or touches, at least a fifth fewer
    particles than level 3, every piece's mesh conforming (no vertex inside an edge, every edge on at most two
    triangles, the piece covered, no sliver), the seams closed, mass and momentum kept by every switch, nothing
    inside the sphere, no compile on the second switch."""
    from multilevel.hierarchy import edge_use, signed_areas

    mg = multilevel_garment(two_squares(), start_level=0)
    scene = tc.Scene(mg, integrator="implicit", dt=1 / 120, precision="f64", colliders=[dict(SPHERE, radius=0.12)],
                     stretch_limit=dict(max_strain=0.1), multilevel=dict(max_time=0.25, refine="local", angle=45.0))
    refiner, sewing = scene.controller("refiner"), scene.controller("sewing")
    probe = SwitchProbe(scene)
    scene.add_controller(probe)
    before, refine = [], refiner.refine

    def spy():
        before.append((scene.positions(), scene.velocities(), scene.model.data))
        return refine()

    refiner.refine = spy
    frames = 0
    while len(refiner.switches) < 2 and frames < 120:
        scene.run(1, progress=False)
        frames += 1
    with tc.CompileCounter() as cc:
        summary = scene.run(40, progress=False)
    assert cc.total == 0, cc.compiled
    assert [s.level for s in refiner.switches] == [0, 1, 2] and refiner.at_finest
    assert sum("level 3 at t" in e for e in summary.events) == 1
    finest = mg.cloth.levels[-1].n_particles
    sizes = [d.n_particles for _, _, _, d, _, _ in probe.after]
    assert mg.cloth.levels[0].n_particles < sizes[0] < sizes[1] < 0.8 * finest
    for (x0, v0, d0), (level, x1, v1, d1, current_of, gaps) in zip(before, probe.after):
        assert d1.mass.sum() == pytest.approx(d0.mass.sum(), rel=1e-13)
        p0, p1 = (d0.mass[:, None] * v0).sum(0), (d1.mass[:, None] * v1).sum(0)
        assert np.abs(p1 - p0).max() <= 1e-12 * max(np.abs(p0).max(), 1e-9), (p0, p1)
        assert gaps.max() == 0.0  # the sewing measures the new mesh's pairs: the seams stay closed
        assert len(np.unique(current_of)) == d1.n_particles
    g = sewing.garment
    assert g is refiner.local.current.level.garment
    # the seams: every pair is one particle, and the two sides have the same samples
    pairs = sewing.current_of[g.seam_pairs]
    assert np.array_equal(pairs[:, 0], pairs[:, 1]) and len(g.seam_pairs) > 6
    # conforming: one mesh (every edge on one or two triangles), no hanging vertex in any piece, pieces covered
    tris = scene.model.data.triangles
    assert edge_use(tris)[1].max() == 2
    for m in g.meshes:
        assert len(hanging_on_edges(m.uv, m.triangles)) == 0
        assert signed_areas(m.uv, m.triangles).min() > 0 and m.quality.slivers == 0
        loop = m.uv[m.boundary_loop]
        outline = 0.5 * np.sum(loop[:, 0] * np.roll(loop[:, 1], -1) - np.roll(loop[:, 0], -1) * loop[:, 1])
        assert signed_areas(m.uv, m.triangles).sum() == pytest.approx(outline, rel=1e-12)
        assert np.array_equal(np.unique(m.triangles), np.arange(m.n_vertices))
    x = scene.positions()
    assert np.linalg.norm(x, axis=1).min() >= 0.12
    assert sewing.gaps().max() == 0.0 and scene.check().max_strain < 0.12


def test_a_pin_holds_its_corner_through_the_merge_and_every_switch():
    """A's outer corner pinned where it was placed (`near`, selected again at the merge and at every switch): the
    pinned particle is that corner on every level, it stays exactly there, and the garment hangs from it."""
    corner = (-0.25, 0.3, -0.1)  # A's bottom-left corner as placed (its pattern origin)
    mg = multilevel_garment(two_squares(), start_level=0)
    scene = tc.Scene(mg, integrator="implicit", dt=1 / 120, precision="f64", pins=[{"near": [corner]}],
                     multilevel=dict(max_time=0.25))
    refiner, pins = scene.controller("refiner"), scene.controller("pins")
    held = []
    frames = 0
    while not refiner.at_finest and frames < 150:
        scene.run(1, progress=False)
        frames += 1
        x = scene.positions()
        held.append((len(refiner.switches), len(pins.indices), np.abs(x[pins.indices] - corner).max()))
    assert [s.level for s in refiner.switches] == [0, 1, 2] and scene.controller("sewing").joined
    assert {n for _, n, _ in held} == {1} and max(d for _, _, d in held) < 1e-12, held
    assert {k for k, _, _ in held} == {1, 2, 3}  # measured on every level
    scene.run(30, progress=False)
    x = scene.positions()
    assert np.abs(x[pins.indices] - corner).max() < 1e-12
    assert x[:, 1].min() < corner[1] - 0.15  # the rest hangs from it (no floor, no body)
