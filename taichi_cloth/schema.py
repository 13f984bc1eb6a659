"""A tiny declarative schema for the engine's TOML files (scene files, garment files): fields with a kind, a
default and a check, tables, arrays of tables, and a validator whose errors read like the TOML
(`file: [cloth.grid] size: must be a list of 2 numbers, got ...`), one line each.
"""
from __future__ import annotations

import difflib
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from .errors import SceneError
from .material import BENDING_MODELS, MATERIALS, MEMBRANE_MODELS, Material
from .material import material as preset

MISSING = object()  # a Field default that makes the key required


@dataclass
class Field:
    """A value: its kind (a KINDS key), default (MISSING: required), a check returning an error text or None, and
    the allowed choices."""

    kind: str                      # number | int | bool | str | vec2 | vec3 | int2 | points | ints | keyframes
    default: Any = MISSING        # MISSING = required
    check: Callable[[Any], str | None] | None = None
    choices: tuple | None = None


@dataclass
class Table:
    """A TOML table: its keys (Field, Table or Array each)."""

    fields: dict[str, Any]
    required: bool = False
    allow_string: Field | None = None  # a table that may also be given as a plain value (material = "cotton")
    extra: bool = False                # unknown keys are checked later (integrator options)
    always: bool = False               # filled with its defaults when absent ([output])
    check: Callable | None = None      # check(validator, table, label): what spans its keys, once they are valid


@dataclass
class Array:
    """An array of tables ([[name]])."""

    table: Table


def positive(v):
    return None if v > 0 else "must be > 0"


def nonneg(v):
    return None if v >= 0 else "must be >= 0"


def nonzero(v):
    return None if any(x != 0 for x in v) else "must be non-zero (a direction)"


def at_least(n):
    return lambda v: None if v >= n else f"must be >= {n}"


def is_number(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def is_int(v):
    return isinstance(v, int) and not isinstance(v, bool)


def vector(n, elem=is_number):
    return lambda v: isinstance(v, list) and len(v) == n and all(elem(x) for x in v)


KINDS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "number": (is_number, "a number"),
    "int": (is_int, "an integer"),
    "bool": (lambda v: isinstance(v, bool), "true or false"),
    "str": (lambda v: isinstance(v, str), "a string"),
    "vec2": (vector(2), "a list of 2 numbers"),
    "vec3": (vector(3), "a list of 3 numbers"),
    "int2": (vector(2, is_int), "a list of 2 integers"),
    "ints": (lambda v: isinstance(v, list) and all(is_int(x) for x in v), "a list of integers"),
    "strs": (lambda v: isinstance(v, list) and len(v) > 0 and all(isinstance(x, str) for x in v),
             "a non-empty list of strings"),
    "points": (lambda v: isinstance(v, list) and all(vector(3)(p) for p in v),
               "a list of [x, y, z] points"),
    "keyframes": (lambda v: isinstance(v, list) and len(v) > 0 and all(vector(4)(p) for p in v),
                  "a list of [t, dx, dy, dz] rows"),
    "tables": (lambda v: isinstance(v, list) and len(v) > 0 and all(isinstance(p, dict) for p in v),
               "a list of inline tables"),
    "corner": (lambda v: isinstance(v, str) or is_int(v), "a corner name or index"),
    "point": (lambda v: isinstance(v, str) or is_int(v) or vector(2)(v), "a corner name or index, or [u, v]"),
    "names": (lambda v: isinstance(v, dict) and all(is_int(i) for i in v.values()),
              "a table of corner name = index"),
    "dt": (lambda v: v == "auto" or is_number(v), 'a number of seconds or "auto"'),
    "start": (lambda v: v == "sewn" or (is_number(v) and v >= 0), 'a time >= 0 [s] or "sewn"'),
}

MATERIAL_TABLE = Table({"preset": Field("str", None, choices=tuple(MATERIALS)),
                        "density": Field("number", None, positive), "stretch": Field("number", None, nonneg),
                        "shear": Field("number", None, nonneg), "bend": Field("number", None, nonneg),
                        "damping": Field("number", None, nonneg), "viscosity": Field("number", None, nonneg),
                        "bending": Field("str", None, choices=BENDING_MODELS),
                        "membrane": Field("str", None, choices=MEMBRANE_MODELS)},
                       allow_string=Field("str", choices=tuple(MATERIALS)))


