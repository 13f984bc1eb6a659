"""2D pattern pieces (taichi_cloth.garment.pattern) and their DXF import/export (taichi_cloth.garment.dxf)."""
import dataclasses
import math

import ezdxf
import numpy as np
import pytest

from taichi_cloth.errors import PatternError
from taichi_cloth.garment.dxf import dxf_units, read_dxf, write_aama_dxf, write_dxf
from taichi_cloth.garment.garmentfile import load_garment
from taichi_cloth.garment.pattern import (
    PatternPiece,
    Segment,
    bspline_eval,
    open_uniform_knots,
    periodic_knots,
    unit_scale,
)


def polyline_distance(q: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance (n,) of points q (n, 2) to the polyline poly (m, 2)."""
    a, b = poly[:-1][None], poly[1:][None]
    ab = b - a
    s = np.clip(np.sum((q[:, None] - a) * ab, axis=2) / np.maximum(np.sum(ab * ab, axis=2), 1e-300), 0, 1)
    return np.linalg.norm(q[:, None] - (a + s[..., None] * ab), axis=2).min(axis=1)


def circle_piece(r: float, name: str = "disk") -> PatternPiece:
    """Two bulge-1 half circles (counter-clockwise) of radius r centred at the origin."""
    return PatternPiece(name, [Segment.arc((r, 0), (-r, 0), 1.0), Segment.arc((-r, 0), (r, 0), 1.0)])


CONTROL = np.array([[0.0, 0.0], [0.1, 0.3], [0.4, 0.35], [0.6, 0.05], [0.9, 0.2], [1.0, 0.0]])


# ---------------------------------------------------------------------------------------------- B-splines

def test_degree_one_spline_is_its_control_polygon():
    t = np.linspace(0, 1, 501)
    curve = bspline_eval(CONTROL, 1, t=t)
    assert np.abs(polyline_distance(curve, CONTROL)).max() < 1e-14
    # open-uniform degree-1 knots put control point i at t = i / (k - 1)
    at_knots = bspline_eval(CONTROL, 1, t=np.linspace(0, 1, len(CONTROL)))
    np.testing.assert_allclose(at_knots, CONTROL, atol=1e-15)


def test_clamped_cubic_on_a_line_is_that_line_and_interpolates_its_ends():
    s = np.array([0.0, 0.1, 0.45, 0.5, 0.8, 1.0])
    ctrl = np.array([0.2, -0.1]) + s[:, None] * np.array([3.0, 2.0])
    curve = bspline_eval(ctrl, 3, t=np.linspace(0, 1, 200))
    d = curve - ctrl[0]
    assert np.abs(d[:, 0] * 2.0 - d[:, 1] * 3.0).max() < 1e-13  # on the line
    curve = bspline_eval(CONTROL, 3, t=[0.0, 1.0])
    np.testing.assert_array_equal(curve[0], CONTROL[0])
    np.testing.assert_allclose(curve[1], CONTROL[-1], atol=1e-15)


@pytest.mark.parametrize("degree", [1, 2, 3, 5])
def test_partition_of_unity(degree):
    k = 7
    rng = np.random.default_rng(degree)
    knots = np.sort(np.concatenate([np.zeros(degree + 1), rng.random(k - degree - 1), np.ones(degree + 1)]))
    t = np.linspace(0, 1, 301)
    basis = np.stack([bspline_eval(np.outer(np.eye(k)[i], [1.0, 0.0]), degree, knots=knots, t=t)[:, 0]
                      for i in range(k)])  # (k, n): basis function i
    np.testing.assert_allclose(basis.sum(axis=0), 1.0, atol=1e-13)
    assert basis.min() >= -1e-15


def test_rational_spline_quarter_circle():
    # a quadratic NURBS with weights (1, sqrt(2)/2, 1) is an exact quarter circle
    ctrl = np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    p = bspline_eval(ctrl, 2, weights=[1.0, math.sqrt(0.5), 1.0], t=np.linspace(0, 1, 50))
    np.testing.assert_allclose(np.hypot(p[:, 0], p[:, 1]), 1.0, atol=1e-14)
    seg = Segment("bspline", ctrl, degree=2, weights=(1.0, math.sqrt(0.5), 1.0))
    assert seg.length() == pytest.approx(math.pi / 2, rel=1e-9)


def test_periodic_spline_closes_with_c2_continuity():
    m, p = 6, 3
    pts = np.array([[math.cos(a), 0.6 * math.sin(a)] for a in np.linspace(0, 2 * math.pi, m, endpoint=False)])
    pts[2] += 0.3  # not symmetric, so equal derivatives are not a coincidence
    ctrl = np.vstack([pts, pts[:p]])
    knots = periodic_knots(m, p)
    ends = bspline_eval(ctrl, p, knots=knots, t=[0.0, 1.0])
    np.testing.assert_allclose(ends[0], ends[1], atol=1e-14)
    h = 1e-3
    left = bspline_eval(ctrl, p, knots=knots, t=[1 - 2 * h, 1 - h, 1.0])
    right = bspline_eval(ctrl, p, knots=knots, t=[0.0, h, 2 * h])
    d1l, d1r = (left[2] - left[1]) / h, (right[1] - right[0]) / h
    d2l, d2r = (left[2] - 2 * left[1] + left[0]) / h**2, (right[2] - 2 * right[1] + right[0]) / h**2
    # one-sided differences are O(h) off the true derivatives, the same amount either side
    np.testing.assert_allclose(d1l, d1r, atol=5 * h * np.abs(d2l).max())
    np.testing.assert_allclose(d2l, d2r, rtol=0.05, atol=0.05)
    assert np.linalg.norm(d2l) > 1.0  # a non-trivial curvature, so the comparison means something


def test_bspline_eval_validates_its_input():
    with pytest.raises(PatternError, match="at least 4 control points"):
        bspline_eval(CONTROL[:3], 3, t=[0.5])
    with pytest.raises(PatternError, match="non-decreasing"):
        bspline_eval(CONTROL, 1, knots=[0, 0, 0.5, 0.2, 0.6, 0.8, 1, 1], t=[0.5])
    with pytest.raises(PatternError, match="needs 8 knots"):
        bspline_eval(CONTROL, 1, knots=[0, 1], t=[0.5])
    with pytest.raises(PatternError, match="weights"):
        bspline_eval(CONTROL, 1, weights=[1, 1, 0, 1, 1, 1], t=[0.5])
    with pytest.raises(PatternError, match="degree"):
        bspline_eval(CONTROL, 0, t=[0.5])
    assert len(open_uniform_knots(6, 3)) == 10


# ----------------------------------------------------------------------------------------------- Segments

def test_circle_from_two_half_circle_arcs():
    r = 0.123
    piece = circle_piece(r)
    piece.validate()
    assert piece.area() == pytest.approx(math.pi * r * r, rel=1e-6)
    assert piece.perimeter() == pytest.approx(2 * math.pi * r, rel=1e-6)
    assert piece.orientation == 1
    assert piece.transformed(mirror=True).orientation == 1
    cw = PatternPiece("cw", [s.reversed() for s in reversed(piece.segments)])
    assert cw.orientation == -1 and cw.area() == pytest.approx(piece.area(), rel=1e-12)


@pytest.mark.parametrize("tol", [1e-3, 1e-4, 1e-6])
def test_sample_obeys_the_tolerance(tol):
    r = 0.2
    arc = Segment.arc((r, 0), (0, r), math.tan(math.pi / 8))  # quarter circle about the origin
    poly = arc.sample(tol)
    assert np.array_equal(poly[0], arc.start) and np.array_equal(poly[-1], arc.end)
    a = np.linspace(0, math.pi / 2, 2001)
    true = r * np.stack([np.cos(a), np.sin(a)], axis=1)
    assert polyline_distance(true, poly).max() <= tol
    assert polyline_distance(true, arc.sample(tol * 100)).max() > tol  # the check has teeth

    spline = Segment("bspline", CONTROL)
    poly = spline.sample(tol)
    true = bspline_eval(CONTROL, 3, t=np.linspace(0, 1, 4001))
    assert polyline_distance(true, poly).max() <= tol
    assert np.array_equal(poly[0], CONTROL[0]) and np.array_equal(poly[-1], CONTROL[-1])


def test_reversed_is_the_same_curve():
    knots = (0.0, 0.0, 0.0, 0.0, 0.3, 0.4, 1.0, 1.0, 1.0, 1.0)
    segs = [Segment("bspline", CONTROL), Segment("bspline", CONTROL, knots=knots),
            Segment("bspline", CONTROL, degree=2, weights=(1, 2, 0.5, 1, 3, 1)),
            Segment.arc((0, 0), (1, 0.5), -0.7), Segment("polyline", CONTROL), Segment.line((0, 0), (1, 2))]
    for s in segs:
        r = s.reversed()
        np.testing.assert_array_equal(r.start, s.end)
        np.testing.assert_array_equal(r.end, s.start)
        fwd, back = s.sample(1e-5), r.sample(1e-5)
        assert polyline_distance(back, fwd).max() < 2e-5
        assert polyline_distance(fwd, back).max() < 2e-5
        assert r.length(1e-9) == pytest.approx(s.length(1e-9), rel=1e-9)
        rr = r.reversed()
        assert rr.kind == s.kind and rr.bulge == s.bulge and rr.weights == s.weights
        np.testing.assert_array_equal(rr.points, s.points)
        if s.knots is not None:
            np.testing.assert_allclose(rr.knots, s.knots, atol=1e-15)


def test_segment_transforms():
    s = Segment.arc((0, 0), (1, 0), 0.5)
    m = s.mirrored_x()
    assert m.bulge == -0.5 and np.array_equal(m.points, [[0, 0], [-1, 0]])
    assert s.scaled(2).length() == pytest.approx(2 * s.length())
    np.testing.assert_array_equal(s.translated((1, 2)).start, [1, 2])


# --------------------------------------------------------------------------------------- pattern pieces

FRONT = [
    {"at": [0, 0], "name": "hem_left", "bspline": [[10, -3], [20, 3]]},
    {"at": [30, 0], "name": "hem_right", "bulge": 0.3},
    {"at": [30, 50], "name": "shoulder", "polyline": [[15, 55]]},
    {"at": [0, 50]},
]


def test_from_corners_in_cm():
    piece = PatternPiece.from_corners("front", FRONT, units="cm")
    assert [s.kind for s in piece.segments] == ["bspline", "arc", "polyline", "line"]
    assert piece.corner_names == ["hem_left", "hem_right", "shoulder", "c3"]
    np.testing.assert_allclose(piece.corners, [[0, 0], [0.3, 0], [0.3, 0.5], [0, 0.5]], atol=1e-15)
    assert piece.corner_index("shoulder") == 2 and piece.corner_index(-1) == 3
    assert piece.segments[0].degree == 3
    assert piece.orientation == 1
    # area check against the densely sampled polygon (shoelace)
    x, y = piece.outline(1e-7).T
    assert piece.area() == pytest.approx(0.5 * abs(x @ np.roll(y, -1) - y @ np.roll(x, -1)), rel=1e-6)
    polys = piece.polylines()
    for i, p in enumerate(polys):
        np.testing.assert_array_equal(p[-1], polys[(i + 1) % len(polys)][0])
    low = PatternPiece.from_corners("low", [{"at": [0, 0], "bspline": [[1, 1]]}, {"at": [2, 0]}, {"at": [1, -1]}])
    assert low.segments[0].degree == 2  # lowered: only three control points


@pytest.mark.parametrize("corners, units, words", [
    ([{"at": [0, 0], "bluge": 1}, {"at": [1, 0]}, {"at": [0, 1]}], "m", ["front", "corner 0", "bluge"]),
    ([{"at": [0, 0]}, {"at": [1, 0], "bulge": 1, "polyline": []}, {"at": [0, 1]}], "m", ["front", "corner 1"]),
    ([{"at": [0, 0]}, {"at": [1, 0]}, {"at": [0, 1]}], "furlong", ["furlong", "mm"]),
    ([{"at": [0, 0]}, {"name": "x"}, {"at": [0, 1]}], "m", ["front", "corner 1", "at"]),
])
def test_from_corners_errors(corners, units, words):
    with pytest.raises(PatternError) as info:
        PatternPiece.from_corners("front", corners, units=units)
    for w in words:
        assert w in str(info.value)


def test_unknown_corner_name_lists_the_valid_ones():
    piece = PatternPiece.from_corners("front", FRONT, units="cm")
    with pytest.raises(PatternError, match="armpit.*hem_left, hem_right, shoulder, c3"):
        piece.corner_index("armpit")
    with pytest.raises(PatternError, match="out of range"):
        piece.corner_index(4)
    with pytest.raises(PatternError, match="parsec"):
        unit_scale("parsec")


def test_validate_errors_name_the_piece():
    square = [[0, 0], [1, 0], [1, 1], [0, 1]]
    with pytest.raises(PatternError, match=r"'bowtie'.*intersects itself near \(0\.5, 0\.5\)"):
        PatternPiece.from_polygon("bowtie", [[0, 0], [1, 1], [1, 0], [0, 1]])
    with pytest.raises(PatternError, match="'dup'.*duplicate corner name 'a'"):
        PatternPiece.from_polygon("dup", square, corner_names=["a", "b", "a", "c"])
    with pytest.raises(PatternError, match="'flat'.*zero area"):
        PatternPiece.from_polygon("flat", [[0, 0], [1, 0], [2, 0]])
    gappy = PatternPiece("gappy", [Segment.line((0, 0), (1, 0)), Segment.line((1, 0), (1, 1)),
                                   Segment.line((1, 1.002), (0, 0))])
    with pytest.raises(PatternError, match=r"'gappy'.*open.*segment 1.*2 mm"):
        gappy.validate()
    nan = PatternPiece("nan", [Segment.line((0, 0), (1, np.nan)), Segment.line((1, np.nan), (0, 0))])
    with pytest.raises(PatternError, match="'nan'.*non-finite"):
        nan.validate()
    with pytest.raises(PatternError, match="'empty'.*no segments"):
        PatternPiece("empty", []).validate()


def test_closed_bspline_piece_and_transforms():
    ctrl = [[0, 0], [40, 0], [45, 30], [20, 50], [-5, 30]]
    piece = PatternPiece.from_bspline("round", ctrl, units="cm")
    assert piece.n_corners == 1 and piece.corner_names == ["c0"]
    seg = piece.segments[0]
    np.testing.assert_allclose(seg.start, seg.end, atol=1e-15)
    x, y = piece.outline(1e-7).T
    assert piece.area() == pytest.approx(0.5 * abs(x @ np.roll(y, -1) - y @ np.roll(x, -1)), rel=1e-6)

    front = PatternPiece.from_corners("front", FRONT, units="cm")
    back = front.transformed(scale=2.0, offset=(1.0, 0.0), mirror=True, name="back")
    assert back.name == "back" and back.orientation == front.orientation
    assert back.area() == pytest.approx(4 * front.area(), rel=1e-12)
    assert back.perimeter() == pytest.approx(2 * front.perimeter(), rel=1e-7)
    for name in front.corner_names:  # names travel with their corners
        p = front.corners[front.corner_index(name)]
        np.testing.assert_allclose(back.corners[back.corner_index(name)], [1 - 2 * p[0], 2 * p[1]], atol=1e-15)
    back.validate()


# ---------------------------------------------------------------------------------------------------- DXF

def example_pieces() -> list:
    poly = PatternPiece.from_polygon("sleeve", [[0, 0], [40, 0], [35, 60], [5, 60]], units="cm",
                                     corner_names=["cuff_l", "cuff_r", "cap_r", "cap_l"])
    front = PatternPiece.from_corners("front", FRONT, units="cm")
    rnd = PatternPiece.from_bspline("patch", [[0, 0], [0.3, 0], [0.35, 0.2], [0.1, 0.3]])
    return [poly, front, rnd, circle_piece(0.05, "button")]


@pytest.mark.parametrize("units", ["mm", "cm", "in"])
def test_dxf_round_trip(tmp_path, units):
    pieces = example_pieces()
    path = write_dxf(pieces, tmp_path / "pattern.dxf", units=units)
    assert ezdxf.readfile(path).units == {"mm": 4, "cm": 5, "in": 1}[units]
    back = read_dxf(path)
    assert [p.name for p in back] == [p.name for p in pieces]
    for p, q in zip(pieces, back):
        assert q.corner_names == p.corner_names
        assert [s.kind for s in q.segments] == [s.kind for s in p.segments]
        np.testing.assert_allclose(q.corners, p.corners, rtol=0, atol=1e-9)
        for a, b in zip(p.polylines(), q.polylines()):
            assert a.shape == b.shape
            np.testing.assert_allclose(b, a, rtol=0, atol=1e-7)
        assert q.area() == pytest.approx(p.area(), rel=1e-12)
    # the file's units are honoured: read as metres, the cm file is 100x too big
    if units == "cm":
        big = read_dxf(path, units="m")
        np.testing.assert_allclose(big[0].corners, 100 * pieces[0].corners, rtol=1e-12)


def test_dxf_chains_shuffled_reversed_lines(tmp_path):
    rng = np.random.default_rng(3)
    a = np.linspace(0, 2 * math.pi, 13)[:-1]
    pts = np.stack([30 * np.cos(a) + 50, 20 * np.sin(a)], axis=1)  # mm
    edges = [(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
    doc = ezdxf.new("R2010")
    doc.units = 4
    msp = doc.modelspace()
    for i in rng.permutation(len(edges)):
        s, e = edges[i]
        if rng.random() < 0.5:
            s, e = e, s
        msp.add_line(tuple(s), tuple(e), dxfattribs={"layer": "yoke"})
    msp.add_text("not a corner", dxfattribs={"layer": "yoke", "insert": (50, 0)})
    msp.add_point((1, 1), dxfattribs={"layer": "yoke"})
    doc.saveas(tmp_path / "shuffled.dxf")
    (piece,) = read_dxf(tmp_path / "shuffled.dxf")
    assert piece.name == "yoke" and piece.n_corners == 12
    x, y = pts.T * 1e-3
    expect = 0.5 * abs(x @ np.roll(y, -1) - y @ np.roll(x, -1))
    assert piece.area() == pytest.approx(expect, rel=1e-12)


def test_dxf_entities_and_corner_text(tmp_path):
    doc = ezdxf.new("R2010")
    doc.units = 5  # cm
    msp = doc.modelspace()
    msp.add_lwpolyline([(0, 0, 0), (10, 0, 0.5), (10, 10, 0), (0, 10, 0)], format="xyb", close=True,
                       dxfattribs={"layer": "lw"})
    msp.add_text("neck", dxfattribs={"layer": "lw", "insert": (10, 10)})
    msp.add_arc((0, 0), 5, 0, 180, dxfattribs={"layer": "half"})
    msp.add_line((-5, 0), (5, 0), dxfattribs={"layer": "half"})
    msp.add_circle((0, 0), 2, dxfattribs={"layer": "dot"})
    msp.add_circle((10, 0), 2, dxfattribs={"layer": "dot"})
    block = doc.blocks.new("POCKET")
    block.add_lwpolyline([(0, 0), (4, 0), (4, 2), (0, 2)], close=True, dxfattribs={"layer": "1"})
    block.add_line((1, 1), (3, 1), dxfattribs={"layer": "7"})  # AAMA grain line: not part of the outline
    msp.add_blockref("POCKET", (100, 0), dxfattribs={"rotation": 90})
    doc.saveas(tmp_path / "mixed.dxf")
    pieces = {p.name: p for p in read_dxf(tmp_path / "mixed.dxf")}
    assert sorted(pieces) == ["POCKET", "dot", "dot.1", "half", "lw"]
    lw = pieces["lw"]
    assert [s.kind for s in lw.segments] == ["line", "arc", "line", "line"]
    assert lw.corner_names == ["c0", "c1", "neck", "c3"]
    # the bulge-0.5 edge bulges outwards: add its circular segment, r = L (1 + b^2) / (4 b)
    sweep, r_arc = 4 * math.atan(0.5), 0.1 * (1 + 0.25) / (4 * 0.5)
    seg_area = 0.5 * r_arc**2 * (sweep - math.sin(sweep))
    assert lw.area() == pytest.approx(0.01 + seg_area, rel=1e-12)
    assert pieces["half"].area() == pytest.approx(math.pi * 0.05**2 / 2, rel=1e-12)
    assert pieces["dot.1"].area() == pytest.approx(math.pi * 0.02**2, rel=1e-12)
    np.testing.assert_allclose(pieces["POCKET"].corners, [[1, 0], [1, 0.04], [0.98, 0.04], [0.98, 0]], atol=1e-12)


def test_dxf_gap_and_bad_files(tmp_path):
    doc = ezdxf.new("R2010")
    doc.units = 4
    msp = doc.modelspace()
    for s, e in [((0, 0), (100, 0)), ((100, 0), (100, 100)), ((100, 100), (0, 100)), ((0, 100), (0, 5))]:
        msp.add_line(s, e, dxfattribs={"layer": "collar"})
    doc.saveas(tmp_path / "gap.dxf")
    with pytest.raises(PatternError) as info:
        read_dxf(tmp_path / "gap.dxf")
    msg = str(info.value)
    assert "gap.dxf" in msg and "'collar'" in msg and "(0, 5) mm" in msg and "5 mm" in msg

    with pytest.raises(PatternError, match="nowhere.dxf.*not found"):
        read_dxf(tmp_path / "nowhere.dxf")
    (tmp_path / "junk.dxf").write_text("this is not a DXF file\n")
    with pytest.raises(PatternError, match="junk.dxf.*not a readable DXF"):
        read_dxf(tmp_path / "junk.dxf")
    empty = ezdxf.new("R2010")
    empty.modelspace().add_point((0, 0))
    empty.saveas(tmp_path / "empty.dxf")
    with pytest.raises(PatternError, match="empty.dxf.*no pattern pieces"):
        read_dxf(tmp_path / "empty.dxf")
    with pytest.raises(PatternError, match="layer name"):
        write_dxf([PatternPiece.from_polygon("a/b", [[0, 0], [1, 0], [0, 1]])], tmp_path / "x.dxf")


# ------------------------------------------------------------------------------ AAMA / ASTM D6673 pattern files

#: a T-shirt front's outline [in] as pattern CAD draws it: hem, side, armhole, shoulder, neck, centre front
FRONT_IN = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 17.0], [7.5, 23.0], [3.0, 24.5], [0.0, 22.0]])


def aama_file(path, scale: float = 1.0, units_text: str | None = None, insunits: int = 0):
    """A pattern file laid out as AAMA / ASTM D6673 CAD exports it: no $INSUNITS (unless `insunits`), the piece a
    block (FRONT) inserted in model space, its outline on the boundary layer 1 in FRONT_IN x `scale` (file
    units), a grade-rule label "# n" at each turn point on layer 2 (two of them "# 0"), a grain line on layer 7,
    a piece-name annotation on layer 1 off the outline, the text "neck" on layer 1 at the neck corner, "side" on
    layer 2 at the armhole's; `units_text` a model-space TEXT ("Units: ENGLISH")."""
    doc = ezdxf.new("R2000" if insunits else "R12")  # R12, as pattern CAD writes it, has no $INSUNITS
    doc.header["$INSUNITS"] = insunits
    block = doc.blocks.new("FRONT")
    pts = FRONT_IN * scale
    block.add_polyline2d([tuple(p) for p in pts], close=True, dxfattribs={"layer": "1"})
    for k, (p, rule) in enumerate(zip(pts, [0, 0, 2, 5, 7, 9])):
        block.add_text(f"# {rule}", dxfattribs={"layer": "2", "insert": tuple(p)})
    block.add_line(tuple(pts[0] + [5 * scale, 5 * scale]), tuple(pts[0] + [5 * scale, 15 * scale]),
                   dxfattribs={"layer": "7"})
    block.add_text("Piece Name: FRONT", dxfattribs={"layer": "1", "insert": tuple(pts[0] + [2 * scale, 8 * scale])})
    block.add_text("neck", dxfattribs={"layer": "1", "insert": tuple(pts[4])})
    block.add_text("side", dxfattribs={"layer": "2", "insert": tuple(pts[2])})
    msp = doc.modelspace()
    msp.add_blockref("FRONT", (0, 0))
    if units_text:
        msp.add_text(units_text, dxfattribs={"layer": "0", "insert": (-20 * scale, -5 * scale)})
    doc.saveas(path)
    return path


@pytest.mark.parametrize("units_text, scale, metres", [("Units: ENGLISH", 1.0, 0.0254), ("UNITS: METRIC", 25.4, 0.001),
                                                       ("units = inch", 1.0, 0.0254)])
def test_an_aama_file_without_insunits_loads_at_its_true_size_from_its_units_text(tmp_path, units_text, scale, metres):
    path = aama_file(tmp_path / "front.dxf", scale, units_text)
    assert dxf_units(path) == {0.0254: "in", 0.001: "mm"}[metres]
    (front,) = read_dxf(path)
    assert front.name == "FRONT"
    np.testing.assert_allclose(front.corners, FRONT_IN * scale * metres, rtol=0, atol=1e-12)
    assert front.corners[:, 1].max() == pytest.approx(24.5 * 0.0254, abs=1e-12)  # 62.2 cm, a T-shirt front
    # names from boundary-layer texts only; grade-rule labels ("# 0" twice) are not names and do not clash
    assert front.corner_names == ["c0", "c1", "c2", "c3", "neck", "c5"]


def test_an_inch_file_without_any_unit_is_refused_in_one_line_and_loads_when_told(tmp_path):
    path = aama_file(tmp_path / "front.dxf")
    for read in (read_dxf, dxf_units):
        with pytest.raises(PatternError) as info:
            read(path)
        msg = str(info.value)
        assert "\n" not in msg and "front.dxf" in msg and "'FRONT'" in msg and "no unit" in msg, msg
        assert "2.65 cm across" in msg and "inches would make it 67 cm" in msg, msg
        assert "one of m, cm, mm, in (read_dxf's units=, a garment file's dxf_units)" in msg, msg
    (front,) = read_dxf(path, units="in")
    np.testing.assert_allclose(front.corners, FRONT_IN * 0.0254, rtol=0, atol=1e-12)
    with pytest.raises(PatternError, match="units must be one of m, cm, mm, in, got 'inch'"):
        read_dxf(path, units="inch")


def test_a_file_without_any_unit_of_a_garment_s_size_in_mm_is_read_in_mm(tmp_path):
    path = aama_file(tmp_path / "front.dxf", scale=25.4)
    assert dxf_units(path) == "mm"
    (front,) = read_dxf(path)
    np.testing.assert_allclose(front.corners, FRONT_IN * 0.0254, rtol=0, atol=1e-12)
    # $INSUNITS comes first: a file that says cm in its header is read in cm whatever its text says
    path = aama_file(tmp_path / "cm.dxf", scale=2.54, units_text="Units: ENGLISH", insunits=5)
    assert dxf_units(path) == "cm"
    np.testing.assert_allclose(read_dxf(path)[0].corners, FRONT_IN * 0.0254, rtol=0, atol=1e-12)


def test_a_units_text_that_names_no_unit_or_two_units_is_refused(tmp_path):
    with pytest.raises(PatternError, match=r"'Units: FURLONGS' names no length unit we read"):
        read_dxf(aama_file(tmp_path / "a.dxf", units_text="Units: FURLONGS"))
    path = aama_file(tmp_path / "b.dxf", units_text="Units: ENGLISH")
    doc = ezdxf.readfile(path)
    doc.blocks.get("FRONT").add_text("Units: METRIC", dxfattribs={"layer": "1", "insert": (50, 50)})
    doc.saveas(path)
    with pytest.raises(PatternError, match=r"give two units \('Units: ENGLISH' and 'Units: METRIC'\)"):
        read_dxf(path)


def test_a_garment_file_passes_its_dxf_s_units(tmp_path):
    aama_file(tmp_path / "front.dxf")
    text = ('name = "front"\nunits = "cm"\nspacing = 2.0\ndxf = "front.dxf"\n{units}\n'
            '[[pieces]]\nname = "FRONT"\nplacement = {{ origin = [0, 1, 0] }}\n')
    (tmp_path / "g.toml").write_text(text.format(units='dxf_units = "in"'))
    (front,) = load_garment(tmp_path / "g.toml").pieces
    np.testing.assert_allclose(front.corners, FRONT_IN * 0.0254, rtol=0, atol=1e-12)
    (tmp_path / "g.toml").write_text(text.format(units=""))
    with pytest.raises(PatternError, match=r"g.toml: .*front.dxf: the file gives no unit"):
        load_garment(tmp_path / "g.toml")
    (tmp_path / "g.toml").write_text(text.format(units='dxf_units = "in"').replace('dxf = "front.dxf"\n', "")
                                     .replace('name = "FRONT"', 'name = "FRONT"\noutline = [{ at = [0, 0] }, '
                                              '{ at = [10, 0] }, { at = [0, 10] }]'))
    with pytest.raises(PatternError, match="dxf_units is about the file `dxf` names"):
        load_garment(tmp_path / "g.toml")


#: the whole front FRONT_IN unfolds to across its centre front x = 0 [in], and its corner names
WHOLE_IN = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 17.0], [7.5, 23.0], [3.0, 24.5], [0.0, 22.0], [-3.0, 24.5],
                     [-7.5, 23.0], [-10.0, 17.0], [-10.0, 0.0]])
