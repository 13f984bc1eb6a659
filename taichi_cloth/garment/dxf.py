"""DXF import and export of 2D pattern pieces (Chen 2013), with ezdxf.

Reading (`read_dxf`):
  * Pieces come from model-space LAYERS (the entities on one layer; piece name = layer name) and from BLOCKS
    that are INSERTed (AAMA-style pattern files; piece name = block name, the INSERT's translation, rotation
    and scale applied through ezdxf's virtual_entities()). Inside a block, when some entity sits on layer "1"
    (the AAMA boundary layer) only layer-"1" entities form the outline, so grain lines and internal lines on
    other layers do not break it.
  * Entities: LINE -> "line"; ARC -> "arc" (bulge and direction from the sweep; a 360-degree ARC is a circle);
    CIRCLE -> a closed loop of two half-circle arcs; SPLINE -> "bspline" (control points, degree, knots and
    weights kept verbatim; a fit-point-only SPLINE gets control points from ezdxf's construction tool);
    ELLIPSE -> rational "bspline"; LWPOLYLINE / 2D or 3D POLYLINE:
      - closed (flag, or last vertex == first) -> one "line"/"arc" segment per edge, every vertex a corner;
      - open with bulges -> one "line"/"arc" segment per edge;
      - open without bulges -> "polyline" segments split at every vertex where the outline turns by more than
        CORNER_TURN degrees (a tangent break: the hem corners of a side-hem-side polyline), each a corner; the
        smooth interior vertices of a curve drawn as a polyline are not corners, so that polyline segments
        survive a write/read round trip. (Pattern CAD marks corners as polyline vertices or sharp turns.)
    TEXT / MTEXT whose insertion (or alignment) point lies on a corner (within tolerance) names that corner.
    Everything else (POINT, HATCH, DIMENSION, ...) is ignored.
  * Open entities on a layer are chained end to end (endpoints matched within tolerance, reversed as needed)
    into closed loops; an entity whose ends meet (or a closed entity) is a loop by itself. A layer with
    several loops gives pieces "layer", "layer.1", "layer.2", ... in file order; an open end that matches
    nothing is a PatternError naming the file, the layer and the gap (in the file's units).
  * Units: the `units` argument if given, else $INSUNITS (1 in, 4 mm, 5 cm, 6 m), else a "Units: ..." TEXT
    anywhere in the file, as AAMA/ASTM D6673 pattern CAD writes it instead of $INSUNITS ("ENGLISH" inches,
    "METRIC" millimetres; also "INCH", "MM", "CM", "M"). A file with neither is read as millimetres (the usual
    pattern-CAD export unit) if its largest piece is then 10 cm to 5 m across, and refused otherwise with one
    PatternError naming the size and the unit options (an inch file read as mm is 25.4x too small: a T-shirt
    front 2.8 cm across). Pieces are returned in metres.
  * An AAMA block with a sew line (layer 14) is the piece inside it: the garment is sewn there, and the cut
    line (layer 1) adds the seam allowance; its notches and turn points mark the sew line's corners only where
    they lie on it.
  * AAMA / ASTM D6673 markings of a block: its grain line (layer 7) and fold or mirror line (layer 6), the
    longest LINE on each, become the piece's `grain` and `fold`; unless `as_drawn`, a half on a fold is unfolded
    into the whole piece (PatternPiece.unfolded) and every piece is turned so its grain line runs up (upright).
    A graded file (a "Size: M" text in each block, or blocks named <piece>_<size> with a "Sample Size: M" text)
    gives the pieces of one size, named without it: `size`, else the sample size.
  * An AAMA block's outline has its corners where pattern CAD marks them: at its turn points (layer 2, where
    grade-rule labels sit), at its notches (layer 4; a straight edge is split there, the corner named
    "notch<k>" in loop order), where a curve meets, and, where no turn point is marked, where it turns by
    more than AAMA_CORNER_TURN; the straight edges between are one "polyline" (a boundary exported as one
    closed polyline would otherwise have a corner at every vertex).
  * Corner names: in an AAMA block (one with entities on the boundary layer "1"), only the texts on layer "1"
    name corners; anywhere, a text that is an AAMA grade-rule label ("# 12") is not a name, and a name that two
    corners of one piece would share is given to the first, the second keeping its default "c<i>".
  * Tolerance [m]: default 1e-5 * the bounding-box diagonal of the layer's (or block's) entities. Chained
    ends are then snapped together exactly (the movable end of a line/polyline/arc/clamped spline moves).

Writing (`write_dxf`): R2010, $INSUNITS set, each piece on its own layer named after the piece, each segment
one entity in loop order (line -> LINE, polyline -> open LWPOLYLINE, arc -> open 2-vertex LWPOLYLINE with a
bulge, bspline -> SPLINE with control points, degree, explicit knots and weights), each corner name a TEXT at
the corner. A round trip gives back equal pieces (a zero-bulge "arc" reads back as a "polyline").
"""
from __future__ import annotations

import dataclasses
import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path

import ezdxf
import numpy as np
from ezdxf import bbox
from ezdxf.lldxf.validator import is_valid_layer_name
from ezdxf.math import rational_bspline_from_ellipse

from ..errors import PatternError
from . import pattern
from .pattern import UNITS, PatternPiece, Segment, open_uniform_knots, unit_scale

__all__ = ["dxf_units", "read_dxf", "write_aama_dxf", "write_dxf"]

