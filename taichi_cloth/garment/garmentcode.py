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
from ..material import Material
from .garment import FreePlacement, GarmentSpec
from .pattern import PatternPiece, Segment
from .seams import DEFAULT_LENGTH_TOLERANCE, Seam, SeamSide

__all__ = ["GATHER_LIMIT", "load_specification"]

#: the largest relative length mismatch a stitch may gather (a ruffle's edge is longer than its partner's)
GATHER_LIMIT = 0.25
#: the margin added to a stitch's own mismatch for its seam's tolerance (the meshed sides round differently)
_MISMATCH_MARGIN = 0.02


def load_specification(path, material: str | Material = "cotton", spacing: float = 0.02) -> GarmentSpec:
    """The GarmentSpec of the GarmentCode `specification.json` at `path` (module docstring): its panels as pieces
    with free placements, its stitches as seams; `material` and `spacing` [m] as in a garment file."""
    path = Path(path)
    try:
        spec = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise PatternError(f"{path}: not a readable GarmentCode specification ({exc})") from None
    try:
        return _garment(spec, path, material, spacing)
    except PatternError as exc:
        raise PatternError(f"{path}: {exc}") from None


def _garment(spec, path: Path, material, spacing: float) -> GarmentSpec:
    pattern = _get(spec, "pattern", dict, "the file")
    props = spec.get("properties") or {}
    if not isinstance(props, dict):
        raise PatternError(f"properties must be a table, got {type(props).__name__}")
    if props.get("curvature_coords", "relative") != "relative":
        raise PatternError(f"properties.curvature_coords is {props.get('curvature_coords')!r}; only 'relative' "
                           f"(pygarment's) is read")
    units = props.get("units_in_meter", 100)
    if isinstance(units, bool) or not isinstance(units, (int, float)) or not units > 0:
        raise PatternError(f"properties.units_in_meter must be a number > 0, got {units!r}")
    scale = 1.0 / float(units)
    panels = _get(pattern, "panels", dict, "pattern")
    order = pattern.get("panel_order") or list(panels)
    pieces, placements, frames = [], {}, {}
    for name in order:
        if name not in panels:
            raise PatternError(f"pattern.panel_order names {name!r}, which is not a panel")
        piece, frame = _panel(name, panels[name], scale)
        pieces.append(piece)
        frames[name] = frame
        origin, axes = frame
        placements[name] = FreePlacement(tuple(origin), tuple(axes[:, 0]), tuple(axes[:, 1]), (0.0, 0.0))
    by_name = {p.name: p for p in pieces}
    seams = [_stitch(k, st, by_name, frames) for k, st in enumerate(_get(pattern, "stitches", list, "pattern"))]
    return GarmentSpec(name=path.parent.name if path.stem == "specification" else path.stem, pieces=pieces,
                       seams=seams, placements=placements, material=material, spacing=spacing)


def _get(table, key: str, kind: type, where: str):
    if not isinstance(table, dict) or key not in table:
        raise PatternError(f"{where} has no {key!r}")
    value = table[key]
    if not isinstance(value, kind):
        raise PatternError(f"{where}.{key} must be a {kind.__name__}, got {type(value).__name__}")
    return value


def _panel(name: str, panel, scale: float) -> tuple[PatternPiece, tuple[np.ndarray, np.ndarray]]:
    """(the piece [m], its 3D frame: origin (3,) [m] and axes (3, 3), columns u, v, normal)."""
    where = f"panel {name!r}"
    try:
        vertices = np.asarray(_get(panel, "vertices", list, where), dtype=np.float64) * scale
        translation = np.asarray(panel.get("translation", [0.0, 0.0, 0.0]), dtype=np.float64) * scale
        rotation = np.asarray(panel.get("rotation", [0.0, 0.0, 0.0]), dtype=np.float64)
    except (TypeError, ValueError):
        raise PatternError(f"{where}: vertices, translation and rotation must be numbers") from None
    if vertices.ndim != 2 or vertices.shape[1] != 2 or translation.shape != (3,) or rotation.shape != (3,):
        raise PatternError(f"{where}: vertices must be [x, y] pairs, translation and rotation three numbers each")
    edges = _get(panel, "edges", list, where)
    segments, names = [], []
    for k, edge in enumerate(edges):
        ends = _get(edge, "endpoints", list, f"{where} edge {k}")
        if len(ends) != 2 or not all(isinstance(i, int) and 0 <= i < len(vertices) for i in ends):
            raise PatternError(f"{where} edge {k}: endpoints must be two vertex indices, got {ends!r}")
        nxt = _get(edges[(k + 1) % len(edges)], "endpoints", list, f"{where} edge {(k + 1) % len(edges)}")
        if ends[1] != nxt[0]:
            raise PatternError(f"{where}: edge {k} ends at vertex {ends[1]} but the next edge starts at {nxt[0]}: "
                               f"the edges must run round the panel in order")
        segments.append(_segment(vertices[ends[0]], vertices[ends[1]], edge.get("curvature"), scale,
                                 f"{where} edge {k}"))
        names.append(f"v{ends[0]}")
    piece = PatternPiece(name, segments, names)
    piece.validate()
    return piece, (translation, _euler_xyz(rotation))


