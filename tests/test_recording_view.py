"""What a user opens: a recording read back has the world's up axis, the default blueprint (views, camera), the
strain colours' legend, and entities per pattern piece, seam and body. Plain data into the Recorder: no scene,
no kernels."""
import io

import numpy as np
import pytest
import rerun as rr
from matplotlib.image import imread

from taichi_cloth.frame import FrameSnapshot, SceneLayout
from taichi_cloth.blueprint import CAMERA_FOV_Y, VIEW_ASPECT
from taichi_cloth.recorder import Recorder
from taichi_cloth.still import FRAME_MARGIN
from taichi_cloth.strain import STRAIN_STOPS, strain_colormap


def _columns(chunk) -> dict:
    rb = chunk.to_record_batch()
    skip = ("rerun.controls.RowId", "log_time", "sim_time")  # pyarrow cannot make Python objects of ns times
    return {k: rb.column(k).to_pylist() for k in rb.schema.names if k not in skip}


def read_back(path):
    """(recording: entity -> list of (static, columns) per chunk, blueprint: entity -> columns) of an .rrd."""
    reader = rr.chunk.RrdReader(path)
    recording = {}
    for chunk in reader.stream():
        recording.setdefault(chunk.entity_path, []).append((chunk.is_static, _columns(chunk)))
    sent = []  # (when, blueprint) per blueprint in the file: the viewer shows the last one sent
    for store in reader.blueprints():
        chunks = list(reader.stream(store=store))
        when = max(max(c.to_record_batch().column("log_time").cast("int64").to_pylist()) for c in chunks)
        sent.append((when, {chunk.entity_path: _columns(chunk) for chunk in chunks}))
    blueprint = max(sent, key=lambda s: s[0])[1]
    return recording, blueprint


def views(blueprint) -> dict:
    """view name -> (kind, origin, content queries, eye controls or None)."""
    out = {}
    for path, cols in blueprint.items():
        if path.startswith("/view/") and path.count("/") == 2:
            eye = blueprint.get(f"{path}/EyeControls3D")
            out[cols["ViewBlueprint:display_name"][0][0]] = (
                cols["ViewBlueprint:class_identifier"][0][0], cols["ViewBlueprint:space_origin"][0][0],
                blueprint[f"{path}/ViewContents"]["ViewContents:query"][0], eye)
    return out


def two_pieces():
    """A garment of two 2x2-particle squares side by side (1 m wide, 0.5 m apart in z), one seam of two pairs."""
    square = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    x = np.concatenate([square + [0, 1, 0.25], square + [0, 1, -0.25]]).astype(np.float32)
    tri = np.array([[0, 1, 2], [1, 3, 2], [4, 5, 6], [5, 7, 6]])
    layout = SceneLayout("two pieces", True, {"energy": ["kinetic", "potential", "total"], "strain/max": "max strain",
                                              "speed/max": "max speed [m/s]", "seam_gap": ["max [mm]", "mean [mm]"]},
                         colliders=[{"kind": "mesh", "vertices": square, "triangles": tri[:2], "name": "body"}],
                         strain_scale=0.1, garment=True)
    colors = strain_colormap().colors(np.linspace(0, 0.1, 8))
    sewing = FrameSnapshot(0, 0.0, x, np.zeros_like(x), tri, 0, colors=colors,
                           pieces={"front": np.arange(4), "back": np.arange(4, 8)},
                           segments={"seams/left side": np.stack([x[[0, 2]], x[[4, 6]]], 1)},
                           scalars={"energy": [0.0, 1.0, 1.0], "strain/max": 0.0, "speed/max": 0.0,
                                    "seam_gap": [500.0, 500.0]})
    merged = FrameSnapshot(1, 1 / 60, x[:6], np.zeros_like(x[:6]), np.array([[0, 1, 2], [1, 3, 2], [4, 5, 0]]), 1,
                           colors=colors[:6], scalars={"energy": [0.0, 1.0, 1.0], "strain/max": 0.01,
                                                       "speed/max": 0.1, "seam_gap": [0.0, 0.0]})
    return layout, sewing, merged


@pytest.fixture(scope="module")
def garment_recording(tmp_path_factory):
    layout, sewing, merged = two_pieces()
    path = tmp_path_factory.mktemp("view") / "garment.rrd"
    with Recorder(path) as rec:
        rec.begin_cloth("cloth", layout)
        rec.log_frame("cloth", sewing)
        rec.log_frame("cloth", merged)
    return read_back(path)


def test_the_world_is_right_handed_with_y_up(garment_recording):
    recording, _ = garment_recording
    (static, cols), = recording["/"]
    assert static and cols["ViewCoordinates:xyz"] == [[[3, 1, 6]]]  # x right, y up, z back (towards the viewer)