_INSUNITS_TO_UNITS = {0: "mm", 1: "in", 4: "mm", 5: "cm", 6: "m"}
_UNITS_TO_INSUNITS = {"in": 1, "mm": 4, "cm": 5, "m": 6}
_AAMA_BOUNDARY_LAYER = "1"
#: the words a "Units:" text may give, and the unit each means (ASTM D6673: ENGLISH inches, METRIC millimetres)
_UNITS_WORDS = {"english": "in", "inch": "in", "inches": "in", "in": "in", "metric": "mm", "mm": "mm",
                "millimeter": "mm", "millimeters": "mm", "millimetre": "mm", "millimetres": "mm", "cm": "cm",
                "centimeter": "cm", "centimeters": "cm", "centimetre": "cm", "centimetres": "cm", "m": "m",
                "meter": "m", "meters": "m", "metre": "m", "metres": "m"}
_UNITS_TEXT = re.compile(r"^\s*units?\s*[:=]\s*(\S+)\s*$", re.IGNORECASE)
_GRADE_RULE_TEXT = re.compile(r"^\s*#\s*\d+\s*$")
_SIZE_TEXT = re.compile(r"^\s*size\s*[:=]\s*(\S+)\s*$", re.IGNORECASE)
_SAMPLE_SIZE_TEXT = re.compile(r"^\s*(?:sample|base)\s+size\s*[:=]\s*(\S+)\s*$", re.IGNORECASE)
_AAMA_TURN_LAYER, _AAMA_FOLD_LAYER, _AAMA_GRAIN_LAYER, _AAMA_SEW_LAYER = "2", "6", "7", "14"
_AAMA_NOTCH_LAYERS = ("4", "80", "81", "82", "83")  # V, T, castle, check and U notches
#: the span [m] a garment's largest pattern piece lies in, to tell whether a file without units is in mm
PLAUSIBLE_PIECE_SIZE = (0.10, 5.0)
#: how a user gives a DXF file's unit, said in every message about a missing or unreadable one
_GIVE_UNITS = f"give the file's unit, one of {', '.join(UNITS)} (read_dxf's units=, a garment file's dxf_units)"
_VTX_SPLINE_FRAME = 16  # POLYLINE vertex flag: spline frame control point, not part of the drawn curve


@dataclass
class _Chunk:
    """Consecutive segments [m] from one entity, in the entity's direction; closed = a loop by itself."""

    segments: list
    source: str
    closed: bool = False

    @property
    def start(self) -> np.ndarray:
        return self.segments[0].start

    @property
    def end(self) -> np.ndarray:
        return self.segments[-1].end

    def reversed(self) -> "_Chunk":
        return _Chunk([s.reversed() for s in reversed(self.segments)], self.source, self.closed)


@dataclass
class _Source:
    """The entities of one would-be piece: a model-space layer or an inserted block; for a block, its grain and
    fold lines ((2, 2) in file units, the longest on AAMA layers 7 and 6) and its "Size:" text."""

    kind: str  # "layer" | "block"
    name: str
    entities: list
    grain: np.ndarray | None = None
    fold: np.ndarray | None = None
    size: str | None = None
    turns: np.ndarray | None = None  # (k, 2) [file units] an AAMA block's turn points (layer 2): its corners
    notches: np.ndarray | None = None  # (k, 2) [file units] the points of its notches (layer 4)


# ----------------------------------------------------------------------------------------------------------
# reading
# ----------------------------------------------------------------------------------------------------------

def read_dxf(path, units: str | None = None, tolerance: float | None = None, size: str | None = None,
             as_drawn: bool = False) -> list:
    """Pattern pieces (list[PatternPiece], metres) from the DXF file at `path` (see the module docstring).

    units: "m" | "cm" | "mm" | "in" to override the file's $INSUNITS; tolerance [m]: endpoint matching and
    text-to-corner distance (default 1e-5 * the size of each layer or block); size: the size of a graded file to
    read (default its "Sample Size:"); as_drawn: the pieces as the file draws them, with their grain and fold
    lines, instead of each half on a fold unfolded and each piece turned upright (PatternPiece.unfolded, upright).
    """
    path = Path(path)
    doc = _open(path)
    scale, unit_name, assumed = _file_units(doc, path, units)
    if tolerance is not None and not (tolerance > 0 and math.isfinite(tolerance)):
        raise PatternError(f"{path}: tolerance must be > 0, got {tolerance!r}")
    found: list[tuple[PatternPiece, str | None]] = []
    for src in _sources(doc):
        loops = _source_loops(src, path, scale, unit_name, tolerance)
        for name, loop, names, tol in loops:
            lines = [None if line is None or len(loops) > 1 else pattern._line(line * scale)
                     for line in (src.grain, src.fold)]
            piece = PatternPiece(name, loop, names, *lines)
            try:
                piece.validate(tolerance=tol)
            except PatternError as exc:
                raise PatternError(f"{path}: {src.kind} '{src.name}': {exc}") from None
            found.append((piece, src.size))
    if not found:
        raise PatternError(f"{path}: no pattern pieces found (no closed outline on any layer or in any "
                           f"inserted block)")
    pieces = _of_size(found, size, _key_text(doc, path, _SAMPLE_SIZE_TEXT, "sample sizes"), path)
    if assumed:
        _check_plausible(pieces, path)
    used: set[str] = set()
    pieces = [dataclasses.replace(p, name=_unique_name(p.name, used)) for p in pieces]
    if not as_drawn:
        pieces = [(p.unfolded() if p.fold is not None else p).upright() for p in pieces]
    return pieces


