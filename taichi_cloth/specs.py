"""The collider and pin tables: one validator for a scene file's [[colliders]] and [[pins]] and for the dicts the
Python API takes (`Scene(cloth, colliders=[{...}], pins=[{...}])`), so that both accept, refuse and name the same
keys with the same line: `[[colliders]] #2: unknown key 'radus' (did you mean 'radius'?)`.

A collider (SI units; taichi_cloth.colliders builds it):
    type = "sphere" (center, radius) | "capsule" (a, b, radius) | "plane" (point, normal) | "mesh" (path: a file or
    "mannequin", or sequence: a deforming body's frames, a .npz or a folder of OBJ/PLY files, with fps [frames/s]
    and start = a time [s] or "sewn"; scale, translate, cell_size, mode = "fuzzy" | "exact", repulsion =
    {stiffness, distance, max_force}) | "standin"; every type: thickness [m] = 0.003 (> 0 for a mesh, >= 0 for the
    others), friction = 0.3, and a scripted rigid motion: keyframes = [[t, dx, dy, dz], ...] (translation [s, m]),
    rotation = [[t, ax, ay, az], ...] (degrees about the x, y, z axes through pivot [m], default the origin), linear
    between keys and held outside them (clothbase.keyframes)
A pin group (taichi_cloth.pins.PinSpec):
    indices = [i, ...], near = [[x, y, z], ...], box = {min = [x, y, z], max = [x, y, z]}: what it selects (at least
    one); keyframes = [[t, dx, dy, dz], ...]: its motion (rows in strictly increasing t)

What only Python can give is read before the shared check: tuples and numpy arrays for lists, a box as a (min, max)
pair, keyframes as a callable t -> offset, a mesh collider's `vertices` and `triangles` arrays (its `path` then only
names it). A key whose value is None counts as not given. A pin's motion was called `path` in Python: that name
still works, with a DeprecationWarning.
"""
from __future__ import annotations

import warnings

import numpy as np

from clothbase.sequences import MeshSequence

from .schema import Field, Table, Validator, nonneg, nonzero, positive

COLLIDER_TYPES = ("sphere", "capsule", "plane", "mesh", "standin")
#: the keys of a collider's scripted rigid motion, every type (clothbase.keyframes.RigidMotion)
MOTION_KEYS = ("keyframes", "rotation", "pivot")
#: keys each collider type needs, and the optional ones it accepts (thickness and friction: every type)
COLLIDER_KEYS = {"sphere": ({"center", "radius"}, set()), "capsule": ({"a", "b", "radius"}, set()),
                 "plane": ({"point", "normal"}, set()), "standin": (set(), set()),
                 "mesh": (set(), {"path", "sequence", "fps", "start", "scale", "translate", "cell_size", "mode",
                                  "repulsion"})}
DEFAULT_THICKNESS = 0.003  # m
DEFAULT_FRICTION = 0.3


def _check_collider(v: Validator, col: dict, where: str) -> None:
    """The keys of the collider's type: those it needs, none it does not take; then the absent ones are dropped."""
    required, optional = COLLIDER_KEYS[col["type"]]
    given = {k for k, val in col.items() if val is not None} - {"type", "thickness", "friction"} - set(MOTION_KEYS)
    for key in sorted(required - given):
        v.fail(where, f"a {col['type']} collider needs {key!r}")
    for key in sorted(given - required - optional):
        v.fail(where, f"{key!r} is not a {col['type']} collider key (it takes {', '.join(sorted(required | optional))},"
                      " thickness, friction, keyframes, rotation, pivot)")
    for key in ("keyframes", "rotation"):
        rows = col.get(key)
        if isinstance(rows, list) and any(b[0] <= a[0] for a, b in zip(rows, rows[1:])):
            v.fail(f"{where} {key}", "times must increase strictly")
    if col.get("pivot") is not None and col.get("rotation") is None:
        v.fail(f"{where} pivot", "is the centre of a rotation: give rotation too")
    if col["type"] == "mesh" and (col.get("path") is None) == (col.get("sequence") is None):
        v.fail(where, "a mesh collider needs 'path' (a mesh file or \"mannequin\") or 'sequence' (a deforming "
                      "body's frames), not both" if col.get("path") is not None else "a mesh collider needs 'path' "
                      "(a mesh file or \"mannequin\") or 'sequence' (a deforming body's frames)")
    if col.get("sequence") is None:
        for key in ("fps", "start"):
            if col.get(key) is not None:
                v.fail(f"{where} {key}", "belongs to a mesh sequence: give sequence too")
    elif col.get("keyframes") is not None or col.get("rotation") is not None:
        v.fail(where, "a mesh sequence moves itself: give it no keyframes or rotation")
    if col["type"] == "mesh" and not col["thickness"] > 0:  # a sphere, capsule or plane may have none
        v.fail(f"{where} thickness", f"must be > 0 for a mesh collider, got {col['thickness']!r}")
    for key in [k for k, val in list(col.items()) if val is None]:
        del col[key]


