"""TOML scene files -> Scene, with one clear error line per mistake.

A scene names only what it needs; every table below except [cloth] and [integrator] is optional,
and a component whose table is absent is never built. The schema (units in brackets):

    name = "hanging_cloth"        # output file stem (default: the file's stem)
    frames = 240                  # frames to run
    fps = 60.0                    # frames per simulated second; steps per frame = round(1 / (fps dt))
    precision = "f32"             # "f32" or "f64" fields
    gravity = [0.0, -9.81, 0.0]   # [m/s^2]
    air_damping = 0.1             # drag rate [1/s]
    self_collision = false        # the cloth against its own triangles (costs a grid rebuild per step)
    quality = "balanced"          # preview | balanced | accurate: a measured preset (taichi_cloth.quality) picks the
                                  # integrator, its options, dt and the 4-8 level; replaces [integrator] name, dt
                                  # and options (step_guard stays); the CLI's --integrator and --dt still override

    [cloth]                       # exactly one source: [cloth.grid], [cloth.mesh] or garment = "file.toml"
    material = "cotton"           # preset name, or a [cloth.material] table
    [cloth.grid]
    size = [1.0, 1.0]             # [m]
    resolution = [48, 48]         # particles along u and v
    center = [0.0, 1.0, 0.0]      # [m]
    plane = "xy"                  # "xy" (hanging), "xz" (horizontal), "yz", "zy"
    # [cloth.mesh] path = "flag.obj", scale = 1.0, translate = [0, 0, 0]
    # [cloth.material] preset = "cotton", density [kg/m^2], stretch [N/m], shear [N/m], bend [N m], damping [s],
    #                   viscosity [m^2/s], bending = "springs" | "quadratic" (bend is then the rigidity B)

    [integrator]
    name = "approx-implicit"      # explicit | verlet | central-difference | approx-implicit | implicit
    dt = 0.004                    # [s], or "auto": chosen per frame from the stable step (taichi_cloth.adaptive)
    # adaptive = { safety = 0.8, dt_min = 1e-6, dt_max = 0.0167, growth = 1.25, calm_steps = 50, motion = 0.5,
    #              rollback = true }   # with dt = "auto" only; dt_max defaults to one frame
    step_guard = "warn"           # warn | refuse | off, when an explicit dt exceeds its stable bound
    # plus the integrator's own options, e.g. sweeps = 2, warm_start = false, jv_term = false (approx-implicit),
    # cg_tolerance = 1e-3, cg_max_iterations = 200 (implicit)

    [[pins]]                      # any number; each selects by indices, near (points [m]) and/or box
    near = [[-0.5, 1.5, 0.0], [0.5, 1.5, 0.0]]
    # indices = [0, 47]; box = { min = [..], max = [..] }; keyframes = [[t, dx, dy, dz], ...] moves the group

    [wind]                        # velocity [m/s], coefficient [kg/(m^2 s)], gust (relative), gust_frequency [Hz]
    [stretch_limit]               # max_strain (0.1 = 10 %), iterations (max passes), tolerance, omega, after_join =
                                  # true (a garment: false leaves the drape to the fabric once the seams are joined)
    [[colliders]]                 # type = "sphere" (center, radius) | "capsule" (a, b, radius) | "plane" (point,
                                  # normal) | "mesh" (path: a file or "mannequin", scale, translate, cell_size,
                                  # mode = "fuzzy" | "exact", repulsion = {stiffness [N], distance [m],
                                  # max_force [N]}) | "standin" (spheres and capsules for the mannequin);
                                  # all: thickness [m] = 0.003, friction = 0.3
    [multilevel]                  # a 4-8 hierarchy over [cloth.grid] (no resolution there) or a garment's pieces:
    levels = 5                    # coarse first, refined as the drape settles (Hsiao 2006 section 2.2); 1..8
                                  # (a garment: 2..6, default the garment file's `levels`, its finest at its spacing)
    base_cells = [4, 4]           # cells of level 1 (alternating diagonals); each level bisects every triangle
    start_level = 1               # the level the run starts on (levels: only the finest); a garment is placed, sewn
                                  # and merged on it, then refined once its seams are joined
    refine = "global"             # "global" (every triangle), "local" (where the dihedral angle across a
                                  # hypotenuse, on a garment any edge, exceeds `angle` = 20 [deg] or a collider
                                  # touches), "none"
    dt_growth = 1.0               # dt multiplier per level below the finest ([integrator] dt is the finest's)
    [multilevel.settle]           # a level is settled when all hold: max_speed [m/s] = 0.05, energy_change = 1e-4
                                  # (|dE| over `window` = 10 frames / (weight x cloth size)); max_time [s] = 3.0
                                  # refines anyway
    # resolution = "fit"         # a garment at a preset spacing: draft (2 cm), fit (1 cm), fine (5 mm); with
                                  # [multilevel] and no levels there, also its levels (3, 5, 5)
    # garment = "skirt.toml"     # a garment file (taichi_cloth.garment.garmentfile): pieces placed around the
                                  # mannequin, sewn, joined, draped; [cloth] material overrides the file's
    [sewing]                      # for a garment: close_speed [m/s] = 0.5 (seam rest lengths shrink this fast),
                                  # max_force [N] (a fixed cap per pair; default: scaled with the seam's stiffness,
                                  # 1.1 x its closing in one step), stiffness [N/m] (default sheet modulus / 2),
                                  # epsilon [m] = 0.002 and energy_tolerance = 0.01 (when sewing stops), gravity =
                                  # false (while sewing), join = "merge" | "spring" | "none", join_stiffness [N/m],
                                  # max_time [s] = 10, stall_gap = 0.25 (a stalled seam closes below this
                                  # fraction of the seam spacing)
    [body]                        # morph the mannequin to measured girths [m] (taichi_cloth.body; Zhang et al. 2017):
    waist = 0.80                  # any of chest, underbust, waist, hips, neck, upper_arm, thigh (tape girths)
    morph = "before"              # "before": the run starts on the morphed body (a garment is placed on it);
                                  # "during": it starts on the shipped body and morphs over morph_time [s] = 1.0
                                  # (after the seams are joined, for a garment), the cloth following it
    tolerance = 0.001             # [m] how close each girth must come; needs a [[colliders]] mesh "mannequin"
    [rest]                        # when the cloth is at rest: every particle under max_speed [m/s] = 0.005, 99 %
                                  # under p99_speed = 0.001, energy not rising over window [s] = 1.0; stop = true
                                  # ends the run there (as `run --until-rest`; frames is then the most it runs)
    [output]                      # dir = "out", record = true, mesh = true, record_every = 1
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .assembly import STEP_GUARDS
from .body.landmarks import Body
from .builder import ClothBuilder
from .errors import BodyError, MeshError, PatternError, SceneError
from .garment.garment import RESOLUTIONS, build_garment
from .garment.garmentfile import load_garment
from .garment.levels import multilevel_garment
from .guards import check_grid, check_multilevel_grid, check_precision
from .integrators import INTEGRATORS
from .paths import check_output_folder
from .quality import QUALITIES, coarsen_resolution, preset
from .scene import Scene
from .schema import MATERIAL_TABLE, Array, Field, Table, Validator, at_least, material_of, nonneg, positive, read_toml
from .specs import COLLIDER_TABLE, PIN_TABLE

#: the girths a [body] table may set (taichi_cloth.body.GIRTHS; spelled out so parsing imports no scipy)
BODY_GIRTHS = ("chest", "underbust", "waist", "hips", "neck", "upper_arm", "thigh")


#: [integrator] dt: seconds, or "auto" (taichi_cloth.adaptive); [integrator] adaptive: the rule's parameters
#: (defaults in AdaptiveOptions, so absent keys stay None here and are dropped)
DT_FIELD = Field("dt", check=lambda v: None if v == "auto" or v > 0 else "must be > 0")
ADAPTIVE_TABLE = Table({"safety": Field("number", None, lambda v: None if 0 < v <= 1 else "must lie in (0, 1]"),
                        "dt_min": Field("number", None, positive), "dt_max": Field("number", None, positive),
                        "growth": Field("number", None, lambda v: None if v > 1 else "must be > 1"),
                        "calm_steps": Field("int", None, at_least(1)), "motion": Field("number", None, positive),
                        "rollback": Field("bool", None)})

SCHEMA = Table({
    "name": Field("str", None),
    "frames": Field("int", 120, at_least(0)),
    "fps": Field("number", 60.0, positive),
    "precision": Field("str", "f32", choices=("f32", "f64")),
    "gravity": Field("vec3", [0.0, -9.81, 0.0]),
    "air_damping": Field("number", 0.1, nonneg),
    # true, or a table of SelfCollision options
    "self_collision": Table({"thickness": Field("number", None, positive), "friction": Field("number", None, nonneg),
                             "continuous": Field("bool", None)}, allow_string=Field("bool")),
    "quality": Field("str", None, choices=QUALITIES),
    "cloth": Table({
        "material": MATERIAL_TABLE,
        "grid": Table({"size": Field("vec2", check=lambda v: None if min(v) > 0 else "must be positive"),
                       "resolution": Field("int2", None, check=lambda v: None if min(v) >= 2 else "must be >= 2 each"),
                       "center": Field("vec3", [0.0, 0.0, 0.0]),
                       "plane": Field("str", "xy", choices=("xy", "xz", "yz", "zy"))}),
        "mesh": Table({"path": Field("str"), "scale": Field("number", 1.0, positive),
                       "translate": Field("vec3", [0.0, 0.0, 0.0])}),
        "garment": Field("str", None),
        "resolution": Field("str", None, choices=tuple(RESOLUTIONS)),
    }, required=True),
    "integrator": Table({"name": Field("str", choices=tuple(INTEGRATORS)),
                         "dt": DT_FIELD, "adaptive": ADAPTIVE_TABLE,
                         "step_guard": Field("str", "warn", choices=STEP_GUARDS)}, required=True, extra=True),
    "pins": Array(PIN_TABLE),  # the tables the Python API checks its dicts by (taichi_cloth.specs)
    "wind": Table({"velocity": Field("vec3"), "coefficient": Field("number", 1.0, nonneg),
                   "gust": Field("number", 0.0, nonneg), "gust_frequency": Field("number", 0.5, positive)}),
    "stretch_limit": Table({"max_strain": Field("number", 0.1, positive),
                            "iterations": Field("int", 100, at_least(1)),
                            "tolerance": Field("number", 1e-3, nonneg),
                            "omega": Field("number", 1.5, lambda v: None if 0 < v < 2 else "must lie in (0, 2)"),
                            "after_join": Field("bool", True)}),
    "colliders": Array(COLLIDER_TABLE),
    "multilevel": Table({
        "levels": Field("int", None, lambda v: None if 1 <= v <= 8 else "must lie in 1..8"),
        "base_cells": Field("int2", [4, 4], lambda v: None if min(v) >= 1 else "must be >= 1 each"),
        "start_level": Field("int", 1, at_least(1)),
        "refine": Field("str", "global", choices=("global", "local", "none")),
        "angle": Field("number", 20.0, lambda v: None if 0 < v < 180 else "must lie in (0, 180) degrees"),
        "dt_growth": Field("number", 1.0, lambda v: None if 1 <= v <= 2 else "must lie in [1, 2]"),
        "settle": Table({"max_speed": Field("number", 0.05, positive),
                         "energy_change": Field("number", 1e-4, positive),
                         "window": Field("int", 10, at_least(1)),
                         "max_time": Field("number", 3.0, positive)}, always=True),
    }),
    "sewing": Table({"close_speed": Field("number", 0.5, positive), "max_force": Field("number", None, positive),
                     "epsilon": Field("number", 0.002, positive), "energy_tolerance": Field("number", 1e-2, positive),
                     "gravity": Field("bool", False),
                     "join": Field("str", "merge", choices=("merge", "spring", "none")),
                     "join_stiffness": Field("number", None, positive), "max_time": Field("number", 10.0, positive),
                     "stall_gap": Field("number", 0.25, positive), "stiffness": Field("number", None, positive)}),
    "body": Table({**{g: Field("number", None, positive) for g in BODY_GIRTHS},
                   "morph": Field("str", "before", choices=("before", "during")),
                   "morph_time": Field("number", 1.0, positive), "tolerance": Field("number", 1e-3, positive)}),
    "rest": Table({"stop": Field("bool", False), "max_speed": Field("number", 5e-3, positive),
                   "p99_speed": Field("number", 1e-3, positive), "window": Field("number", 1.0, positive),
                   "hold": Field("number", 0.5, positive)}),
    "output": Table({"dir": Field("str", "out"), "record": Field("bool", True), "mesh": Field("bool", True),
                     "record_every": Field("int", 1, at_least(1))}, always=True),
})


# ---------------------------------------------------------------------- building
@dataclass
class LoadedScene:
    """A parsed scene file: the Scene plus what the run loop needs."""

    scene: Scene
    name: str
    frames: int
    output: dict
    config: dict = field(repr=False, default_factory=dict)


def parse_scene(source: str | Path | dict, base_dir: Path | None = None, label: str | None = None) -> dict:
    """Validate a scene (TOML path or dict) and return the config dict with defaults filled in.
    Raises SceneError with one line naming the file, table and key."""
    if isinstance(source, dict):
        data, label, base_dir = source, label or "scene", base_dir or Path.cwd()
    else:
        path = Path(source)
        label = label or str(path)
        data = read_toml(path, label, "scene")
        base_dir = base_dir or path.parent
    v = Validator(label)
    cfg = v.table(SCHEMA, data, "", "")
    cfg["name"] = cfg["name"] or "scene"
    cfg["_label"], cfg["_base_dir"] = label, base_dir
    cloth = cfg["cloth"]
    sources = [k for k in ("grid", "mesh", "garment") if cloth.get(k) is not None]
    if len(sources) != 1:
        v.fail("[cloth]", "needs exactly one source: [cloth.grid], [cloth.mesh] or garment = \"file.toml\""
               + (f" (got {' and '.join(sources)})" if sources else ""))
    if cfg.get("sewing") is not None and cloth.get("garment") is None:
        v.fail("[sewing]", "needs a garment cloth ([cloth] garment = \"file.toml\")")
    if cloth.get("resolution") is not None and cloth.get("garment") is None:
        v.fail("[cloth] resolution", "is a garment's preset (draft, fit, fine); a grid takes [cloth.grid] resolution "
                                     "= [nx, ny] particles")
    _check_integrator_options(v, cfg["integrator"])
    ml, grid = cfg.get("multilevel"), cloth.get("grid")
    if ml is not None:
        garment = cloth.get("garment") is not None
        if grid is None and not garment:
            v.fail("[multilevel]", "needs a [cloth.grid] (the rectangle the 4-8 hierarchy covers) or a garment")
        if grid is not None and grid["resolution"] is not None:
            v.fail("[cloth.grid] resolution", "with [multilevel] the resolution comes from base_cells and levels; "
                                              "remove it")
        if ml["levels"] is None and not garment:
            ml["levels"] = 5
        if ml["levels"] is not None and ml["start_level"] > ml["levels"]:
            v.fail("[multilevel] start_level", f"must be <= levels ({ml['levels']}), got {ml['start_level']}")
    elif grid is not None and grid["resolution"] is None:
        v.fail("[cloth.grid]", "missing required key 'resolution'")
    body = cfg.get("body")
    if body is not None:
        if not any(body[g] is not None for g in BODY_GIRTHS):
            v.fail("[body]", f"names no girth: give at least one of {', '.join(BODY_GIRTHS)} [m]")
        if not any(c["type"] == "mesh" and c.get("path") == "mannequin" for c in cfg["colliders"]):
            v.fail("[body]", "morphs the mannequin: add [[colliders]] type = \"mesh\", path = \"mannequin\"")
    # the builder's memory guard, before Taichi starts (the builder checks again what it is asked to build)
    if ml is not None and grid is not None:
        check_multilevel_grid(ml["base_cells"], ml["levels"], f"{label}: [multilevel]")
    elif grid is not None:
        check_grid(grid["resolution"], f"{label}: [cloth.grid] resolution")
    return cfg


def _check_integrator_options(v: Validator, integ: dict) -> None:
    cls = INTEGRATORS[integ["name"]]
    if integ.get("adaptive") is not None and integ["dt"] != "auto":
        v.fail("[integrator] adaptive", f'needs dt = "auto" (dt is {integ["dt"]!r})')
    for key in [k for k in integ if k not in ("name", "dt", "step_guard", "adaptive")]:
        opt = cls.OPTIONS.get(key)
        where = f"[integrator] {key}"
        if opt is None:
            known = ", ".join(cls.OPTIONS) or "none"
            v.fail("[integrator]", f"unknown key {key!r} for integrator {integ['name']!r} (its options: {known})")
        val = integ[key]
        kind = {bool: "bool", int: "int", float: "number", str: "str"}[opt.type]
        integ[key] = v.value(Field(kind, check=opt.check), val, where)


def build_scene(cfg: dict) -> Scene:
    """Build the Scene a validated config describes (only the components it names)."""
    label = cfg["_label"]
    cloth_cfg, mat = cfg["cloth"], material_of(cfg["cloth"].get("material"))
    body, body_morph, colliders = None, None, cfg["colliders"]
    if cfg.get("body") is not None:
        body, body_morph, colliders = _body(cfg["body"], colliders, label)
    try:
        ml = cfg.get("multilevel")
        if ml is not None and cloth_cfg.get("grid") is not None:
            g = cloth_cfg["grid"]
            data = ClothBuilder.multilevel_grid(g["size"], ml["base_cells"], ml["levels"], mat, g["center"],
                                                g["plane"], ml["start_level"] - 1)
        elif cloth_cfg.get("grid") is not None:
            g = cloth_cfg["grid"]
            data = ClothBuilder.grid(g["size"], g["resolution"], mat, g["center"], g["plane"])
        elif cloth_cfg.get("garment") is not None:
            path = Path(cloth_cfg["garment"])
            path = path if path.is_absolute() else cfg["_base_dir"] / path
            spec = load_garment(path, material=mat if cloth_cfg.get("material") else None)
            if cloth_cfg.get("resolution") is not None:
                spec.at_resolution(cloth_cfg["resolution"])
            stiffness = (cfg.get("sewing") or {}).get("stiffness")
            if ml is None:
                data = build_garment(spec, body, seam_stiffness=stiffness)
            else:  # sewn on a coarse level, refined as the drape settles
                spec.levels = ml["levels"] or spec.coarse_to_fine_levels
                data = multilevel_garment(spec, body, stiffness, ml["start_level"] - 1)
        else:
            m = cloth_cfg["mesh"]
            path = Path(m["path"])
            path = path if path.is_absolute() else cfg["_base_dir"] / path
            data = ClothBuilder.mesh_file(path, mat, m["scale"], m["translate"])
    except MeshError as exc:  # a mesh cloth's file, or the body a garment is placed on (the message names it)
        where = f"[cloth] garment {cloth_cfg['garment']}" if cloth_cfg.get("garment") is not None else \
            "[cloth.mesh] path"
        raise SceneError(f"{label}: {where}: {exc}") from None
    except PatternError as exc:
        garment = str(cloth_cfg.get("garment"))
        named = f" {garment}" if cloth_cfg.get("garment") is not None and garment not in str(exc) else ""
        raise SceneError(f"{label}: [cloth] garment{named}: {exc}") from None
    integ = dict(cfg["integrator"])
    name, dt, guard = integ.pop("name"), integ.pop("dt"), integ.pop("step_guard")
    adaptive = {k: val for k, val in (integ.pop("adaptive", None) or {}).items() if val is not None}
    pins = cfg["pins"]  # checked again by the same tables, and named "[[pins]] #k" alike (taichi_cloth.specs)
    try:
        return Scene(data, name=cfg["name"], integrator=name, dt=dt, integrator_options=integ,
                     adaptive=adaptive if dt == "auto" else None,
                     gravity=cfg["gravity"], air_damping=cfg["air_damping"], pins=pins, wind=cfg.get("wind"),
                     stretch_limit=cfg.get("stretch_limit"), colliders=colliders, body_morph=body_morph,
                     self_collision=_self_collision(cfg.get("self_collision")), fps=cfg["fps"],
                     multilevel=_schedule(cfg.get("multilevel")),
                     sewing=_sewing(cfg.get("sewing"), cloth_cfg), precision=cfg["precision"], step_guard=guard,
                     rest=cfg.get("rest"), base_dir=cfg["_base_dir"])
    except SceneError as exc:
        raise SceneError(f"{label}: {exc}") from None
    except ValueError as exc:  # a component refused its parameters
        raise SceneError(f"{label}: {exc}") from None


def _body(table: dict, colliders: list, label: str):
    """(garment placement Body or None, the Scene's body_morph or None, collider specs) of a [body] table: the
    mannequin is fitted to the girths now; "before" puts the fitted body in the mannequin colliders (and places
    a garment on it), "during" hands its weights to the scene to morph toward."""
    from .body import fit_body  # scipy (0.5 s to import): only a [body] table fits a body

    girths = {g: table[g] for g in BODY_GIRTHS if table[g] is not None}
    try:
        fit = fit_body(girths, tolerance=table["tolerance"])
    except BodyError as exc:
        raise SceneError(f"{label}: [body]: {exc}") from None
    if table["morph"] == "during":
        return None, {"weights": fit.weights, "duration": table["morph_time"]}, colliders
    morphed = [dict(c, vertices=fit.vertices, triangles=fit.triangles, path="mannequin (fitted)")
               if c["type"] == "mesh" and c.get("path") == "mannequin" else c for c in colliders]
    try:
        return Body.from_mesh(fit.vertices, fit.triangles, "the mannequin fitted to its girths"), None, morphed
    except MeshError as exc:
        raise SceneError(f"{label}: [body]: {exc}") from None


def _sewing(sewing: dict | None, cloth_cfg: dict) -> dict | None:
    """The Scene's `sewing` argument: the [sewing] table less the seam stiffness (the builder's), or the
    defaults ({}) for a garment without one."""
    if sewing is None:
        return {} if cloth_cfg.get("garment") is not None else None
    return {k: v for k, v in sewing.items() if k != "stiffness" and v is not None}


def _self_collision(cfg: dict | None):
    """The scene's self_collision: False when absent, the bool of `self_collision = true | false`, or the table's
    SelfCollision options (a table turns it on)."""
    if cfg is None:
        return False
    if "preset" in cfg:
        return cfg["preset"]
    return {k: v for k, v in cfg.items() if v is not None} or True


def _schedule(ml: dict | None) -> dict | None:
    """The Scene's `multilevel` argument from a validated [multilevel] table."""
    if ml is None:
        return None
    return dict(ml["settle"], refine=ml["refine"], dt_growth=ml["dt_growth"], angle=ml["angle"])


