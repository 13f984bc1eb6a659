"""Scene: the only time loop. It holds exactly the components a scene names.

Per step: integrator.step(dt) -> moving pins -> stretch limit. Per frame: a measurement (energy,
strain, blow-up check) and, when recording, one recorder call. A blow-up stops the run with a
BlowUpError that names the integrator, the step and a stable step size; what was recorded is kept.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .adaptive import AdaptiveOptions, AdaptiveStep
from .cloth import ClothData
from .colliders import build_colliders
from .contacts import Contacts
from .diagnostics import Diagnostics, Measurement
from .errors import BlowUpError, SceneError
from .forces import ForceModel
from .garment.garment import GarmentCloth
from .integrators import integrator_class
from .model import Model, State, omega_max_bound
from .multilevel_cloth import MultilevelCloth
from .normals import VertexNormals
from .pins import PinDriver, PinSpec
from .stability import stable_dt
from .stretch_limit import StretchLimit
from .wind import Wind

STEP_GUARDS = ("warn", "refuse", "off")


@dataclass
class RunSummary:
    """What a run did. Times in seconds of wall clock unless named sim_."""

    name: str
    integrator: str
    dt: float
    n_particles: int
    n_springs: int
    frames: int = 0
    steps: int = 0
    sim_time: float = 0.0
    wall_step: float = 0.0      # stepping and per-frame checks, frames 2.. (frame 1 compiles)
    timed_steps: int = 0        # steps inside wall_step
    wall_record: float = 0.0    # recorder calls, frames 2..
    first_frame_wall: float = 0.0
    final: Measurement | None = None
    max_strain_seen: float = 0.0
    stats: dict = field(default_factory=dict)
    blowup: str | None = None
    levels: list = field(default_factory=list)  # LevelSwitch history of a multilevel cloth
    dt_min: float | None = None  # smallest and largest step [s] taken (they differ with dt = "auto" or levels)
    dt_max: float | None = None
    timed_sim: float = 0.0       # simulated seconds inside wall_step
    adaptive: str | None = None  # dt = "auto": the rule and what it did (AdaptiveStep.describe)
    events: list[str] = field(default_factory=list)  # what happened on the way (seams closed and joined, ...)
    outputs: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def steps_per_s(self) -> float:
        return self.timed_steps / self.wall_step if self.wall_step > 0 else float("nan")

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall second of stepping (> 1 is faster than real time)."""
        return self.timed_sim / self.wall_step if self.wall_step > 0 else float("nan")

    def format(self) -> str:
        lines = [f"scene {self.name!r}: {self.n_particles} particles, {self.n_springs} springs, "
                 f"integrator {self.integrator}, dt = {'auto' if self.adaptive else f'{self.dt:.3g} s'}",
                 f"  ran {self.frames} frames, {self.steps} steps, {self.sim_time:.3f} s simulated"]
        if self.adaptive is not None:
            lines.append(f"  {self.adaptive}")
        elif self.dt_min is not None and self.dt_max > self.dt_min * (1 + 1e-9):
            lines.append(f"  steps: dt {self.dt_min:.3g} .. {self.dt_max:.3g} s")
        if self.wall_step > 0:
            lines.append(f"  speed: {self.steps_per_s:,.0f} steps/s, {1e3 * self.wall_step / max(self.timed_steps, 1):.3f} "
                         f"ms/step, {self.realtime_factor:.2f}x real time (frames 2..; frame 1 with compiles took "
                         f"{self.first_frame_wall:.2f} s)")
            if self.wall_record > 0:
                lines.append(f"  recording: {1e3 * self.wall_record / max(self.frames - 1, 1):.2f} ms/frame, "
                             f"{100 * self.wall_record / (self.wall_step + self.wall_record):.1f} % of the loop")
        if self.final is not None:
            f = self.final
            lines.append(f"  energy: kinetic {f.kinetic:.4g} J, potential {f.potential:.4g} J "
                         f"(elastic {f.elastic:.4g}, gravity {f.gravity:.4g}), total {f.total:.4g} J")
            lines.append(f"  max strain: {100 * f.max_strain:.2f} % now, {100 * self.max_strain_seen:.2f} % peak; "
                         f"max speed {f.max_speed:.3g} m/s")
        for e in self.events:
            lines.append(f"  {e}")
        if self.levels:
            lines.append("  levels: " + " -> ".join(f"{s.level + 1} (t = {s.t:.3g} s)" for s in self.levels))
        for k, v in self.stats.items():
            lines.append(f"  {k}: {v:.4g}")
        for w in self.warnings:
            lines.append(f"  warning: {w}")
        lines.append(f"  instability: {self.blowup or 'none detected'}")
        for o in self.outputs:
            lines.append(f"  wrote {o}")
        return "\n".join(lines)


