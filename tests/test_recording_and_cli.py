"""Recordings read back with the expected entities and frames; the CLI writes what it says; a blow-up
keeps the recording made so far."""
import numpy as np
import pytest
import rerun as rr

import taichi_cloth as tc
from taichi_cloth.cli import main

SCENE = """
name = "rec"
frames = 5
fps = 50.0
[cloth]
material = "cotton"
[cloth.grid]
size = [0.4, 0.4]
resolution = [7, 7]
center = [0.0, 1.0, 0.0]
[integrator]
name = "{integrator}"
dt = {dt}
[[pins]]
indices = [42, 48]
"""


def rows_by_entity(path):
    """entity path -> (static rows, list of frame numbers, set of columns)."""
    out = {}
    for chunk in rr.chunk.RrdReader(path).stream().to_chunks():
        static, frames, cols = out.setdefault(chunk.entity_path, [0, [], set()])
        rb = chunk.to_record_batch()
        cols_now = set(rb.schema.names)
        if chunk.is_static:
            out[chunk.entity_path][0] += chunk.num_rows
        else:
            frames.extend(rb.column("frame").to_pylist())
        cols |= cols_now
    return out


def test_cli_run_writes_a_recording_that_reads_back(tmp_path, capsys):
    scene = tmp_path / "rec.toml"
    scene.write_text(SCENE.format(integrator="approx-implicit", dt=0.005))
    out = tmp_path / "out"
    assert main(["run", str(scene), "--out", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    # the viewer command is `rerun` or a path ending in it; the summary's instability line says nothing was found
    assert "steps/s" in text and "rerun " + str(out / "rec.rrd") in text
    assert "\n  instability: none detected\n" in text
    for suffix in (".rrd", ".obj", ".ply"):
        assert (out / f"rec{suffix}").stat().st_size > 0
    got = rows_by_entity(out / "rec.rrd")
    static, frames, cols = got["/cloth/mesh"]
    assert static == 1 and "Mesh3D:triangle_indices" in cols
    assert sorted(frames) == list(range(6))  # frame 0 plus 5 frames
    assert {"Mesh3D:vertex_positions", "Mesh3D:vertex_normals"} <= cols
    assert sorted(got["/metrics/cloth/energy"][1]) == list(range(6))
    assert got["/cloth/pins"][0] == 1  # fixed pins: logged once
    import meshio

    mesh = meshio.read(out / "rec.obj")
    assert mesh.points.shape == (49, 3) and len(mesh.cells_dict["triangle"]) == 72


@pytest.mark.filterwarnings(r"ignore:dt = 0\.002 s exceeds the stable step .* of integrator 'explicit'"
                            ":clothbase.errors.EngineWarning")  # the step that blows up
def test_blow_up_stops_cleanly_and_keeps_the_recording(tmp_path, capsys):
    scene = tmp_path / "rec.toml"
    scene.write_text(SCENE.format(integrator="explicit", dt=0.002).replace("frames = 5", "frames = 50"))
    out = tmp_path / "out"
    assert main(["run", str(scene), "--out", str(out), "--no-progress"]) == 3
    captured = capsys.readouterr()
    assert "blow-up: integrator 'explicit'" in captured.err and "suggested stable step" in captured.err
    assert (captured.out + captured.err).count("suggested stable step") == 1  # the message prints once
    assert "instability: blew up by step" in captured.out
    got = rows_by_entity(out / "rec.rrd")
    frames = sorted(got["/cloth/mesh"][1])
    assert 0 < len(frames) < 51 and frames == list(range(len(frames)))
    assert any("TextLog" in c for c in got["/cloth/events"][2])


def test_scene_api_reads_positions_as_numpy(tmp_path):
    scene = tmp_path / "rec.toml"
    scene.write_text(SCENE.format(integrator="implicit", dt=0.01))
    sc = tc.load_scene(scene).scene
    x0 = sc.positions()
    sc.step(10)
    x = sc.positions()
    assert x.shape == (49, 3) and x.dtype == np.float64
    assert np.all(x[:, 1] <= x0[:, 1] + 1e-9) and np.abs(x - x0).max() > 1e-4
    t_before = sc.state.t
    summary = sc.run(2, progress=False)
    # the summary's simulated time counts from the run's start, not from t = 0
    assert summary.steps == 2 * sc.substeps and summary.sim_time == pytest.approx(sc.state.t - t_before)


def test_a_second_run_keeps_the_first_runs_files(tmp_path, capsys):
    scene = tmp_path / "rec.toml"
    scene.write_text(SCENE.format(integrator="implicit", dt=0.02))
    out = tmp_path / "out"
    for _ in range(2):
        assert main(["run", str(scene), "--out", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["rec-2.obj", "rec-2.ply", "rec-2.rrd", "rec.obj", "rec.ply",
                                                     "rec.rrd"]
    assert f"wrote {out / 'rec-2.rrd'}" in text and f"rerun {out / 'rec-2.rrd'}" in text
    rec = tc.Recorder(out / "rec.rrd")  # the API numbers the file too, unless told to overwrite
    assert rec.path.name == "rec-3.rrd"
    rec.close()


def test_the_frame_clock_stays_true_when_dt_does_not_divide_a_frame(tmp_path):
    """dt = 0.01 s at 60 fps: each frame takes two steps of 1/120 s (no longer than dt), so 60 frames are 1 s."""
    scene = tmp_path / "rec.toml"
    scene.write_text(SCENE.format(integrator="implicit", dt=0.01).replace("fps = 50.0", "fps = 60.0"))
    sc = tc.load_scene(scene).scene
    summary = sc.run(60, progress=False)
    assert summary.steps == 120 and summary.sim_time == pytest.approx(1.0, rel=1e-12)
    assert summary.dt_max == pytest.approx(1 / 120, rel=1e-12) and sc.dt == 0.01
    assert "0.01 s requested" in summary.format()
    # a step that divides the frame to 1e-6 (a rounded 1/120 s) is not split further
    sc.dt = 0.008333333
    assert sc.substeps == 2


def test_import_is_light_and_warnings_are_one_line_once():
    """`import taichi_cloth` does not import rerun (only recording does); an engine warning prints once, as one
    line without a source line under it."""
    import subprocess
    import sys

    code = ("import sys, warnings\n"
            "import taichi_cloth as tc\n"
            "assert 'rerun' not in sys.modules\n"
            "from clothbase.errors import warn\n"
            "for _ in range(3):\n"
            "    warn('something to know')\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    lines = [ln for ln in done.stderr.splitlines() if not ln.startswith("[Taichi]")]
    assert lines == ["warning: something to know"]