def _of_size(found: list, size: str | None, sample: str | None, path: Path) -> list:
    """The pieces of one size of a graded file (a block's "Size:" text, else, in a file with a "Sample Size:"
    text, the end of a block named <piece>_<size>), named without the size; every piece of a file not graded."""
    # a name's end is a size when the file has a sample size and the same piece comes in two sizes or more (a
    # one-size POCKET_FLAP beside graded FRONT_S, FRONT_M is a piece, not the pocket in size FLAP)
    tails: dict[str, set] = {}
    for piece, _ in found:
        base, _, tail = piece.name.rpartition("_")
        tails.setdefault(base, set()).add(tail)
    sized = []
    for piece, own in found:
        base, _, tail = piece.name.rpartition("_")
        if own is None and sample is not None and base and (len(tails[base]) > 1 or tail == sample):
            own = tail
        if own is not None and piece.name.endswith(f"_{own}"):
            piece = dataclasses.replace(piece, name=piece.name[:-len(own) - 1])
        sized.append((piece, own))
    sizes = list(dict.fromkeys(own for _, own in sized if own is not None))
    if not sizes:
        if size is not None:
            raise PatternError(f"{path}: size {size!r} asked for, but the file is not graded (no 'Size:' or "
                               f"'Sample Size:' text)")
        return [p for p, _ in sized]
    want = size if size is not None else sample
    if want is None:
        raise PatternError(f"{path}: a graded file (sizes {', '.join(sizes)}) without a 'Sample Size:' text: give "
                           f"the size to read (read_dxf's size=, a garment file's dxf_size)")
    if want not in sizes:
        raise PatternError(f"{path}: no size {want!r} in the file; its sizes are {', '.join(sizes)}")
    return [p for p, own in sized if own is None or own == want]


def dxf_units(path) -> str:
    """The length unit read_dxf reads the DXF file at `path` in when given none ("m", "cm", "mm" or "in": from
    $INSUNITS, else a "Units:" text, else mm when its pieces are of a garment's size); PatternError naming the
    file if it cannot be read, its unit is unsupported, or it has none and is not of a garment's size in mm."""
    path = Path(path)
    _, name, assumed = _file_units(_open(path), path, None)
    if assumed:
        read_dxf(path)  # refuses a file whose pieces are not of a garment's size in mm
    return name


def _open(path: Path):
    if not path.is_file():
        raise PatternError(f"DXF file {path} not found")
    try:
        return ezdxf.readfile(path)
    except Exception as exc:  # ezdxf raises assorted errors (structure, decoding, value) on non-DXF input
        why = str(exc) if str(exc).startswith(type(exc).__name__) else f"{type(exc).__name__}: {exc}"
        raise PatternError(f"{path} is not a readable DXF file ({why})") from None


def _file_units(doc, path: Path, units: str | None) -> tuple[float, str, bool]:
    """(metres per file unit, unit name, whether the unit is only assumed: no units given, none in the file)."""
    if units is not None:
        if units not in UNITS:
            raise PatternError(f"{path}: units must be one of {', '.join(UNITS)}, got {units!r}")
        return UNITS[units], units, False
    code = doc.header.get("$INSUNITS", 0)
    if code not in _INSUNITS_TO_UNITS:
        raise PatternError(f"{path}: unsupported $INSUNITS = {code}: {_GIVE_UNITS}")
    if code:
        name = _INSUNITS_TO_UNITS[code]
        return UNITS[name], name, False
    name = _units_text(doc, path)
    return (UNITS[name], name, False) if name else (UNITS["mm"], "mm", True)


def _label(e) -> str:
    return e.plain_text() if e.dxftype() == "MTEXT" else str(e.dxf.text)


def _key_text(doc, path: Path, key: re.Pattern, what: str) -> str | None:
    """The value of the "Key: value" TEXTs or MTEXTs matching `key` in the model space or any block, or None if
    there is none; PatternError naming `what` if two give different values."""
    found: dict[str, str] = {}
    for layout in (doc.modelspace(), *doc.blocks):
        for e in layout.query("TEXT MTEXT"):
            m = key.match(_label(e))
            if m is not None:
                found.setdefault(m.group(1), _label(e).strip())
    if len(found) > 1:
        raise PatternError(f"{path}: its texts give two {what} ({' and '.join(map(repr, found.values()))})")
    return next(iter(found), None)


def _units_text(doc, path: Path) -> str | None:
    """The unit a "Units: ENGLISH" (or METRIC, INCH, MM, CM, M) TEXT or MTEXT in the model space or a block
    names, or None if there is none; PatternError if one names no unit we know or two disagree."""
    for layout in (doc.modelspace(), *doc.blocks):
        for e in layout.query("TEXT MTEXT"):
            m = _UNITS_TEXT.match(_label(e))
            if m is not None and m.group(1).lower() not in _UNITS_WORDS:
                raise PatternError(f"{path}: the text {_label(e).strip()!r} names no length unit we read (ENGLISH, "
                                   f"METRIC, INCH, MM, CM, M): {_GIVE_UNITS}")
    try:
        word = _key_text(doc, path, _UNITS_TEXT, "units")
    except PatternError as exc:
        raise PatternError(f"{exc}: {_GIVE_UNITS}") from None
    return None if word is None else _UNITS_WORDS[word.lower()]


def _check_plausible(pieces: list, path: Path) -> None:
    """Refuse a file without units whose largest piece, read in mm, is not of a garment's size."""
    largest = max(pieces, key=lambda p: p.size())
    lo, hi = PLAUSIBLE_PIECE_SIZE
    size = largest.size()
    if lo <= size <= hi:
        return
    guess = " (inches would make it {:.0f} cm)".format(100 * size / UNITS["mm"] * UNITS["in"]) if size < lo else ""
    raise PatternError(f"{path}: the file gives no unit ($INSUNITS unset, no 'Units:' text), and read as "
                       f"millimetres its largest piece, {largest.name!r}, is {100 * size:.3g} cm across, "
                       f"{'smaller' if size < lo else 'larger'} than any garment piece{guess}: {_GIVE_UNITS}")


