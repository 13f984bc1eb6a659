"""Still pictures of a run (taichi_cloth.still) and the pattern's seam set-up view (taichi_cloth.pattern_view):
the geometry read back, the PNGs written (no display), the 2D view logged into the recording; the stills' views
framed on the cloth, their z-buffer and their smooth shading."""
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

import taichi_cloth as tc
from taichi_cloth.cli import main
from taichi_cloth.garment.garmentfile import load_garment
from taichi_cloth.pattern_view import log_pattern, pattern_view, plot_pattern
from taichi_cloth.still import (BOTTOM_PX, FRAME_MARGIN, GAP_PX, SIDE_PX, TOP_PX, VIEWS, body_meshes, rasterize,
                                 render_still, render_views)

ROOT = Path(__file__).resolve().parents[1]

SCENE = """
name = "ball"
frames = 20
[cloth]
material = "cotton"
[cloth.grid]
size = [0.6, 0.6]
resolution = [12, 12]
center = [0.0, 0.45, 0.0]
plane = "xz"
[integrator]
name = "implicit"
dt = 0.01
[[colliders]]
type = "sphere"
center = [0.0, 0.2, 0.0]
radius = 0.2
[output]
dir = "{out}"
"""


def read_png(path):
    import matplotlib.image

    return matplotlib.image.imread(path)


def cloth_coloured(img, heights, widths) -> list:
    """The panels of a still picture (float RGB(A) read from its PNG, panels of these heights and widths laid out
    by taichi_cloth.still.compose): per panel, (H,W) bool, the pixels in a cloth colour. The cloth's strain colours
    run from white through orange to red (red >= blue, white lit or not has red = blue), while the body (0.70, 0.72,
    0.76) and the background gradient are bluer than red at any light (by 3 and 7 of 255 at the least)."""
    rgb = np.round(255 * np.asarray(img)[..., :3]).astype(int)
    out, x0 = [], SIDE_PX
    for h, w in zip(heights, widths):
        panel = rgb[TOP_PX:TOP_PX + h, x0:x0 + w]
        out.append(panel[..., 0] >= panel[..., 2])
        x0 += w + GAP_PX
    return out


def test_pattern_view_of_the_tshirt():
    spec = load_garment(ROOT / "demos/garments/tshirt.toml")
    view = pattern_view(spec)
    assert [p.name for p in view.pieces] == ["front", "back", "sleeve_L", "sleeve_R"]
    assert len(view.sides) == 2 * len(spec.seams) == 20
    assert [s.number for s in view.sides] == [k for k in range(1, 11) for _ in (0, 1)]
    # the pieces lie side by side, GAP apart, bottoms on y = 0
    boxes = [(p.outline.min(axis=0), p.outline.max(axis=0)) for p in view.pieces]
    for (lo, hi), (lo2, _) in zip(boxes, boxes[1:]):
        assert lo2[0] - hi[0] == pytest.approx(0.12)
    assert all(lo[1] == pytest.approx(0.0, abs=1e-12) for lo, _ in boxes)
    # each side runs from its start corner to its end corner (pick order), on its own piece
    pieces = {p.name: p for p in view.pieces}
    for side, seam in zip(view.sides, [s for seam in spec.seams for s in (seam.a, seam.b)]):
        p = pieces[seam.piece]
        np.testing.assert_allclose(side.points[0], p.corners[p.corner_names.index(seam.start)], atol=1e-12)
        np.testing.assert_allclose(side.points[-1], p.corners[p.corner_names.index(seam.end)], atol=1e-12)


def test_pattern_png_and_its_recording(tmp_path):
    view = pattern_view(load_garment(ROOT / "demos/garments/skirt.toml"))
    png = read_png(plot_pattern(view, tmp_path / "skirt-pattern.png"))
    assert png.shape[1] == 13 * 110 and png.shape[0] > 300
    assert (png[..., :3] < 0.99).any(axis=2).mean() > 0.05  # something drawn, not a blank page
    with tc.Recorder(tmp_path / "p.rrd") as rec:
        log_pattern(rec, view)
    rows = {}
    for chunk in rr.chunk.RrdReader(tmp_path / "p.rrd").stream().to_chunks():
        if chunk.entity_path.startswith("/pattern"):
            rows[chunk.entity_path] = chunk.is_static
    assert rows == {"/pattern/pieces/front": True, "/pattern/pieces/back": True, "/pattern/corners": True,
                    "/pattern/seams": True, "/pattern/seams/directions": True}


