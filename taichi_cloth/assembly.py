"""Scene assembly: a cloth and the options a scene names -> the parts of a Scene (model, state, forces, integrator,
step clock, controllers). Only what is named is built, and only its kernels are ever compiled.

This is the one place that knows every feature: adding one adds a keyword here and a controller (taichi_cloth.control)
of its own, and the Scene's loop stays as it is.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from clothbase.errors import warn
from collision.self_collision import SelfCollision

from .adaptive import AdaptiveOptions, AdaptiveStep
from .body.blendshapes import BlendShapes
from .body.morphing import MorphingBody
from .clock import FixedStep
from .colliders import Colliders, build_colliders
from .contacts import Contacts
from .diagnostics import Diagnostics
from .errors import SceneError
from .forces import ForceModel
from .garment.garment import GarmentCloth
from .garment.levels import MultilevelGarment
from .garment.sewing import Sewing, SewingOptions
from .guards import check_self_collision_grid
from .integrators import integrator_class
from .linear import NestedLevels
from .model import Model, State
from .multilevel_cloth import MultilevelCloth
from .pins import Pins, PinSpec, pin_spec, pinned_mask
from .refiner import Refiner, SettleCriterion
from .rest import RestCriterion, RestMonitor
from .stability import omega_max_estimate, stable_dt
from .strain import StrainMap
from .stretch_limit import StretchLimit
from .wind import Wind

STEP_GUARDS = ("warn", "refuse", "off")
DEFAULT_INTEGRATOR = "implicit"


@dataclass
class SceneParts:
    """What a Scene is made of. controllers run in this order: the refiner, the body morph, pins, sewing, the
    stretch limit, the colliders, the strain map; the colliders' per-step work is the collision stage, which runs
    after every other controller's step hooks."""

    name: str
    model: Model
    state: State
    forces: ForceModel
    integrator: object
    clock: object
    controllers: list = field(default_factory=list)
    contacts: Contacts | None = None  # the contact normals the collision stage writes and the integrator filters
    collision: Colliders | None = None  # the collision stage (also among the controllers: what it shows and counts)
    normals: object = None
    warnings: list = field(default_factory=list)
    max_speed: float = 200.0
    max_strain: float = 10.0
    rest: RestMonitor | None = None  # when the cloth counts as at rest
    diagnostics: Diagnostics | None = None  # the per-frame measurement
    stop_at_rest: bool = False