def _sources(doc) -> list:
    """Model-space layers (entities other than INSERT, in file order) and one source per INSERT."""
    layers: dict[str, _Source] = {}
    blocks: list[_Source] = []
    for e in doc.modelspace():
        if e.dxftype() == "INSERT":
            ents = list(_flatten(e))
            grain, fold = (_longest_line(x for x in ents if x.dxf.layer == layer)
                           for layer in (_AAMA_GRAIN_LAYER, _AAMA_FOLD_LAYER))
            size = next((m.group(1) for x in ents if _is_text(x) for m in [_SIZE_TEXT.match(_label(x))] if m), None)
            turns = notches = None
            if any(x.dxf.layer == _AAMA_BOUNDARY_LAYER and not _is_text(x) for x in ents):
                turns, notches = (_mark_points(x for x in ents if x.dxf.layer in layers)
                                  for layers in ((_AAMA_TURN_LAYER,), _AAMA_NOTCH_LAYERS))
                # the sew line where the file draws one: the garment is sewn there, not at the cut line
                outline = _AAMA_SEW_LAYER if any(x.dxf.layer == _AAMA_SEW_LAYER and not _is_text(x)
                                                 for x in ents) else _AAMA_BOUNDARY_LAYER
                ents = [x for x in ents if x.dxf.layer == outline and not _is_text(x)
                        or x.dxf.layer == _AAMA_BOUNDARY_LAYER and _is_text(x)]
            blocks.append(_Source("block", e.dxf.name, ents, grain, fold, size, turns, notches))
        else:
            layers.setdefault(e.dxf.layer, _Source("layer", e.dxf.layer, [])).entities.append(e)
    return list(layers.values()) + blocks


def _mark_points(entities) -> np.ndarray:
    """(k, 2) [file units] the points that mark places on an outline: a TEXT's or POINT's location, the ends of a
    LINE (a notch is a short line from the outline inward)."""
    pts = []
    for e in entities:
        kind = e.dxftype()
        if kind == "TEXT":
            pts.append(_xy(e.ocs().to_wcs(e.dxf.insert)))
        elif kind == "POINT":
            pts.append(_xy(e.dxf.location))
        elif kind == "LINE":
            pts += [_xy(e.dxf.start), _xy(e.dxf.end)]
    return np.array(pts, dtype=np.float64).reshape(-1, 2)


def _longest_line(entities) -> np.ndarray | None:
    """(2, 2) [file units] the longest LINE (or a POLYLINE's first to last vertex) among `entities`, or None."""
    best, longest = None, 0.0
    for e in entities:
        kind = e.dxftype()
        if kind == "LINE":
            pts = np.array([_xy(e.dxf.start), _xy(e.dxf.end)])
        elif kind in ("LWPOLYLINE", "POLYLINE"):
            vertices = [_xy(v) for v in (e.vertices_in_wcs() if kind == "LWPOLYLINE" else e.points())]
            if len(vertices) < 2:
                continue
            pts = np.array([vertices[0], vertices[-1]])
        else:
            continue
        if np.linalg.norm(pts[1] - pts[0]) > longest:
            best, longest = pts, float(np.linalg.norm(pts[1] - pts[0]))
    return best


def _flatten(insert, depth: int = 0):
    """Virtual (transformed) entities of an INSERT, nested INSERTs expanded."""
    for e in insert.virtual_entities():
        if e.dxftype() == "INSERT" and depth < 16:
            yield from _flatten(e, depth + 1)
        else:
            yield e


def _is_text(e) -> bool:
    return e.dxftype() in ("TEXT", "MTEXT")


def _unique_name(name: str, used: set) -> str:
    out, k = name, 0
    while out in used:
        k += 1
        out = f"{name}.{k}"
    used.add(out)
    return out


def _source_loops(src: _Source, path: Path, scale: float, unit_name: str, tolerance: float | None):
    """(piece name, segments, corner names, tolerance [m]) of each loop of one source."""
    shapes = [e for e in src.entities if not _is_text(e)]
    if not shapes:
        return []
    tol = tolerance if tolerance is not None else _default_tol(shapes, scale)
    where = f"{path}: {src.kind} '{src.name}'"
    chunks = []
    for e in shapes:
        chunks.extend(_entity_chunks(e, scale, tol, where))
    if not chunks:
        return []
    texts = [t for e in src.entities if _is_text(e) for t in [_text(e, scale)] if t is not None]
    loops = _chain(chunks, tol, where, scale, unit_name)
    out = []
    for k, loop in enumerate(loops):
        loop = _snap(loop)
        names = texts
        if src.turns is not None:  # an AAMA block: corners where the file marks them, notches among them
            loop, notched = _aama_corners(loop, src.turns * scale, src.notches * scale, tol)
            names = texts + [(p[None], f"notch{j + 1}") for j, p in enumerate(notched)]
        name = src.name if k == 0 else f"{src.name}.{k}"
        out.append((name, loop, _corner_names(loop, names, tol), tol))
    return out


#: [deg] an AAMA outline's vertex turning by more than this is a corner even where no turn point marks it: a
#: curve drawn as a polyline turns by a few degrees a vertex (2 mm edges round an 8 cm armhole: 1.5 degrees)
AAMA_CORNER_TURN = 10.0


