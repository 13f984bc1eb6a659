"""Scene: the only time loop. It holds a model, a state, an integrator, a step clock and the controllers the scene
names (taichi_cloth.control), and knows none of them by name.

Per step (Scene.substep): every controller's before_step, the collision stage's begin, the integrator's
step(state, contacts, dt), every controller's after_step, and the collision stage (taichi_cloth.colliders), which
pushes the particles out and writes the contacts the next step reads. Per frame: the
clock plans the frame's steps, one measurement (energy, strain, blow-up check), every controller's after_frame,
whose model changes are applied in one place (Scene.apply), and, when recording, one read-only snapshot for the
recorder. A blow-up stops the run with a BlowUpError that names the integrator, the step and a stable step size;
what was recorded is kept.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .assembly import assemble
from .control import FrameInfo, ModelChange, overrides
from .diagnostics import Diagnostics, Measurement
from .errors import BlowUpError
from .frame import FrameSnapshot, SceneLayout
from .normals import VertexNormals
from .rest import RestMonitor
from .stability import stable_dt
from .summary import RunSummary

__all__ = ["RunSummary", "Scene"]


class Scene:
    """A cloth, an integrator and only the components named.

        scene = Scene(cloth, integrator="implicit", dt=1 / 120, pins=[{"near": [[-0.5, 1.5, 0.0]]}])

    cloth: ClothData (taichi_cloth.ClothBuilder), a Model, a MultilevelCloth (ClothBuilder.multilevel_grid: starts
    on its start level and refines as the drape settles) or a GarmentCloth (taichi_cloth.garment: sewn, joined,
    draped). `options` are those of taichi_cloth.assembly.assemble (integrator, dt, gravity, pins, colliders,
    stretch_limit, wind, multilevel, sewing, body_morph...): it builds the parts and only what they name.

    model, state, forces, integrator: the parts; contacts: the Contacts the collision stage writes and the
    integrator reads (None without colliders); collision: the collision stage (taichi_cloth.colliders.Colliders, or
    None); clock: the step clock (taichi_cloth.clock); controllers: the features, in the order their hooks run
    (Scene.controller(name) finds one); warnings: lines for the summary.
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
        d = self.model.data
        weight = float(d.mass.sum()) * max(float(np.linalg.norm(self.forces.gravity_value)), 9.81)
        size = float(np.linalg.norm(np.ptp(d.positions, axis=0)))
        self.rest = RestMonitor(parts.rest, weight * size)  # when the cloth counts as at rest (taichi_cloth.rest)
        self.stop_at_rest = parts.stop_at_rest  # Scene.run ends a run at rest (unless told otherwise)
        self.diagnostics = Diagnostics(self.model, self.state, self.forces, parts.rest.p99_speed,
                                       self.integrator.staggered_velocity)
        self._normals: VertexNormals | None = parts.normals
        self.steps_taken = 0
        self.topology_version = 0  # counts the changes of the cloth's triangles
        self._notes: list[tuple[str, str]] = []  # (level, text) since they were last collected
        self._bind_hooks()

    def _bind_hooks(self) -> None:
        # the loop calls only the hooks a controller implements (step hooks only where they have work)
        hooks = lambda name, cs: [getattr(c, name) for c in cs if overrides(c, name)]  # noqa: E731
        stepping = [c for c in self.controllers if c.per_step]
        self._before_step, self._after_step = hooks("before_step", stepping), hooks("after_step", stepping)
        self._after_frame = hooks("after_frame", self.controllers)
        self._model_changed = hooks("model_changed", self.controllers)
        self._record = hooks("record", self.controllers)
        # substeps fused into the integrator's kernels where nothing between them needs the host
        inline = [c.inline_step() for c in stepping if overrides(c, "before_step") or overrides(c, "after_step")]
        if self.collision is not None:
            inline.append(self.collision.inline_step())
        self._fused = all(x is not None for x in inline) and self.integrator.fuse(tuple(o for x in inline for o in x))

    def add_controller(self, controller) -> None:
        """Add a controller of your own (a taichi_cloth.control.Controller): its hooks run after the scene's own."""
        self.controllers.append(controller)
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
    def fused(self) -> bool:
        """Whether the integrator runs a frame's steps in few kernel launches (Integrator.fuse: nothing between
        the steps needs the host)."""
        return self._fused

    @property
    def stable_dt(self) -> float | None:
        """The linear-theory stable step [s] of this scene's integrator on the current cloth (None if
        unconditionally stable)."""
        return stable_dt(type(self.integrator), self.model, self.forces.air_damping_value)

    def advance(self, n: int = 1) -> None:
        """n steps of the current dt, without the per-frame measurement and blow-up check."""
        self._advance(n, self.clock.dt)

    def _advance(self, n: int, dt: float) -> None:
        if self._fused:
            self.integrator.advance_fused(self.state, self.contacts, n, dt)
            self.steps_taken += n
            return
        for _ in range(n):
            self.substep(dt)

    def substep(self, dt: float, observe=None) -> None:
        """One step of dt [s] as a run takes it, unfused: the controllers' before_step, the collision stage's begin,
        the integrator's step(state, contacts, dt), the controllers' after_step, the collision stage. observe: a
        callable of no argument, called right after the integrator's step (what the integrator alone did)."""
        state, contacts, collision = self.state, self.contacts, self.collision
        for hook in self._before_step:
            hook(state.t, dt)
        if collision is not None:
            collision.begin(state, contacts)
        self.integrator.step(state, contacts, dt)
        if observe is not None:
            observe()
        for hook in self._after_step:
            hook(state.t, dt)
        if collision is not None:
            collision.collide(state, contacts, dt)
        self.steps_taken += 1

    def step(self, n: int = 1) -> Measurement:
        """Advance n steps, then measure and check for a blow-up (raises BlowUpError). Returns the measurement."""
        self.clock.refresh()
        self._advance(n, self.clock.dt)
        m = self.check()
        self.clock.observe(m.max_speed, n)
        return m

    def measure(self) -> Measurement:
        return self.diagnostics.measure(self.clock.dt)

    def check(self) -> Measurement:
        """Measure the state; raise BlowUpError if it has NaNs, runaway speed or runaway strain."""
        m = self.measure()
        reason = None
        if m.nonfinite:
            reason = f"{m.nonfinite} particles have NaN or infinite coordinates"
        elif m.max_speed > self.max_speed:
            reason = f"max speed {m.max_speed:.3g} m/s exceeds {self.max_speed:.3g} m/s"
        elif m.max_strain > self.max_strain:
            reason = f"max strain {m.max_strain:.3g} exceeds {self.max_strain:.3g}"
        if reason:
            raise self._blowup(reason)
        return m

    def _blowup(self, reason: str) -> BlowUpError:
        name, dt = self.integrator.name, self.clock.dt
        bound = self.stable_dt
        if bound is not None:
            suggested = 0.9 * bound
            advice = f"suggested stable step dt <= {suggested:.3g} s (linear theory, see docs/integrators.md)"
        else:
            suggested = dt / 4
            advice = f"suggested: dt = {suggested:.3g} s or more damping"
        extra = self.integrator.unstable_advice()
        if extra:
            advice += f"; {extra}"
        d = self.model.data
        k_max = float(d.stiffness.max()) if d.n_springs else 0.0
        msg = (f"blow-up: integrator {name!r} went unstable by step {self.steps_taken} "
               f"(t = {self.state.t:.4g} s, dt = {dt:.3g} s): {reason}. Parameters: k_max = {k_max:.3g} N/m, "
               f"m_min = {float(d.mass.min()):.3g} kg, air_damping = {self.forces.air_damping_value:.3g} 1/s; {advice}")
        return BlowUpError(msg, integrator=name, step=self.steps_taken, dt=dt, suggested_dt=suggested, reason=reason)

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
            self.warnings.append(change.warning)
            self._notes.append(("WARN", change.warning))

    def reset(self) -> None:
        """Back to t = 0: rest positions, zero velocity, integrator history cleared, every controller at its start
        (the first level, the pieces apart, pins at their start)."""
        self.steps_taken = 0
        self.state.reset()
        self.integrator.reset()
        for c in self.controllers:
            self.apply(c.reset())
        self.clock.reset()
        self.diagnostics.forget()
        self.rest.reset()
        self._notes.clear()

    # ------------------------------------------------------------------ reading
    def positions(self) -> np.ndarray:
        """(P,3) float64 positions [m]."""
        return self.state.positions()

    def velocities(self) -> np.ndarray:
        """(P,3) float64 velocities [m/s]."""
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
        """Write the current cloth surface with meshio (.obj, .ply, .vtk... by suffix)."""
        import meshio

        path = Path(path)
        tri = self.model.data.triangles
        n = self.model.data.n_particles
        cells = ([("triangle", tri.astype(np.int32))] if len(tri)
                 else [("vertex", np.arange(n, dtype=np.int32)[:, None])])
        meshio.write(path, meshio.Mesh(self.positions(), cells))
        return path

    # ------------------------------------------------------------------ what a recorder gets
    def layout(self) -> SceneLayout:
        """What a recording shows for the whole run: the series, the colliders, whether the topology changes."""
        layout = SceneLayout(self.name, any(c.changes_topology for c in self.controllers),
                             {"energy": ["kinetic", "potential", "total"], "strain/max": "max strain",
                              "speed/max": "max speed [m/s]", "perf/steps_per_s": "steps/s"})
        for c in self.controllers:
            c.layout(layout)
        return layout

    def snapshot(self, frame: int, m: Measurement, steps_per_s: float | None = None, events=()) -> FrameSnapshot:
        """A read-only copy of the frame for a recorder: positions, normals, the topology and its version, the
        measurement's scalars, what every controller shows, and `events` ((level, text) pairs)."""
        tri = self.model.data.triangles
        x, normals = self.surface() if len(tri) else (self.positions().astype(np.float32), None)
        snap = FrameSnapshot(frame, self.state.t, x, normals, tri, self.topology_version, events=list(events))
        snap.scalars["energy"] = [m.kinetic, m.potential, m.total]
        snap.scalars["strain/max"] = m.max_strain
        snap.scalars["speed/max"] = m.max_speed
        if steps_per_s is not None:
            snap.scalars["perf/steps_per_s"] = steps_per_s
        for record in self._record:
            record(snap)
        return snap

    def _stats(self) -> dict:
        """Cumulative counters of the integrator and the controllers (e.g. CG iterations, stretch passes)."""
        out = dict(self.integrator.stats)
        for c in self.controllers:
            out.update(c.stats)
        return out

    def limit_and_colliders(self) -> str | None:
        """Whether the stretch limit and the colliders both hold now, in words (None unless the scene has both): every
        limited spring within max_strain + tolerance, and no particle inside a collider (signed distance < 0); or
        which one lost, and by how much (the colliders run after the limit and have the last word)."""
        from collision.self_collision import SelfCollision

        limit, colliders = self.controller("stretch_limit"), self.controller("colliders")
        if limit is None or colliders is None:
            return None
        d, x = self.model.data, self.positions()
        limited = np.isin(d.kind, [int(k) for k in limit.kinds])
        if not limited.any():
            return None
        a, b = d.springs[limited, 0], d.springs[limited, 1]
        strain = np.linalg.norm(x[b] - x[a], axis=1) / d.rest_length[limited] - 1.0
        allowed = limit.max_strain + limit.tolerance
        over = int(np.count_nonzero(strain > allowed))
        depth = [c.signed_distance(x) for c in colliders.objects
                 if hasattr(c, "signed_distance") and not isinstance(c, SelfCollision)]
        gap = np.min(depth, axis=0) if depth else np.full(len(x), np.inf)
        inside = int(np.count_nonzero(gap < 0))
        strain_text = f"max strain {100 * strain.max():.2f} % (limit {100 * allowed:.2f} %)"
        if not over and not inside:
            return f"stretch limit and colliders agree: {strain_text}, no particle inside a collider"
        lost = []
        if over:
            lost.append(f"{over} springs over the stretch limit, {strain_text}")
        if inside:
            lost.append(f"{inside} particles inside a collider, the deepest {1e3 * -gap.min():.2f} mm")
        return "stretch limit and colliders disagree: " + "; ".join(lost)

    # ------------------------------------------------------------------ the loop
    def run(self, frames: int, recorder=None, entity: str | None = None, progress: bool = True,
            record_every: int = 1, translation=None, until_rest: bool | None = None) -> RunSummary:
        """Run `frames` frames of 1/fps, or, with `until_rest` (default: the scene's rest stop option), until the
        first frame at which the cloth is at rest by the scene's RestCriterion (at most `frames`). With a Recorder,
        log the cloth under `entity` (default "cloth", displaced by `translation` [m] in the viewer) at frame 0,
        after every `record_every`-th frame, the last, and every frame where something happened. A BlowUpError
        propagates after the frames so far are recorded; the summary is attached to it as `.summary`. The summary
        says whether and since when the cloth is at rest."""
        until_rest = self.stop_at_rest if until_rest is None else bool(until_rest)
        if frames < 0:
            raise ValueError("frames must be >= 0")
        summary = RunSummary(self.name, self.integrator.name, self.clock.dt, self.clock.auto,
                             self.model.data.n_particles, self.model.data.n_springs, solver=self.integrator.detail)
        start = (self.state.t, self._stats(), self.clock.counters())
        log = _FrameLog(recorder, entity or "cloth", record_every, frames, summary)
        log.begin(self, translation)
        bar = _progress_bar(frames, self.name) if progress else None
        frame = 0
        try:
            for frame in range(1, frames + 1):
                t0 = time.perf_counter()
                m, n, simulated = self._frame(frame, summary)
                elapsed = time.perf_counter() - t0
                summary.count_frame(frame, n, elapsed, simulated, compiling=frame == 1 < frames)
                self.clock.observe(m.max_speed, n)
                version = self.topology_version
                info = FrameInfo(frame, self.state.t, self.steps_taken, m)
                for change in (hook(info) for hook in self._after_frame):
                    if change is not None:
                        self.apply(change)
                        m = self.measure()
                summary.measured(m)
                busy = next((c.busy for c in self.controllers if c.busy), None)
                rest = self.rest.observe(self.state.t, m, busy)
                stop = until_rest and rest.at_rest
                log.frame(self, frame, m, n / elapsed if elapsed > 0 else None, self.topology_version != version,
                          last=stop)
                if bar is not None:
                    bar.update(1)
                if stop:
                    summary.stopped_at_rest = True
                    break
        except BlowUpError as err:
            summary.blew_up(frame, err)
            log.blow_up(self, frame, err)
            raise
        finally:
            if bar is not None:
                bar.close()
            t_start, stats_start, counters = start
            summary.sim_time = self.state.t - t_start
            summary.n_particles, summary.n_springs = self.model.data.n_particles, self.model.data.n_springs
            summary.warnings = list(dict.fromkeys(self.warnings + self.clock.warnings))
            if summary.steps:
                summary.stats = {f"{k} per step": (v - stats_start.get(k, 0)) / summary.steps
                                 for k, v in self._stats().items()}
            summary.steps_line = self.clock.describe(summary.dt_min, summary.dt_max, counters)
            if self.rest.status is not None:
                summary.rest = self.rest.status.describe(self.rest.criterion)
            summary.agreement = self.limit_and_colliders()
            log.flush()
        return summary

    def _frame(self, frame: int, summary: RunSummary) -> tuple[Measurement, int, float]:
        """One frame: the clock's steps, then the blow-up check. A frame that blows up is rolled back and run again
        at a smaller step when the clock can (dt = "auto"); otherwise the BlowUpError propagates. Returns the
        measurement, the steps and the simulated seconds of the frame."""
        clock = self.clock
        while True:
            n, dt = clock.frame()
            clock.start_frame()
            steps_before, t_before = self.steps_taken, self.state.t
            self._advance(n, dt)
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

    def _collect(self, summary: RunSummary) -> list[tuple[str, str]]:
        """The notes since the last call, also listed in the summary's events."""
        notes, self._notes = self._notes, []
        summary.events.extend(text for _, text in notes if text not in self.warnings)  # warnings are listed apart
        return notes