def assemble(cloth, *, name: str = "cloth", integrator: str = DEFAULT_INTEGRATOR, dt: float | str = 1.0 / 240.0,
             integrator_options: dict | None = None, gravity=(0.0, -9.81, 0.0), air_damping: float = 0.1, pins=(),
             wind: dict | None = None, stretch_limit: dict | None = None, colliders=(), self_collision=False,
             multilevel: dict | None = None, sewing: dict | None = None, body_morph: dict | None = None,
             fps: float = 60.0, adaptive: dict | None = None, precision: str = "f32", step_guard: str = "warn",
             max_speed: float = 200.0, max_strain: float = 10.0, rest: dict | None = None,
             base_dir=None) -> SceneParts:
    """The parts of a scene (Scene(cloth, **options) calls this). Units are SI.

    cloth:              ClothData, a Model, a MultilevelCloth (ClothBuilder.multilevel_grid), a GarmentCloth, or a
                        MultilevelGarment (taichi_cloth.garment.levels: sewn on its start level, refined once joined)
    integrator:         "explicit" | "verlet" | "central-difference" | "approx-implicit" | "implicit" (default:
                        implicit, without a step limit and accurate; see docs/integrators.md)
    dt:                 time step [s], or "auto": chosen before every frame from the integrator's stable step
                        (taichi_cloth.adaptive; one step per frame for the implicit integrators)
    adaptive:           with dt = "auto": AdaptiveOptions keyword arguments (safety, dt_min, dt_max, growth,
                        calm_steps, motion, rollback)
    integrator_options: dict of the integrator's OPTIONS
    gravity:            [m/s^2]; air_damping: drag rate [1/s]
    pins:               PinSpec list or dicts (indices, near, box, keyframes: checked as a scene file's [[pins]],
                        taichi_cloth.specs); fixed pins cost nothing per step, moving ones build a PinDriver
    wind:               None or Wind keyword arguments (velocity [m/s], coefficient, gust, gust_frequency)
    stretch_limit:      None or StretchLimit keyword arguments (max_strain, iterations, tolerance, omega)
    colliders:          collider specs (dicts, checked as a scene file's [[colliders]]: taichi_cloth.specs) or
                        collision objects; resolved after every step, in order
    self_collision:     False, True, or SelfCollision keyword arguments (thickness, friction, continuous): the cloth
                        against its own triangles, resolved after the colliders
    multilevel:         for a MultilevelCloth or a MultilevelGarment: SettleCriterion keyword arguments (max_speed,
                        energy_change, window, max_time), refine ("global" = True, "local", or "none" = False),
                        angle (local refinement: the dihedral angle [deg] that calls for it, default 20) and dt_growth
                        (step multiplier per level below the finest; dt is the finest level's step; default 1)
    sewing:             for a GarmentCloth: SewingOptions keyword arguments (close_speed, max_force, epsilon,
                        energy_tolerance, gravity, join, join_stiffness, max_time)
    body_morph:         weights (channel -> [-1, 1]), duration [s], start ([s] or "sewn"), blend (default: the
                        shipped mannequin's BlendShapes): the scene's first mesh collider morphs during the run
    fps:                frames per simulated second of Scene.run; every frame is filled with equal steps <= dt
    precision:          "f32" or "f64" fields
    step_guard:         what to do when an explicit integrator's dt exceeds its stable bound: warn | refuse | off
    max_speed [m/s], max_strain [-]: beyond these (or at any NaN) a run is declared blown up
    rest:               when the cloth counts as at rest (RestCriterion keyword arguments: max_speed, p99_speed
                        [m/s], hold, window [s]) and stop (bool, default False): Scene.run ends the run there
    base_dir:           the folder relative collider mesh paths are read from
    """
    auto = _check_step_options(dt, adaptive, fps, step_guard)
    rest_criterion, stop_at_rest = _rest(rest)
    source = _cloth_source(cloth, precision, multilevel, sewing, integrator_class(integrator).parallel_from_cpu)
    model = source.model
    state = State(model)
    parts_warnings: list[str] = []

    specs = [pin_spec(p, k) for k, p in enumerate(pins)] + source.pins
    pin_control = None
    if specs:
        moving = [s for s in specs if s.keyframes is not None]
        capacity = max(sum(len(s.select(d.positions)) for s in moving) for d in source.levels) if moving else None
        pin_control = Pins(model, state, specs, capacity)

    wind_source = Wind(model, state, **wind) if wind is not None else None
    objects = build_colliders(colliders, base_dir) if colliders else []
    if self_collision:  # last: a particle a body holds does not move for it (collision.self_collision)
        options = self_collision if isinstance(self_collision, dict) else {}
        seams = np.unique(source.garment.seam_pairs) if source.garment is not None else ()
        # the mesh in use first: its edges give the starting thickness and its particles the seam flags
        shapes = [(d.positions, d.triangles) for d in [model.data] + [d for d in source.levels if d is not model.data]]
        if options.get("cell_size"):
            check_self_collision_grid(shapes, options["cell_size"], options.get("thickness"),
                                      f"self_collision cell_size {options['cell_size']} m")
        objects.append(SelfCollision(model.triangles, model.n_triangles, shapes, seam_particles=seams, **options))
    collide = contacts = None
    if objects:
        contacts = Contacts(model)
        collide = Colliders(model, state, objects, contacts)
    sources = ([wind_source] if wind_source is not None else []) + (collide.repulsions if collide else [])
    forces = ForceModel(model, state, gravity, air_damping, sources)
    stepper = integrator_class(integrator)(model, state, forces, contacts=contacts, **(integrator_options or {}))
    if getattr(stepper, "needs_levels", False):
        _attach_levels(stepper, source, multilevel, parts_warnings)

    if auto:
        try:
            options = AdaptiveOptions(**(adaptive or {}))
            clock = AdaptiveStep(model, state, forces, type(stepper), fps, options,
                                 collide.thickness if collide else None)
        except TypeError:
            unknown = sorted(set(adaptive) - set(AdaptiveOptions.keys()))
            raise SceneError(f"adaptive has no option {unknown[0]!r} "
                             f"(options: {', '.join(AdaptiveOptions.keys())})") from None
        except ValueError as err:
            raise SceneError(str(err)) from None
    else:
        clock = FixedStep(dt, fps)

    limit = StretchLimit(model, state, contacts, **stretch_limit) if stretch_limit else None
    sew = _sewing(model, state, forces, contacts, source.garment, sewing, source.garment_levels) \
        if source.garment is not None else None
    if limit is not None:
        limit.sewing = sew
    morph = _body_morph(body_morph, collide, sew, clock.dt) if body_morph is not None else None
    for body in collide.bodies if collide is not None else []:
        if body.deforming and body.start == "sewn" and sew is not None:  # its motion begins once the seams are joined
            body.ready = lambda: not sew.active
    refiner = None
    if source.multilevel is not None:
        ready = (lambda: sew.joined) if sew is not None else None  # a garment refines once its seams are joined
        refiner = _refiner(model, state, contacts, source.multilevel, multilevel, gravity, ready, source.garment_levels)
        clock.model_changed(refiner.dt_scale(refiner.level))
    strain_map = None
    if source.garment is not None:
        strain_map = StrainMap(model)

    _check_step(step_guard, stepper, model, forces, clock, source, specs, refiner, parts_warnings)
    controllers = [c for c in (refiner, morph, pin_control, sew, limit, collide, strain_map) if c is not None]
    d = model.data
    weight = float(d.mass.sum()) * max(float(np.linalg.norm(forces.gravity_value)), 9.81)
    monitor = RestMonitor(rest_criterion, weight * float(np.linalg.norm(np.ptp(d.positions, axis=0))))
    diagnostics = Diagnostics(model, state, forces, rest_criterion.p99_speed, stepper.staggered_velocity)
    for c in (stepper, *controllers):  # the integrator too (planned CG reports its solves)
        if getattr(c, "report_slots", 0):
            diagnostics.add_reporter(c)
    return SceneParts(name, model, state, forces, stepper, clock, controllers, contacts, collide,
                      wind_source.normals if wind_source is not None else None, parts_warnings,
                      float(max_speed), float(max_strain), monitor, diagnostics, stop_at_rest)


