"""Still pictures of a run (taichi_cloth.still) and the pattern's seam set-up view (taichi_cloth.pattern_view):
the geometry read back, the PNGs written (no display), the 2D view logged into the recording."""
from pathlib import Path

import numpy as np
import pytest
import rerun as rr

import taichi_cloth as tc
from taichi_cloth.cli import main
from taichi_cloth.garment.garmentfile import load_garment
from taichi_cloth.pattern_view import log_pattern, pattern_view, plot_pattern
from taichi_cloth.still import VIEWS, render_still

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
    path = render_still(loaded.scene, tmp_path / "ball.png")
    img = read_png(path)
    assert img.shape[:2] == (int(6.2 * 110), 10 * 110)
    rgb = img[..., :3]
    grey = (np.abs(rgb[..., 0] - rgb[..., 2]) < 0.02) & (rgb[..., 0] < 0.8) & (rgb[..., 0] > 0.1)
    assert grey.mean() > 0.01  # the sphere shows in light grey
    assert [v[0] for v in VIEWS] == ["front", "side"]


def _scene(tmp_path) -> Path:
    path = tmp_path / "ball.toml"
    path.write_text(SCENE.format(out=(tmp_path / "out").as_posix()))
    return path


def test_run_png_writes_the_still_beside_the_recording(tmp_path, capsys):
    assert main(["run", str(_scene(tmp_path)), "--no-progress", "--frames", "3", "--png"]) == 0
    out = capsys.readouterr().out
    still = tmp_path / "out" / "ball.png"
    assert f"wrote {still}" in out and still.is_file()
    assert not (tmp_path / "out" / "ball-pattern.png").exists()  # no garment, no pattern
    assert read_png(still).shape[:2] == (int(6.2 * 110), 10 * 110)
