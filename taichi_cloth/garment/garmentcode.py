"""GarmentCode sewing patterns read as garments (Korosteleva and Sorkine-Hornung, "GarmentCode: Programming
Parametric Sewing Patterns", SIGGRAPH Asia 2023; the `specification.json` its pygarment library writes).

`read_specification` turns a specification into a garment file (the dict tomllib gives for one:
taichi_cloth.garment.garmentfile), so that load_garment, a scene, batch and the pattern studio read it as they read
a garment file, and the studio saves it as one. The file's unit follows `properties.units_in_meter` (100: cm, 1000:
mm, 1: m, any other converted to m); `properties.curvature_coords` must be "relative". Cotton at 2 cm.

  * Each panel is a piece whose outline runs through its `vertices` along its `edges`, in loop order, each
    `endpoints` [i, j] and an optional `curvature`: none, a straight line; {"type": "circle", "params": [radius,
    large_arc, right]} an arc from i to j of that radius, the larger of the two when large_arc, bulging to the right
    of i -> j when right (a `bulge` in the garment file); {"type": "quadratic", "params": [[t, k]]} and {"type":
    "cubic", "params": [[t1, k1], [t2, k2]]} Bezier curves whose control points lie at start + t e + k perp(e),
    e = end - start, perp(e) = (-e_y, e_x) (pygarment's relative coordinates; a bare [t, k] is the older quadratic
    form; a `bspline` through them in the garment file). Corner i is named "v<i>" (its vertex index).
  * `translation` (3,) and `rotation` (Euler angles x, y, z [deg], extrinsic) place the panel flat in GarmentCode's
    body frame: y up, the floor at 0, +z the front, +x the body's left, as the mannequin's. The piece's placement
    is that free placement (`origin`, `u_axis`, `v_axis`): its vertex (0, 0) at the translation.
  * A stitch [{panel, edge}, {panel, edge}] is a seam between the two edges; which ends meet is read from the
    placed panels (the pairing whose ends lie nearer), and its length tolerance is the two edges' relative mismatch
    plus a margin, up to GATHER_LIMIT: GarmentCode gathers a ruffle or a waist onto a shorter edge.
  * An edge shorter than SHORT_EDGE whose corner toward a neighbour is no seam's end is merged into that neighbour
    (the two become one polyline): GarmentCode outlines have sub-millimetre edges, which mesh into slivers.

Bad input gets one PatternError naming the file, the panel or stitch, and the key.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..errors import PatternError
from .pattern import Segment
from .seams import DEFAULT_LENGTH_TOLERANCE

__all__ = ["GATHER_LIMIT", "SHORT_EDGE", "read_specification"]

#: the largest relative length mismatch a stitch may gather (a ruffle's edge is longer than its partner's)
GATHER_LIMIT = 0.25
#: the margin added to a stitch's own mismatch for its seam's tolerance (the meshed sides round differently)
_MISMATCH_MARGIN = 0.02
#: [m] an edge shorter than this that no stitch uses is merged into its unstitched neighbour: a quarter of the
#: default 2 cm spacing, the finest resolution's (a 2 mm edge meshes into a sliver at 2 cm; 5 mm do not)
SHORT_EDGE = 0.005
#: [m] how closely a merged edge's polyline follows the curves it replaces
_MERGE_TOLERANCE = 1e-4
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
    sewn = {(side["piece"], side[end]) for seam in seams for side in (seam["a"], seam["b"]) for end in ("from", "to")}
    for entry in pieces:
        entry["outline"] = _merge_short_edges(entry["outline"], {c for p, c in sewn if p == entry["name"]},
                                              SHORT_EDGE / metres, _MERGE_TOLERANCE / metres)
    spacing = round(0.02 / metres, 12)
    return {"name": path.parent.name if path.stem == "specification" else path.stem, "units": units,
            "material": "cotton", "spacing": spacing, "pieces": pieces, "seams": seams}


def _edge(outline: list, k: int) -> Segment:
    """Edge k of a garment file's outline (corner k to corner k + 1, in its units) as a Segment."""
    corner, end = outline[k], np.asarray(outline[(k + 1) % len(outline)]["at"], dtype=np.float64)
    start = np.asarray(corner["at"], dtype=np.float64)
    if "bulge" in corner:
        return Segment.arc(start, end, corner["bulge"])
    if "bspline" in corner:
        return Segment("bspline", np.array([start, *corner["bspline"], end]), degree=len(corner["bspline"]) + 1)
    if "polyline" in corner:
        return Segment("polyline", np.array([start, *corner["polyline"], end]))
    return Segment.line(start, end)


def _merge_short_edges(outline: list, sewn: set, shortest: float, tolerance: float) -> list:
    """`outline` with every edge shorter than `shortest` merged into a neighbour, where the corner between them is
    no seam's end (`sewn`: corner names): the two edges become one polyline through the corner, within
    `tolerance` of their curves. A short edge between two sewn corners stays (meshing then names it)."""
    outline = list(outline)
    merged = True
    while merged and len(outline) > 3:
        merged = False
        n = len(outline)
        for k in range(n):
            if _edge(outline, k).length() >= shortest:
                continue
            for drop in (k, (k + 1) % n):  # the short edge's start (merge into the edge before) or its end
                if outline[drop]["name"] in sewn:
                    continue
                before = (drop - 1) % n
                points = np.vstack([_edge(outline, before).sample(tolerance)[:-1],
                                    _edge(outline, drop).sample(tolerance)])
                corner = {"at": outline[before]["at"], "name": outline[before]["name"]}
                outline[before] = {**corner, "polyline": points[1:-1].tolist()}
                del outline[drop]
                merged = True
                break
            if merged:
                break
    return outline


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
        corner = _corner(vertices[ends[0]], vertices[ends[1]], edge.get("curvature"), scale, f"{where} edge {k}")
        outline.append({"name": f"v{ends[0]}", **corner})
        corners.append(vertices[ends[0]])
    lengths = [_edge(outline, k).length() for k in range(len(outline))]
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


def _corner(start: np.ndarray, end: np.ndarray, curvature, scale: float, where: str) -> dict:
    """The outline corner at `start` with its edge to `end`: {"at"} and a "bspline" or "bulge"; a circle's radius
    is in the file's units (x scale)."""
    corner = {"at": start.tolist()}
    e = end - start
    chord = float(np.linalg.norm(e))
    if curvature is None:
        return corner
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
        return {**corner, "bspline": [c.tolist() for c in controls]}
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
        return {**corner, "bulge": math.tan(0.25 * sweep) * (1.0 if right else -1.0)}
    raise PatternError(f"{where}: unknown curvature type {kind!r} (line, circle, quadratic or cubic)")


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


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
