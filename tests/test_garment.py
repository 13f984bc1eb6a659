"""Garments: seam pairing, sewing two flat squares, garment-file errors, DXF-sourced garments, and a skirt sewn
onto the mannequin (Chen 2013; Fan et al. 1998; docs/algorithms.md, sewing)."""
from pathlib import Path

import numpy as np
import pytest

import taichi_cloth as tc
from taichi_cloth.errors import PatternError
from taichi_cloth.garment.dxf import write_aama_dxf
from taichi_cloth.garment.garment import FreePlacement, GarmentSpec, build_garment
from taichi_cloth.garment.garmentfile import load_garment
from taichi_cloth.garment.metrics import garment_quality
from taichi_cloth.garment.pattern import PatternPiece
from taichi_cloth.garment.seams import Seam, SeamSide
from test_recording_and_cli import rows_by_entity

GAP = 0.2  # [m] between the two squares


def square(name, size=0.2):
    return PatternPiece.from_polygon(name, [[0, 0], [size, 0], [size, size], [0, size]],
                                     corner_names=["bl", "br", "tr", "tl"])


def two_squares(b_from="bl", b_to="tl", spacing=0.02):
    """Square A at the origin and square B GAP to its right, in the xy plane; A's right side sewn to B's left."""
    seam = Seam("middle", SeamSide("A", "br", "tr"), SeamSide("B", b_from, b_to))
    return GarmentSpec("two squares", [square("A"), square("B")], [seam],
                       {"A": FreePlacement((0.0, 0.0, 0.0)), "B": FreePlacement((0.2 + GAP, 0.0, 0.0))},
                       spacing=spacing)


def test_seam_pairs_follow_the_picks_never_crosswise():
    # B picked bottom-to-top like A: against B's counter-clockwise loop, so the flags differ and B is reversed
    g = build_garment(two_squares("bl", "tl"))
    assert g.seam_flags["middle"] == (True, False)
    x = g.data.positions
    a, b = x[g.seam_pairs[:, 0]], x[g.seam_pairs[:, 1]]
    assert len(g.seam_pairs) == 11  # 0.2 m at 0.02 m: 10 intervals, 11 points on each side
    np.testing.assert_allclose(a[:, 1], b[:, 1], atol=1e-12)  # partners at the same height
    np.testing.assert_allclose(np.linalg.norm(b - a, axis=1), GAP, atol=1e-12)
    assert a[0, 1] == pytest.approx(0.0) and a[-1, 1] == pytest.approx(0.2)  # point 0 is where the pick started

    # the same side picked top-to-bottom: now it runs crosswise, as picked (point 0 of A meets B's top)
    g = build_garment(two_squares("tl", "bl"))
    assert g.seam_flags["middle"] == (True, True)
    x = g.data.positions
    a, b = x[g.seam_pairs[:, 0]], x[g.seam_pairs[:, 1]]
    np.testing.assert_allclose(a[:, 1] + b[:, 1], 0.2, atol=1e-12)


@pytest.mark.parametrize("gap, joins", [(0.006, True), (0.008, False)])
def test_a_seam_that_stalls_short_of_epsilon_joins_below_a_quarter_of_its_spacing(gap, joins):
    """Two squares pinned along their outer sides, each pair's pull capped at 0.2 N: the cloth's tension holds the
    seam open about 2 mm short of the placed gap (4 mm from 6 mm, 6 mm from 8 mm), far above epsilon = 0.5 mm. A
    stalled gap below a quarter of the 20 mm spacing (5 mm) joins, whatever round-off makes of it; one above
    that does not, and sewing gives up at max_time naming the open seam."""
    seam = Seam("middle", SeamSide("A", "br", "tr"), SeamSide("B", "bl", "tl"))
    spec = GarmentSpec("two squares", [square("A"), square("B")], [seam],
                       {"A": FreePlacement((0.0, 0.0, 0.0)), "B": FreePlacement((0.2 + gap, 0.0, 0.0))}, spacing=0.02)
    g = build_garment(spec)
    outer = [{"box": [[-0.01, -1, -1], [0.001, 1, 1]]}, {"box": [[0.4 + gap - 0.001, -1, -1], [0.5, 1, 1]]}]
    scene = tc.Scene(g, integrator="implicit", dt=1 / 240, gravity=(0, 0, 0), pins=outer,
                     sewing=dict(max_force=0.2, epsilon=0.0005, max_time=0.5))
    summary = scene.run(32, progress=False)
    sewing = scene.controller("sewing")
    assert sewing.stall_gap == pytest.approx(0.005, rel=1e-9)  # a quarter of the seam's 20 mm spacing
    stalled = sewing.history[-1].max if not joins else \
        [h for h in sewing.history if h.t <= sewing.closed_at + 1e-9][-1].max
    assert abs(stalled - (gap - 0.002)) < 0.0005, stalled
    assert sewing.joined is joins and sewing.gave_up is not joins
    if joins:
        assert sewing.closed_at < 0.3 and any("stalled at a largest gap" in e for e in summary.events)
        assert summary.n_particles == g.data.n_particles - len(g.seam_pairs)
    else:
        assert any("open seams middle" in w for w in summary.warnings), summary.warnings


