"""Body morphing to measured girths (taichi_cloth.body, Zhang et al. 2017 sections 1 and 3.1): the periodic-spline girth,
blend shapes (exact limits, user meshes, topology checks), the girth gauge on the shipped mannequin, the
coupled fit and the `body` command."""
import argparse
import math
import re

import numpy as np
import pytest
import trimesh
from scipy.special import ellipe

from collision.mannequin import load_mannequin
from taichi_cloth.body import (BlendShapes, GirthGauge, GirthOutOfRange, convex_hull, default_body, fit_body,
                               girth_ranges, hull_perimeter, periodic_spline_length, read_mesh, tape_girth)
from taichi_cloth.body import cli as body_cli
from taichi_cloth.body import section
from taichi_cloth.errors import BodyError, MeshError


@pytest.fixture(scope="module")
def model():
    """(BlendShapes, GirthGauge) of the shipped mannequin (the gauge's body analysis runs once per process)."""
    return default_body()


@pytest.fixture(scope="module")
def base_girths(model):
    blend, gauge = model
    return gauge.measure(blend.base)


# ------------------------------------------------------------------------------------------ spline girth

def test_periodic_spline_length_of_a_circle():
    r = 0.3
    theta = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    pts = r * np.stack([np.cos(theta), np.sin(theta)], axis=1)
    assert abs(periodic_spline_length(pts) / (2 * np.pi * r) - 1) < 1e-5
    # a closing point given explicitly is the same curve
    assert periodic_spline_length(np.vstack([pts, pts[:1]])) == pytest.approx(periodic_spline_length(pts), rel=1e-12)


def test_periodic_spline_length_of_an_ellipse():
    a, b = 0.4, 0.25
    theta = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    exact = 4 * a * ellipe(1 - (b / a) ** 2)
    assert abs(periodic_spline_length(np.stack([a * np.cos(theta), b * np.sin(theta)], axis=1)) / exact - 1) < 1e-4
    # unevenly spaced samples (denser on one side) still follow the curve
    t = 2 * np.pi * np.linspace(0, 1, 64, endpoint=False) ** 1.5
    assert abs(periodic_spline_length(np.stack([a * np.cos(t), b * np.sin(t)], axis=1)) / exact - 1) < 1e-4


def test_tape_girth_bridges_a_hollow():
    """A circle with a 2 cm dent over 40 degrees: the tape (spline through the hull) ignores the dent."""
    r = 0.3
    theta = np.linspace(0, 2 * np.pi, 180, endpoint=False)
    radius = np.where(np.abs(theta - np.pi) < np.radians(20), r - 0.02, r)
    pts = radius[:, None] * np.stack([np.cos(theta), np.sin(theta)], axis=1)
    rng = np.random.default_rng(0)
    tape = tape_girth(pts[rng.permutation(len(pts))])   # any order: the hull orders the points
    assert hull_perimeter(pts) <= tape < periodic_spline_length(pts)
    assert tape == pytest.approx(2 * np.pi * r, rel=2e-3)
    with pytest.raises(BodyError, match="span no area"):
        tape_girth([[0, 0], [1, 1], [2, 2]])


def test_landmarks_use_the_shared_slicer():
    from taichi_cloth.body import landmarks

    assert landmarks.MeshSlicer is section.MeshSlicer and landmarks.loop_girth is section.loop_girth
    hull = convex_hull([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5], [0.5, 0]])
    assert len(hull) == 4 and hull_perimeter(hull) == pytest.approx(4.0)


# ------------------------------------------------------------------------------------------ blend shapes

def test_zero_weights_and_limits_are_exact(model):
    blend, _ = model
    man = load_mannequin()
    np.testing.assert_array_equal(blend.morph({}), man.vertices)
    np.testing.assert_array_equal(blend.morph({n: 0.0 for n in blend.names}), man.vertices)
    stems = {"chest": "bust", "waist": "waist", "hips": "hips", "upper_arm": "upperarm"}
    for name, stem in stems.items():
        for w, kind in ((1.0, "incr"), (-1.0, "decr")):
            index, delta = man.targets[f"measure-{stem}-circ-{kind}"]
            expected = man.vertices.copy()
            expected[index] += delta
            np.testing.assert_array_equal(blend.morph({name: w}), expected)
    # halfway is halfway
    index, delta = man.targets["measure-hips-circ-incr"]
    np.testing.assert_allclose(blend.morph({"hips": 0.5})[index], man.vertices[index] + 0.5 * delta, atol=1e-15)