def _rest(options: dict | None) -> tuple[RestCriterion, bool]:
    opts = dict(options or {})
    stop = opts.pop("stop", False)
    if not isinstance(stop, bool):
        raise SceneError(f"rest stop must be true or false, got {stop!r}")
    try:
        return RestCriterion(**opts), stop
    except TypeError:
        raise SceneError(f"rest has no option {sorted(set(opts) - set(RestCriterion.__dataclass_fields__))[0]!r} "
                         "(options: stop, max_speed, p99_speed, hold, window, energy_tolerance)") from None
    except ValueError as err:
        raise SceneError(str(err)) from None


# ---------------------------------------------------------------------- the cloth source
@dataclass
class _Source:
    """A cloth as the scene will run it: the model on its first level, every level it may reach (pins are
    selected and the step guard checked on each), extra pins, and the cloth objects whose controllers it needs."""

    model: Model
    levels: list
    pins: list
    multilevel: object = None
    garment: object = None
    garment_levels: object = None


def _cloth_source(cloth, precision: str, multilevel, sewing, parallel_from: int) -> _Source:
    """The cloth's source; its model runs its loops in one thread below `parallel_from` particles (the CPU)."""
    if isinstance(cloth, MultilevelGarment):  # the pieces apart on the start level, then the merged levels
        g = cloth.garment
        local = (multilevel or {}).get("refine") == "local"
        model = Model(g.data, precision, capacity=cloth.local_capacity if local else cloth.capacity,
                      parallel_from=parallel_from)
        fixed = [PinSpec(near=g.fixed_targets)] if len(g.fixed) else []
        return _Source(model, [g.data] + list(cloth.cloth.levels), fixed, multilevel=cloth.cloth, garment=g,
                       garment_levels=cloth)
    if isinstance(cloth, MultilevelCloth):
        if sewing is not None:
            raise SceneError("[sewing] needs a garment cloth (a garment file, or taichi_cloth.garment.build_garment)")
        model = Model(cloth.levels[cloth.start_level], precision, capacity=cloth.capacity, parallel_from=parallel_from)
        return _Source(model, list(cloth.levels), [], multilevel=cloth)
    if multilevel is not None:
        raise SceneError("[multilevel] needs a cloth built as a 4-8 hierarchy (ClothBuilder.multilevel_grid)")
    if isinstance(cloth, GarmentCloth):
        model = Model(cloth.data, precision, parallel_from=parallel_from)
        fixed = [PinSpec(near=cloth.fixed_targets)] if len(cloth.fixed) else []
        return _Source(model, [cloth.data], fixed, garment=cloth)
    if sewing is not None:
        raise SceneError("[sewing] needs a garment cloth (a garment file, or taichi_cloth.garment.build_garment)")
    model = cloth if isinstance(cloth, Model) else Model(cloth, precision, parallel_from=parallel_from)
    return _Source(model, [model.data], [])


# ---------------------------------------------------------------------- options and features
def _check_step_options(dt, adaptive, fps, step_guard) -> bool:
    """Validate the step options; True for dt = "auto"."""
    auto = isinstance(dt, str)
    if auto and dt != "auto":
        raise SceneError(f"dt must be a positive number of seconds or 'auto', got {dt!r}")
    number = isinstance(dt, (int, float)) and not isinstance(dt, bool)
    if not auto and not (number and dt > 0 and math.isfinite(dt)):
        raise SceneError(f"dt must be a positive number of seconds or 'auto', got {dt!r}")
    if adaptive is not None and not auto:
        raise SceneError(f"adaptive options need dt = 'auto' (got dt = {dt!r})")
    if not (isinstance(fps, (int, float)) and fps > 0 and math.isfinite(fps)):
        raise SceneError(f"fps must be > 0, got {fps}")
    if step_guard not in STEP_GUARDS:
        raise SceneError(f"step_guard must be one of {', '.join(STEP_GUARDS)}, got {step_guard!r}")
    return auto


