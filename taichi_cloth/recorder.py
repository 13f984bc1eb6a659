"""Recorder: every Rerun call of the engine lives here (rerun-sdk 0.41).

One explicit RecordingStream saved to an .rrd file as it goes (so a run that fails midway keeps what it recorded).
A recorder is given plain data, never a scene: a SceneLayout once per cloth and a FrameSnapshot per recorded frame
(taichi_cloth.frame). The mesh topology is logged once as static data, or on the timeline whenever the snapshot's
topology version changes (a level switch, merged seams); each frame logs only the vertex positions, normals and
colours (Rerun's partial-update pattern), the scalars and the events. The per-frame mesh data and scalars are kept
in memory and sent as columns every BATCH_FRAMES frames (one Rerun call for many frames costs less than a call a
frame: docs/performance.md); flush() and close() send what is kept, so a run that fails
midway loses nothing.
Whole frames only, wherever a Ctrl-C (KeyboardInterrupt) lands: a frame's Rerun calls are planned in plain Python
first (an interrupt there drops the frame), then queued in one step, all or none, and a call leaves the queue only
after it returned, so the recorder's next call (close() at the latest, as a `with` block ends) finishes a frame or a
batch of columns an interrupt stopped; `frames_logged` counts the frames made whole (their columns kept). A call
interrupted just after Rerun took it is made again: the same rows at the same time, drawn one over the other.
Timelines: "frame" (sequence) and "sim_time" (duration, s). Scalars live under
metrics/<entity>/...: energy (kinetic, potential, total [J]), strain/max, speed/max [m/s], level, seam_gap [mm],
perf/steps_per_s.

What a user opens: the world is right-handed with Y up (logged once at "/"), and every recording of a cloth carries
a default blueprint (the viewer's layout: taichi_cloth.blueprint). A garment's pattern pieces are entities of their own (<entity>/pieces/<piece>) until its
seams merge, then one mesh (<entity>/mesh); the seams show as lines (<entity>/seams, every open pair) while they
close; a body mesh is <entity>/body.
Open a recording with `rerun FILE.rrd`.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path

import numpy as np
import rerun as rr

from clothbase.meshes import vertex_normals

from .blueprint import LEGEND, Shown, default_blueprint
from .paths import free_path
from .strain import strain_colormap, strain_colors

#: the engine's world: right-handed, Y up (+z is the body's front)
WORLD = rr.ViewCoordinates.RIGHT_HAND_Y_UP
CLOTH_COLOR = (200, 90, 60, 255)
WHITE = (255, 255, 255, 255)  # the albedo of a mesh with vertex colours (the albedo multiplies them)
SEAM_COLOR = (40, 110, 220, 255)
PIN_COLOR = (30, 30, 30, 255)
BODY_COLOR = (170, 170, 180, 255)
FLOOR_COLOR = (120, 140, 120, 255)
#: frames of mesh data and scalars kept before they are sent in one call (half a second at 60 frames per second)
BATCH_FRAMES = 30


@dataclass
class _Kept:
    """One whole frame of a cloth entity kept to be sent with others as columns: its frame index and simulated time
    t [s]; (P,3) float32 positions [m] (None: a cloth without triangles, whose points are logged at once), (P,3)
    float32 normals and (P,4) uint8 colours or None; scalars: series path -> (n,) float64 values."""

    frame: int
    t: float
    positions: np.ndarray | None
    normals: np.ndarray | None
    colors: np.ndarray | None
    scalars: dict


@dataclass(frozen=True)
class _Call:
    """One call of the recording stream: stream.<method>(*args, **kwargs) (method "": none, only the time set), made
    with the stream's time set to `time` ((timeline, set_time keyword, value) triples, see _at) or, when None, to
    whatever it is (static data, columns, the blueprint)."""

    method: str
    args: tuple = ()
    kwargs: dict = field(default_factory=dict)
    time: tuple | None = None


def _at(frame: int, t: float) -> tuple:
    """The time of a frame: index `frame` on the "frame" timeline, simulated time t [s] on "sim_time"."""
    return ("frame", "sequence", frame), ("sim_time", "duration", t)


def _index(kept: list) -> list:
    """The time columns of the frames `kept` (_Kept)."""
    return [rr.TimeColumn("frame", sequence=[k.frame for k in kept]),
            rr.TimeColumn("sim_time", duration=[k.t for k in kept])]


def _path(*parts: str) -> str:
    """An entity path from plain names (a seam named "left side" keeps its space): each `/`-separated part escaped."""
    return "/".join(rr.escape_entity_path_part(p) for part in parts for p in part.split("/") if p)


def _collider_names(colliders: list) -> list[str]:
    """The entity name of each collider description: a mesh is the body, primitives are colliders (numbered from
    the second of a kind)."""
    names, seen = [], {}
    for d in colliders:
        base = "body" if d["kind"] == "mesh" else "colliders"
        seen[base] = seen.get(base, 0) + 1
        names.append(base if seen[base] == 1 else f"{base}_{seen[base]}")
    return names


def _quaternion_z_to(direction) -> list:
    """xyzw quaternion rotating +z onto `direction` (Rerun capsules extend along +z)."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    c = float(z @ d)
    if c < -1 + 1e-9:
        return [1.0, 0.0, 0.0, 0.0]
    axis = np.cross(z, d)
    q = np.array([*axis, 1.0 + c])
    return (q / np.linalg.norm(q)).tolist()


