"""GarmentCode specifications read as garments (taichi_cloth.garment.garmentcode): edges and their curvatures,
the panels' 3D frames as placements, stitches as seams with their pick direction and gathers, and the refusals,
on specifications written in the test in pygarment's format; and the shipped ones (demos/garments/*.json: trousers,
a dress, a flared skirt) sew and rest on the mannequin."""
import json
import math
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from taichi_cloth.body import Body
from taichi_cloth.errors import PatternError
from taichi_cloth.garment.garment import FreePlacement, build_garment
from taichi_cloth.garment.garmentcode import GATHER_LIMIT, read_specification
from taichi_cloth.garment.garmentfile import load_garment
from taichi_cloth.material import material
from taichi_cloth.scenefile import load_scene

#: a half circle skirt [cm]: waist radius 15 (a 94 cm waist over the two halves), 40 cm long, front and back
WAIST, LENGTH = 15.0, 40.0


def sector(front: bool) -> dict:
    """A half-annulus panel centred at (0, 0) [cm]: the waist arc on top, the hem arc below, as GarmentCode draws a
    circle skirt's panel (v0, v3 the waist's ends; v1, v2 the hem's). The back runs the other way round."""
    r0, r1 = WAIST, WAIST + LENGTH
    v = [[-r0, 0], [-r1, 0], [r1, 0], [r0, 0]]
    edges = [{"endpoints": [0, 1]}, {"endpoints": [1, 2], "curvature": {"type": "circle", "params": [r1, 0, 1]}},
             {"endpoints": [2, 3]}, {"endpoints": [3, 0], "curvature": {"type": "circle", "params": [r0, 0, 0]}}]
    if not front:  # mirrored loop: v0, v3, v2, v1 order
        v = [[-r0, 0], [r0, 0], [r1, 0], [-r1, 0]]
        edges = [{"endpoints": [0, 1], "curvature": {"type": "circle", "params": [r0, 0, 1]}},
                 {"endpoints": [1, 2]},
                 {"endpoints": [2, 3], "curvature": {"type": "circle", "params": [r1, 0, 0]}},
                 {"endpoints": [3, 0]}]
    return {"translation": [0.0, 104.0, 18.0 if front else -14.0], "rotation": [0.0, 0.0, 0.0],
            "vertices": v, "edges": edges}


def skirt(**changes) -> dict:
    spec = {"pattern": {"panels": {"front": sector(True), "back": sector(False)},
                        "stitches": [[{"panel": "front", "edge": 0}, {"panel": "back", "edge": 3}],
                                     [{"panel": "front", "edge": 2}, {"panel": "back", "edge": 1}]],
                        "panel_order": ["front", "back"]},
            "properties": {"curvature_coords": "relative", "units_in_meter": 100}}
    spec.update(changes)
    return spec


def write(tmp_path, spec, name="specification.json"):
    path = tmp_path / name
    path.write_text(json.dumps(spec))
    return path


def test_a_specification_s_panels_are_pieces_with_their_curves_in_metres(tmp_path):
    path = write(tmp_path, skirt())
    doc = read_specification(path)  # the garment file it reads as: in the specification's centimetres
    assert doc["units"] == "cm" and doc["spacing"] == 2.0 and doc["pieces"][0]["placement"]["origin"] == [0, 104, 18]
    g = load_garment(path)
    assert g.name == tmp_path.name and [p.name for p in g.pieces] == ["front", "back"]
    front = g.pieces[0]
    assert front.corner_names == ["v0", "v1", "v2", "v3"] and [s.kind for s in front.segments] == ["line", "arc",
                                                                                                     "line", "arc"]
    # the half annulus: half of pi (r1^2 - r0^2), its hem and waist half circles (the arcs bulge downwards)
    assert front.area() == pytest.approx(0.5 * math.pi * (0.55 ** 2 - 0.15 ** 2), rel=1e-12)
    assert front.segments[1].length() == pytest.approx(math.pi * 0.55, rel=1e-12)
    assert front.segments[3].length() == pytest.approx(math.pi * 0.15, rel=1e-12)
    assert front.outline()[:, 1].min() == pytest.approx(-0.55, abs=1e-4)  # the hem's lowest point, below centre
    # placed where GarmentCode puts it: vertex (0, 0) at the translation [m], flat in the xy plane
    assert g.placements["front"] == FreePlacement((0.0, 1.04, 0.18), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0))