WHOLE_NAMES = ["c0", "c1", "c2", "c3", "c4", "c5", "c4_mirror", "c3_mirror", "c2_mirror", "c1_mirror"]
SIDEWAYS = np.array([[0.0, 1.0], [-1.0, 0.0]])  # p -> (y, -x): up becomes +x, as pattern CAD lays a piece down


def graded_file(path, sizes=(("S", 0.95), ("M", 1.0), ("L", 1.05)), sample: str | None = "M"):
    """A graded AAMA file in inches: a block FRONT_<size> per size holding the half front FRONT_IN x its grade,
    laid on its side (SIDEWAYS), the centre front on the fold (layer 6), the grain line (layer 7) along the
    piece's up, the size as a "Size:" text in each block; model-space texts "Units: ENGLISH" and "Sample Size:"."""
    doc = ezdxf.new("R12")
    msp = doc.modelspace()
    for k, (size, grade) in enumerate(sizes):
        block = doc.blocks.new(f"FRONT_{size}")
        block.add_polyline2d([tuple(SIDEWAYS @ p * grade) for p in FRONT_IN], close=True, dxfattribs={"layer": "1"})
        block.add_line(tuple(SIDEWAYS @ [0, 0]), tuple(SIDEWAYS @ [0, 22 * grade]), dxfattribs={"layer": "6"})
        block.add_line(tuple(SIDEWAYS @ [5, 5]), tuple(SIDEWAYS @ [5, 15]), dxfattribs={"layer": "7"})
        block.add_text(f"Size: {size}", dxfattribs={"layer": "1", "insert": tuple(SIDEWAYS @ [4, 10])})
        msp.add_blockref(f"FRONT_{size}", (0, 0))
    msp.add_text("Units: ENGLISH", dxfattribs={"insert": (-40, 0)})
    if sample:
        msp.add_text(f"Sample Size: {sample}", dxfattribs={"insert": (-40, -5)})
    doc.saveas(path)
    return path