def test_the_blueprint_lays_out_the_scene_the_pattern_the_legend_and_the_plots(garment_recording):
    _, blueprint = garment_recording
    got = views(blueprint)
    assert sorted(got) == ["energy [J]", "events", "max speed [m/s]", "max strain [-]", "pattern", "scene",
                           "seam gap [mm]", "strain colours"]
    assert got["scene"][:3] == ("3D", "/", ["+ /**", "- /metrics/**", "- /legend/strain/**", "- /pattern/**"])
    assert got["pattern"][:2] == ("2D", "/pattern") and got["strain colours"][:2] == ("2D", "/legend/strain")
    assert got["energy [J]"][:3] == ("TimeSeries", "/metrics", ["/metrics/cloth/energy/**"])
    assert got["events"][:3] == ("TextLog", "/", ["/cloth/events"])
    # the camera: in front (+z) of the last frame's box (x 0..1, y 1..2, z -0.25..0.25), looking at its centre, y
    # up, as near as it can be while every point of that frame lies inside the view with the still pictures'
    # margin around it (FRAME_MARGIN of the box's largest extent, 1 m), as their front view frames it
    eye = got["scene"][3]
    target = np.array(eye["EyeControls3D:look_target"][0][0])
    np.testing.assert_allclose(target, [0.5, 1.5, 0.0], atol=1e-6)
    position = np.array(eye["EyeControls3D:position"][0][0])
    assert abs(position[0] - 0.5) < 1e-6 and position[2] > 0.25 and eye["EyeControls3D:eye_up"][0][0] == [0, 1, 0]
    forward = (target - position) / np.linalg.norm(target - position)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    d = (two_pieces()[2].positions - position) @ np.stack([right, np.cross(right, forward), forward]).T
    tan = np.tan(np.radians(CAMERA_FOV_Y / 2)) * np.array([VIEW_ASPECT, 1.0])
    used = (np.abs(d[:, :2]) + FRAME_MARGIN * 1.0) / (d[:, 2:] * tan)  # 1: at the view's edge less the margin
    assert used.max() == pytest.approx(1.0, abs=1e-4)


def test_the_legend_shows_the_strain_colour_map_in_per_cent(garment_recording):
    recording, _ = garment_recording
    (static, cols), = recording["/legend/strain"]
    assert static and cols["EncodedImage:media_type"] == [["image/png"]]
    image = imread(io.BytesIO(bytes(cols["EncodedImage:blob"][0][0])), format="png")
    rgb = (image[..., :3] * 255).round().astype(int)
    bar = rgb[int(0.33 * len(rgb))]  # a row through the colour bar (drawn 18-48 % of the height from the top)
    coloured = bar[(bar[:, 0] == 255) & (bar[:, 2] < 250)]  # the bar, but its white end, the frame, the margin
    assert len(coloured) > 0.8 * len(bar)
    # from white through the map's orange at half scale to its red at full scale, left to right
    np.testing.assert_allclose(coloured[-1], STRAIN_STOPS[-1][1], atol=3)
    np.testing.assert_allclose(coloured[len(coloured) // 2], STRAIN_STOPS[1][1], atol=6)
    assert coloured[0][2] > 240 and (np.diff(coloured[:, 1]) <= 0).all()  # white-ish, then green falls
    assert strain_colormap(0.12).range_percent == (0.0, 12.0)


def test_pieces_seams_and_body_are_entities_of_their_own_until_the_merge(garment_recording):
    recording, _ = garment_recording
    for piece in ("front", "back"):
        chunks = recording[f"/cloth/pieces/{piece}"]
        topology = [c for _, c in chunks if "Mesh3D:triangle_indices" in c]
        assert topology[0]["Mesh3D:triangle_indices"][0] == [[0, 1, 2], [1, 3, 2]]  # local to the piece
        assert topology[0]["Mesh3D:albedo_factor"][0] == [0xFFFFFFFF]  # white: the strain colours show as they are
        positions = [c for _, c in chunks if "Mesh3D:vertex_positions" in c][0]["Mesh3D:vertex_positions"][0]
        assert len(positions) == 4
        assert any("Clear:is_recursive" in c for _, c in chunks)  # gone at the merge
    mesh = [c for _, c in recording["/cloth/mesh"] if "Mesh3D:triangle_indices" in c]
    assert mesh[0]["Mesh3D:triangle_indices"][0] == [[0, 1, 2], [1, 3, 2], [4, 5, 0]] and mesh[0]["frame"] == [1]
    seam = sorted((c["frame"], c) for _, c in recording["/cloth/seams/left\\ side"])  # the chunks in time order
    assert [f for f, _ in seam] == [[0], [1]] and "LineStrips3D:strips" in seam[0][1]
    assert "Clear:is_recursive" in seam[1][1]
    assert "Mesh3D:vertex_positions" in recording["/cloth/body"][0][1]


def test_a_plain_cloth_has_no_pattern_and_no_legend(tmp_path):
    layout = SceneLayout("sheet", False, {"energy": ["kinetic", "potential", "total"]})
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    with Recorder(tmp_path / "sheet.rrd") as rec:
        rec.begin_cloth("cloth", layout)
        rec.log_frame("cloth", FrameSnapshot(0, 0.0, x, np.zeros_like(x), np.array([[0, 1, 2]]), 0,
                                             scalars={"energy": [0.0, 0.0, 0.0]}))
    recording, blueprint = read_back(tmp_path / "sheet.rrd")
    assert sorted(views(blueprint)) == ["energy [J]", "events", "scene"]
    assert "/legend/strain" not in recording
    mesh = [c for _, c in recording["/cloth/mesh"] if "Mesh3D:triangle_indices" in c][0]
    assert mesh["Mesh3D:albedo_factor"][0] != [0xFFFFFFFF]  # the cloth's own colour


def test_the_camera_is_framed_anew_at_close_on_where_the_cloth_went(tmp_path):
    layout = SceneLayout("falling", False, {"energy": ["kinetic", "potential", "total"]})
    x = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    with Recorder(tmp_path / "moved.rrd") as rec:
        rec.begin_cloth("cloth", layout)
        for frame, shift in enumerate((0.0, 1.0, 3.0)):
            rec.log_frame("cloth", FrameSnapshot(frame, frame / 60, x + [shift, 0, 0], np.zeros_like(x),
                                                 np.array([[0, 1, 2]]), 0))
    eye = views(read_back(tmp_path / "moved.rrd")[1])["scene"][3]
    np.testing.assert_allclose(eye["EyeControls3D:look_target"][0][0], [3.5, 0.5, 0.0], atol=1e-6)