def test_bezier_edges_follow_pygarment_s_relative_control_points(tmp_path):
    spec = skirt()
    edges = spec["pattern"]["panels"]["front"]["edges"]
    edges[0]["curvature"] = {"type": "quadratic", "params": [[0.5, 0.25]]}
    edges[2]["curvature"] = {"type": "cubic", "params": [[0.25, -0.1], [0.75, 0.1]]}
    front = load_garment(write(tmp_path, spec)).pieces[0]
    start, end = np.array([-0.15, 0.0]), np.array([-0.55, 0.0])
    e = end - start
    control = start + 0.5 * e + 0.25 * np.array([-e[1], e[0]])  # start + t e + k perp(e)
    np.testing.assert_allclose(front.segments[0].points, [start, control, end], atol=1e-15)
    assert front.segments[0].kind == "bspline" and front.segments[0].degree == 2
    assert front.segments[2].degree == 3 and len(front.segments[2].points) == 4
    # a quadratic Bezier's midpoint lies half way between the chord's midpoint and its control point
    mid = 0.5 * (0.5 * (start + end) + control)
    assert np.min(np.linalg.norm(front.segments[0].sample(1e-6) - mid, axis=1)) < 1e-5


def test_stitches_pair_the_ends_that_meet_and_gather_up_to_the_limit(tmp_path):
    g = load_garment(write(tmp_path, skirt()))
    left, right = g.seams
    # front v0 -> v1 (the left side, waist to hem) meets back v0 -> v3: the back's edge 3 runs v3 -> v0
    assert (left.a.piece, left.a.start, left.a.end) == ("front", "v0", "v1")
    assert (left.b.piece, left.b.start, left.b.end) == ("back", "v0", "v3")
    assert (right.b.start, right.b.end) == ("v2", "v1")
    # a stitch 20 % gathered gets a tolerance above its mismatch; one past the limit is refused
    spec = skirt()
    spec["pattern"]["panels"]["back"]["vertices"][3] = [-WAIST - 0.8 * LENGTH, 0]
    spec["pattern"]["panels"]["back"]["vertices"][2] = [WAIST + 0.8 * LENGTH, 0]
    spec["pattern"]["panels"]["back"]["edges"][2]["curvature"]["params"][0] = WAIST + 0.8 * LENGTH
    gathered = load_garment(write(tmp_path, spec)).seams[0]
    assert 0.2 < gathered.tolerance <= GATHER_LIMIT
    spec["pattern"]["panels"]["back"]["vertices"][3] = [-WAIST - 0.7 * LENGTH, 0]
    spec["pattern"]["panels"]["back"]["vertices"][2] = [WAIST + 0.7 * LENGTH, 0]
    spec["pattern"]["panels"]["back"]["edges"][2]["curvature"]["params"][0] = WAIST + 0.7 * LENGTH
    with pytest.raises(PatternError, match=r"stitch 0: its edges are 40.0 and 28.0 cm long, 30 % apart: more than "
                                           r"the 25 % a seam gathers"):
        load_garment(write(tmp_path, spec))


def test_an_unsewn_edge_shorter_than_a_quarter_spacing_is_merged_and_the_piece_meshes(tmp_path):
    """A 1 mm edge at the front's hem corner v1 (GarmentCode outlines have sub-millimetre ones), which meshes into
    a sliver at 2 cm: v1 is no seam's end, so the short edge is merged into the hem, which becomes a polyline from
    v4 through v1, the piece's area kept; where both its corners are seams' ends it stays."""
    spec = skirt()
    front = spec["pattern"]["panels"]["front"]
    front["vertices"].append([-WAIST - LENGTH + 0.1, 0])  # v4, on the side 1 mm before the hem corner v1
    front["edges"][0:1] = [{"endpoints": [0, 4]}, {"endpoints": [4, 1]}]
    spec["pattern"]["stitches"][1][0]["edge"] = 3  # the front's other side is edge 3 now
    path = write(tmp_path, spec)
    outline = read_specification(path)["pieces"][0]["outline"]
    assert [c["name"] for c in outline] == ["v0", "v4", "v2", "v3"] and "polyline" in outline[1]
    # the polyline's chords cut the hem's arc by at most 1e-4 m each: a parabolic segment of (2/3) sagitta x chord
    whole = 0.5 * math.pi * ((WAIST + LENGTH) ** 2 - WAIST ** 2) * 1e-4  # [m^2]
    assert 0 < whole - load_garment(path).pieces[0].area() <= 2 / 3 * 1e-4 * math.pi * (WAIST + LENGTH) * 1e-2
    assert build_garment(load_garment(path), Body.from_mannequin()).piece_names == ["front", "back"]
    # the hem sewn too (to the back's): v1 is a seam's end, the short edge stays
    spec["pattern"]["stitches"].append([{"panel": "front", "edge": 2}, {"panel": "back", "edge": 2}])
    names = [c["name"] for c in read_specification(write(tmp_path, spec))["pieces"][0]["outline"]]
    assert names == ["v0", "v4", "v1", "v2", "v3"]