def _attach_levels(stepper, source: _Source, multilevel, notes: list) -> None:
    """Give an integrator that asks for them the cloth's nested 4-8 levels (linear.NestedLevels; None and the reason
    where it has none: no multilevel cloth, or local refinement): it decides what it makes of them (the implicit
    step: linear.policy); a note it returns goes into the run's warnings."""
    ml = source.multilevel
    why = None
    if ml is None:
        why = "needs a multilevel cloth ([multilevel] in a scene file, ClothBuilder.multilevel_grid in Python)"
    elif (multilevel or {}).get("refine") == "local":
        why = "needs the nested levels of global refinement, not refine = local"
    garment = source.garment is not None
    nested = None if why else NestedLevels(ml.hierarchy.levels, ml.levels, None if garment else ml.start_level, garment)
    note = stepper.attach_levels(nested, why, garment=garment)
    if note:
        notes.append(note)


def _sewing(model, state, forces, contacts, garment, options: dict | None, levels=None):
    try:
        return Sewing(model, state, forces, contacts, garment, SewingOptions(**(options or {})), levels)
    except (TypeError, ValueError) as err:
        raise SceneError(f"sewing: {err}") from None


def _refiner(model, state, contacts, cloth, options: dict | None, gravity, ready=None, garment=None):
    opts = dict(options or {})
    refine, dt_growth, angle = opts.pop("refine", True), opts.pop("dt_growth", 1.0), opts.pop("angle", 20.0)
    try:
        return Refiner(model, state, contacts, cloth, SettleCriterion(**opts), refine, dt_growth, angle, gravity,
                       ready, garment)
    except (TypeError, ValueError) as err:
        raise SceneError(f"multilevel: {err}") from None


def _body_morph(options: dict, collide, sewing, dt: float):
    """The MorphingBody of `body_morph` (see assemble): it drives the scene's first mesh collider, which must be
    the blend shapes' base body; start "sewn" (the default for a garment) waits for the seams to be joined."""
    opts = dict(options)
    bodies = collide.bodies if collide is not None else []
    if not bodies:
        raise SceneError("body_morph needs a mesh collider (the body to morph), e.g. path = \"mannequin\"")
    blend = opts.pop("blend", None) or BlendShapes.from_mannequin()
    if bodies[0].n_vertices != len(blend.base):
        raise SceneError(f"body_morph: the mesh collider {bodies[0].source!r} has {bodies[0].n_vertices} vertices, "
                         f"the blend shapes' base body {len(blend.base)}: morph the body the scene collides with")
    opts.setdefault("start", "sewn" if sewing is not None else 0.0)
    index = collide.objects.index(bodies[0])
    ready = (lambda: not sewing.active) if sewing is not None else None
    try:
        morph = MorphingBody(blend, collider=bodies[0], ready=ready, index=index, **opts)
        morph.check_speed(dt)
    except TypeError as err:
        raise SceneError(f"body_morph: {err}") from None
    collide.moving.add(index)
    return morph


def _check_step(guard: str, stepper, model, forces, clock, source: _Source, specs, refiner, notes: list) -> None:
    """The step guard: an explicit integrator's step against its linear-theory bound on every level the scene may
    run on (warn, refuse with a SceneError, or off)."""
    cls, air = type(stepper), forces.air_damping_value
    if guard == "off" or cls.unconditionally_stable:
        return
    if refiner is None:
        bound = stable_dt(cls, model, air)
        candidates = [("", clock.step_for(bound) if clock.auto else clock.dt, bound)]
    else:
        candidates = []
        levels = list(enumerate(refiner.cloth.levels))
        if source.garment is not None:  # the pieces apart, sewn on the start level
            levels.append((refiner.cloth.start_level, source.garment.data))
        for k, data in levels:
            bound = stable_dt(cls, model, air, omega=omega_max_estimate(data, pinned_mask(specs, data.positions)))
            candidates.append((f" on level {k + 1}", clock.step_for(bound) if clock.auto
                               else clock.base * refiner.dt_scale(k), bound))
    for where, dt, bound in candidates:
        if bound is None or dt <= bound:
            continue
        msg = (f"dt = {dt:.3g} s exceeds the stable step {bound:.3g} s of integrator {stepper.name!r} on this "
               f"cloth{where} (linear theory, see docs/integrators.md)")
        if guard == "refuse":
            raise SceneError(msg + "; lower dt or pick approx-implicit/implicit")
        notes.append(msg)
        warn(msg)
        return


__all__ = ["DEFAULT_INTEGRATOR", "STEP_GUARDS", "SceneParts", "assemble"]