def _aama_corners(segs: list, turns: np.ndarray, notches: np.ndarray, tol: float) -> tuple[list, list]:
    """An AAMA outline's segments with its corners where pattern CAD marks them: at its turn points, at its
    notches (a straight edge split there), where a curve (arc, spline) meets, and, in a file that marks no turn
    points, where it turns by more than AAMA_CORNER_TURN; between them its straight edges are one "polyline" (a
    boundary exported as one polyline otherwise has a corner at every vertex: 148 a piece, edges of 2 mm). Also
    the notch points on it, in order."""
    notched: list = []
    split = []
    for seg in segs:
        if seg.kind not in ("line", "polyline") or not len(notches):
            split.append(seg)
            continue
        pts = seg.points
        for q in notches:
            d = pattern._point_segment_distance(q, pts[:-1], pts[1:])
            i = int(np.argmin(d))
            if d[i] <= tol and np.min(np.linalg.norm(pts - q, axis=1)) > tol:  # on an edge, not at a vertex
                pts = np.insert(pts, i + 1, q, axis=0)
        cuts = [j for j in range(1, len(pts) - 1) if np.min(np.linalg.norm(notches - pts[j], axis=1)) <= tol]
        notched += [pts[j] for j in cuts]
        cuts = [0, *cuts, len(pts) - 1]
        split += [Segment("line" if b - a == 1 else "polyline", pts[a:b + 1]) for a, b in zip(cuts, cuts[1:])]
    marked = np.vstack([turns, notches]) if len(notches) else turns
    n = len(split)
    keep = []
    for i in range(n):  # corner i is where split[i - 1] ends and split[i] starts
        a, b = split[i - 1], split[i]
        straight = a.kind in ("line", "polyline") and b.kind in ("line", "polyline")
        p = b.start
        if not straight or (len(marked) and np.min(np.linalg.norm(marked - p, axis=1)) <= tol):
            keep.append(i)
            continue
        if len(turns):
            continue  # the file marks its turn points: the others are points of curves, however sharp
        u, v = a.points[-1] - a.points[-2], b.points[1] - b.points[0]
        if np.dot(u, v) < math.cos(math.radians(AAMA_CORNER_TURN)) * np.linalg.norm(u) * np.linalg.norm(v):
            keep.append(i)
    if len(keep) < 3:
        return segs, []  # a smooth outline without marks: every vertex stays a corner, as drawn
    out = []
    for k, i in enumerate(keep):
        j = keep[(k + 1) % len(keep)]
        run = [split[m % n] for m in range(i, j if j > i else j + n)]
        if len(run) == 1:
            out.append(run[0])
        else:
            pts = np.vstack([run[0].points] + [r.points[1:] for r in run[1:]])
            out.append(Segment("polyline", pts))
    return out, notched


def _default_tol(entities, scale: float) -> float:
    box = bbox.extents(entities, fast=True)
    diag = float(box.size.magnitude) if box.has_data else 0.0
    return max(1e-5 * diag * scale, 1e-9)


# -- entities -> chunks ----------------------------------------------------------------------------------

def _describe(e) -> str:
    handle = e.dxf.get("handle", None)
    return f"{e.dxftype()} {handle}" if handle else e.dxftype()


def _entity_chunks(e, scale: float, tol: float, where: str) -> list:
    kind = e.dxftype()
    try:
        if kind == "LINE":
            p = np.array([_xy(e.dxf.start), _xy(e.dxf.end)]) * scale
            return [] if np.array_equal(p[0], p[1]) else [_Chunk([Segment("line", p)], _describe(e))]
        if kind == "LWPOLYLINE":
            ocs, elev = e.ocs(), e.dxf.elevation
            rows = e.get_points("xyb")
            pts = [_xy(ocs.to_wcs((x, y, elev))) for x, y, _ in rows]
            bulges = [b for _, _, b in rows]
            return _vertex_chunks(pts, bulges, e.closed, e.dxf.extrusion[2] < 0, scale, tol, _describe(e))
        if kind == "POLYLINE":
            return _polyline_chunks(e, scale, tol)
        if kind == "ARC":
            return _arc_chunks(e, scale)
        if kind == "CIRCLE":
            return [_circle_chunk(e, scale)]
        if kind == "SPLINE":
            return [_spline_chunk(e, scale)]
        if kind == "ELLIPSE":
            return [_ellipse_chunk(e, scale)]
    except PatternError as exc:
        raise PatternError(f"{where}: {_describe(e)}: {exc}") from None
    return []


def _xy(v) -> np.ndarray:
    return np.array([float(v[0]), float(v[1])])


def _vertex_chunks(pts, bulges, closed: bool, flip: bool, scale: float, tol: float, source: str) -> list:
    """Segments of a (LW)POLYLINE given its WCS vertices (file units) and OCS bulges."""
    pts = [p * scale for p in pts]
    bulges = [(-b if flip else b) for b in bulges]  # an OCS seen from below turns the other way in WCS
    if len(pts) < 2:
        return []
    if not closed and len(pts) >= 3 and np.linalg.norm(pts[-1] - pts[0]) <= tol:
        closed, pts, bulges = True, pts[:-1], bulges[:-1]
    n = len(pts)
    edges = [(pts[i], pts[(i + 1) % n], bulges[i]) for i in range(n if closed else n - 1)]
    edges = [(a, b, bu) for a, b, bu in edges if not np.array_equal(a, b)]  # zero-length edges carry nothing
    if not edges:
        return []
    if not closed and all(bu == 0 for _, _, bu in edges):
        poly = np.array([edges[0][0]] + [b for _, b, _ in edges])
        return [_Chunk(_split_at_turns(poly), source)]
    segs = [Segment("arc", np.array([a, b]), bulge=bu) if bu != 0 else Segment("line", np.array([a, b]))
            for a, b, bu in edges]
    return [_Chunk(segs, source, closed=closed)]