def test_bad_weights_name_the_channel(model):
    blend, _ = model
    with pytest.raises(BodyError, match=r"unknown blend-shape channel 'wasit'; valid channels: chest, underbust"):
        blend.morph({"wasit": 0.5})
    with pytest.raises(BodyError, match=r"channel 'waist': weight 1.5 is outside \[-1, 1\]"):
        blend.morph({"waist": 1.5})
    with pytest.raises(BodyError, match="channel 'hips'"):
        blend.morph({"hips": float("nan")})


def test_overlaps_of_the_mannequin_channels(model):
    blend, _ = model
    ov = blend.overlaps()
    assert ov[("chest", "underbust")] > 800 and ov[("underbust", "waist")] > 600 and ov[("hips", "thigh")] > 300
    assert ("neck", "thigh") not in ov and ("upper_arm", "thigh") not in ov
    sets = {n: blend.channels[n].vertices() for n in blend.names}
    for (a, b), n in ov.items():
        assert n == len(np.intersect1d(sets[a], sets[b]))


def _sphere_files(tmp_path):
    """A base icosphere and two limits (OBJ). The smaller one squashes y to 3 %: there base + (limit - base)
    differs from limit in the last bit, which the morph must not show."""
    ico = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    v, t = np.asarray(ico.vertices), np.asarray(ico.faces)
    larger = v * [1.1, 1.0, 1.2] + [0.0, 1e-4, 0.0]
    smaller = v * [0.9, 0.03, 0.85] + [0.0, 1e-7, 0.0]
    smaller[v[:, 1] > 0.05] = v[v[:, 1] > 0.05]          # the top does not move
    paths = {}
    for name, verts in (("base", v), ("larger", larger), ("smaller", smaller)):
        paths[name] = tmp_path / f"{name}.obj"
        trimesh.Trimesh(verts, t, process=False).export(paths[name], include_normals=False, digits=17)
    return paths, v, t


def test_from_meshes_reproduces_the_limit_files_exactly(tmp_path):
    paths, v, t = _sphere_files(tmp_path)
    blend = BlendShapes.from_meshes(paths["base"], {"size": (paths["larger"], paths["smaller"])})
    base, small = read_mesh(paths["base"])[0], read_mesh(paths["smaller"])[0]
    assert np.any(base + (small - base) != small)          # the plain sum would miss the file by an ulp
    for w, name in ((1.0, "larger"), (-1.0, "smaller")):
        np.testing.assert_array_equal(blend.morph({"size": w}), read_mesh(paths[name])[0])
    np.testing.assert_array_equal(blend.morph({"size": 0.0}), read_mesh(paths["base"])[0])
    assert len(blend.channels["size"].smaller) < len(v)     # rows that do not move are dropped
    # arrays work as well; a missing smaller limit narrows the weights to [0, 1]
    blend2 = BlendShapes.from_meshes((v, t), {"size": (read_mesh(paths["larger"])[0], None)})
    np.testing.assert_allclose(blend2.morph({"size": 0.5}), 0.5 * (v + read_mesh(paths["larger"])[0]), atol=1e-15)
    with pytest.raises(BodyError, match=r"outside \[0, 1\] \(it has no smaller limit\)"):
        blend2.morph({"size": -0.5})