class _FrameLog:
    """A run's recording: frame 0, every `record_every`-th frame, the last, and every frame with an event or a new
    topology; the time it takes (frames 2..) goes to the summary. Without a recorder it only collects the events."""

    def __init__(self, recorder, entity: str, record_every: int, frames: int, summary: RunSummary):
        self.recorder, self.entity, self.every = recorder, entity, record_every
        self.frames, self.summary = frames, summary

    def begin(self, scene: Scene, translation) -> None:
        events = scene._collect(self.summary)
        if self.recorder is not None:  # not in wall_record: like frame 1's steps, the start compiles (the normals)
            self.recorder.begin_cloth(self.entity, scene.layout(), translation)
            self.recorder.log_frame(self.entity, scene.snapshot(0, scene.measure(), events=events))

    def frame(self, scene: Scene, frame: int, m: Measurement, steps_per_s: float | None, new_topology: bool,
              last: bool = False) -> None:
        events = scene._collect(self.summary)
        due = frame % self.every == 0 or frame == self.frames or last or events or new_topology
        if self.recorder is not None and due:
            t0 = time.perf_counter()
            self.recorder.log_frame(self.entity, scene.snapshot(frame, m, steps_per_s, events))
            if frame > 1:
                self.summary.wall_record += time.perf_counter() - t0

    def blow_up(self, scene: Scene, frame: int, err: BlowUpError) -> None:
        events = scene._collect(self.summary) + [("ERROR", str(err))]
        if self.recorder is not None:
            self.recorder.log_events(self.entity, frame, scene.state.t, events)

    def flush(self) -> None:
        if self.recorder is not None:
            self.recorder.flush()


def _progress_bar(frames: int, name: str):
    from tqdm import tqdm

    return tqdm(total=frames, unit="frame", desc=name, leave=False)