def test_a_stiffer_fabric_sews_as_fast_because_its_seams_pull_harder():
    """The seam pull scales with the seam's stiffness (k_s = sheet modulus / 2): a pair's spring is never stretched
    more than REACH x close_speed x dt beyond its rest length. Two free squares 0.2 m apart in zero gravity, in cotton
    and in a cotton 8 times as stiff: both close at the ramp's 0.5 m/s (the fixed 5 N cap of before closed the stiff
    one at 0.14 m/s, in 1.4 s), and the stiff one's pairs pull 8 times as hard."""
    from taichi_cloth.garment.sewing import Sewing

    closed, pull = {}, {}
    for scale in (1.0, 8.0):
        cotton = tc.MATERIALS["cotton"]
        spec = two_squares()
        spec.material = cotton.replace(stretch=cotton.stretch * scale, shear=cotton.shear * scale)
        g = build_garment(spec)
        dt = 1 / 240
        scene = tc.Scene(g, integrator="implicit", dt=dt, gravity=(0, 0, 0), sewing=dict(close_speed=0.5))
        sewing = scene.controller("sewing")
        scene.run(12, progress=False)  # 0.2 s: halfway
        d = scene.model
        first, n = g.first_seam_spring, len(g.seam_pairs)
        k = d.stiffness.to_numpy()[first:first + n].astype(np.float64)
        rest = d.rest_length.to_numpy()[first:first + n].astype(np.float64)
        x = scene.positions()
        a, b = d.spring_a.to_numpy()[first:first + n], d.spring_b.to_numpy()[first:first + n]
        stretch = np.linalg.norm(x[b] - x[a], axis=1) - rest
        reach = Sewing.REACH * 0.5 * dt
        assert stretch.max() <= reach * (1 + 1e-3)  # the cap: never stretched beyond one step's reach
        pull[scale] = float((k * stretch).max())
        scene.run(36, progress=False)  # to 0.8 s
        assert sewing.joined, scale
        closed[scale] = sewing.closed_at
    assert pull[8.0] == pytest.approx(8 * pull[1.0], rel=0.05)
    # the ramp takes GAP / close_speed = 0.4 s; both stop within the same two frames
    assert closed[1.0] <= 0.6 and abs(closed[8.0] - closed[1.0]) <= 2 / 60 + 1e-9, closed


@pytest.mark.parametrize("after_join", [True, False])
def test_a_stretch_limit_not_after_the_join_holds_the_pieces_while_they_are_sewn_only(after_join):
    """[stretch_limit] after_join = false: the limit works while the seams close (its pass count grows) and stops at
    the join (the count stays); by default it goes on."""
    g = build_garment(two_squares())
    scene = tc.Scene(g, integrator="implicit", dt=1 / 240, gravity=(0, 0, 0),
                     stretch_limit=dict(max_strain=0.01, after_join=after_join), sewing=dict(close_speed=0.5))
    limit, sewing = scene.controller("stretch_limit"), scene.controller("sewing")
    while not sewing.joined:
        scene.run(1, progress=False)
        assert scene.state.t < 0.8
    at_join = limit.stats["stretch_passes"]
    assert at_join > 0  # a 1 % limit works while the pieces are pulled together
    scene.forces.set_gravity((0, -9.81, 0))  # a load the limit would have to hold
    scene.run(12, progress=False)
    assert (limit.stats["stretch_passes"] > at_join) is after_join


