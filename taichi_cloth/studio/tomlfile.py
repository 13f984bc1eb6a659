"""A garment file's content (the dict tomllib reads from it) written back as TOML, laid out as the shipped garment
files are: the top-level keys, then a `[[pieces]]` table per piece (an outline one corner a line), then the
`[[seams]]` and `[[fixed]]` tables. tomllib reads the text back to the same dict.
"""
from __future__ import annotations

import math
import re

#: top-level keys in the order the shipped garment files give them; any other key follows them
TOP_KEYS = ("name", "dxf", "dxf_units", "dxf_size", "seam_allowance", "units", "material", "spacing", "resolution",
            "levels")
#: arrays of tables, in this order
TABLE_ARRAYS = ("pieces", "seams", "fixed")
_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


def garment_text(doc: dict, comments=()) -> str:
    """TOML text of a garment file's content `doc`; `comments`: lines written first, each after `# `."""
    lines = [f"# {c}" for c in comments]
    rest = [k for k in doc if k not in TOP_KEYS and k not in TABLE_ARRAYS]
    lines += [f"{key(k)} = {value(doc[k])}" for k in (*TOP_KEYS, *rest) if k in doc and doc[k] is not None]
    for array in TABLE_ARRAYS:
        for table in doc.get(array) or []:
            lines += ["", f"[[{array}]]"]
            for k, v in table.items():
                if k == "outline" and isinstance(v, list):
                    lines += ["outline = ["] + [f"  {value(c)}," for c in v] + ["]"]
                elif v is not None:
                    lines.append(f"{key(k)} = {value(v)}")
    return "\n".join(lines) + "\n"


def key(k: str) -> str:
    return k if _BARE_KEY.match(k) else string(k)


def string(s: str) -> str:
    """A TOML basic string: quotes, backslashes and control characters escaped."""
    out = []
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ch == "\n":
            out.append("\\n")
        elif ch == "\t":
            out.append("\\t")
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def value(v) -> str:
    """A TOML value: bool, int, float, string, array or inline table (nested as deep as needed)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return string(v)
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{key(k)} = {value(x)}" for k, x in v.items() if x is not None) + " }"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(value(x) for x in v) + "]"
    raise TypeError(f"no TOML value for {type(v).__name__} {v!r}")