def test_a_graded_file_gives_its_sample_size_upright_and_unfolded_and_any_size_by_name(tmp_path):
    path = graded_file(tmp_path / "graded.dxf")
    (front,) = read_dxf(path)
    assert front.name == "FRONT" and front.corner_names == WHOLE_NAMES
    np.testing.assert_allclose(front.corners, WHOLE_IN * 0.0254, rtol=0, atol=1e-12)
    half = PatternPiece.from_polygon("half", FRONT_IN, units="in")
    assert front.area() == pytest.approx(2 * half.area(), rel=1e-12) and front.orientation == half.orientation
    (large,) = read_dxf(path, size="L")
    np.testing.assert_allclose(large.corners, WHOLE_IN * 0.0254 * 1.05, rtol=0, atol=1e-12)
    with pytest.raises(PatternError, match=r"no size 'XL' in the file; its sizes are S, M, L"):
        read_dxf(path, size="XL")
    # as drawn: the half on its side, its grain and fold lines kept (metres)
    (drawn,) = read_dxf(path, as_drawn=True)
    np.testing.assert_allclose(drawn.corners, FRONT_IN @ SIDEWAYS.T * 0.0254, rtol=0, atol=1e-12)
    np.testing.assert_allclose(drawn.grain, [[5 * 0.0254, -5 * 0.0254], [15 * 0.0254, -5 * 0.0254]], atol=1e-12)
    np.testing.assert_allclose(drawn.fold, [[0, 0], [22 * 0.0254, 0]], atol=1e-12)
    # a one-size piece whose name has an underscore stays whole beside the graded ones
    doc = ezdxf.readfile(path)
    flap = doc.blocks.new("POCKET_FLAP")
    flap.add_polyline2d([(0, 0), (5, 0), (5, 3), (0, 3)], close=True, dxfattribs={"layer": "1"})
    doc.modelspace().add_blockref("POCKET_FLAP", (30, 0))
    doc.saveas(tmp_path / "flap.dxf")
    assert [p.name for p in read_dxf(tmp_path / "flap.dxf", size="S")] == ["FRONT", "POCKET_FLAP"]
    # without a sample size, a graded file asks for one
    with pytest.raises(PatternError, match=r"graded file \(sizes S, M, L\) without a 'Sample Size:' text"):
        read_dxf(graded_file(tmp_path / "nosample.dxf", sample=None))
    with pytest.raises(PatternError, match="not graded"):
        read_dxf(aama_file(tmp_path / "plain.dxf", units_text="Units: ENGLISH"), size="M")