def test_two_squares_close_below_epsilon_and_stay_below_the_stretch_limit():
    g = build_garment(two_squares())
    scene = tc.Scene(g, integrator="implicit", dt=1 / 240, gravity=(0, 0, 0), stretch_limit=dict(max_strain=0.1),
                     sewing=dict(close_speed=0.5, epsilon=0.002))
    summary = scene.run(60, progress=False)  # 1 s
    sewing = scene.controller("sewing")
    assert sewing.joined and not sewing.gave_up
    # the ramp needs GAP / close_speed = 0.4 s; sewing must have stopped within twice that
    assert sewing.closed_at <= 0.8
    closing = [h for h in sewing.history if h.t <= sewing.closed_at + 1e-9]
    assert closing[-1].max < 0.002
    # merged: one particle per pair, so the particle count drops by the number of pairs
    assert summary.n_particles == g.data.n_particles - len(g.seam_pairs)
    q = garment_quality(scene)
    assert q.seam_gap_max == 0.0
    for piece in q.pieces:
        assert piece.max_strain < 0.1  # the stretch limit held through sewing and merging
        assert piece.area_error < 1e-3  # the squares stay flat and unstretched
    # no gravity, no pins, no colliders: internal forces and the merge conserve momentum (which starts at 0), up
    # to what each CG solve leaves in its residual (sum_i r_i = -sum_i m_i dv_i, CG to 1e-3) and float32: 1.0e-6
    # kg m/s measured
    momentum = (scene.model.data.mass[:, None] * scene.velocities()).sum(0)
    assert np.abs(momentum).max() < 3e-6
    # the merged seam is bent like the cloth: bend springs now span it, with the flat rest length of the pattern
    x = scene.positions()
    assert np.ptp(x[:, 2]) < 1e-6 and np.ptp(x[:, 0]) == pytest.approx(0.4, abs=0.01)
    d = scene.model.data
    bend = d.kind == int(tc.SpringKind.BEND)
    assert bend.sum() > g.data.count(tc.SpringKind.BEND)
    length = np.linalg.norm(x[d.springs[bend, 1]] - x[d.springs[bend, 0]], axis=1)
    np.testing.assert_allclose(length, d.rest_length[bend], rtol=2e-3)


def test_join_by_stiff_springs_keeps_the_particles():
    g = build_garment(two_squares())
    scene = tc.Scene(g, integrator="implicit", dt=1 / 240, gravity=(0, 0, 0), sewing=dict(join="spring"))
    scene.run(60, progress=False)
    assert scene.controller("sewing").joined and scene.model.data.n_particles == g.data.n_particles
    assert scene.controller("sewing").gaps().max() < 0.002


GOOD = """
name = "pair"
units = "cm"
spacing = 4
[[pieces]]
name = "A"
outline = [{at = [0, 0], name = "bl"}, {at = [20, 0], name = "br"}, {at = [20, 20], name = "tr"},
           {at = [0, 20], name = "tl"}]
placement = {origin = [0, 0, 0]}
[[pieces]]
name = "B"
copy = "A"
placement = {origin = [40, 0, 0]}
[[seams]]
name = "middle"
a = {piece = "A", from = "br", to = "tr"}
b = {piece = "B", from = "bl", to = "tl"}
"""


def _garment_file(tmp_path, text):
    p = tmp_path / "g.toml"
    p.write_text(text)
    return p


def test_garment_file_loads_in_its_units(tmp_path):
    spec = load_garment(_garment_file(tmp_path, GOOD))
    assert spec.spacing == pytest.approx(0.04)
    assert spec.piece("B").area() == pytest.approx(0.04)
    g = build_garment(spec)
    assert len(g.seam_pairs) == 6


