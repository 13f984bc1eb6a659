"""What a recorder is given: a scene's layout once (what does not change frame to frame) and a read-only snapshot
of each recorded frame. Plain data (numpy arrays, numbers, strings): the recorder never sees a scene, a model or a
controller, and a snapshot can be written to any viewer.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: the scalar series every recording has (path -> series names), before the controllers add theirs
SERIES = {"energy": ["kinetic", "potential", "total"], "strain/max": "max strain", "speed/max": "max speed [m/s]",
          "perf/steps_per_s": "steps/s"}


@dataclass
class SceneLayout:
    """A scene as it starts.

    name:             the scene's name
    topology_changes: the triangles may change during the run (a level switch, merged seams): they are logged on
                      the timeline at every change instead of once
    series:           scalar series path (under the cloth's metrics) -> series names: energy, level, seam gap...
    colliders:        one description dict per collider (collision objects' describe(), plus "moving": the body
                      moves during the run and its vertices arrive in the snapshots' `meshes`)
    strain_scale:     the strain [-] the vertex colours show as full red (taichi_cloth.strain.strain_colormap), or
                      None when the colours are not a strain map
    garment:          the cloth is a garment sewn from pattern pieces (its recording has a pattern view)
    """

    name: str
    topology_changes: bool
    series: dict = field(default_factory=dict)
    colliders: list = field(default_factory=list)
    strain_scale: float | None = None
    garment: bool = False


@dataclass
class FrameSnapshot:
    """One frame of a cloth, copied out of the fields (the simulation may go on while it is written).

    frame:            frame index (0: the start)
    t:                simulated time [s]
    positions:        (P,3) float32 [m]
    normals:          (P,3) float32 unit vertex normals, or None (a cloth without triangles)
    triangles:        (T,3) int the current triangles; topology_version counts their changes since the start, so
                      a recorder logs them only when the version differs from what it logged last
    colors:           (P,4) uint8 RGBA vertex colours, or None (the cloth's own colour)
    points:           name -> (N,3) float32 extra points [m] that move (e.g. "pins" moving along a path)
    fixed_points:     name -> (N,3) float32 points [m] that stay where they are while the topology does (fixed
                      pins): logged with the triangles
    pieces:           name -> (P_k,) int particle indices: the cloth's parts shown as entities of their own (a
                      garment's pattern pieces until the seams merge), logged with the triangles; empty: one mesh
    segments:         name -> (S,2,3) float32 line segments [m] that move (e.g. a seam's open pairs while sewing);
                      a name logged before and missing now is cleared
    meshes:           collider index -> (V,3) float32 new vertex positions [m] of a body that moved
    poses:            collider index -> (R (3,3), translation (3,)) of a collider on a scripted path: it lies at
                      R r + translation [m] for each point r of it as built
    scalars:          series path -> a value or a list of values (e.g. "energy" -> [kinetic, potential, total] [J])
    events:           (level, text) pairs: what happened since the last snapshot ("INFO", "WARN", "ERROR")
    """

    frame: int
    t: float
    positions: np.ndarray
    normals: np.ndarray | None
    triangles: np.ndarray
    topology_version: int
    colors: np.ndarray | None = None
    points: dict = field(default_factory=dict)
    fixed_points: dict = field(default_factory=dict)
    pieces: dict = field(default_factory=dict)
    segments: dict = field(default_factory=dict)
    meshes: dict = field(default_factory=dict)
    poses: dict = field(default_factory=dict)
    scalars: dict = field(default_factory=dict)
    events: list = field(default_factory=list)


def scene_layout(scene) -> SceneLayout:
    """What a recording shows for the whole run of `scene` (a Scene): the series, the colliders, whether the
    topology changes."""
    layout = SceneLayout(scene.name, any(c.changes_topology for c in scene.controllers), dict(SERIES))
    for c in scene.controllers:
        c.layout(layout)
    return layout


def scene_snapshot(scene, frame: int, m, steps_per_s: float | None = None, events=()) -> FrameSnapshot:
    """A read-only copy of `scene`'s frame for a recorder: positions, normals, the topology and its version, the
    scalars of the measurement `m` (a Measurement), what every controller shows, and `events` ((level, text)
    pairs)."""
    tri = scene.model.data.triangles
    x, normals = scene.surface() if len(tri) else (scene.positions().astype(np.float32), None)
    snap = FrameSnapshot(frame, scene.state.t, x, normals, tri, scene.topology_version, events=list(events))
    snap.scalars["energy"] = [m.kinetic, m.potential, m.total]
    snap.scalars["strain/max"] = m.max_strain
    snap.scalars["speed/max"] = m.max_speed
    if steps_per_s is not None:
        snap.scalars["perf/steps_per_s"] = steps_per_s
    for c in scene.controllers:
        c.record(snap)
    return snap
