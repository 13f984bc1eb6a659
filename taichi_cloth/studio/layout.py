"""The pieces laid flat for the page to draw, in the garment file's units: outlines, one side per outline segment
(corner to corner) with its length, the corners and their names, the grain (u, v) directions, and every seam's two
sides in pick order with their lengths and whether they pair.

The pieces lie in rows, in file order, each as drawn in the pattern (v up), so that the drawing is about as wide as
it is tall; seam sides run the shorter way round between their corners (taichi_cloth.garment.seams.route), in
pick order, as the seam set-up picture draws them (taichi_cloth.pattern_view).
"""
from __future__ import annotations

import numpy as np

from ..garment.seams import route

#: [m] how finely outlines are sampled for drawing
DRAW_TOLERANCE = 5e-4
#: [m] space between two pieces on the page (room for their corner names)
GAP = 0.2
#: a piece's colour, the same on the page and in the placement picture (by piece order, repeating)
PIECE_COLOURS = ("#7fa7d9", "#e3a76f", "#8cc084", "#c994c7", "#e6d86e", "#76c7c0", "#d98c8c", "#a8a8d8")


def piece_colour(k: int) -> str:
    return PIECE_COLOURS[k % len(PIECE_COLOURS)]


def _pts(a: np.ndarray, scale: float) -> list:
    """(n, 2) [m] as lists in file units, rounded to what a drawing needs (a thousandth of the unit)."""
    return np.round(np.asarray(a) / scale, 3).tolist()


_LENGTHS: dict = {}


def segment_lengths(piece) -> np.ndarray:
    """(S,) [m] length of each outline segment of a PatternPiece. Kept per piece object (the session reads a DXF
    once, so its pieces are the same objects edit after edit, and a B-spline's length is an integral)."""
    kept = _LENGTHS.get(id(piece))
    if kept is None or kept[0] is not piece:
        if len(_LENGTHS) > 256:
            _LENGTHS.clear()
        kept = _LENGTHS[id(piece)] = (piece, np.array([s.length() for s in piece.segments]))
    return kept[1]


def side_lengths(spec, seam) -> tuple:
    """(route a, route b) of a seam of a GarmentSpec: the segments each side covers, its direction flag and its
    length [m]; PatternError naming the seam for an unknown corner, a side from a corner to itself, or a side
    half way round (ambiguous)."""
    pa, pb = spec.piece(seam.a.piece), spec.piece(seam.b.piece)
    return (route(pa, seam, seam.a, segment_lengths(pa)), route(pb, seam, seam.b, segment_lengths(pb)))


def mismatch(length_a: float, length_b: float) -> float:
    """Relative length difference of two seam sides, as the seam planner measures it."""
    return abs(length_a - length_b) / max(length_a, length_b)


def shifts(pieces, gap: float = GAP) -> list:
    """Where each piece goes: (2,) [m] added to its pattern coordinates. Rows of pieces `gap` apart, bottoms on
    each row's line, rows filled in order up to about the width that makes the drawing as wide as tall."""
    outlines = [p.outline(DRAW_TOLERANCE) for p in pieces]
    boxes = [(o.min(axis=0), o.max(axis=0)) for o in outlines]
    widths = [float(hi[0] - lo[0]) for lo, hi in boxes]
    heights = [float(hi[1] - lo[1]) for lo, hi in boxes]
    total = sum(widths) + gap * (len(widths) - 1)
    rows = max(1, round(float(np.sqrt(total / (max(heights) + gap)))))
    limit = max(max(widths), 1.15 * total / rows)
    rows_of, x = [[]], 0.0  # piece indices per row
    for k, w in enumerate(widths):
        if x > 0 and x + w > limit:
            rows_of.append([])
            x = 0.0
        rows_of[-1].append(k)
        x += w + gap
    out, top = [None] * len(pieces), 0.0
    for row in rows_of:  # each row's bottom a gap below the row above
        bottom = top - max(heights[k] for k in row)
        x = 0.0
        for k in row:
            lo = boxes[k][0]
            out[k] = np.array([x - lo[0], bottom - lo[1]])
            x += widths[k] + gap
        top = bottom - gap
    return out


def _side_points(piece, r, tolerance: float = DRAW_TOLERANCE) -> np.ndarray:
    """(n, 2) [m] a seam side's outline stretch (its route r), in pick order."""
    lines = piece.polylines(tolerance)
    pts = np.vstack([lines[r.segments[0]]] + [lines[k][1:] for k in r.segments[1:]])
    return pts if r.forward else pts[::-1]


def layout(spec, scale: float) -> dict:
    """The drawing of a GarmentSpec whose seams all route (the session keeps only those), lengths in file units
    (`scale`: metres per unit): {"pieces": [...], "seams": [...]} (docs/studio.md lists the fields)."""
    shift = dict(zip((p.name for p in spec.pieces), shifts(spec.pieces)))
    pieces = []
    for k, piece in enumerate(spec.pieces):
        d = shift[piece.name]
        lines = piece.polylines(DRAW_TOLERANCE)
        outline = np.vstack([q[:-1] for q in lines] + [lines[0][:1]]) + d
        lengths = segment_lengths(piece)
        names = piece.corner_names
        n = len(names)
        lo, hi = outline.min(axis=0), outline.max(axis=0)
        pieces.append({
            "name": piece.name, "index": k, "colour": piece_colour(k),
            "outline": _pts(outline, scale),
            "corners": [{"name": names[i], "at": _pts(piece.corners[i] + d, scale), "uv": _pts(piece.corners[i], scale)}
                        for i in range(n)],
            "sides": [{"index": i, "from": names[i], "to": names[(i + 1) % n], "points": _pts(lines[i] + d, scale),
                       "length": round(float(lengths[i]) / scale, 3)} for i in range(n)],
            # the grain: the pattern's v (up) axis; u across it. Drawn from the middle of the piece's box.
            "grain": {"at": _pts(0.5 * (lo + hi), scale), "size": round(0.25 * float(min(hi - lo)) / scale, 3)},
            "box": [_pts(lo, scale), _pts(hi, scale)],
            "area": round(piece.area() / scale ** 2, 3),
            "perimeter": round(float(lengths.sum()) / scale, 3),
        })
    seams = []
    for number, seam in enumerate(spec.seams, start=1):
        ra, rb = side_lengths(spec, seam)
        entry = {"number": number, "name": seam.name, "tolerance": seam.tolerance,
                 "mismatch": round(mismatch(ra.length, rb.length), 5),
                 "pairs": bool(mismatch(ra.length, rb.length) <= seam.tolerance)}
        for key, side, r in (("a", seam.a, ra), ("b", seam.b, rb)):
            entry[key] = {"piece": side.piece, "from": side.start, "to": side.end, "length": round(r.length / scale, 3),
                          "points": _pts(_side_points(spec.piece(side.piece), r) + shift[side.piece], scale)}
        seams.append(entry)
    return {"pieces": pieces, "seams": seams}