@pytest.mark.parametrize("change, words", [
    (("b = {piece = \"B\"", "b = {piece = \"C\""), ["seam", "middle", "'C'"]),
    (("spacing = 4", "spacing = -4"), ["spacing"]),
    (("{at = [20, 20], name = \"tr\"}", "{at = [0, 10], name = \"tr\"}, {at = [20, 20], name = \"x\"}"),
     ["'A'", "intersect"]),
])
def test_bad_garment_file_gets_one_clear_error(tmp_path, change, words):
    text = GOOD.replace(*change)
    assert text != GOOD
    with pytest.raises(PatternError) as err:
        build_garment(load_garment(_garment_file(tmp_path, text)))
    msg = str(err.value)
    assert "\n" not in msg
    for w in words:
        assert w in msg


def test_a_resolution_preset_sets_the_spacing_and_the_coarse_to_fine_levels(tmp_path):
    from taichi_cloth.garment.garment import RESOLUTIONS

    spec = load_garment(_garment_file(tmp_path, GOOD.replace("spacing = 4", 'resolution = "fit"')))
    assert spec.spacing == 0.01 and spec.resolution == "fit"
    assert spec.levels == 1 and spec.coarse_to_fine_levels == RESOLUTIONS["fit"][1] == 5
    spec = load_garment(_garment_file(tmp_path, GOOD.replace("spacing = 4", 'resolution = "fine"\nlevels = 3')))
    assert spec.spacing == 0.005 and spec.coarse_to_fine_levels == 3  # the file's levels win
    for text, words in ((GOOD.replace("spacing = 4", 'spacing = 4\nresolution = "fit"'), "not both"),
                        (GOOD.replace("spacing = 4", ""), "not neither"),
                        (GOOD.replace("spacing = 4", 'resolution = "final"'), "resolution")):
        with pytest.raises(PatternError, match=words):
            load_garment(_garment_file(tmp_path, text))


def test_open_outline_is_an_error():
    a = PatternPiece.from_polygon("open", [[0, 0], [1, 0], [1, 1]])
    from taichi_cloth.garment.pattern import Segment

    broken = PatternPiece("open", [a.segments[0], a.segments[1],
                                   Segment("line", np.array([[1.0, 1.0], [0.0, 0.1]]))], ["c0", "c1", "c2"])
    with pytest.raises(PatternError, match="open"):
        broken.validate()


GARMENTS = Path(__file__).resolve().parents[1] / "demos" / "garments"


@pytest.fixture(scope="module")
def body():
    from taichi_cloth.body.landmarks import Body

    return Body.from_mannequin()


def test_dxf_round_trip_of_a_generated_garment(tmp_path, body):
    """The shipped T-shirt written as DXF and read back through a garment file builds the same cloth."""
    import sys

    sys.path.insert(0, str(GARMENTS))
    from make_dxf import GARMENTS as NAMES, main

    written = main(tmp_path)
    assert len(written) == 2 * len(NAMES) + 2  # and the T-shirt as pattern CAD exports it
    direct = build_garment(load_garment(GARMENTS / "tshirt.toml"), body)
    via_dxf = build_garment(load_garment(tmp_path / "tshirt_dxf.toml"), body)
    assert via_dxf.piece_names == direct.piece_names
    np.testing.assert_array_equal(via_dxf.data.triangles, direct.data.triangles)
    np.testing.assert_array_equal(via_dxf.seam_pairs, direct.seam_pairs)
    np.testing.assert_allclose(via_dxf.data.positions, direct.data.positions, atol=1e-9)
    # the shipped DXF files are the ones make_dxf.py writes
    for name in NAMES:
        assert load_garment(GARMENTS / f"{name}_dxf.toml").spacing == load_garment(GARMENTS / f"{name}.toml").spacing


