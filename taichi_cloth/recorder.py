"""Recorder: every Rerun call of the engine lives here (rerun-sdk 0.41).

One explicit RecordingStream saved to an .rrd file as it goes (so a run that fails midway keeps what
it recorded). The mesh topology is logged once as static data (for a multilevel cloth: on the timeline,
again at every level switch, with a metrics/<entity>/level series and an event; for a garment, again when its
seams merge); each frame logs only the vertex positions and normals (Rerun's partial-update pattern), and for a
garment the strain map as vertex colours and the seam gap (metrics/<entity>/seam_gap, mm). Timelines: "frame" (sequence) and
"sim_time" (duration, s). Scalars live under metrics/<entity>/...: energy (three series: kinetic,
potential, total [J]), strain/max, perf/steps_per_s. Open a recording with `rerun FILE.rrd`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun as rr

from .garment.metrics import strain_colors, vertex_strain

CLOTH_COLOR = (200, 90, 60, 255)
PIN_COLOR = (30, 30, 30, 255)
BODY_COLOR = (170, 170, 180, 255)
FLOOR_COLOR = (120, 140, 120, 255)


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
        rec.log(f"metrics/{entity}/energy", rr.SeriesLines(names=["kinetic", "potential", "total"]), static=True)
        if not scene.topology_changes:
            self._log_topology(entity, scene, static=True)
        else:  # the topology changes at each level switch or seam merge: log it on the timeline
            if scene.refiner is not None:
                rec.log(f"metrics/{entity}/level", rr.SeriesLines(names="level"), static=True)
            self.log_topology(entity, scene, 0)
        if scene.sewing is not None:
            rec.log(f"metrics/{entity}/seam_gap", rr.SeriesLines(names=["max [mm]", "mean [mm]"]), static=True)

    def log_topology(self, entity: str, scene, frame: int, message: str | None = None) -> None:
        """The cloth's triangles (and fixed pins) as of `frame`: logged at a multilevel switch or a seam merge,
        with an event saying what changed (default: the level)."""
        self.stream.set_time("frame", sequence=frame)
        self.stream.set_time("sim_time", duration=scene.state.t)
        self._log_topology(entity, scene, static=False)
        if frame > 0:
            if message is None:
                message = (f"level {scene.level + 1}: {scene.model.data.n_particles} particles, "
                           f"{scene.model.data.n_springs} springs")
            self.log_event(entity, scene, frame, message, level="INFO")

    def _log_topology(self, entity: str, scene, static: bool) -> None:
        rec = self.stream
        tri = scene.model.data.triangles
        if len(tri):
            rec.log(f"{entity}/mesh", rr.Mesh3D.from_fields(triangle_indices=tri.astype(np.uint32),
                                                            albedo_factor=CLOTH_COLOR), static=static)
        if len(scene.pinned_indices) and scene.pins is None:
            rec.log(f"{entity}/pins", rr.Points3D(scene.model.data.positions[scene.pinned_indices].astype(np.float32),
                                                  radii=0.01, colors=PIN_COLOR), static=static)

    def log_collider(self, entity: str, description: dict, static: bool = True) -> None:
        """A collider, once, as static data: a body mesh, spheres, capsules and planes (a 4 m square). A body that
        morphs during the run is logged on the timeline instead (static=False; log_frame moves its vertices)."""
        rec = self.stream
        if description["kind"] == "self":
            return
        if description["kind"] == "mesh":
            rec.log(entity, rr.Mesh3D(vertex_positions=np.asarray(description["vertices"], np.float32),
                                      triangle_indices=np.asarray(description["triangles"], np.uint32),
                                      albedo_factor=BODY_COLOR), static=static)
            return
        if description["spheres"]:
            rec.log(f"{entity}/spheres", rr.Ellipsoids3D(
                centers=[c for c, _ in description["spheres"]],
                half_sizes=[[r, r, r] for _, r in description["spheres"]], colors=BODY_COLOR,
                fill_mode=rr.components.FillMode.Solid), static=True)
        if description["capsules"]:
            caps = description["capsules"]
            rec.log(f"{entity}/capsules", rr.Capsules3D(
                lengths=[float(np.linalg.norm(b - a)) for a, b, _ in caps], radii=[r for *_, r in caps],
                translations=[a for a, _, _ in caps], quaternions=[_quaternion_z_to(b - a) for a, b, _ in caps],
                colors=BODY_COLOR, fill_mode=rr.components.FillMode.Solid), static=True)
        for k, (point, normal) in enumerate(description["planes"]):
            u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
            u /= np.linalg.norm(u)
            w = np.cross(normal, u)
            corners = np.array([point + 2 * (su * u + sw * w) for su, sw in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
            rec.log(f"{entity}/planes/{k}", rr.Mesh3D(vertex_positions=corners.astype(np.float32),
                                                      triangle_indices=np.array([[0, 1, 2], [0, 2, 3]], np.uint32),
                                                      albedo_factor=FLOOR_COLOR), static=True)

    def log_frame(self, entity: str, scene, frame: int, measurement, steps_per_s: float | None = None) -> None:
        """Log the cloth's state at `frame` (positions, normals, moving pins) and its scalar metrics."""
        rec = self.stream
        rec.set_time("frame", sequence=frame)
        rec.set_time("sim_time", duration=scene.state.t)
        if len(scene.model.data.triangles):
            x, normals = scene.surface()
            colors = None
            if scene.garment is not None:  # the strain map of a garment
                colors = strain_colors(vertex_strain(scene.model.data, x))
            rec.log(f"{entity}/mesh", rr.Mesh3D.from_fields(vertex_positions=x, vertex_normals=normals,
                                                            vertex_colors=colors))
        else:
            x = scene.positions().astype(np.float32)
            rec.log(f"{entity}/particles", rr.Points3D(x, radii=0.005, colors=CLOTH_COLOR))
        if scene.pins is not None:
            rec.log(f"{entity}/pins", rr.Points3D(x[scene.pinned_indices], radii=0.01, colors=PIN_COLOR))
        morph = scene.body_morph
        if morph is not None and morph.changed:  # the body moved: its new vertex positions only
            rec.log(f"{entity}/colliders/{scene.body_collider_index}",
                    rr.Mesh3D.from_fields(vertex_positions=morph.vertices.astype(np.float32)))
            morph.changed = False
        m = measurement
        metrics = f"metrics/{entity}"
        rec.log(f"{metrics}/energy", rr.Scalars([m.kinetic, m.potential, m.total]))
        rec.log(f"{metrics}/strain/max", rr.Scalars(m.max_strain))
        if scene.refiner is not None:
            rec.log(f"{metrics}/level", rr.Scalars(scene.level + 1))
        if scene.sewing is not None:
            gaps = scene.sewing.gaps(x.astype(np.float64))
            rec.log(f"{metrics}/seam_gap", rr.Scalars([1e3 * gaps.max(), 1e3 * gaps.mean()] if len(gaps) else [0.0, 0.0]))
        if steps_per_s is not None:
            rec.log(f"{metrics}/perf/steps_per_s", rr.Scalars(steps_per_s))
        self.frames_logged += 1

    def log_event(self, entity: str, scene, frame: int, text: str, level: str = "ERROR") -> None:
        """A text event (e.g. a blow-up report) at `frame`."""
        self.stream.set_time("frame", sequence=frame)
        self.stream.set_time("sim_time", duration=scene.state.t)
        self.stream.log(f"{entity}/events", rr.TextLog(text, level=level))

    def log_flat_pieces(self, entity: str, pieces, layouts=None, translation=(0.0, 0.0, 0.0), gap: float = 0.05,
                        full_scale: float = 0.05) -> None:
        """Flattened pieces (taichi_cloth.flatten.FlatPiece), static, side by side in the x-y plane from
        `translation` [m] with `gap` [m] between them: each a mesh coloured by its error map (the mean |edge
        length error| at each vertex: white at 0, red at `full_scale` and above) and its outline.
        layouts: optional (V,2) arrays to draw instead of each piece's uv (e.g. aligned to the pattern)."""
        rec = self.stream
        layouts = list(layouts) if layouts is not None else [p.uv for p in pieces]
        x0 = 0.0
        for piece, uv in zip(pieces, layouts):
            uv = np.asarray(uv, dtype=np.float64)
            lo = uv.min(axis=0)
            pos = np.c_[uv - lo + [x0, 0.0], np.zeros(len(uv))] + np.asarray(translation, dtype=np.float64)
            x0 += float(np.ptp(uv[:, 0])) + gap
            path = f"{entity}/{piece.name}"
            rec.log(f"{path}/mesh", rr.Mesh3D(vertex_positions=pos.astype(np.float32),
                                              triangle_indices=piece.triangles.astype(np.uint32),
                                              vertex_colors=strain_colors(piece.vertex_error(), full_scale)),
                    static=True)
            outline = pos[np.append(piece.boundary, piece.boundary[0])]
            rec.log(f"{path}/outline", rr.LineStrips3D([outline.astype(np.float32)], colors=[[20, 20, 20]],
                                                       radii=0.002), static=True)

    def log_points(self, entity: str, points, radius: float = 0.01, color=PIN_COLOR, static: bool = True) -> None:
        """Extra points (e.g. markers), static by default."""
        self.stream.log(entity, rr.Points3D(np.asarray(points, np.float32), radii=radius, colors=color), static=static)

    # ------------------------------------------------------------------ studies (benchmark results)
    def log_document(self, entity: str, markdown: str) -> None:
        """A markdown text (e.g. a benchmark's report), static."""
        self.stream.log(entity, rr.TextDocument(markdown, media_type=rr.MediaType.MARKDOWN), static=True)

    def log_image_file(self, entity: str, path) -> None:
        """An image file (e.g. a benchmark's PNG plot), static."""
        self.stream.log(entity, rr.EncodedImage(path=Path(path)), static=True)

    def log_samples(self, entity: str, times, positions, triangles, translation=(0.0, 0.0, 0.0)) -> None:
        """A cloth sampled at simulated `times` (S,) [s]: `positions` (S,P,3) [m] on the sim_time timeline, its
        (T,3) `triangles` once, the whole displaced by `translation` [m]. NaN samples (after a blow-up) are skipped."""
        rec = self.stream
        rec.log(entity, rr.Transform3D(translation=np.asarray(translation, np.float32)), static=True)
        rec.log(f"{entity}/mesh", rr.Mesh3D.from_fields(triangle_indices=np.asarray(triangles, np.uint32),
                                                        albedo_factor=CLOTH_COLOR), static=True)
        for t, x in zip(times, positions):
            if np.isfinite(x).all():
                rec.set_time("sim_time", duration=float(t))
                rec.log(f"{entity}/mesh", rr.Mesh3D.from_fields(vertex_positions=np.asarray(x, np.float32)))

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