#: [deg] a polyline vertex where the outline turns by more than this is a corner (a tangent break); a curve drawn
#: as a polyline turns less at each vertex (a circle needs only 8 vertices to stay below it)
CORNER_TURN = 45.0


def _split_at_turns(poly: np.ndarray) -> list:
    """Segments of an open polyline (n, 2) [m], split at the interior vertices that turn by more than CORNER_TURN:
    "polyline" pieces, or "line" where a piece is one edge."""
    d = np.diff(poly, axis=0)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    cos_turn = np.einsum("ij,ij->i", d[:-1], d[1:])
    cuts = [0] + [i + 1 for i in np.nonzero(cos_turn < math.cos(math.radians(CORNER_TURN)))[0]] + [len(poly) - 1]
    return [Segment("line" if b - a == 1 else "polyline", poly[a:b + 1]) for a, b in zip(cuts, cuts[1:])]


def _polyline_chunks(e, scale: float, tol: float) -> list:
    if not (e.is_2d_polyline or e.is_3d_polyline):
        return []  # polyface and polygon meshes are not outlines
    ocs = e.ocs() if e.is_2d_polyline else None
    pts, bulges = [], []
    for v in e.vertices:
        if v.dxf.flags & _VTX_SPLINE_FRAME:
            continue
        loc = v.dxf.location
        pts.append(_xy(ocs.to_wcs(loc) if ocs is not None else loc))
        bulges.append(float(v.dxf.get("bulge", 0.0)) if ocs is not None else 0.0)
    flip = ocs is not None and e.dxf.extrusion[2] < 0
    return _vertex_chunks(pts, bulges, e.is_closed, flip, scale, tol, _describe(e))


def _arc_chunks(e, scale: float) -> list:
    sweep = (e.dxf.end_angle - e.dxf.start_angle) % 360.0
    p0, p1 = _xy(e.start_point) * scale, _xy(e.end_point) * scale
    if sweep < 1e-9 or np.array_equal(p0, p1):
        return [_circle_chunk(e, scale, start_angle=e.dxf.start_angle)]
    bulge = math.tan(math.radians(sweep) / 4.0)
    if e.dxf.extrusion[2] < 0:
        bulge = -bulge
    return [_Chunk([Segment("arc", np.array([p0, p1]), bulge=bulge)], _describe(e))]


def _circle_chunk(e, scale: float, start_angle: float = 0.0) -> _Chunk:
    """Two half-circle arcs (bulge 1 counter-clockwise in the entity's OCS) starting at start_angle."""
    ocs, c, r = e.ocs(), e.dxf.center, e.dxf.radius
    a = math.radians(start_angle)
    p0 = _xy(ocs.to_wcs((c[0] + r * math.cos(a), c[1] + r * math.sin(a), c[2]))) * scale
    p1 = _xy(ocs.to_wcs((c[0] - r * math.cos(a), c[1] - r * math.sin(a), c[2]))) * scale
    b = -1.0 if e.dxf.extrusion[2] < 0 else 1.0
    segs = [Segment("arc", np.array([p0, p1]), bulge=b), Segment("arc", np.array([p1, p0]), bulge=b)]
    return _Chunk(segs, _describe(e), closed=True)


def _spline_chunk(e, scale: float) -> _Chunk:
    if e.control_point_count() > 0:
        ctrl = np.array([_xy(p) for p in e.control_points])
        degree = int(e.dxf.degree)
        knots = [float(k) for k in e.knots] or None
        weights = [float(w) for w in e.weights] or None
    elif e.fit_point_count() > 0:
        bs = e.construction_tool()
        ctrl = np.array([_xy(p) for p in bs.control_points])
        degree = int(bs.degree)
        knots = [float(k) for k in bs.knots()]
        weights = [float(w) for w in bs.weights()] or None
    else:
        raise PatternError("SPLINE has neither control points nor fit points")
    k = len(ctrl)
    if knots is not None and len(knots) == k + 2 * degree + 1 and e.closed:
        # a periodic SPLINE may list only the distinct control points: wrap the first `degree` ones
        ctrl = np.vstack([ctrl, ctrl[:degree]])
        weights = None if weights is None else weights + weights[:degree]
    if knots is not None and np.array_equal(knots, open_uniform_knots(len(ctrl), degree)):
        knots = None  # our own default: keep Segment equality across a round trip
    seg = Segment("bspline", ctrl * scale, degree=degree, knots=knots, weights=weights)
    return _Chunk([seg], _describe(e))


def _ellipse_chunk(e, scale: float) -> _Chunk:
    bs = rational_bspline_from_ellipse(e.construction_tool())
    seg = Segment("bspline", np.array([_xy(p) for p in bs.control_points]) * scale, degree=int(bs.degree),
                  knots=[float(k) for k in bs.knots()], weights=[float(w) for w in bs.weights()] or None)
    return _Chunk([seg], _describe(e))


