"""GarmentCode sewing patterns read as garments (Korosteleva and Sorkine-Hornung, "GarmentCode: Programming
Parametric Sewing Patterns", SIGGRAPH Asia 2023; the `specification.json` its pygarment library writes).

A specification holds `pattern.panels` and `pattern.stitches`, and `properties` (`units_in_meter`, 100 for cm;
`curvature_coords`, which must be "relative"). Each panel is read as a pattern piece and a placement:

  * `vertices` (k, 2) and `edges` in loop order, each `endpoints` [i, j] and an optional `curvature`: none, a
    straight "line"; {"type": "circle", "params": [radius, large_arc, right]} an arc from i to j of that radius,
    the larger of the two when large_arc, bulging to the right of i -> j when right; {"type": "quadratic",
    "params": [[t, k]]} and {"type": "cubic", "params": [[t1, k1], [t2, k2]]} Bezier curves whose control points
    lie at start + t e + k perp(e), e = end - start, perp(e) = (-e_y, e_x) (pygarment's relative coordinates; a
    bare [t, k] is the older quadratic form). Corner i is named "v<i>" (its vertex index).
  * `translation` (3,) and `rotation` (Euler angles x, y, z [deg], extrinsic) place the panel flat in GarmentCode's
    body frame: y up, the floor at 0, +z the front, +x the body's left, as the mannequin's. The panel becomes a
    FreePlacement there: its vertex (0, 0) at the translation, u and v along the rotated x and y axes.

A stitch [{panel, edge}, {panel, edge}] is a seam between the two edges; which ends meet is read from the placed
panels (the pairing whose ends lie nearer), and its length tolerance is the two edges' relative mismatch plus a
margin, up to GATHER_LIMIT: GarmentCode gathers a ruffle or a waist onto a shorter edge. Bad input gets one
PatternError naming the file, the panel or stitch, and the key.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..errors import PatternError
from .seams import DEFAULT_LENGTH_TOLERANCE

__all__ = ["GATHER_LIMIT", "read_specification"]

#: the largest relative length mismatch a stitch may gather (a ruffle's edge is longer than its partner's)
GATHER_LIMIT = 0.25
#: the margin added to a stitch's own mismatch for its seam's tolerance (the meshed sides round differently)
_MISMATCH_MARGIN = 0.02
#: the garment file's unit for pygarment's units_in_meter (any other: converted to metres)
_UNITS = {1: "m", 100: "cm", 1000: "mm"}


def read_specification(path) -> dict:
    """The garment file (as tomllib would parse it: taichi_cloth.garment.garmentfile) of the GarmentCode
    `specification.json` at `path` (module docstring): its panels as pieces with inline outlines and free
    placements, its stitches as seams; cotton at 2 cm. load_garment reads a .json file through this; the pattern
    studio opens one as a new garment file."""
    path = Path(path)
    try:
        spec = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PatternError(f"{path}: not a readable GarmentCode specification ({exc})") from None
    try:
        return _document(spec, path)
    except PatternError as exc:
        raise PatternError(f"{path}: {exc}") from None


def _document(spec, path: Path) -> dict:
    pattern = _get(spec, "pattern", dict, "the file")
    props = spec.get("properties") or {}
    if not isinstance(props, dict):
        raise PatternError(f"properties must be a table, got {type(props).__name__}")
    if props.get("curvature_coords", "relative") != "relative":
        raise PatternError(f"properties.curvature_coords is {props.get('curvature_coords')!r}; only 'relative' "
                           f"(pygarment's) is read")
    per_metre = props.get("units_in_meter", 100)
    if isinstance(per_metre, bool) or not isinstance(per_metre, (int, float)) or not per_metre > 0:
        raise PatternError(f"properties.units_in_meter must be a number > 0, got {per_metre!r}")
    units = _UNITS.get(per_metre, "m")
    scale = 1.0 if units != "m" else 1.0 / float(per_metre)  # file units -> the document's
    metres = {"m": 1.0, "cm": 0.01, "mm": 0.001}[units]  # the document's units -> m
    panels = _get(pattern, "panels", dict, "pattern")
    order = pattern.get("panel_order") or list(panels)
    pieces, placed = [], {}
    for name in order:
        if name not in panels:
            raise PatternError(f"pattern.panel_order names {name!r}, which is not a panel")
        entry, corners3d, lengths = _panel(name, panels[name], scale)
        pieces.append(entry)
        placed[name] = (corners3d, [metres * x for x in lengths], [c["name"] for c in entry["outline"]])
    seams = [_stitch(k, st, placed) for k, st in enumerate(_get(pattern, "stitches", list, "pattern"))]
    spacing = round(0.02 / metres, 12)
    return {"name": path.parent.name if path.stem == "specification" else path.stem, "units": units,
            "material": "cotton", "spacing": spacing, "pieces": pieces, "seams": seams}


def _get(table, key: str, kind: type, where: str):
    if not isinstance(table, dict) or key not in table:
        raise PatternError(f"{where} has no {key!r}")
    value = table[key]
    if not isinstance(value, kind):
        raise PatternError(f"{where}.{key} must be a {kind.__name__}, got {type(value).__name__}")
    return value


def _panel(name: str, panel, scale: float) -> tuple[dict, np.ndarray, list]:
    """(the garment file's [[pieces]] entry, its corners placed (k, 3) and its edges' lengths, in the document's
    units: the file's x scale)."""
    where = f"panel {name!r}"
    try:
        vertices = np.asarray(_get(panel, "vertices", list, where), dtype=np.float64) * scale
        translation = np.asarray(panel.get("translation", [0.0, 0.0, 0.0]), dtype=np.float64) * scale
        rotation = np.asarray(panel.get("rotation", [0.0, 0.0, 0.0]), dtype=np.float64)
    except (TypeError, ValueError):
        raise PatternError(f"{where}: vertices, translation and rotation must be numbers") from None
    if vertices.ndim != 2 or vertices.shape[1] != 2 or translation.shape != (3,) or rotation.shape != (3,):
        raise PatternError(f"{where}: vertices must be [x, y] pairs, translation and rotation three numbers each")
    if not (np.all(np.isfinite(vertices)) and np.all(np.isfinite(translation)) and np.all(np.isfinite(rotation))):
        raise PatternError(f"{where}: vertices, translation and rotation must be finite")
    edges = _get(panel, "edges", list, where)
    outline, corners, lengths = [], [], []
    for k, edge in enumerate(edges):
        ends = _get(edge, "endpoints", list, f"{where} edge {k}")
        if len(ends) != 2 or not all(isinstance(i, int) and 0 <= i < len(vertices) for i in ends):
            raise PatternError(f"{where} edge {k}: endpoints must be two vertex indices, got {ends!r}")
        nxt = _get(edges[(k + 1) % len(edges)], "endpoints", list, f"{where} edge {(k + 1) % len(edges)}")
        if ends[1] != nxt[0]:
            raise PatternError(f"{where}: edge {k} ends at vertex {ends[1]} but the next edge starts at {nxt[0]}: "
                               f"the edges must run round the panel in order")
        corner, length = _corner(vertices[ends[0]], vertices[ends[1]], edge.get("curvature"), scale,
                                 f"{where} edge {k}")
        outline.append({"name": f"v{ends[0]}", **corner})
        corners.append(vertices[ends[0]])
        lengths.append(length)
    axes = _euler_xyz(rotation)
    entry = {"name": name, "outline": outline,
             "placement": {"origin": translation.tolist(), "u_axis": axes[:, 0].tolist(),
                           "v_axis": axes[:, 1].tolist(), "at": [0.0, 0.0]}}
    return entry, translation + np.asarray(corners) @ axes[:, :2].T, lengths


def _euler_xyz(degrees: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation by x, then y, then z [deg] about the fixed axes (pygarment's euler_xyz_to_R)."""
    (cx, cy, cz), (sx, sy, sz) = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _corner(start: np.ndarray, end: np.ndarray, curvature, scale: float, where: str) -> tuple[dict, float]:
    """(the outline corner at `start` with its edge to `end`: {"at"} and a "bspline" or "bulge", the edge's
    length); a circle's radius is in the file's units (x scale)."""
    corner = {"at": start.tolist()}
    e = end - start
    chord = float(np.linalg.norm(e))
    if curvature is None:
        return corner, chord
    if isinstance(curvature, list):  # pygarment's older form: the quadratic's control point
        curvature = {"type": "quadratic", "params": [curvature]}
    if not isinstance(curvature, dict):
        raise PatternError(f"{where}: curvature must be a table (type, params), got {curvature!r}")
    kind, params = curvature.get("type"), curvature.get("params")
    perp = np.array([-e[1], e[0]])
    if kind in ("quadratic", "cubic"):
        n = 1 if kind == "quadratic" else 2
        if not isinstance(params, list) or len(params) != n or not all(
                isinstance(p, list) and len(p) == 2 and all(_is_number(x) for x in p) for p in params):
            raise PatternError(f"{where}: a {kind} curvature needs {n} control point(s) [t, k], got {params!r}")
        controls = [start + float(t) * e + float(k) * perp for t, k in params]
        points = np.array([start, *controls, end])
        return {**corner, "bspline": [c.tolist() for c in controls]}, _bezier_length(points)
    if kind == "circle":
        if not isinstance(params, list) or len(params) != 3 or not _is_number(params[0]):
            raise PatternError(f"{where}: a circle curvature needs [radius, large_arc, right], got {params!r}")
        radius, large, right = float(params[0]) * scale, bool(params[1]), bool(params[2])
        if not radius >= 0.5 * chord * (1 - 1e-9):
            raise PatternError(f"{where}: a circle of radius {radius / scale:g} cannot join ends {chord / scale:g} "
                               f"apart")
        sweep = 2.0 * math.asin(min(1.0, 0.5 * chord / radius))
        if large:
            sweep = 2.0 * math.pi - sweep
        # a positive bulge turns counter-clockwise: the arc lies to the right of the chord's direction
        return {**corner, "bulge": math.tan(0.25 * sweep) * (1.0 if right else -1.0)}, radius * sweep
    raise PatternError(f"{where}: unknown curvature type {kind!r} (line, circle, quadratic or cubic)")


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _bezier_length(points: np.ndarray, samples: int = 256) -> float:
    """The length of the Bezier curve of control points (n, 2), to about 1e-5 of it (a chord sum; it only sets a
    seam's tolerance)."""
    t = np.linspace(0.0, 1.0, samples + 1)[:, None]
    n = len(points) - 1
    curve = sum(math.comb(n, i) * t ** i * (1 - t) ** (n - i) * points[i] for i in range(n + 1))
    return float(np.linalg.norm(np.diff(curve, axis=0), axis=1).sum())


def _stitch(k: int, stitch, placed: dict) -> dict:
    """The garment file's [[seams]] entry of stitch k: its two edges, the second run so that its ends meet the
    first's where the panels are placed, and a tolerance that takes the stitch's gather."""
    where = f"stitch {k}"
    if not isinstance(stitch, list) or len(stitch) != 2:
        raise PatternError(f"{where}: must be two {{panel, edge}} tables, got {stitch!r}")
    sides, points = [], []
    for side in stitch:
        panel, edge = (side.get("panel"), side.get("edge")) if isinstance(side, dict) else (None, None)
        if (not isinstance(panel, str) or panel not in placed or isinstance(edge, bool) or not isinstance(edge, int)
                or not 0 <= edge < len(placed[panel][1])):
            raise PatternError(f"{where}: no edge {edge!r} on a panel {panel!r}")
        corners, lengths, names = placed[panel]
        end = (edge + 1) % len(lengths)
        sides.append({"piece": panel, "from": names[edge], "to": names[end], "length": lengths[edge]})
        points.append((corners[edge], corners[end]))
    (a0, a1), (b0, b1) = points
    if np.linalg.norm(a0 - b0) + np.linalg.norm(a1 - b1) > np.linalg.norm(a0 - b1) + np.linalg.norm(a1 - b0):
        sides[1]["from"], sides[1]["to"] = sides[1]["to"], sides[1]["from"]  # the b edge runs the other way
    la, lb = sides[0].pop("length"), sides[1].pop("length")
    mismatch = abs(la - lb) / max(la, lb)
    if mismatch > GATHER_LIMIT:
        raise PatternError(f"{where}: its edges are {100 * la:.1f} and {100 * lb:.1f} cm long, {100 * mismatch:.0f} % "
                           f"apart: more than the {100 * GATHER_LIMIT:.0f} % a seam gathers")
    a, b = sides
    return {"name": f"{a['piece']}.{a['from']}-{b['piece']}.{b['from']}", "a": a, "b": b,
            "tolerance": max(DEFAULT_LENGTH_TOLERANCE, min(GATHER_LIMIT, mismatch + _MISMATCH_MARGIN))}