def test_still_of_a_drape_on_a_sphere(tmp_path):
    loaded = tc.load_scene(_scene(tmp_path))
    loaded.scene.run(loaded.frames, progress=False)
    path = render_still(loaded.scene, tmp_path / "ball.png", panel_px=240)
    img = read_png(path)
    panels = render_views(loaded.scene.positions()[:144], loaded.scene.model.data.triangles, np.ones((144, 3)),
                          body_meshes(loaded.scene), panel_px=240)
    assert [p.name for p in panels] == [v[0] for v in VIEWS] == ["front", "back", "side"]
    heights = {p.rgb.shape[0] for p in panels}
    assert len(heights) == 1  # one scale, y up in every view: the panels share their height ...
    widths = [p.rgb.shape[1] for p in panels]
    assert img.shape[0] > heights.pop() and img.shape[1] > sum(widths)  # ... and lie side by side under the title
    for p in panels:
        # framed on the cloth: its pixels span the panel but for the margin (FRAME_MARGIN of the cloth's largest
        # extent on each side) along the cloth's larger extent in the view, and the sphere shows where it is in frame
        rows, cols = np.flatnonzero(p.cloth.any(axis=1)), np.flatnonzero(p.cloth.any(axis=0))
        span = max((rows[-1] - rows[0] + 1) / p.rgb.shape[0], (cols[-1] - cols[0] + 1) / p.rgb.shape[1])
        assert span > 1 - 2 * FRAME_MARGIN - 0.02, p.name
        assert p.body.mean() > 0.05 and not (p.body & p.cloth).any()
    # the PNG: in each panel the cloth-coloured pixels are exactly where the cloth is the nearest surface (the
    # panels are composed at one pixel per pixel), and the draped sheet fills a good part of each view (43,518
    # and 43,519 of 105,120 pixels measured)
    for p, coloured in zip(panels, cloth_coloured(img, [p.rgb.shape[0] for p in panels], widths)):
        np.testing.assert_array_equal(coloured, p.cloth, err_msg=p.name)
        assert p.cloth.mean() > 0.3, p.name


def _sphere(radius=0.2, center=(0.0, 0.2, 0.0)):
    import trimesh

    ball = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    return [(np.asarray(ball.vertices) + center, np.asarray(ball.faces, np.int64))]


def _grid(n, size, z):
    """An n x n particle square sheet `size` [m] wide in the plane z = `z`, centred at (0, 0.2): (x (n*n,3),
    triangles)."""
    u = np.linspace(-0.5 * size, 0.5 * size, n)
    x = np.array([[a, 0.2 + b, z] for b in u for a in u])
    k = np.arange(n * n).reshape(n, n)
    a, b, c, d = k[:-1, :-1].ravel(), k[:-1, 1:].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel()
    return x, np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


