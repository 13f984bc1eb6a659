"""Scene: the only time loop. It holds a model, a state, an integrator, a step clock and the controllers the scene
names (taichi_cloth.control), and knows none of them by name.

Per step: the integrator's step with the controllers' step hooks and the collision stage around it, fused where
it can be (taichi_cloth.stepping). Per frame: the clock plans the frame's steps, one measurement and blow-up check
(taichi_cloth.blowup), every controller's after_frame, whose model changes are applied in one place (Scene.apply),
and, when recording, one snapshot for the recorder (taichi_cloth.runlog).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from clothbase.meshes import write_triangle_mesh

from .assembly import assemble
from .blowup import blowup_error, blowup_reason
from .control import FrameInfo, ModelChange, overrides
from .diagnostics import Measurement
from .errors import BlowUpError
from .hostreads import HostReads
from .normals import VertexNormals
from .runlog import FrameLog, close_summary, open_summary
from .self_intersection import IntersectionCount
from .stability import stable_dt
from .stepping import Stepper
from .summary import RunSummary

__all__ = ["RunSummary", "Scene"]


class Scene:
    """A cloth, an integrator and only the components named.

        scene = Scene(cloth, integrator="implicit", dt=1 / 120, pins=[{"near": [[-0.5, 1.5, 0.0]]}])

    cloth: ClothData (taichi_cloth.ClothBuilder), a Model, a MultilevelCloth or a GarmentCloth; `options` are those
    of taichi_cloth.assembly.assemble (integrator, dt, gravity, pins, colliders, stretch_limit, wind, multilevel,
    sewing, body_morph...): it builds the parts and only what they name (taichi_cloth.assembly.SceneParts).

    model, state, forces, integrator, clock: the parts; contacts: what the collision stage (`collision`, a
    Colliders) writes and the integrator reads (both None without colliders); controllers: the features, in the
    order their hooks run (Scene.controller(name) finds one); warnings: lines for the summary; fused: whether a
    frame's steps run fused (taichi_cloth.stepping.Stepper).
    """

    def __init__(self, cloth, **options):
        parts = assemble(cloth, **options)
        self.name = parts.name
        self.model, self.state, self.forces = parts.model, parts.state, parts.forces
        self.integrator, self.clock = parts.integrator, parts.clock
        self.contacts, self.collision = parts.contacts, parts.collision
        self.controllers = list(parts.controllers)
        self.max_speed, self.max_strain = parts.max_speed, parts.max_strain
        self.warnings: list[str] = list(parts.warnings)
        self.rest = parts.rest  # when the cloth counts as at rest (taichi_cloth.rest)
        self.stop_at_rest = parts.stop_at_rest  # Scene.run ends a run at rest (unless told otherwise)
        self.diagnostics = parts.diagnostics
        self._normals: VertexNormals | None = parts.normals
        self.steps_taken = 0
        self.topology_version = 0  # counts the changes of the cloth's triangles
        self._notes: list[tuple[str, str]] = []  # (level, text) since they were last collected
        self._step_reads = HostReads()  # the host reads inside the last frame's steps (taichi_cloth.hostreads)
        self._bind_hooks()

    def _bind_hooks(self) -> None:
        # the loop calls only the hooks a controller implements
        self._after_frame = [c.after_frame for c in self.controllers if overrides(c, "after_frame")]
        self._model_changed = [c.model_changed for c in self.controllers if overrides(c, "model_changed")]
        self._stepper = Stepper(self.integrator, self.state, self.contacts, self.collision, self.controllers)
        self.fused = self._stepper.fused

    def add_controller(self, controller) -> None:
        """Add a controller of your own (a taichi_cloth.control.Controller): its hooks run after the scene's own."""
        self.controllers.append(controller)
        if getattr(controller, "report_slots", 0):
            self.diagnostics.add_reporter(controller)
        self._bind_hooks()

    def controller(self, name: str):
        """The controller called `name` ("pins", "colliders", "sewing", "refiner"...), or None if the scene has none."""
        return next((c for c in self.controllers if c.name == name), None)

    # ------------------------------------------------------------------ the step
    @property
    def dt(self) -> float:
        """The step [s] of Scene.step calls. Assigning it sets the base step (the finest level's, for a
        multilevel cloth); with dt = "auto" the clock keeps choosing and an assignment only re-plans."""
        return self.clock.dt

    @dt.setter
    def dt(self, value: float) -> None:
        self.clock.set_dt(value)

    @property
    def substeps(self) -> int:
        """Steps in each frame of a run (they fill exactly 1/fps)."""
        return self.clock.frame()[0]

    @property
    def stable_dt(self) -> float | None:
        """The linear-theory stable step [s] of this scene's integrator on the current cloth (None if
        unconditionally stable)."""
        return stable_dt(type(self.integrator), self.model, self.forces.air_damping_value)

    def advance(self, n: int = 1, dt: float | None = None) -> None:
        """n steps of dt [s] (default: the current dt), without the per-frame measurement and blow-up check."""
        self._stepper.advance(n, self.clock.dt if dt is None else dt)
        self.steps_taken += n

    def substep(self, dt: float, observe=None) -> None:
        """One step of dt [s] as a run takes it, unfused (taichi_cloth.stepping.Stepper.step). observe: a callable of
        no argument, called right after the integrator's step (what the integrator alone did)."""
        self._stepper.step(dt, observe)
        self.steps_taken += 1

    def step(self, n: int = 1) -> Measurement:
        """Advance n steps, then measure and check for a blow-up (raises BlowUpError). Returns the measurement."""
        self.clock.refresh()
        self.advance(n)
        m = self.check()
        self.clock.observe(m.max_speed, n)
        return m

    def measure(self) -> Measurement:
        """Energy, strain and speed of the state now (taichi_cloth.diagnostics)."""
        return self.diagnostics.measure(self.clock.dt)

    def check(self) -> Measurement:
        """Measure the state; raise BlowUpError if it has NaNs, runaway speed or runaway strain."""
        m = self.measure()
        reason = blowup_reason(m, self.max_speed, self.max_strain)
        if reason:
            raise blowup_error(reason, self.integrator, self.model, self.forces.air_damping_value, self.state.t,
                               self.clock.dt, self.steps_taken, self.stable_dt)
        return m

    # ------------------------------------------------------------------ model changes
    def apply(self, change: ModelChange | None) -> None:
        """Apply a controller's model change: refill the model's fields (live counts included), write or prolong the
        state, re-plan the step, tell the integrator and every controller, count a new topology for the recorder,
        and note the event or warning."""
        if change is None:
            return
        if change.data is not None or change.x is not None or change.v is not None or change.rest \
                or change.prolong is not None or change.dt_scale is not None:
            n_before = self.model.data.n_particles
            if change.data is not None:
                self.model.load(change.data)
            if change.rest:
                self.state.to_rest()
            if change.x is not None or change.v is not None:
                self.state.set(x=change.x, v=change.v)
            if change.prolong is not None:
                change.prolong(self.state, n_before)
            self.clock.model_changed(change.dt_scale)
            if change.refills:
                self.integrator.topology_changed(change.level)
                self.diagnostics.forget()  # other particles: no motion to measure against
                self.rest.reset()
            for hook in self._model_changed:
                hook(change, self.state.t, self.clock.dt)
        if change.topology:
            self.topology_version += 1
        if change.event:
            self._notes.append(("INFO", change.event))
        if change.warning:
            self.warn(change.warning)

    def warn(self, message: str) -> None:
        """A warning for the run summary and the recording's events."""
        self.warnings.append(message)
        self._notes.append(("WARN", message))

    def reset(self) -> None:
        """Back to t = 0: rest positions, zero velocity, integrator history cleared, every controller at its start
        (the first level, the pieces apart, pins at their start)."""
        self.steps_taken = 0
        self.state.reset()
        self.integrator.reset()
        if self.contacts is not None:
            self.contacts.reset()  # the first step's friction must not read the last run's contacts
        for c in self.controllers:
            self.apply(c.reset())
        self.clock.reset()
        self.diagnostics.forget()
        self.rest.reset()
        self._notes.clear()

    def positions(self) -> np.ndarray:  # (P,3) float64 [m]
        return self.state.positions()

    def velocities(self) -> np.ndarray:  # (P,3) float64 [m/s]
        return self.state.velocities()

    def net_forces(self) -> np.ndarray:
        """(P,3) total force [N] on each particle now (springs, gravity, drag, wind); zero rows for pins."""
        f = self.forces.net_forces()
        f[self.model.pinned] = 0.0
        return f

    def surface(self) -> tuple[np.ndarray, np.ndarray]:
        """(P,3) float32 positions [m] and unit vertex normals of the current shape, in one kernel launch
        (the normal kernel is built on first use)."""
        if self._normals is None:
            self._normals = VertexNormals(self.model, self.state)
        return self._normals.snapshot()

    def export_mesh(self, path) -> Path:
        """Write the current cloth surface (.obj, .ply, .vtk... by suffix; clothbase.meshes.write_triangle_mesh)."""
        return write_triangle_mesh(path, self.positions(), self.model.data.triangles)

    # ------------------------------------------------------------------ the loop
    def run(self, frames: int, recorder=None, entity: str | None = None, progress: bool = True,
            record_every: int = 1, translation=None, until_rest: bool | None = None) -> RunSummary:
        """Run `frames` frames of 1/fps, or, with `until_rest` (default: the scene's rest stop option), until the
        first frame at which the cloth is at rest by the scene's RestCriterion (at most `frames`). With a Recorder,
        log the cloth under `entity` (default "cloth", displaced by `translation` [m] in the viewer) at frame 0,
        after every `record_every`-th frame, the last, and every frame where something happened. A BlowUpError
        propagates after the frames so far are recorded; the summary is attached to it as `.summary`. The summary
        says whether and since when the cloth is at rest, and how many of its triangle pairs intersect, counted every
        quarter of a simulated second and at the end (taichi_cloth.self_intersection)."""
        until_rest = self.stop_at_rest if until_rest is None else bool(until_rest)
        if frames < 0:
            raise ValueError("frames must be >= 0")
        summary, start = open_summary(self)
        counts = IntersectionCount(1.0 / self.clock.frame_time) if len(self.model.data.triangles) >= 2 else None
        log = FrameLog(recorder, entity or "cloth", record_every, frames, summary, self.name if progress else None,
                       counts)
        log.begin(self, translation)
        frame = 0
        reads = HostReads()
        try:
            for frame in range(1, frames + 1):
                t0 = time.perf_counter()
                with reads:
                    m, n, simulated = self._frame(frame, summary)
                elapsed = time.perf_counter() - t0
                summary.count_frame(frame, n, elapsed, simulated, compiling=frame == 1 < frames)
                self.clock.observe(m.max_speed, n)
                version = self.topology_version
                info = FrameInfo(frame, self.state.t, self.steps_taken, m)
                with reads:
                    for change in (hook(info) for hook in self._after_frame):
                        if change is not None:
                            self.apply(change)
                            m = self.measure()
                    summary.measured(m)
                    busy = next((c.busy for c in self.controllers if c.busy), None)
                    rest = self.rest.observe(self.state.t, m, busy)
                if frame > 1:
                    summary.host_reads_steps += self._step_reads.total
                    summary.host_reads_frames += reads.total - self._step_reads.total
                reads.by_site.clear()
                stop = until_rest and rest.at_rest
                log.frame(self, frame, m, n / elapsed if elapsed > 0 else None, self.topology_version != version,
                          last=stop)
                if stop:
                    summary.stopped_at_rest = True
                    break
        except BlowUpError as err:
            summary.blew_up(frame, err)
            log.blow_up(self, frame, err)
            raise
        finally:
            close_summary(self, summary, start, counts)
            log.close()
        return summary

    def _frame(self, frame: int, summary: RunSummary) -> tuple[Measurement, int, float]:
        """One frame: the clock's steps, then the blow-up check. A frame that blows up is rolled back and run again
        at a smaller step when the clock can (dt = "auto"); otherwise the BlowUpError propagates. Returns the
        measurement, the steps and the simulated seconds of the frame."""
        clock = self.clock
        self._step_reads = HostReads()  # the reads inside the steps (the run's summary counts them apart)
        while True:
            n, dt = clock.frame()
            clock.start_frame()
            steps_before, t_before = self.steps_taken, self.state.t
            with self._step_reads:
                self.advance(n, dt)
            try:
                m = self.check()  # also syncs: the measurement reads the device
                summary.took_step(dt)
                return m, n, self.state.t - t_before
            except BlowUpError as err:
                if not clock.roll_back():
                    raise
                self.steps_taken = steps_before
                self.integrator.reset()  # any history (warm starts) belongs to the discarded steps
                self._notes.append(("WARN", f"frame {frame}: {err.reason} at dt = {dt:.3g} s; rolled back, dt "
                                            f"halved to {0.5 * dt:.3g} s"))

    def collect_notes(self, summary: RunSummary) -> list[tuple[str, str]]:
        """The notes since the last call, also listed in the summary's events."""
        notes, self._notes = self._notes, []
        summary.events.extend(text for _, text in notes if text not in self.warnings)  # warnings are listed apart
        return notes