def _euler_xyz(degrees: np.ndarray) -> np.ndarray:
    """(3, 3) the rotation by x, then y, then z [deg] about the fixed axes (pygarment's euler_xyz_to_R)."""
    (cx, cy, cz), (sx, sy, sz) = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _segment(start: np.ndarray, end: np.ndarray, curvature, scale: float, where: str) -> Segment:
    """The edge from start to end [m]; a circle's radius is in the file's units (x scale [m])."""
    if curvature is None:
        return Segment.line(start, end)
    if isinstance(curvature, list):  # pygarment's older form: the quadratic's control point
        curvature = {"type": "quadratic", "params": [curvature]}
    if not isinstance(curvature, dict):
        raise PatternError(f"{where}: curvature must be a table (type, params), got {curvature!r}")
    kind, params = curvature.get("type"), curvature.get("params")
    e = end - start
    perp = np.array([-e[1], e[0]])
    if kind in ("quadratic", "cubic"):
        n = 1 if kind == "quadratic" else 2
        if not isinstance(params, list) or len(params) != n:
            raise PatternError(f"{where}: a {kind} curvature needs {n} control point(s), got {params!r}")
        controls = [start + float(t) * e + float(k) * perp for t, k in params]
        return Segment("bspline", np.array([start, *controls, end]), degree=n + 1)
    if kind == "circle":
        if not isinstance(params, list) or len(params) != 3:
            raise PatternError(f"{where}: a circle curvature needs [radius, large_arc, right], got {params!r}")
        radius, large, right = float(params[0]) * scale, bool(params[1]), bool(params[2])
        chord = float(np.linalg.norm(e))
        if not radius >= 0.5 * chord * (1 - 1e-9):
            raise PatternError(f"{where}: a circle of radius {radius / scale:g} cannot join ends {chord / scale:g} "
                               f"apart")
        sweep = 2.0 * math.asin(min(1.0, 0.5 * chord / radius))
        if large:
            sweep = 2.0 * math.pi - sweep
        # a positive bulge turns counter-clockwise: the arc lies to the right of the chord's direction
        return Segment.arc(start, end, math.tan(0.25 * sweep) * (1.0 if right else -1.0))
    raise PatternError(f"{where}: unknown curvature type {kind!r} (line, circle, quadratic or cubic)")


def _stitch(k: int, stitch, pieces: dict, frames: dict) -> Seam:
    where = f"stitch {k}"
    if not isinstance(stitch, list) or len(stitch) != 2:
        raise PatternError(f"{where}: must be two {{panel, edge}} tables, got {stitch!r}")
    sides, points = [], []
    for side in stitch:
        panel, edge = (side.get("panel"), side.get("edge")) if isinstance(side, dict) else (None, None)
        if panel not in pieces or not isinstance(edge, int) or not 0 <= edge < len(pieces[panel].segments):
            raise PatternError(f"{where}: no edge {edge!r} on a panel {panel!r}")
        piece = pieces[panel]
        start, end = piece.corner_names[edge], piece.corner_names[(edge + 1) % len(piece.segments)]
        origin, axes = frames[panel]
        ends = [origin + axes[:, :2] @ piece.corners[piece.corner_index(c)] for c in (start, end)]
        sides.append([panel, start, end, piece.segments[edge].length()])
        points.append(ends)
    (a0, a1), (b0, b1) = points
    if np.linalg.norm(a0 - b0) + np.linalg.norm(a1 - b1) > np.linalg.norm(a0 - b1) + np.linalg.norm(a1 - b0):
        sides[1][1], sides[1][2] = sides[1][2], sides[1][1]  # the b edge runs the other way round its panel
    mismatch = abs(sides[0][3] - sides[1][3]) / max(sides[0][3], sides[1][3])
    if mismatch > GATHER_LIMIT:
        raise PatternError(f"{where}: its edges are {100 * sides[0][3]:.1f} and {100 * sides[1][3]:.1f} cm long, "
                           f"{100 * mismatch:.0f} % apart: more than the {100 * GATHER_LIMIT:.0f} % a seam gathers")
    return Seam(f"{sides[0][0]}.{sides[0][1]}-{sides[1][0]}.{sides[1][1]}",
                SeamSide(*sides[0][:3]), SeamSide(*sides[1][:3]),
                tolerance=max(DEFAULT_LENGTH_TOLERANCE, min(GATHER_LIMIT, mismatch + _MISMATCH_MARGIN)))
