"""A Ctrl-C anywhere in a recording leaves whole frames: a KeyboardInterrupt raised at the k-th Rerun call of a
recording (every k of a short run), or at the k-th line the Recorder runs, then the recorder closed as a `with`
block closes it (as the command line's run does), and the recording read back: no RerunWarning, every frame that
`frames_logged` announces is there with all of its mesh data, scalars, points, segments and events, each row
whole, and nothing of a frame beyond. Plain data into the Recorder (no scene, no kernels); a batch of 3 frames so a
short run sends several batches, a topology change (the pieces merge) at frame 5."""
import sys
import warnings
from collections import Counter

import numpy as np
import pyarrow.compute as pc
import pytest
import rerun as rr

from taichi_cloth import recorder as recorder_module
from taichi_cloth.frame import FrameSnapshot, SceneLayout
from taichi_cloth.recorder import Recorder

FRAMES, MERGE, BATCH = 10, 5, 3
EVENTS = (2, 7)  # the frames with an event
SERIES = {"energy": 3, "strain/max": 1, "seam_gap": 2}  # series path -> values a frame
#: the columns read back: the components of the rows on the frame timeline (index columns left out)
INDEX = ("rerun.controls.RowId", "log_time", "frame", "sim_time")


def snapshots() -> list[FrameSnapshot]:
    """FRAMES frames of a garment of two 4-particle pieces (front: 0-3, back: 4-7) sewn by one seam until MERGE,
    then one mesh of 6 particles: positions, normals, colours, moving pins, a moving body, scalars, events."""
    square = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    x = np.concatenate([square + [0, 1, 0.25], square + [0, 1, -0.25]]).astype(np.float32)
    out = []
    for f in range(FRAMES):
        merged = f >= MERGE
        p = (x[:6] if merged else x) + np.float32(0.01 * f)
        tri = np.array([[0, 1, 2], [1, 3, 2], [4, 5, 0]] if merged else [[0, 1, 2], [1, 3, 2], [4, 5, 6], [5, 7, 6]])
        snap = FrameSnapshot(f, f / 60, p, np.tile(np.float32([0, 0, 1]), (len(p), 1)), tri, int(merged),
                             colors=np.full((len(p), 4), 200, np.uint8), points={"pins": p[:2]},
                             meshes={0: square + np.float32(0.01 * f)},
                             scalars={path: [0.1 * f] * n if n > 1 else 0.1 * f for path, n in SERIES.items()},
                             events=[("INFO", f"event at frame {f}")] if f in EVENTS else [])
        if not merged:
            snap.pieces = {"front": np.arange(4), "back": np.arange(4, 8)}
            snap.segments = {"seams/left side": np.stack([p[[0, 2]], p[[4, 6]]], 1)}
        out.append(snap)
    return out


def layout() -> SceneLayout:
    square = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    return SceneLayout("two pieces", True, {path: ["v"] * n if n > 1 else "v" for path, n in SERIES.items()},
                       colliders=[{"kind": "mesh", "vertices": square, "triangles": np.array([[0, 1, 2], [1, 3, 2]]),
                                   "moving": True}], garment=True)