def test_the_nearest_surface_wins_at_each_pixel():
    # two triangles covering the same pixels, the nearer one (depth 1) drawn first or last: it wins either way
    far = [[1.0, 1.0], [9.0, 1.0], [1.0, 9.0]]
    near = [[0.5, 0.5], [9.5, 0.5], [0.5, 9.5]]
    for order in ([far, near], [near, far]):
        depth = [[0.0] * 3, [1.0] * 3] if order[1] is near else [[1.0] * 3, [0.0] * 3]
        tri, bary, z = rasterize(np.array(order), np.array(depth), (10, 10))
        assert tri[3 * 10 + 3] == order.index(near) and z[3 * 10 + 3] == 1.0
        np.testing.assert_allclose(bary[tri >= 0].sum(axis=1), 1.0)
    # the same triangle twice at the same depth: the lower index wins at every pixel (deterministic)
    tri, _, _ = rasterize(np.array([near, near]), np.ones((2, 3)), (10, 10))
    assert set(tri[tri >= 0]) == {0} and (tri >= 0).sum() > 40
    # a sheet 5 cm in front of a sphere (+z): the cloth's colour in front, the sphere's from the back, whichever is
    # listed first; no pixel is drawn in the background's colours where both project
    x, tris = _grid(5, 0.3, 0.25)
    red = np.tile([1.0, 0.0, 0.0], (len(x), 1))
    front, back, _ = render_views(x, tris, red, _sphere(center=(0.0, 0.2, 0.0)), panel_px=120)
    for panel, cloth_wins in ((front, True), (back, False)):
        h, w = panel.cloth.shape
        centre = (h // 2, w // 2)
        assert panel.cloth[centre] == cloth_wins and panel.body[centre] != cloth_wins
        r, g, b = panel.rgb[centre]
        assert (r > 3 * max(g, b)) == cloth_wins  # the red cloth, or the grey body
        assert (panel.cloth | panel.body)[h // 4: 3 * h // 4, w // 4: 3 * w // 4].all()


def test_shading_is_smooth_across_a_coarse_curved_cloth():
    # a half cylinder (axis y, radius 0.3 m) bulging toward the viewer, only 7 columns of particles round: flat
    # facets would be 30 degrees apart; interpolated normals change the brightness a little at every pixel
    angle = np.linspace(-np.pi / 2, np.pi / 2, 7)
    x = np.array([[0.3 * np.sin(a), y, 0.3 * np.cos(a)] for y in (0.0, 0.3) for a in angle])
    k = np.arange(14).reshape(2, 7)
    a, b, c, d = k[0, :-1], k[0, 1:], k[1, :-1], k[1, 1:]
    tris = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    front, back = render_views(x, tris, np.ones((14, 3)), (), views=VIEWS[:2], panel_px=200, max_width_px=400)
    row = front.rgb[front.rgb.shape[0] // 2]
    brightness = row[front.cloth[front.rgb.shape[0] // 2]].mean(axis=1)
    assert len(brightness) > 300
    steps = np.abs(np.diff(brightness))
    assert steps.max() < 0.02  # no jump at a facet's edge ...
    assert (steps > 1e-6).mean() > 0.9  # ... and no flat facet: neighbouring pixels differ almost everywhere
    assert brightness.max() - brightness.min() > 0.3  # the light does turn round the cylinder
    # two-sided: the inside, seen from the back, is lit as well (not left at the ambient term)
    inside = back.rgb[back.cloth].mean(axis=1)
    assert inside.max() > 0.8
    # the same input draws the same pixels
    again = render_views(x, tris, np.ones((14, 3)), (), views=VIEWS[:2], panel_px=200, max_width_px=400)
    assert all(np.array_equal(a.rgb, b.rgb) for a, b in zip(again, (front, back)))


def _scene(tmp_path) -> Path:
    path = tmp_path / "ball.toml"
    path.write_text(SCENE.format(out=(tmp_path / "out").as_posix()))
    return path


def test_run_png_writes_the_still_beside_the_recording(tmp_path, capsys):
    """The scene's 20 frames: after 3 the sheet was still flat and level, edge-on in all three views, and the
    picture held no cloth pixel at all."""
    assert main(["run", str(_scene(tmp_path)), "--no-progress", "--png"]) == 0
    out = capsys.readouterr().out
    still = tmp_path / "out" / "ball.png"
    assert f"wrote {still}" in out and still.is_file()
    assert not (tmp_path / "out" / "ball-pattern.png").exists()  # no garment, no pattern
    img = read_png(still)
    h, w = img.shape[:2]
    assert h > 300 and w > 3 * 300  # three panels side by side
    # three panels of one height (the picture's less its title and legend) and equal widths here (the views of
    # the drape on the ball are alike): the draped sheet covers 41.3 % of each (226,415-226,432 of 548,000
    # pixels measured), the rest is the ball and the background
    panel_h, panel_w = h - TOP_PX - BOTTOM_PX, (w - 2 * SIDE_PX - 2 * GAP_PX) // 3
    for coloured in cloth_coloured(img, [panel_h] * 3, [panel_w] * 3):
        assert 0.3 < coloured.mean() < 0.6
