"""A run's bookkeeping around Scene.run's loop: what is recorded when (FrameLog), the progress bar, and the run
summary's closing lines."""
from __future__ import annotations

import time

from tqdm import tqdm

from .agreement import limit_and_colliders
from .diagnostics import Measurement
from .errors import BlowUpError
from .frame import scene_layout, scene_snapshot
from .self_intersection import IntersectionCount
from .summary import RunSummary


class FrameLog:
    """A run's recording: frame 0, every `record_every`-th frame, the last, and every frame with an event or a new
    topology; the time it takes (frames 2..) goes to the summary. Without a recorder it only collects the events.
    With a `progress` name it shows a progress bar over the frames."""

    def __init__(self, recorder, entity: str, record_every: int, frames: int, summary: RunSummary,
                 progress: str | None = None, intersections: IntersectionCount | None = None):
        self.recorder, self.entity, self.every = recorder, entity, record_every
        self.frames, self.summary, self.intersections = frames, summary, intersections
        self.bar = tqdm(total=frames, unit="frame", desc=progress, leave=False) if progress is not None else None

    def begin(self, scene, translation) -> None:
        crossed = None
        if self.intersections is not None:
            crossed = self.intersections.count(scene.positions(), scene.model.data.triangles, scene.state.t)
            colliders = scene.controller("colliders")
            if crossed and colliders is not None and colliders.self_collision is not None:
                scene.warn(f"the cloth starts with {crossed} intersecting triangle pairs: self-collision keeps "
                           "every layer on the side it starts on and cannot pull these apart (place the pieces "
                           "apart before the run)")
        events = scene.collect_notes(self.summary)
        if self.recorder is not None:  # not in wall_record: like frame 1's steps, the start compiles (the normals)
            layout = scene_layout(scene)
            if self.intersections is not None:
                layout.series["intersections"] = "intersecting triangle pairs"
            self.recorder.begin_cloth(self.entity, layout, translation)
            snap = scene_snapshot(scene, 0, scene.measure(), events=events)
            if crossed is not None:
                snap.scalars["intersections"] = crossed
            self.recorder.log_frame(self.entity, snap)

    def frame(self, scene, frame: int, m: Measurement, steps_per_s: float | None, new_topology: bool,
              last: bool = False) -> None:
        if self.bar is not None:
            self.bar.update(1)
        events = scene.collect_notes(self.summary)
        counted = None
        if self.intersections is not None and self.intersections.due(frame):
            counted = self.intersections.count(scene.positions(), scene.model.data.triangles, scene.state.t)
        due = frame % self.every == 0 or frame == self.frames or last or events or new_topology or counted is not None
        if self.recorder is not None and due:
            t0 = time.perf_counter()
            snap = scene_snapshot(scene, frame, m, steps_per_s, events)
            if counted is not None:
                snap.scalars["intersections"] = counted
            self.recorder.log_frame(self.entity, snap)
            if frame > 1:
                self.summary.wall_record += time.perf_counter() - t0

    def blow_up(self, scene, frame: int, err: BlowUpError) -> None:
        events = scene.collect_notes(self.summary) + [("ERROR", str(err))]
        if self.recorder is not None:
            self.recorder.log_events(self.entity, frame, scene.state.t, events)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        if self.recorder is not None:
            self.recorder.flush()


def counters(scene) -> dict:
    """Cumulative counters of the scene's integrator and controllers (e.g. CG iterations, stretch passes)."""
    out = dict(scene.integrator.stats)
    for c in scene.controllers:
        out.update(c.stats)
    return out


def open_summary(scene) -> tuple[RunSummary, tuple]:
    """The summary of a run that starts now, and what close_summary measures the run from (the simulated time [s],
    the counters, the clock's counters)."""
    d = scene.model.data
    summary = RunSummary(scene.name, scene.integrator.name, scene.clock.dt, scene.clock.auto, d.n_particles,
                         d.n_springs, solver=scene.integrator.detail)
    return summary, (scene.state.t, counters(scene), scene.clock.counters())


def close_summary(scene, summary: RunSummary, start: tuple, intersections: IntersectionCount | None = None) -> None:
    """Fill the summary's closing lines: simulated time, the final counts, warnings (one more where self-collision
    still needed impact zones in the run's last second), counters per step, the steps taken, the rest status,
    whether the stretch limit and the colliders agree, and the run's `intersections` with a last count (unless it
    blew up)."""
    t_start, stats_start, clock_start = start
    summary.sim_time = scene.state.t - t_start
    summary.n_particles, summary.n_springs = scene.model.data.n_particles, scene.model.data.n_springs
    summary.warnings = list(dict.fromkeys(scene.warnings + scene.clock.warnings))
    if summary.steps:
        summary.stats = {f"{k} per step": (v - stats_start.get(k, 0)) / summary.steps
                         for k, v in counters(scene).items()}
    summary.steps_line = scene.clock.describe(summary.dt_min, summary.dt_max, clock_start)
    if scene.rest.status is not None:
        summary.rest = scene.rest.status.describe(scene.rest.criterion)
    limit, colliders = scene.controller("stretch_limit"), scene.controller("colliders")
    if limit is not None and colliders is not None:
        summary.agreement = limit_and_colliders(scene.model.data, scene.positions(), limit, colliders)
    held = colliders.self_collision.zones_in_last(1.0) if colliders is not None and colliders.self_collision else 0
    if held:
        advice = (f"dt = \"auto\" in [integrator], with adaptive = {{ dt_max = {scene.clock.dt:.3g} }} to keep this "
                  "step as the longest: it halves the step while the cloth moves fast"
                  if not scene.clock.auto else "a finer mesh or a thinner [self_collision] thickness")
        summary.warnings.append(
            f"self-collision held parts of the cloth in {held} impact zones in the run's last second: where the "
            "cloth cannot move without crossing itself it is stopped, and a response at a step too long for the "
            "motion leaves its stretch in the springs, so a fold in its own plane or a tight twist can lock; try "
            f"{advice} (docs/collision.md, self-collision; [self_collision] continuous = false lets it cross instead)")
    if intersections is not None and summary.blowup is None:
        summary.intersections = intersections.count(scene.positions(), scene.model.data.triangles, scene.state.t)
        summary.intersections_max = intersections.largest
        summary.self_intersection = intersections.describe()