def test_upright_follows_the_grain_line_and_unfolding_refuses_a_fold_off_the_outline():
    square = PatternPiece.from_polygon("sq", [[0, 0], [2, 0], [2, 1], [0, 1]])
    down = dataclasses.replace(square, grain=((1.0, 1.0), (1.0, 0.0)))  # drawn pointing down: turned half round
    np.testing.assert_allclose(down.upright().corners, -square.corners, atol=1e-15)
    np.testing.assert_allclose(down.upright(rotate=90).corners, square.corners @ SIDEWAYS, atol=1e-15)
    assert square.upright() is square  # no grain line: as drawn
    off = dataclasses.replace(square, fold=((0.5, -1.0), (0.5, 2.0)))
    with pytest.raises(PatternError, match="'sq': its fold line .* is not an edge of its outline"):
        off.unfolded()
    with pytest.raises(PatternError, match="'sq' has no fold line"):
        square.unfolded()
    whole = dataclasses.replace(square, fold=((0.0, 0.0), (0.0, 1.0))).unfolded()
    assert whole.area() == pytest.approx(4.0, rel=1e-12)
    np.testing.assert_allclose(whole.corners, [[0, 0], [2, 0], [2, 1], [0, 1], [-2, 1], [-2, 0]], atol=1e-15)