class Recorder:
    """Writes one .rrd file at `path` (its folder is created); `application_id` names the app in the viewer. An
    existing file is kept: the recording goes to the first free `NAME-2.rrd`, `NAME-3.rrd`... unless `overwrite`;
    `path` says where it went.

    Every Rerun call after the constructor's goes through one queue (see the module's docstring): a public method
    first finishes what an interrupt left queued, then plans its calls and state changes without making any
    (the _..._ops methods: a list of _Call and of callables without arguments that change the recorder's state,
    each of which may run twice in a row with the effect of once), queues them in one step and makes them."""

    def __init__(self, path: str | Path, application_id: str = "taichi_cloth", recording_name: str | None = None,
                 overwrite: bool = False):
        self.path = Path(path) if overwrite else free_path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._versions: dict[str, int] = {}  # entity -> the topology version it logged last
        self._static_topology: dict[str, bool] = {}  # entity -> its triangles never change
        self._batches: dict[str, list[_Kept]] = {}  # entity -> the frames kept for one send
        self._parts: dict[str, list] = {}  # entity -> (mesh entity path, (P_k,) particles or None: all) per part
        self._segments: dict[str, set] = {}  # entity -> the segment entity paths logged last
        self._colliders: dict[str, list] = {}  # entity -> the entity path of each collider
        self._shown: dict[str, Shown] = {}  # entity -> what the blueprint frames and plots
        self._framed = None  # the box [m] (lo, hi) the blueprint sent last frames
        self._queue: deque = deque()  # the calls and state changes planned and not made yet, in order
        self._time = None  # the time (_Call.time) the stream is known to be set to
        # an OSError naming the file when it cannot be written (rerun's save says so only in a RuntimeError's text)
        open(self.path, "wb").close()
        self.stream = rr.RecordingStream(application_id)
        self.stream.save(str(self.path))
        if recording_name:
            self.stream.send_recording_name(recording_name)
        self.stream.log("/", WORLD, static=True)
        self.frames_logged = 0

    # ------------------------------------------------------------------ the queue
    def _commit(self, ops: list) -> None:
        """Queue `ops` (planned while nothing was queued) and make them."""
        # deque.extend of a list runs no bytecode, so no KeyboardInterrupt lands inside it: all of them or none
        self._queue.extend(ops)
        self._drain()

    def _drain(self) -> None:
        """Make the queued calls and state changes in order. One that an interrupt stopped stays first in the
        queue, to be made again by the next drain; one that raised an Exception is dropped (it would fail again, and
        close() could not finish the file)."""
        queue = self._queue
        while queue:
            op = queue[0]
            try:
                self._make(op)
            except Exception:
                queue.popleft()
                raise
            queue.popleft()

    def _make(self, op) -> None:
        """Make one queued op: a state change, or a _Call at its time."""
        if not isinstance(op, _Call):
            op()
            return
        if op.time is not None and op.time != self._time:
            self._time = None  # unknown until every timeline is set
            for timeline, kind, value in op.time:
                self.stream.set_time(timeline, **{kind: value})
            self._time = op.time
        if op.method:
            getattr(self.stream, op.method)(*op.args, **op.kwargs)

    @staticmethod
    def _state(target: dict, key, value) -> partial:
        """A state change that queues: target[key] = value (value None: the key removed)."""
        return partial(target.__setitem__, key, value) if value is not None else partial(target.pop, key, None)

    # ------------------------------------------------------------------ cloth
    def begin_cloth(self, entity: str, layout, translation=None) -> None:
        """What does not change during a run of the cloth `entity` (a SceneLayout): series names, colliders, and an
        optional placement [m] of the entity in the viewer."""
        self._drain()
        ops = []
        if translation is not None:
            ops.append(_Call("log", (entity, rr.Transform3D(translation=np.asarray(translation, np.float32))),
                             {"static": True}))
        for path, names in layout.series.items():
            ops.append(_Call("log", (f"metrics/{entity}/{path}", rr.SeriesLines(names=names)), {"static": True}))
        colliders = [f"{entity}/{name}" for name in _collider_names(layout.colliders)]
        for path, description in zip(colliders, layout.colliders):
            ops += self._collider_ops(path, description, static=not description.get("moving", False))
        if layout.strain_scale is not None:
            legend = rr.EncodedImage(contents=strain_colormap(layout.strain_scale).legend_png(), media_type="image/png")
            ops.append(_Call("log", (LEGEND, legend), {"static": True}))
        offset = np.zeros(3) if translation is None else np.asarray(translation, np.float64)
        ops += [self._state(self._static_topology, entity, not layout.topology_changes),
                self._state(self._versions, entity, None), self._state(self._colliders, entity, colliders),
                self._state(self._shown, entity, Shown(layout, offset))]
        self._commit(ops)

    def log_collider(self, entity: str, description: dict, static: bool = True) -> None:
        """A collider, once, as static data: a body mesh, spheres, capsules and planes (a 4 m square). A body that
        morphs during the run is logged on the timeline instead (static=False; log_frame moves its vertices)."""
        self._drain()
        self._commit(self._collider_ops(entity, description, static))

    def _collider_ops(self, entity: str, description: dict, static: bool) -> list:
        if description["kind"] == "self":
            return []
        if description["kind"] == "mesh":
            v, tri = np.asarray(description["vertices"], np.float32), np.asarray(description["triangles"], np.int64)
            normals = vertex_normals(v, tri).astype(np.float32)  # without them the viewer draws a flat silhouette
            return [_Call("log", (entity, rr.Mesh3D(vertex_positions=v, triangle_indices=tri.astype(np.uint32),
                                                    vertex_normals=normals, albedo_factor=BODY_COLOR)),
                          {"static": static})]
        ops = []
        if description["spheres"]:
            ops.append(_Call("log", (f"{entity}/spheres", rr.Ellipsoids3D(
                centers=[c for c, _ in description["spheres"]],
                half_sizes=[[r, r, r] for _, r in description["spheres"]], colors=BODY_COLOR,
                fill_mode=rr.components.FillMode.Solid)), {"static": True}))
        if description["capsules"]:
            caps = description["capsules"]
            ops.append(_Call("log", (f"{entity}/capsules", rr.Capsules3D(
                lengths=[float(np.linalg.norm(b - a)) for a, b, _ in caps], radii=[r for *_, r in caps],
                translations=[a for a, _, _ in caps], quaternions=[_quaternion_z_to(b - a) for a, b, _ in caps],
                colors=BODY_COLOR, fill_mode=rr.components.FillMode.Solid)), {"static": True}))
        for k, (point, normal) in enumerate(description["planes"]):
            u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
            u /= np.linalg.norm(u)
            w = np.cross(normal, u)
            corners = np.array([point + 2 * (su * u + sw * w) for su, sw in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
            ops.append(_Call("log", (f"{entity}/planes/{k}", rr.Mesh3D(
                vertex_positions=corners.astype(np.float32),
                triangle_indices=np.array([[0, 1, 2], [0, 2, 3]], np.uint32), albedo_factor=FLOOR_COLOR)),
                {"static": True}))
        return ops

    def log_frame(self, entity: str, frame) -> None:
        """Log a FrameSnapshot of the cloth `entity`: the topology when its version is new, positions, normals,
        colours, points (pins), moved collider vertices, scalars and events. The frame is logged whole or not at
        all (an interrupt while it is planned drops it; one while it is made leaves the rest to the next call)."""
        self._drain()
        self._commit(self._frame_ops(entity, frame))

    def _frame_ops(self, entity: str, frame) -> list:
        """log_frame's calls and state changes, in order."""
        at = _at(frame.frame, frame.t)
        ops = [_Call("", time=at)]  # the stream's time is the frame's after it, as what is logged without one expects
        triangles = len(frame.triangles) > 0
        kept = self._batches.get(entity, [])
        parts = self._parts.get(entity)
        if self._versions.get(entity) != frame.topology_version:
            ops += self._send_ops(entity, kept, parts)  # the frames kept belong to the topology before
            kept = []
            static = self._static_topology.get(entity, True)
            if triangles:
                topology, parts = self._topology_ops(entity, frame, static, at)
                ops += topology + [self._state(self._parts, entity, parts)]
            for name, points in frame.fixed_points.items():
                ops.append(_Call("log", (f"{entity}/{name}", rr.Points3D(np.asarray(points, np.float32), radii=0.01,
                                                                         colors=PIN_COLOR)), {"static": static}, at))
            ops.append(self._state(self._versions, entity, frame.topology_version))
        if triangles or frame.scalars:
            kept = [*kept, self._kept(frame, triangles)]
            ops.append(partial(self._keep, entity, kept))
        if not triangles:
            ops.append(_Call("log", (f"{entity}/particles", rr.Points3D(frame.positions, radii=0.005,
                                                                        colors=CLOTH_COLOR)), time=at))
        for name, points in frame.points.items():
            ops.append(_Call("log", (f"{entity}/{name}", rr.Points3D(np.asarray(points, np.float32), radii=0.01,
                                                                     colors=PIN_COLOR)), time=at))
        ops += self._segment_ops(entity, frame.segments, at)
        for k, vertices in frame.meshes.items():
            ops.append(_Call("log", (self._colliders[entity][k], rr.Mesh3D.from_fields(vertex_positions=vertices)),
                             time=at))
        for k, (rotation, translation) in frame.poses.items():  # drawn as built, placed by its pose
            ops.append(_Call("log", (self._colliders[entity][k], rr.Transform3D(translation=translation,
                                                                                mat3x3=rotation)), time=at))
        ops += self._event_ops(entity, at, frame.events)
        shown = self._shown.get(entity)
        if shown is not None and len(frame.positions):
            x = np.asarray(frame.positions)
            now = replace(shown, lo=x.min(axis=0) + shown.translation, hi=x.max(axis=0) + shown.translation, points=x)
            ops.append(self._state(self._shown, entity, now))
            if shown.lo is None:  # a layout from the start (kept if the run dies), framed anew at close() on the last
                ops += self._blueprint_ops({**self._shown, entity: now})
        ops.append(partial(setattr, self, "frames_logged", self.frames_logged + 1))
        if len(kept) >= BATCH_FRAMES:
            ops += self._send_ops(entity, kept, parts)
        return ops

    @staticmethod
    def _kept(frame, triangles: bool) -> _Kept:
        """What a frame sends as columns: its mesh data when it has triangles, its scalars."""
        positions = normals = colors = None
        if triangles:
            positions = np.asarray(frame.positions, np.float32)
            normals = None if frame.normals is None else np.asarray(frame.normals, np.float32)
            colors = None if frame.colors is None else np.asarray(frame.colors, np.uint8)
        scalars = {path: np.atleast_1d(np.asarray(v, np.float64)) for path, v in frame.scalars.items()}
        return _Kept(frame.frame, frame.t, positions, normals, colors, scalars)

    def _keep(self, entity: str, kept: list) -> None:
        """The frames `kept` of `entity`: the last is new."""
        self._batches[entity] = kept  # one store: the batch before or the batch with the frame, never between

    def _topology_ops(self, entity: str, frame, static: bool, at: tuple) -> tuple[list, list]:
        """(calls, parts): the triangles of each part of the cloth (frame.pieces, or the whole mesh), white-lit when
        the vertices carry colours; parts of the topology before that are gone are cleared."""
        tri = np.asarray(frame.triangles, np.int64)
        parts = [(f"{entity}/pieces/{_path(name)}", np.asarray(idx, np.int64)) for name, idx in frame.pieces.items()]
        parts = parts or [(f"{entity}/mesh", None)]
        ops = [_Call("log", (path, rr.Clear(recursive=False)), time=at)  # e.g. the pieces at the seam merge
               for path in sorted({path for path, _ in self._parts.get(entity, [])} - {path for path, _ in parts})]
        albedo = CLOTH_COLOR if frame.colors is None else WHITE
        for path, idx in parts:
            local = tri
            if idx is not None:
                index = np.full(len(frame.positions), -1, np.int64)
                index[idx] = np.arange(len(idx))
                local = index[tri]
                local = local[(local >= 0).all(axis=1)]
            mesh = rr.Mesh3D.from_fields(triangle_indices=local.astype(np.uint32), albedo_factor=albedo)
            ops.append(_Call("log", (path, mesh), {"static": static}, at))
        return ops, parts

    def _segment_ops(self, entity: str, segments: dict, at: tuple) -> list:
        """Line segments (S,2,3) [m] by name; a name logged before and missing now is cleared."""
        ops, now = [], set()
        for name, seg in segments.items():
            path = f"{entity}/{_path(name)}"
            strips = rr.LineStrips3D(np.asarray(seg, np.float32), radii=0.0015, colors=SEAM_COLOR)
            ops.append(_Call("log", (path, strips), time=at))
            now.add(path)
        ops += [_Call("log", (path, rr.Clear(recursive=False)), time=at)
                for path in sorted(self._segments.get(entity, set()) - now)]
        return ops + [self._state(self._segments, entity, now)]

    def _blueprint_ops(self, shown: dict) -> list:
        """Send the default layout of the cloths `shown` (entity -> Shown) when the box it frames changed since it
        was sent last."""
        framed = [s for s in shown.values() if s.lo is not None]
        if not framed:
            return []
        box = (np.min([s.lo for s in framed], axis=0), np.max([s.hi for s in framed], axis=0))
        if self._framed is not None and all(np.allclose(a, b, atol=1e-3) for a, b in zip(box, self._framed)):
            return []
        points = np.concatenate([np.asarray(s.points, np.float64) + s.translation for s in framed])
        return [_Call("send_blueprint", (default_blueprint(shown, *box, points),)),
                partial(setattr, self, "_framed", box)]

    def _send_ops(self, entity: str, kept: list, parts: list | None) -> list:
        """The calls that send the frames `kept` (_Kept, whole) of `entity` as columns (one for each mesh part:
        `parts`, None: the whole mesh; one per scalar series), then forget them."""
        if not kept:
            return []
        ops = []
        mesh = [k for k in kept if k.positions is not None]
        if mesh:
            fields = {"vertex_positions": [k.positions for k in mesh]}
            if all(k.normals is not None for k in mesh):
                fields["vertex_normals"] = [k.normals for k in mesh]
            if all(k.colors is not None for k in mesh):
                fields["vertex_colors"] = [k.colors for k in mesh]
            for path, idx in parts or [(f"{entity}/mesh", None)]:
                part = {name: [a if idx is None else a[idx] for a in arrays] for name, arrays in fields.items()}
                lengths = [len(p) for p in part["vertex_positions"]]
                columns = rr.Mesh3D.columns(**{name: np.concatenate(arrays) for name, arrays in part.items()})
                ops.append(_Call("send_columns", (path,), {"indexes": _index(mesh),
                                                           "columns": columns.partition(lengths)}))
        series: dict[str, list[_Kept]] = {}
        for k in kept:
            for path in k.scalars:
                series.setdefault(path, []).append(k)
        for path, rows in series.items():
            values = [k.scalars[path] for k in rows]
            column = rr.Scalars.columns(scalars=np.concatenate(values)).partition([len(v) for v in values])
            ops.append(_Call("send_columns", (f"metrics/{entity}/{path}",), {"indexes": _index(rows),
                                                                             "columns": column}))
        return ops + [self._state(self._batches, entity, None)]

    def log_events(self, entity: str, frame: int, t: float, events) -> None:
        """Text events ((level, text) pairs: "INFO", "WARN", "ERROR") at `frame`, simulated time t [s]."""
        self._drain()
        self._commit(self._event_ops(entity, _at(frame, t), events))

    @staticmethod
    def _event_ops(entity: str, at: tuple, events) -> list:
        return [_Call("log", (f"{entity}/events", rr.TextLog(text, level=level)), time=at) for level, text in events]

    def log_flat_pieces(self, entity: str, pieces, layouts=None, translation=(0.0, 0.0, 0.0), gap: float = 0.05,
                        full_scale: float = 0.05) -> None:
        """Flattened pieces (taichi_cloth.flatten.FlatPiece), static, side by side in the x-y plane from
        `translation` [m] with `gap` [m] between them: each a mesh coloured by its error map (the mean |edge
        length error| at each vertex: white at 0, red at `full_scale` and above) and its outline.
        layouts: optional (V,2) arrays to draw instead of each piece's uv (e.g. aligned to the pattern)."""
        self._drain()
        ops = []
        layouts = list(layouts) if layouts is not None else [p.uv for p in pieces]
        x0 = 0.0
        for piece, uv in zip(pieces, layouts):
            uv = np.asarray(uv, dtype=np.float64)
            lo = uv.min(axis=0)
            pos = np.c_[uv - lo + [x0, 0.0], np.zeros(len(uv))] + np.asarray(translation, dtype=np.float64)
            x0 += float(np.ptp(uv[:, 0])) + gap
            path = f"{entity}/{piece.name}"
            ops.append(_Call("log", (f"{path}/mesh", rr.Mesh3D(
                vertex_positions=pos.astype(np.float32), triangle_indices=piece.triangles.astype(np.uint32),
                vertex_colors=strain_colors(piece.vertex_error(), full_scale))), {"static": True}))
            outline = pos[np.append(piece.boundary, piece.boundary[0])]
            ops.append(_Call("log", (f"{path}/outline", rr.LineStrips3D(
                [outline.astype(np.float32)], colors=[[20, 20, 20]], radii=0.002)), {"static": True}))
        self._commit(ops)

    def log_pattern(self, outlines: dict, corners, corner_names, sides, side_labels, side_colors) -> None:
        """A garment's pattern as static 2D data under `pattern/` (taichi_cloth.pattern_view): outlines {piece name:
        (n, 2) [m]} as pattern/pieces/<name>, corners (k, 2) [m] labelled corner_names as pattern/corners, seam
        sides (list of (m, 2) [m], in pick order) as pattern/seams, labelled by seam number (a pair shares one),
        with an arrow at each side's end for its direction (pattern/seams/directions)."""
        self._drain()
        static = {"static": True}
        ops = [_Call("log", (f"pattern/pieces/{name}", rr.LineStrips2D(
            [np.asarray(outline, np.float32)], colors=[[60, 60, 60]], labels=[name])), static)
            for name, outline in outlines.items()]
        ops.append(_Call("log", ("pattern/corners", rr.Points2D(
            np.asarray(corners, np.float32), labels=list(corner_names), colors=[[0, 0, 0]], radii=0.004)), static))
        sides = [np.asarray(s, np.float32) for s in sides]
        ops.append(_Call("log", ("pattern/seams", rr.LineStrips2D(
            sides, labels=list(side_labels), colors=list(side_colors), radii=0.004)), static))
        tails = [s[max(0, len(s) - 3)] for s in sides]
        arrows = rr.Arrows2D(origins=tails, vectors=[s[-1] - t for s, t in zip(sides, tails)], colors=list(side_colors),
                             radii=0.004)
        ops.append(_Call("log", ("pattern/seams/directions", arrows), static))
        self._commit(ops)

    # ------------------------------------------------------------------ studies (benchmark results)
    def log_document(self, entity: str, markdown: str) -> None:
        """A markdown text (e.g. a benchmark's report), static."""
        self._drain()
        self._commit([_Call("log", (entity, rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN)),
                            {"static": True})])

    def log_image_file(self, entity: str, path) -> None:
        """An image file (e.g. a benchmark's PNG plot), static."""
        self._drain()
        self._commit([_Call("log", (entity, rr.EncodedImage(path=Path(path))), {"static": True})])

    def log_samples(self, entity: str, times, positions, triangles, translation=(0.0, 0.0, 0.0)) -> None:
        """A cloth sampled at simulated `times` (S,) [s]: `positions` (S,P,3) [m] on the sim_time timeline, its
        (T,3) `triangles` once, the whole displaced by `translation` [m]. NaN samples (after a blow-up) are skipped."""
        self._drain()
        ops = [_Call("log", (entity, rr.Transform3D(translation=np.asarray(translation, np.float32))),
                     {"static": True}),
               _Call("log", (f"{entity}/mesh", rr.Mesh3D.from_fields(
                   triangle_indices=np.asarray(triangles, np.uint32), albedo_factor=CLOTH_COLOR)), {"static": True})]
        for t, x in zip(times, positions):
            if np.isfinite(x).all():
                ops.append(_Call("log", (f"{entity}/mesh", rr.Mesh3D.from_fields(
                    vertex_positions=np.asarray(x, np.float32))), time=(("sim_time", "duration", float(t)),)))
        self._commit(ops)

    # ------------------------------------------------------------------ lifetime
    def flush(self) -> None:
        """Finish what an interrupt left, send every kept frame and write what the stream holds to the file."""
        self._drain()
        ops = [op for entity, kept in self._batches.items() for op in self._send_ops(entity, kept,
                                                                                      self._parts.get(entity))]
        self._commit(ops + [_Call("flush")])

    def close(self) -> None:
        """Frame the 3D view on where the cloths went, flush and finish the file (writes the footer); the recorder
        cannot be used afterwards."""
        self._drain()
        self._commit(self._blueprint_ops(self._shown))
        self.flush()
        self._commit([_Call("disconnect")])

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, kind, exc, traceback) -> None:
        self.close()
        if exc is not None and getattr(exc, "output", None) is None:
            exc.output = str(self.path)  # what the command line names as kept (taichi_cloth.cli.ends)