def test_the_tshirt_exported_as_graded_aama_reads_back_at_either_size_and_builds_with_the_same_seams(tmp_path, body):
    """The shipped T-shirt written as pattern CAD exports it (AAMA blocks, inches, no $INSUNITS, sizes S and M)
    and read through its DXF garment file: the same pieces (curves sampled within 0.2 mm), the same seams."""
    spec = load_garment(GARMENTS / "tshirt.toml")
    small = [p.transformed(scale=0.95) for p in spec.pieces]
    write_aama_dxf({"S": small, "M": spec.pieces}, tmp_path / "tshirt_aama.dxf", units="in", sample_size="M")
    text = (GARMENTS / "tshirt_dxf.toml").read_text(encoding="utf-8")
    assert 'dxf = "tshirt.dxf"' in text
    (tmp_path / "m.toml").write_text(text.replace('dxf = "tshirt.dxf"', 'dxf = "tshirt_aama.dxf"'))
    (tmp_path / "s.toml").write_text(text.replace('dxf = "tshirt.dxf"', 'dxf = "tshirt_aama.dxf"\ndxf_size = "S"'))
    for path, pieces in ((tmp_path / "m.toml", spec.pieces), (tmp_path / "s.toml", small)):
        read = load_garment(path)
        assert [p.name for p in read.pieces] == [p.name for p in pieces]
        for p, q in zip(pieces, read.pieces):
            assert q.corner_names == p.corner_names
            np.testing.assert_allclose(q.corners, p.corners, rtol=0, atol=1e-12)
            assert q.area() == pytest.approx(p.area(), rel=2e-4) and q.perimeter() == pytest.approx(p.perimeter(),
                                                                                                  rel=2e-4)
    direct, via_aama = build_garment(spec, body), build_garment(load_garment(tmp_path / "m.toml"), body)
    assert via_aama.piece_names == direct.piece_names
    np.testing.assert_array_equal(np.bincount(via_aama.seam_of_pair), np.bincount(direct.seam_of_pair))


@pytest.mark.slow
def test_skirt_sews_onto_the_mannequin(body):
    """The shipped skirt (at 3 cm spacing to keep the test short): every seam closes, no particle ends inside the
    body, and the per-piece area error between pattern and drape stays under 3 % (Fan et al. 1998 reports 0.3-2.6 %)."""
    spec = load_garment(GARMENTS / "skirt.toml")
    spec.spacing = 0.03
    g = build_garment(spec, body)
    scene = tc.Scene(g, integrator="implicit", dt=1 / 120, integrator_options={"cg_tolerance": 1e-2},
                     air_damping=1.0, colliders=[{"type": "mesh", "path": "mannequin", "thickness": 0.004,
                                                  "friction": 0.4}],
                     stretch_limit=dict(max_strain=0.1, iterations=20), sewing=dict(energy_tolerance=0.05))
    summary = scene.run(120, progress=False)  # 2 s: sewing (gravity off) then draping
    assert scene.controller("sewing").joined and not scene.controller("sewing").gave_up, summary.format()
    q = garment_quality(scene)
    assert q.penetrations == 0
    assert len(q.pieces) == 2
    for piece in q.pieces:
        assert piece.area_error < 0.03
        assert piece.boundary_error < 0.03
    # draped under gravity after the join, the skirt stays on the body: its waistband rests between the hips and
    # a little above the waist (it would fall to the floor if the drape or the body failed). Sewing pulls the band
    # up the body (friction is off while sewing); friction then holds it there and it slides down slowly: 4.9 cm
    # above the waist at 2 s, 4.1 cm at 6 s
    top = scene.positions()[:, 1].max()
    assert body.landmarks["hips"] < top < body.landmarks["waist"] + 0.06


def test_garment_file_with_an_open_dxf_outline_names_the_layer(tmp_path):
    import ezdxf

    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = 5  # cm
    msp = doc.modelspace()
    for a, b in (((0, 0), (20, 0)), ((20, 0), (20, 20)), ((20, 20), (0, 20))):  # the left side is missing
        msp.add_line(a, b, dxfattribs={"layer": "A"})
    doc.saveas(tmp_path / "open.dxf")
    text = GOOD.replace('units = "cm"', 'units = "cm"\ndxf = "open.dxf"').replace(
        'outline = [{at = [0, 0], name = "bl"}, {at = [20, 0], name = "br"}, {at = [20, 20], name = "tr"},\n'
        '           {at = [0, 20], name = "tl"}]\n', "")
    assert "outline" not in text
    with pytest.raises(PatternError) as err:
        load_garment(_garment_file(tmp_path, text))
    msg = str(err.value)
    assert "open.dxf" in msg and "layer 'A'" in msg and "do not close" in msg and "\n" not in msg, msg