def test_a_garment_file_picks_a_size_and_keeps_a_half_or_turns_a_piece(tmp_path):
    graded_file(tmp_path / "graded.dxf")
    text = ('name = "front"\nunits = "in"\nspacing = 1.0\ndxf = "graded.dxf"\n{top}\n'
            '[[pieces]]\nname = "FRONT"\nplacement = {{ origin = [0, 40, 0] }}\n{piece}\n')
    cases = (("", "", WHOLE_IN), ('dxf_size = "S"', "", WHOLE_IN * 0.95),
             ("", "unfold = false", FRONT_IN), ("", "unfold = false\nrotate = 0", FRONT_IN @ SIDEWAYS.T))
    for top, piece, corners in cases:
        (tmp_path / "g.toml").write_text(text.format(top=top, piece=piece))
        (front,) = load_garment(tmp_path / "g.toml").pieces
        np.testing.assert_allclose(front.corners, corners * 0.0254, rtol=0, atol=1e-12, err_msg=f"{top} {piece}")


def bezier(p0, c, p1, n: int) -> np.ndarray:
    """(n + 1, 2) points of the quadratic Bezier p0, c, p1."""
    t = np.linspace(0, 1, n + 1)[:, None]
    return (1 - t) ** 2 * np.array(p0) + 2 * t * (1 - t) * np.array(c) + t ** 2 * np.array(p1)


