"""A batch spec (TOML): the garments, bodies and materials a batch fits, how each job runs, where it writes.

    name = "size_chart"                        # the batch's name (default: the file's stem)
    garments = ["../garments/tshirt.toml"]     # garment files, or tables { file = "...", name = "...",
                                               #   bodies = ["mannequin", "S"] }: bodies, the ones it is cut for
                                               #   (default: every body of the spec)
    materials = ["cotton", "denim"]            # presets, or tables { name = "stiff", preset = "cotton", bend = 1e-5 }
                                               # (the [cloth.material] keys); default: each garment file's own
    bodies = ["mannequin"]                     # "mannequin" (the shipped body), or tables of tape girths in CM:
    # [[bodies]] name = "S", chest = 82, waist = 63, hips = 92, tolerance = 0.1   (`body` command's girths)

    [run]                                      # every job's settings
    scene = "../scenes/sew_tshirt.toml"        # the scene the jobs start from (integrator, sewing, colliders...);
                                               # default: the shipped garment scenes' settings (jobs.TEMPLATE)
    frames = 600                               # the cap: a job not at rest by then is "not at rest by the cap"
    until_rest = true                          # end a job at rest (the scene's [rest] criterion)
    resolution = "draft"                       # a garment's spacing preset (draft 2 cm, fit 1 cm, fine 5 mm)
    # quality = "balanced"                     # a measured preset (integrator, step)
    timeout = 1800                             # [s] of wall time a job may take, else "timed out"
    max_inside = 0                             # particles inside the body a fit may leave, else "inside the body"
    png = true                                 # each job's still picture (and the contact sheet)
    record = false                             # each job's Rerun recording
    # perturb = 1e-7                           # [m]: every particle's start moved by this much, in random
    # seeds = [1, 2, 3]                        #   directions of each seed: each job once per seed (a figure that
                                               #   holds over moved starts is a margin, not luck)
    # integrator = { cg_tolerance = 1e-3 }     # merged into the scene's [integrator]
    # rest = { max_speed = 0.005 }             # merged into the scene's [rest]

    [[jobs]]                                   # optional: these jobs instead of every garment x material x body
    garment = "tshirt"                         # names from the lists above
    body = "S"
    material = "cotton"
    # run = { frames = 900 }                   # this job's [run] keys instead of the batch's

    [output]
    dir = "out/batch"                          # relative to the current folder, as a scene's is

Paths in the spec are relative to the spec file. Bad input is one BatchError naming the file and the key.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import PatternError, TaichiClothError
from ..garment.garment import RESOLUTIONS
from ..garment.garmentfile import load_garment
from ..quality import QUALITIES
from ..schema import MATERIAL_TABLE, Field, Table, Validator, at_least, nonneg, positive, read_toml
from ..scenefile import BODY_GIRTHS


class BatchError(TaichiClothError, ValueError):
    """A batch spec is malformed: the message names the file and the key."""


MANNEQUIN = "mannequin"

RUN_TABLE = Table({
    "scene": Field("str", None),
    "frames": Field("int", 600, at_least(1)),
    "until_rest": Field("bool", True),
    "resolution": Field("str", None, choices=tuple(RESOLUTIONS)),
    "quality": Field("str", None, choices=QUALITIES),
    "timeout": Field("number", 1800.0, positive),
    "max_inside": Field("int", 0, at_least(0)),
    "png": Field("bool", True),
    "record": Field("bool", False),
    "perturb": Field("number", None, nonneg),
    "seeds": Field("ints", None),
    "integrator": Table({}, extra=True),
    "rest": Table({}, extra=True),
}, always=True)

BODY_TABLE = Table({"name": Field("str"), "tolerance": Field("number", 0.1, positive),
                    **{g: Field("number", None, positive) for g in BODY_GIRTHS}})
GARMENT_TABLE = Table({"file": Field("str"), "name": Field("str", None), "bodies": Field("strs", None)})
JOB_TABLE = Table({"garment": Field("str"), "body": Field("str", MANNEQUIN), "material": Field("str", None),
                   "run": Table({}, extra=True)})
#: the spec's keys besides its lists (garments, bodies, materials, jobs: LISTS, read item by item)
SPEC_TABLE = Table({"name": Field("str", None), "run": RUN_TABLE,
                    "output": Table({"dir": Field("str", "out/batch")}, always=True)})
LISTS = ("garments", "bodies", "materials", "jobs")

#: what a name may hold: it names the job's folder and files
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")


@dataclass
class Garment:
    """name; path; bodies: the names of the bodies it is fitted to (None: every body of the spec)."""

    name: str
    path: Path
    bodies: list | None = None


@dataclass
class BodySpec:
    """name; girths {name: cm} (empty: the shipped mannequin); tolerance [cm]."""

    name: str
    girths: dict = field(default_factory=dict)
    tolerance: float = 0.1


@dataclass
class MaterialSpec:
    """name; table: the scene's [cloth] material (a preset name or a MATERIAL_TABLE dict), None: the garment's."""

    name: str
    table: dict | str | None


@dataclass
class BatchSpec:
    name: str
    path: Path
    garments: list
    bodies: list
    materials: list
    run: dict
    jobs: list | None   # [(garment, body, material, run overrides)] or None: the product
    out: Path


def _tables(v: Validator, items, key: str, plain: str, normalise) -> list:
    """A list whose items are a plain string (`plain`: what it means) or a table, each made a dict by `normalise`."""
    if items is None:
        return []
    if not isinstance(items, list) or not items:
        v.fail(key, f"must be a non-empty list of {plain} or tables, got {items!r}")
    return [normalise(item, f"{key} #{k + 1}") for k, item in enumerate(items)]


def _name(v: Validator, name, where: str) -> str:
    if not isinstance(name, str) or not NAME.match(name):
        v.fail(where, f"name {name!r} must be letters, digits, '_', '.', '+' or '-' (it names files)")
    return name


def _unique(v: Validator, items: list, key: str) -> None:
    seen = set()
    for item in items:
        if item.name in seen:
            v.fail(key, f"the name {item.name!r} is used twice")
        seen.add(item.name)


def load_spec(path: str | Path, out: str | Path | None = None) -> BatchSpec:
    """Read and check a batch spec; `out` replaces its [output] dir. Raises BatchError (one line)."""
    path = Path(path)
    label = str(path)
    data = read_toml(path, label, "batch spec", error=BatchError)
    v = Validator(label, error=BatchError)
    if "garments" not in data:
        v.fail("top level", "missing required key 'garments' (a list of garment files)")
    raw = {k: data.get(k) for k in LISTS}
    cfg = v.table(SPEC_TABLE, {k: val for k, val in data.items() if k not in LISTS}, "", "")
    base = path.parent

    def garment(item, where):
        item = {"file": item} if isinstance(item, str) else item
        g = v.table(GARMENT_TABLE, item, "garments", where) if isinstance(item, dict) else v.fail(
            where, f"must be a garment file or a table {{ file = ..., name = ... }}, got {item!r}")
        file = Path(g["file"])
        file = file if file.is_absolute() else base / file
        try:
            load_garment(file)
        except PatternError as exc:
            v.fail(where, str(exc))
        return Garment(_name(v, g["name"] or file.stem, where), file.resolve(), g["bodies"])

    def body(item, where):
        if item == MANNEQUIN:
            return BodySpec(MANNEQUIN)
        if not isinstance(item, dict):
            v.fail(where, f"must be \"{MANNEQUIN}\" or a table of girths in cm {{ name = ..., chest = ... }}, "
                          f"got {item!r}")
        b = v.table(BODY_TABLE, item, "bodies", where)
        girths = {g: b[g] for g in BODY_GIRTHS if b[g] is not None}
        if not girths:
            v.fail(where, f"names no girth: give at least one of {', '.join(BODY_GIRTHS)} [cm], or use "
                          f"\"{MANNEQUIN}\"")
        return BodySpec(_name(v, b["name"], where), girths, b["tolerance"])

    def material(item, where):
        if isinstance(item, str):
            v.value(MATERIAL_TABLE.allow_string, item, where)
            return MaterialSpec(item, item)
        if not isinstance(item, dict) or "name" not in item:
            v.fail(where, f"must be a preset name or a table with a name {{ name = ..., preset = ... }}, got {item!r}")
        table = v.table(MATERIAL_TABLE, {k: val for k, val in item.items() if k != "name"}, "materials", where)
        return MaterialSpec(_name(v, item["name"], where), {k: val for k, val in table.items() if val is not None})

    garments = _tables(v, raw["garments"], "garments", "garment files", garment)
    bodies = _tables(v, raw["bodies"], "bodies", f'"{MANNEQUIN}"', body) or [BodySpec(MANNEQUIN)]
    materials = _tables(v, raw["materials"], "materials", "presets", material) or [MaterialSpec("garment", None)]
    for items, key in ((garments, "garments"), (bodies, "bodies"), (materials, "materials")):
        _unique(v, items, key)
    for k, g in enumerate(garments):
        unknown = [b for b in g.bodies or [] if b not in {b.name for b in bodies}]
        if unknown:
            v.fail(f"garments #{k + 1} bodies", f"{unknown[0]!r} is not one of the batch's bodies: "
                                                 f"{', '.join(b.name for b in bodies)}")
    run = cfg["run"]
    _check_run(v, run, base, "[run]")
    jobs = None
    if raw["jobs"] is not None:
        jobs = []
        names = {"garment": {g.name: g for g in garments}, "body": {b.name: b for b in bodies},
                 "material": {m.name: m for m in materials}}
        for k, item in enumerate(_tables(v, raw["jobs"], "jobs", "tables", lambda i, w: i)):
            where = f"[[jobs]] #{k + 1}"
            j = v.table(JOB_TABLE, item, "jobs", where)
            if j["material"] is None:
                j["material"] = materials[0].name
            picked = []
            for key in ("garment", "body", "material"):
                if j[key] not in names[key]:
                    v.fail(f"{where} {key}", f"{j[key]!r} is not one of the batch's {key}s: "
                                             f"{', '.join(names[key])}")
                picked.append(names[key][j[key]])
            given = j.get("run") or {}
            overrides = v.table(Table(RUN_TABLE.fields), given, "run", f"{where} run")
            overrides = {key: val for key, val in overrides.items() if key in given}
            _check_run(v, dict(run, **overrides), base, f"{where} run")
            jobs.append((*picked, overrides))
    out_dir = Path(out) if out is not None else Path(cfg["output"]["dir"])
    return BatchSpec(cfg["name"] or path.stem, path.resolve(), garments, bodies, materials, run, jobs, out_dir)


def _check_run(v: Validator, run: dict, base: Path, where: str) -> None:
    if run["scene"] is not None:
        scene = Path(run["scene"])
        scene = scene if scene.is_absolute() else base / scene
        if not scene.is_file():
            v.fail(f"{where} scene", f"no such scene file: {scene}")