def _text(e, scale: float):
    """(candidate points (m, 2) [m], text) of a TEXT/MTEXT, or None when empty."""
    if e.dxftype() == "MTEXT":
        label = e.plain_text().strip()
        pts = [_xy(e.dxf.insert)]
    else:
        label = str(e.dxf.text).strip()
        ocs = e.ocs()
        pts = [_xy(ocs.to_wcs(e.dxf.insert))]
        if e.dxf.hasattr("align_point"):
            pts.append(_xy(ocs.to_wcs(e.dxf.align_point)))
    if not label or any(p.match(label) for p in (_GRADE_RULE_TEXT, _UNITS_TEXT, _SIZE_TEXT, _SAMPLE_SIZE_TEXT)):
        return None
    return np.array(pts) * scale, label


# -- chaining --------------------------------------------------------------------------------------------

def _chain(chunks: list, tol: float, where: str, scale: float, unit_name: str) -> list:
    """Closed loops (lists of Segments) from chunks: closed chunks alone, open ones joined end to end."""
    is_loop = [c.closed or np.linalg.norm(c.end - c.start) <= tol for c in chunks]
    used = [False] * len(chunks)
    loops = []
    for i, c in enumerate(chunks):
        if used[i]:
            continue
        used[i] = True
        if is_loop[i]:
            loops.append(list(c.segments))
            continue
        segs, start, end = list(c.segments), c.start, c.end
        while np.linalg.norm(end - start) > tol:
            best = None  # (distance, index, reverse)
            for j, d in enumerate(chunks):
                if used[j] or is_loop[j]:
                    continue
                for dist, rev in ((np.linalg.norm(d.start - end), False), (np.linalg.norm(d.end - end), True)):
                    if best is None or dist < best[0]:
                        best = (dist, j, rev)
            if best is None or best[0] > tol:
                raise PatternError(_gap_message(where, chunks, used, is_loop, start, end, tol, scale, unit_name))
            _, j, rev = best
            used[j] = True
            nxt = chunks[j].reversed() if rev else chunks[j]
            segs.extend(nxt.segments)
            end = nxt.end
        loops.append(segs)
    return loops


def _gap_message(where, chunks, used, is_loop, start, end, tol, scale, unit_name) -> str:
    """Where a chain stops: its open end and the nearest free endpoint (or the chain's start), file units."""
    others = [start] + [p for j, c in enumerate(chunks) if not used[j] and not is_loop[j] for p in (c.start, c.end)]
    near = min(others, key=lambda p: np.linalg.norm(p - end))
    gap = np.linalg.norm(near - end)

    def fmt(p):
        return f"({p[0] / scale:.6g}, {p[1] / scale:.6g}) {unit_name}"

    return (f"{where}: the entities do not close into a loop: the open end at {fmt(end)} is "
            f"{gap / scale:.4g} {unit_name} from the nearest free endpoint at {fmt(near)} "
            f"(tolerance {tol / scale:.3g} {unit_name})")


def _snap(segs: list) -> list:
    """Make each junction exact: move the next segment's start onto the previous end, or, when that start is
    an evaluated (unclamped spline) point, the previous end onto it."""
    segs = list(segs)
    n = len(segs)
    for i in range(n):
        j = (i + 1) % n
        e, s = segs[i].end, segs[j].start
        if np.array_equal(e, s):
            continue
        if segs[j].end_movable(0):
            segs[j] = segs[j]._moved_end(0, e)
        elif segs[i].end_movable(-1):
            segs[i] = segs[i]._moved_end(-1, s)
    return segs


def _corner_names(segs: list, texts: list, tol: float) -> list:
    """Corner names from texts lying on corners (nearest corner within tol, first text wins; a name already given
    to a corner of this loop is not given again); else "c<i>"."""
    corners = np.array([s.start for s in segs])
    names = [None] * len(segs)
    for pts, label in texts:
        if label in names:
            continue
        d = np.linalg.norm(corners[:, None, :] - pts[None, :, :], axis=2).min(axis=1)
        for i in np.argsort(d, kind="stable"):
            if d[i] > tol:
                break
            if names[i] is None:
                names[i] = label
                break
    return [nm if nm is not None else f"c{i}" for i, nm in enumerate(names)]


# ----------------------------------------------------------------------------------------------------------
# writing
# ----------------------------------------------------------------------------------------------------------

def write_dxf(pieces, path, units: str = "mm") -> Path:
    """Write pieces (iterable of PatternPiece, metres) to an R2010 DXF at `path` in `units`; returns the path.

    Each piece on its own layer (the piece name), segments as entities in loop order, corner names as TEXT
    at the corners (height 1% of the piece size)."""
    path = Path(path)
    scale = unit_scale(units)
    pieces = list(pieces)
    seen: dict[str, str] = {}
    for p in pieces:
        if not isinstance(p, PatternPiece):
            raise PatternError(f"write_dxf: expected PatternPiece objects, got {type(p).__name__}")
        if not p.name or not is_valid_layer_name(p.name):
            raise PatternError(f"write_dxf: pattern piece name {p.name!r} is not a valid DXF layer name")
        if p.name.lower() in seen:  # DXF layer names are case-insensitive
            raise PatternError(f"write_dxf: pattern pieces {seen[p.name.lower()]!r} and {p.name!r} would share "
                               f"one DXF layer")
        seen[p.name.lower()] = p.name
    doc = ezdxf.new("R2010")
    doc.units = _UNITS_TO_INSUNITS[units]
    doc.header["$MEASUREMENT"] = 0 if units == "in" else 1
    msp = doc.modelspace()
    for piece in pieces:
        doc.layers.add(piece.name)
        attrs = {"layer": piece.name}
        for seg in piece.segments:
            _write_segment(msp, seg, scale, attrs)
        height = 0.01 * piece.size() / scale or 1.0
        for label, corner in zip(piece.corner_names, piece.corners):
            msp.add_text(label, height=height, dxfattribs={**attrs, "insert": (*(corner / scale), 0.0)})
    try:
        doc.saveas(path)
    except OSError as exc:
        raise PatternError(f"cannot write DXF file {path}: {exc}") from None
    return path