#: the half front FRONT_IN as one closed boundary polyline, as CLO exports it: its armhole and neck curves drawn
#: with 30 and 20 short edges (vertices every 1-4 mm)
DENSE_IN = np.vstack([[[0.0, 0.0], [10.0, 0.0]], bezier((10, 17), (8, 19), (7.5, 23), 30),
                      bezier((3, 24.5), (2.5, 22), (0, 22), 20)])


@pytest.mark.parametrize("marked", [True, False])
def test_an_aama_outline_has_corners_at_its_turn_points_and_notches_not_at_every_vertex(tmp_path, marked):
    doc = ezdxf.new("R12")
    block = doc.blocks.new("FRONT")
    block.add_polyline2d([tuple(p) for p in DENSE_IN], close=True, dxfattribs={"layer": "1"})
    if marked:  # turn points: grade-rule labels on layer 2
        for k, p in enumerate(FRONT_IN):
            block.add_text(f"# {k}", dxfattribs={"layer": "2", "insert": tuple(p)})
    side_notch = (10.0, 8.0)
    arm_notch = tuple(0.5 * (DENSE_IN[2 + 12] + DENSE_IN[2 + 13]))  # half way along an edge of the armhole
    block.add_line(side_notch, (9.75, 8.0), dxfattribs={"layer": "4"})
    block.add_line(arm_notch, tuple(np.array(arm_notch) + [-0.2, -0.1]), dxfattribs={"layer": "4"})
    doc.modelspace().add_blockref("FRONT", (0, 0))
    doc.modelspace().add_text("Units: ENGLISH", dxfattribs={"insert": (-30, 0)})
    doc.saveas(tmp_path / "clo.dxf")
    (front,) = read_dxf(tmp_path / "clo.dxf")
    expect = np.vstack([FRONT_IN[:2], [side_notch], FRONT_IN[2:3], [arm_notch], FRONT_IN[3:]]) * 0.0254
    np.testing.assert_allclose(front.corners, expect, rtol=0, atol=1e-12)
    assert front.corner_names == ["c0", "c1", "notch1", "c3", "notch2", "c5", "c6", "c7"]
    assert [s.kind for s in front.segments] == ["line", "line", "line", "polyline", "polyline", "line", "polyline",
                                                "line"]
    outline = PatternPiece.from_polygon("dense", DENSE_IN, units="in")
    assert front.area() == pytest.approx(outline.area(), rel=1e-12)  # the same outline, fewer corners