def expected(n: int) -> dict:
    """entity -> Counter of (frame, ((component, values), ...)) rows on the frame timeline of frames 0..n-1."""
    out = {}

    def row(entity, frame, **lengths):
        out.setdefault(entity, Counter())[(frame, tuple(sorted(lengths.items())))] += 1

    mesh = {"Mesh3D:vertex_positions": 0, "Mesh3D:vertex_normals": 0, "Mesh3D:vertex_colors": 0}
    for piece in ("front", "back")[:2 if n else 0]:  # the pieces' triangles: on the timeline (they change)
        row(f"/cloth/pieces/{piece}", 0, **{"Mesh3D:triangle_indices": 2, "Mesh3D:albedo_factor": 1})
    for f in range(n):
        for path, count in SERIES.items():
            row(f"/metrics/cloth/{path}", f, **{"Scalars:scalars": count})
        row("/cloth/pins", f, **{"Points3D:positions": 2, "Points3D:radii": 1, "Points3D:colors": 1})
        row("/cloth/body", f, **{"Mesh3D:vertex_positions": 4})
        if f in EVENTS:
            row("/cloth/events", f, **{"TextLog:text": 1, "TextLog:level": 1})
        if f < MERGE:
            for piece in ("front", "back"):
                row(f"/cloth/pieces/{piece}", f, **{name: 4 for name in mesh})
            row("/cloth/seams/left\\ side", f, **{"LineStrips3D:strips": 2, "LineStrips3D:radii": 1,
                                                  "LineStrips3D:colors": 1})
        else:
            row("/cloth/mesh", f, **{name: 6 for name in mesh})
    if n > MERGE:  # the merge: the pieces' triangles and the seam cleared, the mesh's triangles on the timeline
        for path in ("/cloth/pieces/front", "/cloth/pieces/back", "/cloth/seams/left\\ side"):
            row(path, MERGE, **{"Clear:is_recursive": 1})
        row("/cloth/mesh", MERGE, **{"Mesh3D:triangle_indices": 3, "Mesh3D:albedo_factor": 1})
    return out


def read_back(path) -> dict:
    """entity -> Counter of (frame, ((component, values), ...)) of each row on the frame timeline of the .rrd at
    `path` (a row's components that are not null, with the number of values each holds)."""
    out = {}
    for chunk in rr.chunk.RrdReader(path).stream().to_chunks():
        rb = chunk.to_record_batch()
        if chunk.is_static or "frame" not in rb.schema.names:
            continue
        frames = rb.column("frame").to_pylist()
        lengths = {name: pc.list_value_length(rb.column(name)).to_pylist() for name in rb.schema.names
                   if name not in INDEX}
        for i, f in enumerate(frames):
            got = tuple(sorted((name, n[i]) for name, n in lengths.items() if n[i] is not None))
            out.setdefault(chunk.entity_path, Counter())[(f, got)] += 1
    return out


def record(path, interrupt=lambda rec: None) -> tuple[Recorder, int]:
    """Record snapshots() to `path` as a run does: interrupt(rec) arms the interrupt once the recorder is open; a
    KeyboardInterrupt ends the run, the `with` block closes the recorder. Returns (the recorder, the frame being
    logged when the interrupt came: -1 before the first, FRAMES without one)."""
    frames, at = snapshots(), -1
    try:
        with Recorder(path) as rec:
            interrupt(rec)
            rec.begin_cloth("cloth", layout())
            for at, snap in enumerate(frames):
                rec.log_frame("cloth", snap)
            at = FRAMES
    except KeyboardInterrupt as err:
        assert err.output == str(path)  # what the command line names as kept
    return rec, at


#: the stream's calls an interrupt may stop: every call a frame or a batch makes
CALLS = ("set_time", "log", "send_columns", "send_blueprint")


def at_call(k: int, made: list):
    """An interrupt(rec) for record(): the k-th of the stream's CALLS (from 1; 0: none) raises KeyboardInterrupt
    instead of being made, once; `made` collects the name of each call, the interrupted one included."""
    def arm(rec):
        for name in CALLS:
            def call(*args, _real=getattr(rec.stream, name), _name=name, **kwargs):
                made.append(_name)
                if len(made) == k:
                    raise KeyboardInterrupt
                return _real(*args, **kwargs)
            setattr(rec.stream, name, call)
    return arm


def at_line(k: int, lines: list):
    """An interrupt(rec) for record(): KeyboardInterrupt at the k-th line (from 1; 0: none) the Recorder's methods
    run, before the line (as a signal lands between bytecodes), once; lines[0] counts the lines."""
    def local(frame, event, arg):
        if event == "line":
            lines[0] += 1
            if lines[0] == k:
                sys.settrace(None)
                raise KeyboardInterrupt
        return local

    def trace(frame, event, arg):
        code = frame.f_code
        mine = code.co_filename == recorder_module.__file__ and code.co_qualname.startswith("Recorder.")
        return local if mine else None

    return lambda rec: sys.settrace(trace)