def write_aama_dxf(pieces, path, units: str = "in", sample_size: str | None = None,
                   tolerance: float = 2e-4) -> Path:
    """Write pattern pieces to `path` as AAMA / ASTM D6673 pattern CAD exports them; returns the path.

    pieces: a list of PatternPiece [m], or, for a graded file, {size: [PatternPiece, ...]} with `sample_size` one
    of its keys. units: "in" (written "Units: ENGLISH") or "mm" ("Units: METRIC"); no $INSUNITS (DXF R12). Each
    piece is a block (<piece>_<size> when graded) inserted at the origin: its outline one closed POLYLINE on layer
    1 (arcs as bulges, B-splines sampled within `tolerance` [m]), a grade-rule label "# k" at each corner on
    layer 2 (turn points), the corner's name as a TEXT on layer 1, a grain line along +v on layer 7, and the
    annotations "Piece Name:" and "Size:" on layer 1; the sample size as a model-space text."""
    if units not in ("in", "mm"):
        raise PatternError(f"write_aama_dxf: AAMA files are in inches or millimetres (units 'in' or 'mm'), "
                           f"got {units!r}")
    graded = dict(pieces) if isinstance(pieces, dict) else {None: list(pieces)}
    if isinstance(pieces, dict) and sample_size not in graded:
        raise PatternError(f"write_aama_dxf: sample_size {sample_size!r} is not one of the sizes "
                           f"{', '.join(map(str, graded))}")
    path, scale = Path(path), unit_scale(units)
    quiet = logging.getLogger("ezdxf")
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # ezdxf.new sets $INSUNITS, which R12 lacks, and warns: the "Units:" text says it
    try:
        doc = ezdxf.new("R12", units=1 if units == "in" else 4)
    finally:
        quiet.setLevel(level)
    msp = doc.modelspace()
    msp.add_text(f"Units: {'ENGLISH' if units == 'in' else 'METRIC'}", dxfattribs={"insert": (0.0, -1.0)})
    if sample_size is not None:
        msp.add_text(f"Sample Size: {sample_size}", dxfattribs={"insert": (0.0, -2.0)})
    for size, group in graded.items():
        for piece in group:
            name = piece.name if size is None else f"{piece.name}_{size}"
            if not is_valid_layer_name(name) or name in doc.blocks:
                raise PatternError(f"write_aama_dxf: piece name {name!r} is not a valid block name or is used twice")
            block = doc.blocks.new(name)
            vertices = []  # (x, y, bulge) [file units]: each segment's points but its last, the next one's first
            for seg in piece.segments:
                if seg.kind == "arc":
                    vertices.append((*(seg.start / scale), seg.bulge))
                else:
                    pts = seg.points if seg.kind in ("line", "polyline") else seg.sample(tolerance)
                    vertices += [(*(p / scale), 0.0) for p in pts[:-1]]
            block.add_polyline2d(vertices, format="xyb", close=True, dxfattribs={"layer": _AAMA_BOUNDARY_LAYER})
            height = 0.01 * piece.size() / scale or 1.0
            for k, (label, corner) in enumerate(zip(piece.corner_names, piece.corners)):
                at = {"insert": tuple(corner / scale), "height": height}
                block.add_text(f"# {k}", dxfattribs={"layer": _AAMA_TURN_LAYER, **at})
                block.add_text(label, dxfattribs={"layer": _AAMA_BOUNDARY_LAYER, **at})
            points = np.vstack([s.points for s in piece.segments]) / scale
            lo, hi = points.min(axis=0), points.max(axis=0)
            mid, quarter = 0.5 * (lo + hi), 0.25 * (hi[1] - lo[1])
            block.add_line((mid[0], mid[1] - quarter), (mid[0], mid[1] + quarter),
                           dxfattribs={"layer": _AAMA_GRAIN_LAYER})
            labels = [f"Piece Name: {piece.name}"] + ([] if size is None else [f"Size: {size}"])
            for k, label in enumerate(labels):
                block.add_text(label, dxfattribs={"layer": _AAMA_BOUNDARY_LAYER, "height": height,
                                                  "insert": (mid[0], mid[1] - (k + 1) * 2 * height)})
            msp.add_blockref(name, (0.0, 0.0))
    try:
        doc.saveas(path)
    except OSError as exc:
        raise PatternError(f"cannot write DXF file {path}: {exc}") from None
    return path


def _write_segment(msp, seg: Segment, scale: float, attrs: dict) -> None:
    pts = seg.points / scale
    if seg.kind == "line":
        msp.add_line(tuple(pts[0]), tuple(pts[1]), dxfattribs=attrs)
    elif seg.kind == "polyline":
        msp.add_lwpolyline([tuple(p) for p in pts], format="xy", dxfattribs=attrs)
    elif seg.kind == "arc":
        msp.add_lwpolyline([(*pts[0], seg.bulge), (*pts[1], 0.0)], format="xyb", dxfattribs=attrs)
    else:
        ctrl = [(x, y, 0.0) for x, y in pts]
        knots = list(seg.knots) if seg.knots is not None else list(open_uniform_knots(len(pts), seg.degree))
        if seg.weights is not None:
            msp.add_rational_spline(ctrl, list(seg.weights), degree=seg.degree, knots=knots, dxfattribs=attrs)
        else:
            msp.add_open_spline(ctrl, degree=seg.degree, knots=knots, dxfattribs=attrs)
