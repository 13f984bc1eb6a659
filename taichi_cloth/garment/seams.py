"""Seams (Chen 2013): a seam joins a stretch of one piece's outline to a stretch of another's (or of the same
piece, e.g. a sleeve's underarm).

A side of a seam is picked as two corners of a piece, `start` then `end`. The stretch between them is the
shorter way round the outline (in segments; a tie is ambiguous and refused). Its boundary points are stored in
the outline's loop order together with a direction flag that records whether the pick ran with the loop or
against it (Chen 2013's flag); when the two flags differ, side B's list is reversed, so point i of A meets
point i of B and the pick "from the hem up to the armpit" on both pieces never sews crosswise.

Both sides are resampled to the same number of points: `plan_counts` gives every segment of a seam side its
share of one interval count N = round(max(length A, length B) / spacing), in proportion to its length, so the
two sides have N + 1 points each and pair by arc length. Sides whose lengths differ by more than the seam's
tolerance (Chen 2013: a seam that cannot pair) are an error that names the seam.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import PatternError
from .pattern import PatternPiece

DEFAULT_LENGTH_TOLERANCE = 0.1  # relative; sleeve caps are commonly eased by a few per cent onto the armhole


@dataclass(frozen=True)
class SeamSide:
    """piece: piece name; start, end: corner names (or indices) in pick order."""

    piece: str
    start: str | int
    end: str | int


@dataclass(frozen=True)
class Seam:
    """name; a, b: the two sides; tolerance: largest relative length mismatch accepted."""

    name: str
    a: SeamSide
    b: SeamSide
    tolerance: float = DEFAULT_LENGTH_TOLERANCE


@dataclass(frozen=True)
class SideRoute:
    """Where a seam side runs on its piece: the outline segments in loop order and the pick direction.

    segments: tuple of segment indices in loop order (from the loop-first corner to the loop-last one)
    forward:  True if the pick (start -> end) runs with the loop order
    length:   [m] along the outline
    """

    segments: tuple
    forward: bool
    length: float


def _piece(pieces: dict, seam: Seam, side: SeamSide) -> PatternPiece:
    if side.piece not in pieces:
        raise PatternError(f"seam {seam.name!r}: unknown piece {side.piece!r} (pieces: {', '.join(pieces)})")
    return pieces[side.piece]


def route(piece: PatternPiece, seam: Seam, side: SeamSide, lengths: np.ndarray) -> SideRoute:
    """The segments between the side's two corners, the shorter way round (lengths: (S,) [m] per segment)."""
    try:
        i, j = piece.corner_index(side.start), piece.corner_index(side.end)
    except PatternError as err:
        raise PatternError(f"seam {seam.name!r}: {err}") from None
    S = len(piece.segments)
    if i == j:
        raise PatternError(f"seam {seam.name!r}: side on piece {piece.name!r} starts and ends at the same corner "
                           f"{side.start!r}")
    ahead = (j - i) % S  # segments going with the loop from i to j
    if 2 * ahead == S:
        raise PatternError(f"seam {seam.name!r}: corners {side.start!r} and {side.end!r} of piece {piece.name!r} are "
                           "equally far apart both ways round; split the stretch into two seams")
    forward = 2 * ahead < S
    first, n = (i, ahead) if forward else (j, S - ahead)
    segs = tuple((first + k) % S for k in range(n))
    return SideRoute(segs, forward, float(sum(lengths[s] for s in segs)))


def _share(total: int, lengths: np.ndarray) -> np.ndarray:
    """Split `total` intervals over segments in proportion to `lengths`, at least 1 each (largest remainder)."""
    n = len(lengths)
    raw = total * lengths / lengths.sum()
    counts = np.maximum(1, np.floor(raw)).astype(np.int64)
    while counts.sum() < total:
        counts[np.argmax(raw - counts)] += 1
    while counts.sum() > total:
        over = np.where(counts > 1, counts - raw, -np.inf)
        counts[np.argmax(over)] -= 1
    assert counts.sum() == total and n <= total
    return counts


def plan_counts(pieces: dict, seams: list, spacing: float, lengths: dict) -> tuple[dict, dict]:
    """Intervals per outline segment so that every seam's two sides have equal counts.

    pieces:  name -> PatternPiece; seams: list of Seam; spacing [m]; lengths: name -> (S,) segment lengths [m]
    Returns (counts: name -> (S,) int64, routes: seam name -> (SideRoute a, SideRoute b)). Segments not in a
    seam get round(length / spacing). A segment in two seams, an unknown piece or corner, or sides whose
    lengths differ beyond the seam's tolerance raise PatternError naming the seam.
    """
    counts = {name: np.maximum(1, np.round(lengths[name] / spacing)).astype(np.int64) for name in pieces}
    owner: dict = {}
    routes = {}
    for seam in seams:
        ra = route(_piece(pieces, seam, seam.a), seam, seam.a, lengths[seam.a.piece])
        rb = route(_piece(pieces, seam, seam.b), seam, seam.b, lengths[seam.b.piece])
        for side, r in ((seam.a, ra), (seam.b, rb)):
            for s in r.segments:
                key = (side.piece, s)
                if key in owner:
                    raise PatternError(f"seam {seam.name!r}: segment {s} of piece {side.piece!r} is already sewn by "
                                       f"seam {owner[key]!r}")
                owner[key] = seam.name
        mismatch = abs(ra.length - rb.length) / max(ra.length, rb.length)
        if mismatch > seam.tolerance:
            raise PatternError(f"seam {seam.name!r} cannot pair: side {seam.a.piece}:{seam.a.start}->{seam.a.end} is "
                               f"{100 * ra.length:.1f} cm and side {seam.b.piece}:{seam.b.start}->{seam.b.end} is "
                               f"{100 * rb.length:.1f} cm ({100 * mismatch:.1f} % apart, tolerance "
                               f"{100 * seam.tolerance:.0f} %)")
        n = max(int(round(max(ra.length, rb.length) / spacing)), len(ra.segments), len(rb.segments))
        for side, r in ((seam.a, ra), (seam.b, rb)):
            seg_len = np.array([lengths[side.piece][s] for s in r.segments])
            counts[side.piece][list(r.segments)] = _share(n, seg_len)
        routes[seam.name] = (ra, rb)
    return counts, routes


def side_vertices(boundary_segments: list, r: SideRoute) -> np.ndarray:
    """The mesh vertices of a seam side in LOOP order (corners once), from a mesh's per-segment boundary lists."""
    parts = [np.asarray(boundary_segments[s]) for s in r.segments]
    return np.concatenate([parts[0]] + [p[1:] for p in parts[1:]])


def pair_sides(a_loop: np.ndarray, ra: SideRoute, b_loop: np.ndarray, rb: SideRoute, seam_name: str = "") -> np.ndarray:
    """(N+1, 2) pairs (vertex of A, vertex of B): both sides stored in loop order with their pick flags; B is
    reversed when the flags differ (Chen 2013), so point i of A's pick meets point i of B's pick."""
    if len(a_loop) != len(b_loop):
        raise PatternError(f"seam {seam_name!r}: the sides have {len(a_loop)} and {len(b_loop)} points")
    b = b_loop if ra.forward == rb.forward else b_loop[::-1]
    return np.stack([a_loop, b], 1).astype(np.int64)