def test_an_aama_piece_with_a_sew_line_is_the_piece_inside_its_seam_allowance(tmp_path):
    path = aama_file(tmp_path / "front.dxf", units_text="Units: ENGLISH")
    doc = ezdxf.readfile(path)
    block = doc.blocks.get("FRONT")
    centre = FRONT_IN.mean(axis=0)
    for e in list(block):
        if e.dxftype() == "POLYLINE":
            block.delete_entity(e)
    block.add_polyline2d([tuple(centre + 1.1 * (p - centre)) for p in FRONT_IN], close=True,
                         dxfattribs={"layer": "1"})  # the cut line, 10 % out
    block.add_polyline2d([tuple(p) for p in FRONT_IN], close=True, dxfattribs={"layer": "14"})
    doc.saveas(path)
    (front,) = read_dxf(path)
    np.testing.assert_allclose(front.corners, FRONT_IN * 0.0254, rtol=0, atol=1e-12)
    assert front.corner_names == ["c0", "c1", "c2", "c3", "neck", "c5"]  # layer-1 texts name sew-line corners


def test_a_seam_allowance_taken_off_moves_every_edge_in_by_it():
    square = PatternPiece.from_polygon("sq", [[0, 0], [2, 0], [2, 1], [0, 1]])
    for piece in (square, square.transformed(mirror=True)):  # counter-clockwise and clockwise
        inner = piece.inset(0.1)
        toward_centre = np.sign(piece.corners.mean(axis=0) - piece.corners)  # each corner moves 0.1 in x and y
        np.testing.assert_allclose(inner.corners, piece.corners + 0.1 * toward_centre, rtol=0, atol=1e-15)
        assert inner.area() == pytest.approx(1.8 * 0.8, rel=1e-12) and inner.corner_names == piece.corner_names
    assert square.inset(0.0) is square
    circle = circle_piece(0.1)
    assert circle.inset(0.01, tolerance=1e-6).area() == pytest.approx(math.pi * 0.09 ** 2, rel=1e-4)
    with pytest.raises(PatternError, match="'sq': a seam allowance of 60 cm leaves no outline"):
        square.inset(0.6)
    with pytest.raises(PatternError, match="must be a length >= 0"):
        square.inset(-0.01)