COLLIDER_TABLE = Table({
    "type": Field("str", choices=COLLIDER_TYPES),
    "center": Field("vec3", None), "radius": Field("number", None, positive),
    "a": Field("vec3", None), "b": Field("vec3", None),
    "point": Field("vec3", None), "normal": Field("vec3", None, nonzero),
    "path": Field("str", None), "scale": Field("number", None, positive), "translate": Field("vec3", None),
    "sequence": Field("str", None), "fps": Field("number", None, positive), "start": Field("start", None),
    "cell_size": Field("number", None, positive), "mode": Field("str", None, choices=("fuzzy", "exact")),
    "repulsion": Table({"stiffness": Field("number", 1e-3, nonneg), "distance": Field("number", 0.01, positive),
                        "max_force": Field("number", 0.05, positive)}),
    "thickness": Field("number", DEFAULT_THICKNESS, nonneg), "friction": Field("number", DEFAULT_FRICTION, nonneg),
    "keyframes": Field("keyframes", None), "rotation": Field("keyframes", None), "pivot": Field("vec3", None)},
    check=_check_collider)


def _check_pin(v: Validator, pin: dict, where: str) -> None:
    if not pin["indices"] and not pin["near"] and pin.get("box") is None:
        v.fail(where, "selects nothing: give indices, near or box")
    rows = pin["keyframes"]
    if isinstance(rows, list) and any(b[0] <= a[0] for a, b in zip(rows, rows[1:])):
        v.fail(f"{where} keyframes", "times must increase strictly")


PIN_TABLE = Table({"indices": Field("ints", []), "near": Field("points", []),
                   "box": Table({"min": Field("vec3"), "max": Field("vec3")}),
                   "keyframes": Field("keyframes", None)}, check=_check_pin)


def plain(value):
    """`value` with tuples and numpy arrays as lists and numpy scalars as Python numbers, all the way down (dicts
    included): what a TOML file would have given."""
    if isinstance(value, dict):
        return {k: plain(x) for k, x in value.items()}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [plain(x) for x in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


def collider_table(spec: dict, where: str, validator: Validator | None = None) -> dict:
    """A collider dict of the Python API, checked as a scene file's collider table `where` ("[[colliders]] #2")
    is: SceneError naming the key and the value. Returns it with the defaults filled in and the absent keys
    dropped; a mesh's `vertices` and `triangles` arrays and a MeshSequence (Python only) pass through unchanged."""
    v = validator or Validator("")
    if not isinstance(spec, dict):
        v.fail(where, f"must be a table (a dict), got {spec!r}")
    sequence = spec.get("sequence") if isinstance(spec.get("sequence"), MeshSequence) else None
    if sequence is not None:  # a sequence built in Python passes through; its source names it
        spec = dict(spec, sequence=sequence.source)
    arrays = {k: spec[k] for k in ("vertices", "triangles") if k in spec}
    data = plain({k: x for k, x in spec.items() if k not in arrays and x is not None})
    if arrays:
        if len(arrays) != 2:
            v.fail(where, "a mesh given as arrays needs both 'vertices' and 'triangles'")
        if data.get("type") != "mesh":
            v.fail(where, f"'vertices' and 'triangles' are a mesh collider's, not a {data.get('type')!r} collider's")
        data.setdefault("path", "mesh")  # a name for messages
    out = v.table(COLLIDER_TABLE, data, "colliders", where)
    out.update(arrays)
    if sequence is not None:
        out["sequence"] = sequence
    return out


def pin_table(spec: dict, where: str, validator: Validator | None = None) -> dict:
    """A pin dict of the Python API, checked as a scene file's pin table `where` ("[[pins]] #1") is: SceneError
    naming the key and the value. Returns {indices, near, box: (min, max) or None, keyframes: rows, a callable or
    None}. The old name of keyframes, `path`, is read with a DeprecationWarning; a box may be a (min, max) pair."""
    v = validator or Validator("")
    if not isinstance(spec, dict):
        v.fail(where, f"must be a table (a dict), got {spec!r}")
    spec = {k: x for k, x in spec.items() if x is not None}  # None: not given
    if "path" in spec:
        if "keyframes" in spec:
            v.fail(where, "give keyframes, not both keyframes and path (its old name)")
        warnings.warn(f"{where}: a pin's 'path' is now called 'keyframes' (as in a scene file's [[pins]])",
                      DeprecationWarning, stacklevel=3)
        spec["keyframes"] = spec.pop("path")
    motion = spec.pop("keyframes") if callable(spec.get("keyframes")) else None
    box = spec.get("box")
    if isinstance(box, (list, tuple, np.ndarray)) and len(box) == 2:
        spec["box"] = {"min": box[0], "max": box[1]}
    out = v.table(PIN_TABLE, plain(spec), "pins", where)
    box = out.get("box")
    out["box"] = (box["min"], box["max"]) if box is not None else None
    if motion is not None:
        out["keyframes"] = motion
    return out