class Scene:
    """A cloth, an integrator and only the components named.

    cloth:              ClothData (from ClothBuilder), a Model, a MultilevelCloth (ClothBuilder.multilevel_grid):
                        the scene then starts on its start level and refines as the drape settles, or a
                        GarmentCloth (taichi_cloth.garment): the scene sews its seams, joins them and drapes on
    integrator:         "explicit" | "verlet" | "central-difference" | "approx-implicit" | "implicit"
    dt:                 time step [s], or "auto": chosen before every frame from the integrator's stable step
                        (taichi_cloth.adaptive: safety x the damped closed-form bound at the Gershgorin frequency,
                        halved on fast motion near colliders, frame-aligned, recomputed when the model changes;
                        one step per frame for approx-implicit/implicit); `scene.dt` reads the current step
    adaptive:           with dt = "auto": AdaptiveOptions keyword arguments (safety, dt_min, dt_max, growth,
                        calm_steps, motion, rollback)
    integrator_options: dict of the integrator's OPTIONS
    gravity:            [m/s^2]; air_damping: drag rate [1/s]
    pins:               PinSpec list (fixed pins cost nothing per step; moving ones build a PinDriver)
    wind:               None or Wind keyword arguments (velocity [m/s], coefficient, gust, gust_frequency)
    stretch_limit:      None or StretchLimit keyword arguments (max_strain, iterations)
    colliders:          collider specs (dicts, see taichi_cloth.colliders) or collision objects
                        (MeshCollider, PrimitiveColliders); resolved after every step, in order
    self_collision:     False, True, or SelfCollision keyword arguments (thickness, friction): the cloth
                        against its own triangles, resolved before the colliders
    multilevel:         for a MultilevelCloth: SettleCriterion keyword arguments (max_speed, energy_change,
                        window, max_time), refine ("global" = True, "local", or "none" = False: stay on the
                        start level), angle (local refinement: dihedral angle [deg] that calls for it, default
                        20) and dt_growth (time step multiplier per level below the finest; dt is the finest
                        level's step; default 1)
    sewing:             for a GarmentCloth: SewingOptions keyword arguments (close_speed, max_force, epsilon,
                        energy_tolerance, gravity, join, join_stiffness, max_time); defaults when omitted
    fps:                frames per simulated second for run() and recording; substeps = round(1/(fps dt))
    step_guard:         what to do when an explicit integrator's dt exceeds its stable bound: warn/refuse/off
    max_speed [m/s], max_strain [-]: beyond these (or at any NaN) a run is declared blown up
    """

    def __init__(self, cloth: ClothData | Model | MultilevelCloth, *, name: str = "cloth", integrator: str = "approx-implicit",
                 dt: float | str = 1.0 / 240.0, integrator_options: dict | None = None, gravity=(0.0, -9.81, 0.0),
                 air_damping: float = 0.1, pins=(), wind: dict | None = None, stretch_limit: dict | None = None,
                 colliders=(), self_collision=False, multilevel: dict | None = None, sewing: dict | None = None,
                 body_morph: dict | None = None, fps: float = 60.0, adaptive: dict | None = None,
                 precision: str = "f32", step_guard: str = "warn", max_speed: float = 200.0, max_strain: float = 10.0,
                 base_dir=None):
        auto = isinstance(dt, str)
        if auto and dt != "auto":
            raise SceneError(f"dt must be a positive number of seconds or 'auto', got {dt!r}")
        number = isinstance(dt, (int, float)) and not isinstance(dt, bool)
        if not auto and not (number and dt > 0 and math.isfinite(dt)):
            raise SceneError(f"dt must be a positive number of seconds or 'auto', got {dt!r}")
        if adaptive is not None and not auto:
            raise SceneError(f"adaptive options need dt = 'auto' (got dt = {dt!r})")
        try:
            adaptive_options = AdaptiveOptions(**(adaptive or {})) if auto else None
        except TypeError:
            unknown = sorted(set(adaptive) - set(AdaptiveOptions.keys()))
            raise SceneError(f"adaptive has no option {unknown[0]!r} "
                             f"(options: {', '.join(AdaptiveOptions.keys())})") from None
        except ValueError as err:
            raise SceneError(str(err)) from None
        if not fps > 0:
            raise SceneError(f"fps must be > 0, got {fps}")
        if step_guard not in STEP_GUARDS:
            raise SceneError(f"step_guard must be one of {', '.join(STEP_GUARDS)}, got {step_guard!r}")
        self.name = name
        self.multilevel_cloth = cloth if isinstance(cloth, MultilevelCloth) else None
        if multilevel is not None and self.multilevel_cloth is None:
            raise SceneError("[multilevel] needs a cloth built as a 4-8 hierarchy (ClothBuilder.multilevel_grid)")
        self.garment = cloth if isinstance(cloth, GarmentCloth) else None
        if sewing is not None and self.garment is None:
            raise SceneError("[sewing] needs a garment cloth (a garment file, or taichi_cloth.garment.build_garment)")
        if self.garment is not None and self_collision:
            raise SceneError("self_collision is not supported on a garment yet (merging the seams changes its "
                             "triangles)")
        if self.multilevel_cloth is not None:
            if self_collision:
                raise SceneError("self_collision is not supported on a multilevel cloth yet (its triangle grid "
                                 "would have to be rebuilt at every level switch)")
            ml = self.multilevel_cloth
            self.model = Model(ml.levels[ml.start_level], precision, capacity=ml.capacity)
        elif self.garment is not None:
            self.model = Model(self.garment.data, precision)
        else:
            self.model = cloth if isinstance(cloth, Model) else Model(cloth, precision)
        self.state = State(self.model)
        self.adaptive: AdaptiveStep | None = None
        self._dt = None if auto else float(dt)
        self.fps = float(fps)
        self.max_speed, self.max_strain = float(max_speed), float(max_strain)
        self.warnings: list[str] = []

        self.pin_specs = [p if isinstance(p, PinSpec) else PinSpec(**p) for p in pins]
        if self.garment is not None and len(self.garment.fixed):
            self.pin_specs.append(PinSpec(near=self.garment.fixed_targets))
        moving = [spec for spec in self.pin_specs if spec.path is not None]
        self.pins: PinDriver | None = None
        if moving:
            levels = self.multilevel_cloth.levels if self.multilevel_cloth else [self.model.data]
            capacity = max(sum(len(spec.select(d.positions)) for spec in moving) for d in levels)
            self.pins = PinDriver(self.model, self.state, [(spec.select(self.model.data.positions), spec.path)
                                                           for spec in moving], capacity)
        self._apply_pins()

        self.wind = Wind(self.model, self.state, **wind) if wind is not None else None
        self.colliders = build_colliders(colliders, base_dir) if colliders else []
        if self_collision:  # first, so that the body colliders have the last word on every position
            from collision.self_collision import SelfCollision

            options = self_collision if isinstance(self_collision, dict) else {}
            self.colliders.insert(0, SelfCollision(self.model.data.triangles, self.model.data.positions, **options))
        self.contacts = Contacts(self.model) if self.colliders else None
        self.state.contacts = self.contacts
        for c in self.colliders:
            c.attach(self.state.x, self.state.v, self.model.inv_mass, self.model.n_particles, self.contacts.normal)
        # force sources: the wind and the repulsion of mesh colliders that ask for it
        sources = [s for s in [self.wind] + [getattr(c, "repulsion", None) for c in self.colliders] if s is not None]
        self.forces = ForceModel(self.model, self.state, gravity, air_damping, sources)
        self.integrator = integrator_class(integrator)(self.model, self.state, self.forces,
                                                       **(integrator_options or {}))
        if getattr(self.integrator, "needs_levels", False):
            ml = self.multilevel_cloth
            if ml is not None and (multilevel or {}).get("refine") == "local":
                raise SceneError("multigrid_cycles needs the nested levels of global refinement, not refine = local")
            if ml is None:
                raise SceneError(f"integrator {integrator!r} with multigrid_cycles needs a multilevel cloth "
                                 "([multilevel] in a scene file, ClothBuilder.multilevel_grid in Python)")
            self.integrator.attach_levels(ml.hierarchy.levels, ml.levels, [self._pinned_on(d) for d in ml.levels],
                                          ml.start_level)
        if auto:  # before anything reads dt (body morph, refiner)
            try:
                self.adaptive = AdaptiveStep(self, adaptive_options)
            except ValueError as err:
                raise SceneError(str(err)) from None
        self.stretch_limit = StretchLimit(self.model, self.state, **stretch_limit) if stretch_limit else None
        self.sewing = None
        if self.garment is not None:
            from .garment.sewing import Sewing, SewingOptions

            try:
                options = SewingOptions(**(sewing or {}))
            except (TypeError, ValueError) as err:
                raise SceneError(f"sewing: {err}") from None
            self.sewing = Sewing(self, self.garment, options)
        self.body_morph = self._body_morph(body_morph) if body_morph is not None else None
        self.diagnostics = Diagnostics(self.model, self.state, self.forces)
        self._normals: VertexNormals | None = None
        self.steps_taken = 0
        self.refiner = None
        if self.multilevel_cloth is not None:
            from .refiner import Refiner, SettleCriterion

            opts = dict(multilevel or {})
            refine, dt_growth = opts.pop("refine", True), opts.pop("dt_growth", 1.0)
            angle = opts.pop("angle", 20.0)
            try:
                self.refiner = Refiner(self, self.multilevel_cloth, SettleCriterion(**opts), refine, dt_growth, angle)
            except (TypeError, ValueError) as err:
                raise SceneError(f"multilevel: {err}") from None
        self._check_step(step_guard)
        if self.pins is not None:
            self.pins.apply(0.0, None)

    # ------------------------------------------------------------------ construction helpers
    def _body_morph(self, options: dict):
        """The MorphingBody of `body_morph`: keys weights (channel -> [-1, 1]), duration [s], start ([s] or
        "sewn", default "sewn" for a garment, else 0), blend (default: the shipped mannequin's BlendShapes); it
        drives the scene's first mesh collider, which must be that blend's base body."""
        from collision.body import MeshCollider

        from .body import BlendShapes
        from .body.morphing import MorphingBody

        opts = dict(options)
        bodies = [c for c in self.colliders if isinstance(c, MeshCollider)]
        if not bodies:
            raise SceneError("body_morph needs a mesh collider (the body to morph), e.g. path = \"mannequin\"")
        blend = opts.pop("blend", None) or BlendShapes.from_mannequin()
        if bodies[0].n_vertices != len(blend.base):
            raise SceneError(f"body_morph: the mesh collider {bodies[0].source!r} has {bodies[0].n_vertices} vertices, "
                             f"the blend shapes' base body {len(blend.base)}: morph the body the scene collides with")
        opts.setdefault("start", "sewn" if self.sewing is not None else 0.0)
        try:
            morph = MorphingBody(blend, collider=bodies[0], **opts)
            morph.check_speed(self.dt)
        except TypeError as err:
            raise SceneError(f"body_morph: {err}") from None
        self.body_collider_index = self.colliders.index(bodies[0])
        return morph

    @classmethod
    def from_file(cls, path, **overrides) -> "Scene":
        """The Scene of a TOML scene file; overrides as scenefile.load_scene (integrator, dt, precision...).
        Use load_scene itself to also get the file's frame count and output settings."""
        from .scenefile import load_scene

        return load_scene(path, **overrides).scene

    def _apply_pins(self) -> None:
        """Select the pinned particles on the current level's rest positions (specs are predicates on rest
        coordinates, so they carry over to a refined level) and load the moving ones into the driver."""
        rest = self.model.data.positions
        groups = [(spec.select(rest), spec) for spec in self.pin_specs]
        self.model.pin(np.concatenate([idx for idx, _ in groups]) if groups else [])
        if self.pins is not None:
            self.pins.load([idx for idx, spec in groups if spec.path is not None])
        self.pinned_indices = np.nonzero(self.model.pinned)[0]

    def _pinned_on(self, data: ClothData) -> np.ndarray:
        """(P,) bool: the particles of `data` (a level of this scene's cloth) that the pins select."""
        pinned = np.zeros(data.n_particles, dtype=bool)
        for spec in self.pin_specs:
            pinned[spec.select(data.positions)] = True
        return pinned

    def _load_level(self, data: ClothData) -> None:
        """Refill the model with another level of a multilevel cloth (same fields) and re-apply the pins."""
        self.model.load(data)
        self._apply_pins()

    def _topology_changed(self) -> None:
        """After a level switch (state already prolonged): integrator history, limits, moving pins."""
        self.integrator.topology_changed(self.level)
        if self.stretch_limit is not None:
            self.stretch_limit.refresh()
        if self.pins is not None:
            self.pins.apply(self.state.t, self.dt)

    def refine(self) -> None:
        """Switch a multilevel cloth to its next level now."""
        if self.refiner is None:
            raise SceneError("this scene's cloth has no levels to refine (build it with ClothBuilder.multilevel_grid)")
        self.refiner.refine()

    @property
    def level(self) -> int | None:
        """The current level of a multilevel cloth (0-based), else None."""
        return None if self.refiner is None else self.refiner.level

    @property
    def stable_dt(self) -> float | None:
        """The linear-theory stable step [s] of this scene's integrator on the current cloth (None if
        unconditionally stable). The step limit shrinks by about 1/sqrt(2) per 4-8 level."""
        return stable_dt(type(self.integrator), self.model, self.forces.air_damping_value)

    @property
    def dt(self) -> float:
        """The time step [s] of the next step. With dt = "auto" it is the current automatic choice, and assigning
        it only re-plans it (the refiner assigns it after a level switch)."""
        return self._dt

    @dt.setter
    def dt(self, value: float) -> None:
        # with dt = "auto" the step is managed: a write (the refiner's, after a level switch) re-plans it
        if self.adaptive is not None:
            self.adaptive.plan()
        else:
            self._dt = float(value)

    def _level_steps(self):
        """(label, dt [s], stable dt [s] or None) for every level this scene may run on."""
        auto = self.adaptive
        if self.multilevel_cloth is None:
            bound = self.stable_dt
            return [("", auto.step_for(bound) if auto else self.dt, bound)]
        out = []
        for k, data in enumerate(self.multilevel_cloth.levels):
            bound = stable_dt(type(self.integrator), self.model, self.forces.air_damping_value,
                              omega=omega_max_bound(data, self._pinned_on(data)))
            out.append((f" on level {k + 1}", auto.step_for(bound) if auto else self.refiner.level_dt(k), bound))
        return out

    def _check_step(self, guard: str) -> None:
        if guard == "off":
            return
        for where, dt, bound in self._level_steps():
            if bound is None or dt <= bound:
                continue
            msg = (f"dt = {dt:.3g} s exceeds the stable step {bound:.3g} s of integrator "
                   f"{self.integrator.name!r} on this cloth{where} (linear theory, ALGORITHMS.md 1.4)")
            if guard == "refuse":
                raise SceneError(msg + "; lower dt or pick approx-implicit/implicit")
            self.warnings.append(msg)
            warnings.warn(msg, stacklevel=3)
            return

    @property
    def substeps(self) -> int:
        """Steps per frame: round(1 / (fps dt)), at least 1 (with dt = "auto", dt = 1 / (fps substeps) exactly)."""
        return max(1, round(1.0 / (self.fps * self.dt)))

    # ------------------------------------------------------------------ stepping
    def step(self, n: int = 1) -> Measurement:
        """Advance n steps, then measure and check for a blow-up (raises BlowUpError). Returns the measurement."""
        self._advance(n)
        m = self.check()
        if self.adaptive is not None:
            self.adaptive.observe(m.max_speed, n)
        return m

    def _advance(self, n: int) -> None:
        if self.adaptive is not None:
            self.adaptive.plan()  # cheap unless the model changed
        dt = self.dt
        colliders = self.colliders
        morph = self.body_morph
        for _ in range(n):
            if morph is not None and not morph.done:
                morph.update(self.state.t, self.sewing is not None and self.sewing.active)
            for c in colliders:
                c.begin_step()
            self.integrator.step(dt)
            if self.pins is not None:
                self.pins.apply(self.state.t, dt)
            if self.sewing is not None and self.sewing.active:
                self.sewing.step(dt)
            if self.stretch_limit is not None:
                self.stretch_limit.apply(dt)
            if colliders:
                self.contacts.clear()
                for c in colliders:
                    c.resolve(dt)
            self.steps_taken += 1

    def measure(self) -> Measurement:
        return self.diagnostics.measure()

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
        name = self.integrator.name
        bound = self.stable_dt
        if bound is not None:
            suggested = 0.9 * bound
            advice = f"suggested stable step dt <= {suggested:.3g} s (linear theory, ALGORITHMS.md 1.4)"
        else:
            suggested = self.dt / 4
            advice = f"suggested: dt = {suggested:.3g} s or more damping"
            if name == "approx-implicit" and self.integrator.options["sweeps"] > 2 and not self.integrator.options["jv_term"]:
                advice += "; more than 2 sweeps need jv_term = true"
        d = self.model.data
        k_max = float(d.stiffness.max()) if d.n_springs else 0.0
        msg = (f"blow-up: integrator {name!r} went unstable by step {self.steps_taken} "
               f"(t = {self.state.t:.4g} s, dt = {self.dt:.3g} s): {reason}. Parameters: k_max = {k_max:.3g} N/m, "
               f"m_min = {float(d.mass.min()):.3g} kg, air_damping = {self.forces.air_damping_value:.3g} 1/s; {advice}")
        return BlowUpError(msg, integrator=name, step=self.steps_taken, dt=self.dt, suggested_dt=suggested,
                           reason=reason)

    def _stats(self) -> dict:
        """Cumulative counters of the integrator and the constraints (e.g. CG iterations, stretch passes)."""
        out = dict(self.integrator.stats)
        if self.stretch_limit is not None:
            out.update(self.stretch_limit.stats)
        return out

    def reset(self) -> None:
        """Back to t = 0: rest positions, zero velocity, integrator history cleared, pins at their start."""
        self.steps_taken = 0
        self.state.t = 0.0
        if self.refiner is not None:
            self.refiner.reset()
        if self.sewing is not None and self.model.data is not self.garment.data:
            self._load_level(self.garment.data)
        self.state.reset()
        self.integrator.reset()
        if self.refiner is not None:
            self.integrator.topology_changed(self.level)
        if self.sewing is not None:
            self.integrator.topology_changed()
            if self.stretch_limit is not None:
                self.stretch_limit.refresh()
            self.sewing.reset()
        if self.pins is not None:
            self.pins.apply(0.0, None)
        if self.adaptive is not None:
            self.adaptive.reset()

    @property
    def topology_changes(self) -> bool:
        """True if the cloth's triangles may change during a run (level switches, merged seams)."""
        return self.refiner is not None or (self.sewing is not None and self.sewing.options.join == "merge")

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
            self._normals = self.wind.normals if self.wind is not None else VertexNormals(self.model, self.state)
        return self._normals.snapshot()

    def export_mesh(self, path) -> Path:
        """Write the current cloth surface with meshio (.obj, .ply, .vtk... by suffix)."""
        import meshio

        path = Path(path)
        tri = self.model.data.triangles
        n = self.model.data.n_particles
        cells = [("triangle", tri.astype(np.int32))] if len(tri) else [("vertex", np.arange(n, dtype=np.int32)[:, None])]
        meshio.write(path, meshio.Mesh(self.positions(), cells))
        return path

    def _sewing_event(self) -> str:
        s = self.sewing
        gap = s.history[-1].max if s.history else 0.0
        what = {"merge": "pairs merged", "spring": "pairs joined by stiff springs", "none": "seam springs kept"}
        return (f"seams closed at t = {s.closed_at:.3f} s after {self.steps_taken} steps and {s.wall:.2f} s of wall "
                f"time, compiles included (largest gap {1e3 * gap:.2f} mm): {what[s.options.join]}; "
                f"{self.model.data.n_particles} particles now")

    # ------------------------------------------------------------------ the loop
    def run(self, frames: int, recorder=None, entity: str | None = None, progress: bool = True,
            record_every: int = 1, translation=None) -> RunSummary:
        """Run `frames` frames of `substeps` steps. With a Recorder, log the cloth under `entity` (default
        "cloth", displaced by `translation` [m] in the viewer) at frame 0 and after every `record_every`-th
        frame. A BlowUpError propagates after the frames so far are recorded; the summary is attached to it
        as `.summary`."""
        if frames < 0:
            raise ValueError("frames must be >= 0")
        entity = entity or "cloth"
        summary = RunSummary(self.name, self.integrator.name, self.dt, self.model.data.n_particles,
                             self.model.data.n_springs, warnings=list(self.warnings))
        stats_start = self._stats()
        if recorder is not None:
            t0 = time.perf_counter()
            recorder.begin_cloth(entity, self, translation)
            for k, c in enumerate(self.colliders):
                morphing = self.body_morph is not None and k == self.body_collider_index
                recorder.log_collider(f"{entity}/colliders/{k}", c.describe(), static=not morphing)
            recorder.log_frame(entity, self, 0, self.measure())
            summary.wall_record += time.perf_counter() - t0
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=frames, unit="frame", desc=self.name, leave=False)
        auto = self.adaptive
        counters = auto.counters() if auto is not None else None
        if self.sewing is not None and self.sewing.active:
            self.sewing.start_clock()
        try:
            for frame in range(1, frames + 1):
                t0 = time.perf_counter()
                try:
                    while True:
                        # per frame: a level switch or dt = "auto" changes the step, and frames stay 1/fps long
                        if auto is not None:
                            auto.plan()
                            auto.save()
                        n, dt, sim0 = self.substeps, self.dt, self.state.t
                        self._advance(n)
                        try:
                            m = self.check()  # also syncs: the measurement reads the device
                            break
                        except BlowUpError as err:
                            if auto is None or not auto.roll_back():
                                raise
                            summary.events.append(f"frame {frame}: {err.reason} at dt = {dt:.3g} s; rolled back, "
                                                  f"dt halved to {0.5 * dt:.3g} s")
                            if recorder is not None:
                                recorder.log_event(entity, self, frame, summary.events[-1], level="WARN")
                except BlowUpError as err:
                    summary.frames, summary.steps, summary.sim_time = frame, summary.steps + n, self.state.t
                    summary.blowup = str(err)
                    summary.dt_min = min(summary.dt_min or dt, dt)
                    summary.dt_max = max(summary.dt_max or dt, dt)
                    err.summary = summary
                    if recorder is not None:
                        recorder.log_event(entity, self, frame, str(err))
                    raise
                elapsed = time.perf_counter() - t0
                summary.frames, summary.steps, summary.sim_time = frame, summary.steps + n, self.state.t
                summary.dt_min = min(summary.dt_min or dt, dt)
                summary.dt_max = max(summary.dt_max or dt, dt)
                if auto is not None:
                    auto.observe(m.max_speed, n)
                if frame == 1 and frames > 1:
                    summary.first_frame_wall = elapsed  # compiles; kept out of the speed figures
                else:
                    summary.wall_step += elapsed
                    summary.timed_steps += n
                    summary.timed_sim += self.state.t - sim0
                summary.final = m
                summary.max_strain_seen = max(summary.max_strain_seen, m.max_strain)
                if self.refiner is not None and self.refiner.observe(m):
                    m = self.measure()
                    if recorder is not None:
                        recorder.log_topology(entity, self, frame)
                if self.sewing is not None:
                    was_sewing = self.sewing.active
                    merged = self.sewing.observe(m)
                    if was_sewing and self.sewing.joined:
                        summary.events.append(self._sewing_event())
                        m = self.measure()
                        if recorder is not None:
                            if merged:
                                recorder.log_topology(entity, self, frame, summary.events[-1])
                            else:
                                recorder.log_event(entity, self, frame, summary.events[-1], level="INFO")
                morph = self.body_morph
                if morph is not None and morph.done and not morph.reported:
                    morph.reported = True
                    summary.events.append(f"body morphed from t = {morph.begin:.3f} s to {morph.begin + morph.duration:.3f} s "
                                          f"(max vertex travel {1e3 * morph.max_displacement():.1f} mm)")
                    if recorder is not None:
                        recorder.log_event(entity, self, frame, summary.events[-1], level="INFO")
                if recorder is not None and (frame % record_every == 0 or frame == frames):
                    t0 = time.perf_counter()
                    recorder.log_frame(entity, self, frame, m, steps_per_s=n / elapsed if elapsed > 0 else None)
                    if frame > 1:
                        summary.wall_record += time.perf_counter() - t0
                if bar is not None:
                    bar.update(1)
        finally:
            if bar is not None:
                bar.close()
            if self.refiner is not None:
                summary.levels = list(self.refiner.switches)
            if self.topology_changes:
                summary.n_particles, summary.n_springs = self.model.data.n_particles, self.model.data.n_springs
            if self.sewing is not None or auto is not None:  # both may warn during the run
                summary.warnings = list(self.warnings)
            if summary.steps:
                summary.stats = {f"{k} per step": (v - stats_start.get(k, 0)) / summary.steps
                                 for k, v in self._stats().items()}
            if auto is not None:
                summary.adaptive = auto.describe(summary.dt_min, summary.dt_max, counters)
            if recorder is not None:
                recorder.flush()
        return summary