@pytest.mark.parametrize("edit, words", [
    (lambda s: s["pattern"]["panels"]["front"]["edges"][1]["curvature"].update(type="spiral"),
     "panel 'front' edge 1: unknown curvature type 'spiral'"),
    (lambda s: s["pattern"]["panels"]["front"]["edges"][1].update(endpoints=[1, 3]),
     "panel 'front': edge 1 ends at vertex 3 but the next edge starts at 2"),
    (lambda s: s["pattern"]["panels"]["front"]["edges"][3]["curvature"].update(params=[5.0, 0, 0]),
     "panel 'front' edge 3: a circle of radius 5 cannot join ends 30 apart"),
    (lambda s: s["pattern"]["stitches"][0][1].update(edge=7), "stitch 0: no edge 7 on a panel 'back'"),
    (lambda s: s["properties"].update(curvature_coords="absolute"), "only 'relative'"),
    (lambda s: s.pop("pattern"), "the file has no 'pattern'"),
    (lambda s: s["pattern"]["panels"]["back"]["edges"][0].update(curvature=3), "curvature must be a table"),
])
def test_a_broken_specification_is_refused_in_one_line_naming_where(tmp_path, edit, words):
    spec = skirt()
    edit(spec)
    with pytest.raises(PatternError) as info:
        load_garment(write(tmp_path, spec))
    assert words in str(info.value) and "specification.json" in str(info.value) and "\n" not in str(info.value)
    (tmp_path / "junk.json").write_text("{not json")
    with pytest.raises(PatternError, match="junk.json: not a readable GarmentCode specification"):
        load_garment(tmp_path / "junk.json")


def test_load_garment_reads_a_specification_and_the_skirt_builds_with_its_seams_planned(tmp_path):
    g = load_garment(write(tmp_path, skirt(), "half_circle.json"))
    assert g.name == "half_circle" and g.material == material("cotton") and g.spacing == pytest.approx(0.02, rel=1e-12)
    built = build_garment(g, Body.from_mannequin())
    assert built.piece_names == ["front", "back"]
    counts = np.bincount(built.seam_of_pair)
    assert len(counts) == 2 and counts[0] == counts[1] == round(0.40 / 0.02) + 1  # 40 cm sides at 2 cm


DEMOS = Path(__file__).resolve().parents[1] / "demos"
#: the GarmentCode garments shipped in demos/garments, with their scenes in demos/scenes
SHIPPED = ("trousers", "dress", "flared_skirt")


def test_the_shipped_specifications_are_what_make_garmentcode_writes(tmp_path):
    """demos/garments/*.json are generated (make_garmentcode.py): the files match the script, so an edit to one is
    not lost at the next run of the other."""
    sys.path.insert(0, str(DEMOS / "garments"))
    try:
        import make_garmentcode
    finally:
        sys.path.pop(0)
    for name in SHIPPED:
        assert json.loads((DEMOS / "garments" / f"{name}.json").read_text()) == make_garmentcode.GARMENTS[name]()


@pytest.mark.slow
@pytest.mark.parametrize("name", SHIPPED)
def test_a_shipped_garmentcode_garment_sews_and_rests_on_the_mannequin_at_2_cm(name):
    """demos/scenes/sew_NAME.toml as shipped (2 cm, cotton, the implicit step): every seam joined, at rest by the
    scene's criterion within 5 s of simulated time, no particle inside the body, the stretch limit and the body
    agreeing, and no two of the garment's triangles crossing at the end."""
    config = tomllib.loads((DEMOS / "scenes" / f"sew_{name}.toml").read_text(encoding="utf-8"))
    config["output"] = {"record": False}
    scene = load_scene(config, frames=300, base_dir=DEMOS / "scenes").scene
    summary = scene.run(300, progress=False, until_rest=True)
    text = summary.format()
    assert scene.controller("sewing").joined and summary.stopped_at_rest and scene.state.t <= 5.0, text
    assert "stretch limit and colliders agree" in text and "no particle inside a collider" in text, text
    assert "self-intersection: 0 intersecting triangle pairs now" in text, text