class Validator:
    """Checks data against a schema. Locations read like the TOML: `[cloth.grid] size`, `[[pins]] #2 near`.
    `source` names the file in every message ("": none, a dict of the Python API); `error` is the exception raised
    (SceneError, PatternError...)."""

    def __init__(self, source: str, error: type[Exception] = SceneError):
        self.source = source
        self.error = error

    def fail(self, where: str, msg: str):
        text = f"{where}: {msg}" if where else msg
        raise self.error(f"{self.source}: {text}" if self.source else text)

    @staticmethod
    def key_at(table: str, key: str) -> str:
        return f"{table} {key}" if table else key

    def value(self, spec: Field, v, where: str):
        ok, what = KINDS[spec.kind]
        if spec.kind == "number" and is_int(v):
            v = float(v)
        if not ok(v):
            self.fail(where, f"must be {what}, got {v!r}")
        if spec.choices is not None and v not in spec.choices:
            self.fail(where, f"{v!r} is not one of: {', '.join(map(str, spec.choices))}")
        if spec.check is not None:
            problem = spec.check(v)
            if problem:
                self.fail(where, f"{problem}, got {v!r}")
        return v

    def table(self, spec: Table, data, name: str, label: str) -> dict:
        """Validate table `data`; `name` is its dotted TOML name ("" at top level), `label` how errors show it."""
        if not isinstance(data, dict):
            if spec.allow_string is not None:
                return {"preset": self.value(spec.allow_string, data, label)}
            self.fail(label, f"must be a table, got {data!r}")
        out = {}
        for key, value in data.items():
            sub = spec.fields.get(key)
            if sub is None:
                if spec.extra:
                    out[key] = value
                    continue
                near = difflib.get_close_matches(key, list(spec.fields), n=1)
                hint = f" (did you mean {near[0]!r}?)" if near else f" (known keys: {', '.join(spec.fields)})"
                self.fail(label or "top level", f"unknown key {key!r}{hint}")
            out[key] = self.node(sub, value, name, key, label)
        for key, sub in spec.fields.items():
            if key in out:
                continue
            if isinstance(sub, Field):
                if sub.default is MISSING:
                    self.fail(label or "top level", f"missing required key {key!r}")
                out[key] = sub.default
            elif isinstance(sub, Table) and sub.required:
                self.fail(label or "top level", f"missing required table [{self.dotted(name, key)}]")
            elif isinstance(sub, Table) and sub.always:
                out[key] = self.table(sub, {}, self.dotted(name, key), f"[{self.dotted(name, key)}]")
            elif isinstance(sub, Array):
                out[key] = []
        if spec.check is not None:
            spec.check(self, out, label)
        return out

    @staticmethod
    def dotted(name: str, key: str) -> str:
        return f"{name}.{key}" if name else key

    def node(self, spec, value, name: str, key: str, label: str):
        if isinstance(spec, Field):
            return self.value(spec, value, self.key_at(label, key))
        if isinstance(spec, Table):
            if not isinstance(value, dict) and spec.allow_string is not None:
                return {"preset": self.value(spec.allow_string, value, self.key_at(label, key))}
            sub = self.dotted(name, key)
            return self.table(spec, value, sub, f"[{sub}]" if not label.startswith("[[") else f"{label} {key}")
        if isinstance(spec, Array):
            if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
                self.fail(self.key_at(label, key), "must be an array of tables ([[...]])")
            return [self.table(spec.table, v, key, f"[[{key}]] #{k + 1}") for k, v in enumerate(value)]
        raise TypeError(spec)


def read_toml(path: Path, label: str, what: str, error=SceneError) -> dict:
    """The TOML file at `path` as a dict, its `name` defaulting to the file's stem; `error` (naming `label`)
    if it is missing, a folder, not TOML or not UTF-8 text. `what` says which kind of file ("scene", "garment")."""
    if path.is_dir():
        raise error(f"{label}: is a folder, not a {what} file")
    if not path.is_file():
        raise error(f"{label}: no such {what} file")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{label}: not valid TOML: {exc}") from None
    except UnicodeDecodeError:
        raise error(f"{label}: not a UTF-8 text file") from None
    data.setdefault("name", path.stem)
    return data


def material_of(table: dict | None) -> Material:
    """The Material of a validated MATERIAL_TABLE (None: cotton): the preset, with any given value replacing
    the preset's."""
    m = table or {"preset": "cotton"}
    base = preset(m.get("preset") or "cotton")
    return base.replace(**{k: val for k, val in m.items() if k != "preset" and val is not None})