def _apply_quality(cfg: dict) -> None:
    """Replace the config's integrator (name, options, dt) by its quality preset's and move the cloth to the
    preset's 4-8 level: fewer [multilevel] levels, or a coarser [cloth.grid] resolution (a mesh or garment
    cloth keeps its mesh). The chosen preset is kept as cfg["_quality"] (the CLI prints it)."""
    p = preset(cfg["quality"])
    cfg["integrator"] = {"name": p.integrator, "step_guard": cfg["integrator"]["step_guard"], **p.options,
                         "dt": p.dt if p.dt is not None else "auto"}
    if p.dt_bound_fraction is not None:
        cfg["integrator"]["adaptive"] = {"safety": p.dt_bound_fraction}
    ml, grid = cfg.get("multilevel"), cfg["cloth"].get("grid")
    if p.level < 0 and ml is not None and grid is not None:
        ml["levels"] = max(1, ml["levels"] + p.level)
        ml["start_level"] = min(ml["start_level"], ml["levels"])
    elif p.level < 0 and grid is not None:
        grid["resolution"] = coarsen_resolution(grid["resolution"], p.level)
    cfg["_quality"] = p


def load_scene(source: str | Path | dict, *, frames: int | None = None, integrator: str | None = None,
               dt: float | None = None, precision: str | None = None, out: str | Path | None = None,
               integrator_options: dict | None = None, quality: str | None = None,
               resolution: str | None = None, base_dir: str | Path | None = None) -> LoadedScene:
    """Parse and build a scene; keyword arguments override the file (as the CLI flags do).

    `quality` (preview | balanced | accurate) replaces the file's integrator, options, dt and level by the
    measured preset (taichi_cloth.quality); `integrator` and `dt` then override the preset's choice. `resolution`
    (draft | fit | fine) meshes a garment at that preset (taichi_cloth.garment.garment.RESOLUTIONS).
    Overriding the integrator drops the file's options that the new integrator does not have. A scene given as a
    dict reads its relative paths from `base_dir` (default: the current folder)."""
    cfg = parse_scene(source, Path(base_dir) if base_dir is not None else None)
    v = Validator(cfg["_label"] + " (override)")
    if quality is not None:
        cfg["quality"] = v.value(Field("str", choices=QUALITIES), quality, "--quality")
    if cfg["quality"] is not None:
        _apply_quality(cfg)
    if integrator is not None:
        v.value(Field("str", choices=tuple(INTEGRATORS)), integrator, "--integrator")
        if integrator != cfg["integrator"]["name"]:
            cfg["integrator"] = {k: cfg["integrator"][k] for k in ("dt", "step_guard", "adaptive")
                                 if k in cfg["integrator"]} | {"name": integrator}
    if integrator_options:
        cfg["integrator"].update(integrator_options)
        _check_integrator_options(v, cfg["integrator"])
    if dt is not None:
        cfg["integrator"]["dt"] = v.value(DT_FIELD, dt, "--dt")
        if dt != "auto":
            cfg["integrator"].pop("adaptive", None)  # a fixed step replaces the automatic one
    if frames is not None:
        cfg["frames"] = v.value(Field("int", check=at_least(0)), frames, "--frames")
    if precision is not None:
        cfg["precision"] = v.value(Field("str", choices=("f32", "f64")), precision, "--precision")
    if out is not None:
        cfg["output"]["dir"] = str(out)
    if resolution is not None:
        cfg["cloth"]["resolution"] = v.value(Field("str", choices=tuple(RESOLUTIONS)), resolution, "--resolution")
        if cfg["cloth"].get("garment") is None:
            v.fail("--resolution", "is a garment's preset; this scene's cloth is not a garment")
    check_output_dir(cfg["output"]["dir"], cfg["_label"])
    scene = build_scene(cfg)
    check_precision(scene, cfg["precision"], cfg["_label"])
    return LoadedScene(scene, cfg["name"], cfg["frames"], cfg["output"], cfg)


def check_output_dir(path: str | Path, label: str) -> None:
    """Refuse (SceneError) an output folder that cannot be one before the scene is built: a file, below a file, or
    read-only (taichi_cloth.paths.check_output_folder)."""
    try:
        check_output_folder(path)
    except OSError as exc:
        raise SceneError(f"{label}: [output] dir {str(path)!r} {exc.strerror}") from None