def test_a_garment_file_takes_its_seam_allowance_off_a_dxf_s_cut_lines(tmp_path):
    aama_file(tmp_path / "front.dxf", units_text="Units: ENGLISH")
    text = ('name = "front"\nunits = "in"\nspacing = 1.0\ndxf = "front.dxf"\n{top}\n'
            '[[pieces]]\nname = "FRONT"\nplacement = {{ origin = [0, 40, 0] }}\n{piece}\n')
    sew = PatternPiece.from_polygon("FRONT", FRONT_IN, units="in")
    for top, piece, allowance in (("seam_allowance = 0.5", "", 0.5), ("seam_allowance = 0.5", "seam_allowance = 0.25",
                                                                      0.25), ("", "", 0.0)):
        (tmp_path / "g.toml").write_text(text.format(top=top, piece=piece))
        (front,) = load_garment(tmp_path / "g.toml").pieces
        np.testing.assert_allclose(front.corners, sew.inset(allowance * 0.0254).corners, rtol=0, atol=1e-12)
    (tmp_path / "g.toml").write_text(text.format(top="", piece="seam_allowance = 0.5\noutline = [{ at = [0, 0] }, "
                                                 "{ at = [10, 0] }, { at = [0, 10] }]"))
    with pytest.raises(PatternError, match="an outline or a copy is a sew line already"):
        load_garment(tmp_path / "g.toml")


def test_write_aama_dxf_round_trips_lines_and_arcs_and_refuses_what_aama_cannot_hold(tmp_path):
    disk, square = circle_piece(0.1), PatternPiece.from_polygon("sq", [[0, 0], [0.3, 0], [0.3, 0.2], [0, 0.2]])
    path = write_aama_dxf([disk, square], tmp_path / "a.dxf", units="mm")
    assert ezdxf.readfile(path).header.get("$INSUNITS", 0) == 0 and dxf_units(path) == "mm"
    back = {p.name: p for p in read_dxf(path)}
    assert [s.kind for s in back["disk"].segments] == ["arc", "arc"]
    assert back["disk"].area() == pytest.approx(disk.area(), rel=1e-12)
    np.testing.assert_allclose(back["sq"].corners, square.corners, rtol=0, atol=1e-15)
    with pytest.raises(PatternError, match="AAMA files are in inches or millimetres"):
        write_aama_dxf([disk], tmp_path / "b.dxf", units="cm")
    with pytest.raises(PatternError, match="sample_size 'L' is not one of the sizes S, M"):
        write_aama_dxf({"S": [disk], "M": [disk]}, tmp_path / "c.dxf", sample_size="L")