def test_from_meshes_refuses_another_topology(tmp_path):
    paths, v, t = _sphere_files(tmp_path)
    coarse = trimesh.creation.icosphere(subdivisions=1, radius=0.1)
    coarse.export(tmp_path / "coarse.obj")
    with pytest.raises(BodyError, match=r"coarse\.obj.*42 vertices.*base mesh .*base\.obj has 162"):
        BlendShapes.from_meshes(paths["base"], {"size": (tmp_path / "coarse.obj", None)})
    flipped = t.copy()
    flipped[:10] = flipped[:10, ::-1]                       # same vertices, ten triangles wound the other way
    trimesh.Trimesh(v * 1.1, flipped, process=False).export(tmp_path / "flipped.obj", include_normals=False)
    with pytest.raises(BodyError, match=r"flipped\.obj: different topology .*10 of 320 triangles differ"):
        BlendShapes.from_meshes(paths["base"], {"size": (tmp_path / "flipped.obj", None)})
    bad = v.copy()
    bad[3] = np.nan
    with pytest.raises(MeshError, match="1 of 162 vertices have NaN"):
        BlendShapes.from_meshes((bad, t), {"size": (paths["larger"], None)})
    with pytest.raises(MeshError, match="nothing.obj: no such file"):
        BlendShapes.from_meshes(tmp_path / "nothing.obj", {"size": (paths["larger"], None)})


# ------------------------------------------------------------------------------------------ girth gauge

def test_gauge_agrees_with_placement_hull_girths(model, base_girths):
    from taichi_cloth.body.landmarks import Body

    blend, gauge = model
    body = Body.from_mesh(blend.base, blend.triangles)
    hull = gauge.measure(blend.base, method="hull")
    for name in ("chest", "waist", "hips", "neck"):       # the same planes and loops as placement's Body.girths
        assert hull[name] == pytest.approx(body.girths[name], abs=1e-9), name
    for name, spline in base_girths.items():
        # the spline through the hull's vertices rounds off its chords: never shorter, 0.1-0.5 % longer
        assert hull[name] <= spline <= 1.006 * hull[name], (name, spline, hull[name])
    assert base_girths["chest"] == pytest.approx(0.80, abs=0.005)
    assert base_girths["waist"] == pytest.approx(0.67, abs=0.005)
    assert base_girths["hips"] == pytest.approx(0.957, abs=0.005)
    assert gauge.landmarks["underbust"] == pytest.approx(1.166, abs=0.002)
    assert "horizontal plane at y = 1.1661 m" in repr(gauge.definitions["underbust"])


def test_girth_is_monotone_in_the_weight(model):
    blend, gauge = model
    for name in ("waist", "hips"):
        g = [gauge.measure(blend.morph({name: w}), [name])[name] for w in np.linspace(-1, 1, 21)]
        assert np.all(np.diff(g) > 0), (name, np.round(g, 4))


def test_gauge_refuses_bad_input(model):
    blend, gauge = model
    with pytest.raises(BodyError, match=r"unknown girth 'bust'; valid girths: chest, underbust"):
        gauge.measure(blend.base, ["bust"])
    with pytest.raises(BodyError, match="not a morph"):
        gauge.measure(blend.base[:100])


# ------------------------------------------------------------------------------------------ fit

def test_fit_three_girths_at_once(model, base_girths):
    blend, gauge = model
    targets = {"chest": base_girths["chest"] + 0.04, "waist": base_girths["waist"] + 0.03,
               "hips": base_girths["hips"] - 0.02}
    fit = fit_body(targets, blend, gauge, tolerance=1e-3)
    assert fit.sweeps >= 1 and set(fit.weights) == set(targets)
    assert all(-1 <= w <= 1 for w in fit.weights.values())
    measured = gauge.measure(fit.vertices, list(targets))
    for name, target in targets.items():
        assert abs(measured[name] - target) <= 1e-3, name
        assert fit.girths[name] == pytest.approx(measured[name], abs=1e-12)
    np.testing.assert_array_equal(fit.vertices, blend.morph(fit.weights))
    # a gauge built afresh on the morphed body re-finds its landmarks (the bust 5 mm lower) and agrees within
    # 0.5 cm (measured: chest -4.3 mm, waist -0.5 mm, hips 0.0 mm)
    fresh = GirthGauge.from_body(fit.vertices, fit.triangles, underbust_height=gauge.landmarks["underbust"])
    again = fresh.measure(fit.vertices, list(targets))
    print({n: f"{1000 * (again[n] - targets[n]):+.2f} mm" for n in targets})
    for name, target in targets.items():
        assert abs(again[name] - target) < 0.005, (name, again[name], target)
    table = fit.format()
    assert "waist" in table and "error mm" in table and "sweep" in table