def test_seam_errors_name_the_seam():
    long_b = PatternPiece.from_polygon("B", [[0, 0], [0.2, 0], [0.2, 0.3], [0, 0.3]],
                                       corner_names=["bl", "br", "tr", "tl"])
    spec = two_squares()
    spec.pieces[1] = long_b  # B's left side is 0.3 m against A's 0.2 m: 33 % apart
    with pytest.raises(PatternError, match=r"seam 'middle' cannot pair: .*20\.0 cm.*30\.0 cm"):
        build_garment(spec)
    with pytest.raises(PatternError, match=r"seam 'middle'.*'nowhere'"):
        build_garment(two_squares("bl", "nowhere"))


def test_mesh_quality_counts_slivers_and_inverted_triangles():
    from taichi_cloth.garment.mesh import check_quality, mesh_quality

    uv = np.array([[0, 0], [1, 0], [0, 1], [0.5, 0.01]], dtype=float)
    q = mesh_quality(uv, np.array([[0, 1, 2], [0, 1, 3], [0, 2, 1]]))  # good, a sliver, clockwise
    assert (q.n_triangles, q.inverted, q.slivers) == (3, 1, 1)
    assert q.min_angle == pytest.approx(np.degrees(np.arctan2(0.01, 0.5)), rel=1e-6)
    with pytest.raises(PatternError, match="piece 'p'.*inverted"):
        check_quality("p", q)


def test_multilevel_meshing_keeps_seams_paired_on_every_level():
    spec = two_squares(spacing=0.02)
    spec.levels = 3
    g = build_garment(spec)  # the finest level is simulated, at the garment's spacing
    assert len(g.seam_pairs) == 11
    for mesh in g.meshes:
        assert len(mesh.hierarchy.levels) == 3 and mesh.level == 2
        counts = [len(lev.boundary_segments[1]) for lev in mesh.hierarchy.levels]
        assert counts == [6, 6, 11]  # 5 intervals at 0.04 m, then 10 at 0.02 m (4-8: 2**(L // 2))


@pytest.mark.slow
def test_fixed_points_hold_while_the_rest_falls():
    from taichi_cloth.garment.garment import FixedPoint

    spec = two_squares()
    spec.fixed = [FixedPoint("A", "tl")]
    g = build_garment(spec)
    held = g.data.positions[g.fixed].copy()
    np.testing.assert_allclose(held, [[0.0, 0.2, 0.0]], atol=1e-12)
    spec.fixed = [FixedPoint("A", (0.001, 0.199))]  # a point in the pattern picks its nearest particle
    assert build_garment(spec).fixed.tolist() == g.fixed.tolist()
    scene = tc.Scene(g, integrator="implicit", dt=1 / 240, sewing=dict(gravity=True))
    sewing = scene.controller("sewing")
    com0 = (g.data.mass * g.data.positions[:, 1]).sum() / g.data.mass.sum()
    coms = []
    for _ in range(6):
        scene.run(5, progress=False)
        x = scene.positions()
        np.testing.assert_allclose(x[sewing.current_of[g.fixed]], held, atol=1e-6)
        coms.append((scene.model.data.mass * x[:, 1]).sum() / scene.model.data.mass.sum())
    # everything else sagged under gravity (on while sewing here): by 0.14 m at frame 20; then the closing seams
    # swing the hanging square up (a run at a tenth of the step does the same)
    assert min(coms) < com0 - 0.1, coms


def test_recording_has_the_strain_map_seam_gap_and_merge(tmp_path):
    g = build_garment(two_squares())
    scene = tc.Scene(g, integrator="implicit", dt=1 / 240, gravity=(0, 0, 0))
    rec = tc.Recorder(tmp_path / "sew.rrd")
    summary = scene.run(45, recorder=rec, progress=False)
    rec.close()
    assert scene.controller("sewing").joined and any("seams closed" in e for e in summary.events)
    got = rows_by_entity(tmp_path / "sew.rrd")
    static, frames, cols = got["/cloth/mesh"]
    assert static == 0  # the topology is on the timeline: it changes at the merge
    assert any("vertex_colors" in c.lower() or "color" in c.lower() for c in cols)
    assert len(got["/metrics/cloth/seam_gap"][1]) == 46  # frame 0 and every frame after
    assert len(got["/cloth/events"][1]) == 1  # the merge
