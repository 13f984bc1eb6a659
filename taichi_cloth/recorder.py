"""Recorder: every Rerun call of the engine lives here (rerun-sdk 0.41).

One explicit RecordingStream saved to an .rrd file as it goes (so a run that fails midway keeps what
it recorded). The mesh topology is logged once as static data; each frame logs only the vertex
positions and normals (Rerun's partial-update pattern). Timelines: "frame" (sequence) and
"sim_time" (duration, s). Scalars live under metrics/<entity>/...: energy (three series: kinetic,
potential, total [J]), strain/max, perf/steps_per_s. Open a recording with `rerun FILE.rrd`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

CLOTH_COLOR = (200, 90, 60, 255)
PIN_COLOR = (30, 30, 30, 255)


class Recorder:
    """Writes one .rrd file. `path` is created (with its folder); `application_id` names the app in the viewer."""

    def __init__(self, path: str | Path, application_id: str = "taichi_cloth", recording_name: str | None = None):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.stream = rr.RecordingStream(application_id)
        self.stream.save(str(self.path))
        if recording_name:
            self.stream.send_recording_name(recording_name)
        self.frames_logged = 0

    # ------------------------------------------------------------------ cloth
    def begin_cloth(self, entity: str, scene, translation=None) -> None:
        """Log what does not change: topology, colour, fixed pins, an optional placement of the entity."""
        rec = self.stream
        if translation is not None:
            rec.log(entity, rr.Transform3D(translation=np.asarray(translation, np.float32)), static=True)
        tri = scene.model.data.triangles
        if len(tri):
            rec.log(f"{entity}/mesh", rr.Mesh3D.from_fields(triangle_indices=tri.astype(np.uint32),
                                                            albedo_factor=CLOTH_COLOR), static=True)
        rec.log(f"metrics/{entity}/energy", rr.SeriesLines(names=["kinetic", "potential", "total"]), static=True)
        if len(scene.pinned_indices) and scene.pins is None:
            rec.log(f"{entity}/pins", rr.Points3D(scene.model.data.positions[scene.pinned_indices].astype(np.float32),
                                                  radii=0.01, colors=PIN_COLOR), static=True)

    def log_frame(self, entity: str, scene, frame: int, measurement, steps_per_s: float | None = None) -> None:
        """Log the cloth's state at `frame` (positions, normals, moving pins) and its scalar metrics."""
        rec = self.stream
        rec.set_time("frame", sequence=frame)
        rec.set_time("sim_time", duration=scene.state.t)
        if len(scene.model.data.triangles):
            x, normals = scene.surface()
            rec.log(f"{entity}/mesh", rr.Mesh3D.from_fields(vertex_positions=x, vertex_normals=normals))
        else:
            x = scene.positions().astype(np.float32)
            rec.log(f"{entity}/particles", rr.Points3D(x, radii=0.005, colors=CLOTH_COLOR))
        if scene.pins is not None:
            rec.log(f"{entity}/pins", rr.Points3D(x[scene.pinned_indices], radii=0.01, colors=PIN_COLOR))
        m = measurement
        metrics = f"metrics/{entity}"
        rec.log(f"{metrics}/energy", rr.Scalars([m.kinetic, m.potential, m.total]))
        rec.log(f"{metrics}/strain/max", rr.Scalars(m.max_strain))
        if steps_per_s is not None:
            rec.log(f"{metrics}/perf/steps_per_s", rr.Scalars(steps_per_s))
        self.frames_logged += 1

    def log_event(self, entity: str, scene, frame: int, text: str, level: str = "ERROR") -> None:
        """A text event (e.g. a blow-up report) at `frame`."""
        self.stream.set_time("frame", sequence=frame)
        self.stream.set_time("sim_time", duration=scene.state.t)
        self.stream.log(f"{entity}/events", rr.TextLog(text, level=level))

    def log_points(self, entity: str, points, radius: float = 0.01, color=PIN_COLOR, static: bool = True) -> None:
        """Extra points (e.g. markers), static by default."""
        self.stream.log(entity, rr.Points3D(np.asarray(points, np.float32), radii=radius, colors=color), static=static)

    # ------------------------------------------------------------------ lifetime
    def flush(self) -> None:
        self.stream.flush()

    def close(self) -> None:
        """Flush and finish the file (writes the footer); the recorder cannot be used afterwards."""
        self.stream.flush()
        self.stream.disconnect()

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