def count_run(path, arm, count) -> int:
    """Record snapshots() to `path` through a recorder armed by `arm` (counting, never interrupting); returns
    count() as the run ends, before the close: what an interrupt can stop is the run's calls and lines."""
    rec = Recorder(path)
    try:
        arm(rec)
        rec.begin_cloth("cloth", layout())
        for snap in snapshots():
            rec.log_frame("cloth", snap)
        return count()
    finally:
        sys.settrace(None)
        rec.close()


def interrupted(path, arm) -> tuple[Recorder, int, list]:
    """record() armed by `arm`, warnings caught: (recorder, the frame interrupted, the warnings)."""
    tracing = sys.gettrace()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            rec, at = record(path, arm)
        finally:
            sys.settrace(tracing)
    return rec, at, [str(w.message) for w in caught]


@pytest.fixture(autouse=True)
def small_batches(monkeypatch):
    monkeypatch.setattr(recorder_module, "BATCH_FRAMES", BATCH)


def test_a_clean_run_reads_back_whole(tmp_path):
    """The reference the interrupted runs are held to: all FRAMES frames, as expected() says."""
    rec, at, caught = interrupted(tmp_path / "clean.rrd", lambda rec: None)
    assert (at, rec.frames_logged, caught) == (FRAMES, FRAMES, [])
    assert read_back(rec.path) == expected(FRAMES)


def test_an_interrupt_at_any_rerun_call_leaves_every_frame_announced_whole(tmp_path, capfd):
    """KeyboardInterrupt at each call the run makes (k = 1..all: set_time, log, send_columns of every batch,
    send_blueprint): close() finishes the frame under way (frames_logged = that frame + 1), no warning, and the
    recording holds exactly expected(frames_logged): each row once, whole, nothing beyond."""
    made = []
    total = count_run(tmp_path / "count.rrd", at_call(0, made), lambda: len(made))
    assert total >= 60 and set(made[:total]) == set(CALLS)  # every frame's middle and every batch send is a k below
    for k in range(1, total + 1):
        rec, at, caught = interrupted(tmp_path / f"call{k}.rrd", at_call(k, []))
        assert caught == [], (k, made[k - 1])
        assert at < FRAMES and rec.frames_logged == at + 1, (k, made[k - 1])
        assert read_back(rec.path) == expected(rec.frames_logged), (k, made[k - 1])
    assert "Warn" not in capfd.readouterr().err  # nor one from rerun's own log


def test_an_interrupt_at_any_line_of_the_recorder_drops_the_frame_or_finishes_it(tmp_path, capfd):
    """KeyboardInterrupt before one line in 60 the Recorder's methods run (planning, queueing, making the calls,
    the state changes): the frame under way is dropped (an interrupt while it is planned) or finished, and the
    recording holds every row of expected(frames_logged) and nothing else; a call interrupted after Rerun took it
    and before it left the queue is made again: its rows twice, one call's at most."""
    lines = [0]
    total = count_run(tmp_path / "count.rrd", at_line(0, lines), lambda: lines[0])
    assert total > 600
    for k in range(1, total + 1, total // 60):
        rec, at, caught = interrupted(tmp_path / f"line{k}.rrd", at_line(k, [0]))
        assert caught == [], k
        n = rec.frames_logged
        assert at < FRAMES and n in (at, at + 1), k
        got, want = read_back(rec.path), expected(n)
        assert sorted(got) == sorted(want), k
        assert all(got[e] >= want[e] for e in want), k  # every row
        again = {e: got[e] - want[e] for e in want if got[e] != want[e]}
        assert len(again) <= 1 and all(set(rows) <= set(want[e]) for e, rows in again.items()), (k, again)
    assert "Warn" not in capfd.readouterr().err