def test_fit_coupled_chest_and_underbust(model, base_girths):
    """The bust target widens the underbust nearly as much as the underbust target does: the sweeps converge
    linearly, extrapolation helps, and the result is within the tolerance."""
    blend, gauge = model
    targets = {"chest": base_girths["chest"] + 0.04, "underbust": base_girths["underbust"] + 0.031}
    fit = fit_body(targets, blend, gauge, tolerance=1e-3)
    assert fit.sweeps > 1
    assert fit.weights["chest"] > 0 > fit.weights["underbust"]   # grow the bust, take the ribcage back in
    for name, err in fit.errors().items():
        assert abs(err) <= 1e-3, name
    with pytest.raises(BodyError, match=r"chest, underbust cannot all be fitted within 1 mm.*underbust .*mm off"):
        fit_body({"chest": 0.90, "underbust": 0.78}, blend, gauge)


def test_fit_out_of_range_and_unknown_girth(model):
    blend, gauge = model
    lo, hi = girth_ranges(blend, gauge)["waist"]
    assert 0.55 < lo < 0.62 and 0.72 < hi < 0.80
    with pytest.raises(GirthOutOfRange) as info:
        fit_body({"waist": 1.20}, blend, gauge)
    assert str(info.value) == (f"waist 1.200 m is outside the reachable range {lo:.3f}-{hi:.3f} m of this body's "
                               "waist channel")
    with pytest.raises(BodyError, match=r"unknown girth 'bust'; valid girths: chest, underbust, waist, hips, "
                                        r"neck, upper_arm, thigh"):
        fit_body({"bust": 0.9}, blend, gauge)
    with pytest.raises(BodyError, match="positive"):
        fit_body({"waist": -0.7}, blend, gauge)


# ------------------------------------------------------------------------------------------ command line

def _parser():
    parser = argparse.ArgumentParser(prog="python -m taichi_cloth")
    body_cli.add_parser(parser.add_subparsers(dest="command", required=True))
    return parser


def test_cli_writes_a_body_with_the_asked_girths(model, tmp_path, capsys):
    _, gauge = model
    out = tmp_path / "sub" / "body.obj"
    args = _parser().parse_args(["body", "--chest", "86", "--waist", "70", "--hips", "98", "--out", str(out)])
    assert args.func(args) == 0
    text = capsys.readouterr().out
    assert f"wrote {out}" in text and "target cm" in text
    vertices, triangles, _ = read_mesh(out)
    measured = gauge.measure(vertices, ["chest", "waist", "hips"])
    for name, cm in (("chest", 86), ("waist", 70), ("hips", 98)):
        assert abs(100 * measured[name] - cm) < 0.5, (name, measured[name])


@pytest.mark.parametrize("argv, message", [
    (["body", "--waist", "120"], r"^error: waist 120 cm is outside the reachable range \d+\.\d-\d+\.\d cm"),
    (["body"], "^error: no girth given"),
    (["body", "--waist", "70", "--out", "body.vtk"], r"^error: --out body.vtk: unsupported suffix '.vtk'"),
])
def test_cli_bad_input_is_one_line(argv, message, capsys):
    args = _parser().parse_args(argv)
    assert body_cli.run(args) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert "\n" not in err and captured.out == ""
    assert re.search(message, err), err


def test_cli_ranges(model, capsys):
    args = _parser().parse_args(["body", "--ranges"])
    assert body_cli.run(args) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].split() == ["girth", "min", "cm", "base", "cm", "max", "cm"]
    rows = {line.split()[0]: [float(x) for x in line.split()[1:]] for line in lines[1:]}
    assert list(rows) == ["chest", "underbust", "waist", "hips", "neck", "upper_arm", "thigh"]
    assert all(lo < base < hi for lo, base, hi in rows.values())
    assert math.isclose(rows["waist"][1], 67.0, abs_tol=0.1)
