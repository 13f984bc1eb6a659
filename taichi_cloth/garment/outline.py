"""Multilevel meshes of an arbitrary 2D pattern outline (docs/algorithms.md, multilevel, "Arbitrary outlines"; ours).

At level L (0-based) the mesh has two parts:

* the *regular* interior: the 4-8 mesh of the rectangle hierarchy (multilevel.hierarchy) laid over the
  outline's bounding rectangle, restricted to the lattice vertices strictly inside the level's boundary
  polygon and farther than ``margin * s_L`` from it, and to the lattice triangles whose three vertices are
  kept. s_L = spacing / 2**(L // 2) is the level's nominal boundary spacing, so the threshold is
  0.5 h_L at even levels and 0.71 h_L at odd ones with the default margin 0.5 (h_L = spacing / 2**(L/2) is
  the leg of the level's right isosceles triangles: even levels are axis-aligned grids of cell h_L with
  alternating diagonals, odd levels the 45-degree tetrakis lattice). The kept region is then cleaned
  until its boundary is one simple loop per component: isolated triangles and 45-degree spikes (a
  triangle with its hypotenuse and a leg on the boundary) are dropped, at a pinch vertex all but the
  largest edge-connected fan, and any triangle with a boundary edge closer than 0.5 * margin * s_L to the
  boundary polygon (a reflex corner of the outline can come close to an edge whose ends are far);
* the irregular *band* between the boundary samples and the kept region: the constrained Delaunay
  triangulation (ear clipping with hole bridges, then Lawson edge flips) of the polygon-with-holes
  "boundary polygon minus kept region". It uses no other vertices and is rebuilt at every level.

The boundary is the caller's list of segments (polylines meeting at the corners, forming one closed loop),
each resampled at uniform arc length with an exact number of intervals count_L = base_count * 2**(L // 2)
(base_count per segment from the caller, so that a seam between two pieces gets matching counts on both
sides, or round(length / spacing)). Corners are always vertices, and the samples are nested: the samples
of level L are every other sample of level L+1 (L odd), or the same samples (L even).

Prolongation tables (Level.parents / weights) map a per-vertex quantity of level L-1 onto level L:
a vertex that coincides with one of level L-1 (a nested boundary sample or a lattice vertex) copies it
(weight 1); a new boundary sample takes 1/2 + 1/2 from the two neighbouring samples of level L-1 along its
segment (so seam partners stay paired and a closed seam stays closed; uv is then off by the boundary's
sagitta); a new interior vertex takes the barycentric weights of the level L-1 triangle that contains it
(or, where it lies outside the level L-1 mesh, of the closest point of the nearest triangle).

Pure numpy; no scipy, no taichi.
"""
from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np

from multilevel.hierarchy import Hierarchy48, Level, identity_tables

MAX_LEVELS = 6
DEFAULT_MARGIN = 0.5
_MAX_LATTICE_POINTS = 20_000_000
_EDGE_CLEAR = 0.5  # kept boundary edges keep 0.5 * margin * s_L clear of the boundary polygon


@dataclass
class OutlineLevel(Level):
    """One level of an outline hierarchy (index 0 = the base). Fields of Level, and:

    boundary_segments: list, one (count_L + 1,) int64 array per input segment: the indices of the vertices
                       along it, corners included, in the direction the segment was given
    boundary_loop:     (m,) int64 the boundary vertices in counter-clockwise order, starting at the first
                       corner; vertices 0..m-1 are the boundary vertices in this order
    regular:           (t,) bool True for a 4-8 triangle (hyp_a, hyp_b, apex) of the interior lattice,
                       False for a band triangle (any counter-clockwise order); regular ones come first
    spacing:           float [m] h_L, the leg length of the level's 4-8 triangles
    diamonds:          all -1 here (band vertices have no diamonds; see Level)
    """

    boundary_segments: list
    boundary_loop: np.ndarray
    regular: np.ndarray
    spacing: float


class OutlineHierarchy(Hierarchy48):
    """The levels of `outline_hierarchy` (levels[0] the coarsest), with the outline they mesh.

    segments:     the validated input polylines (k_i, 2) [m], in the caller's order and orientation
    base_counts:  (S,) int64 intervals per segment at level 0
    spacing:      h_0 [m]
    """

    def __init__(self, levels: list, segments=None, base_counts=None, spacing: float | None = None):
        super().__init__(levels)
        self.segments = segments
        self.base_counts = None if base_counts is None else np.asarray(base_counts, np.int64)
        self.spacing = spacing

    def segment_count(self, level: int, segment: int) -> int:
        """Number of intervals (vertices - 1) of `segment` at `level`."""
        return int(self.base_counts[segment]) * 2 ** (level // 2)


def outline_hierarchy(segments, levels: int, spacing: float, segment_counts=None, *,
                      margin: float = DEFAULT_MARGIN) -> OutlineHierarchy:
    """Nested multilevel meshes of the closed pattern outline made of `segments`.

    segments:       list of (k_i, 2) float polylines [m], k_i >= 2; segment i ends where segment i+1 starts
                    (to 1e-7 of the outline's size), the last ends where the first starts (a single closed
                    polyline is one segment). Counter-clockwise; a clockwise loop is accepted and meshed
                    reversed, with boundary_segments[i] still running in the direction segment i was given.
                    The outline must be a simple polygon.
    levels:         number of levels, 1..6
    spacing:        h_0 [m], the base lattice cell (and the nominal boundary spacing at level 0)
    segment_counts: optional list of ints >= 1, the intervals of each segment at level 0 (seam partners
                    must get equal counts); default max(1, round(length / spacing)). Level L has
                    count * 2**(L // 2) intervals, i.e. count * 2**(L // 2) + 1 vertices with the corners.
    margin:         lattice vertices closer than margin * s_L to the boundary polygon are not kept,
                    s_L = spacing / 2**(L // 2) the nominal boundary spacing of level L (the default 0.5
                    gave the best smallest angles in our trials)

    Returns an OutlineHierarchy of OutlineLevel. Raises ValueError, with one message naming the problem,
    on bad input (open or self-intersecting loop, fewer than 3 points, zero area, levels or spacing out of
    range, bad counts, or a sampling so coarse that the level's boundary polygon self-intersects).
    """
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or not 1 <= levels <= MAX_LEVELS:
        raise ValueError(f"levels must be an integer in 1..{MAX_LEVELS}, got {levels!r}")
    levels = int(levels)
    try:
        h0 = float(spacing)
    except (TypeError, ValueError):
        raise ValueError(f"spacing must be a positive length [m], got {spacing!r}") from None
    if not (math.isfinite(h0) and h0 > 0):
        raise ValueError(f"spacing must be a positive length [m], got {spacing!r}")
    if not (math.isfinite(margin) and 0 < margin < 2):
        raise ValueError(f"margin must lie in (0, 2), got {margin!r}")

    segs, tol = _validate_segments(segments)
    S = len(segs)
    lengths = np.array([_polyline_length(p) for p in segs])
    if segment_counts is None:
        counts = np.maximum(1, np.round(lengths / h0)).astype(np.int64)
    else:
        counts = _validate_counts(segment_counts, S)

    dense = np.concatenate([p[:-1] for p in segs])
    area = _signed_area(dense)
    span = float(np.ptp(dense, axis=0).max())
    if len(dense) < 3:
        raise ValueError(f"an outline needs at least 3 distinct points, got {len(dense)}")
    hit = _self_intersection(dense, tol)
    if hit is not None:
        raise ValueError(f"the outline intersects itself (near ({hit[0]:.6g}, {hit[1]:.6g}) m)")
    if abs(area) <= 1e-12 * span * span:
        raise ValueError("the outline encloses no area")

    reversed_input = area < 0
    if reversed_input:  # mesh the counter-clockwise loop; map the segments back at the end
        isegs = [p[::-1].copy() for p in segs[::-1]]
        icounts = counts[::-1].copy()
    else:
        isegs, icounts = segs, counts

    builder = _Builder(isegs, icounts, levels, h0, margin)
    out = []
    prev = None
    for L in range(levels):
        lev = builder.level(L, prev)
        prev = lev
        out.append(lev)
    if reversed_input:
        for lev in out:
            lev.boundary_segments = [lev.boundary_segments[S - 1 - i][::-1].copy() for i in range(S)]
    return OutlineHierarchy(out, segments=segs, base_counts=counts, spacing=h0)


# ---------------------------------------------------------------------- input
def _validate_segments(segments) -> tuple[list[np.ndarray], float]:
    if isinstance(segments, np.ndarray) and segments.ndim == 2:
        segments = [segments]
    try:
        segs = [np.array(p, dtype=np.float64) for p in segments]
    except (TypeError, ValueError) as exc:
        raise ValueError(f"segments must be a list of (k, 2) point arrays [m]: {exc}") from None
    if not segs:
        raise ValueError("segments is empty: an outline needs at least one polyline")
    for i, p in enumerate(segs):
        if p.ndim != 2 or p.shape[1] != 2:
            raise ValueError(f"segments[{i}] must have shape (k, 2), got {p.shape}")
        if len(p) < 2:
            raise ValueError(f"segments[{i}] needs at least 2 points, got {len(p)}")
        if not np.all(np.isfinite(p)):
            raise ValueError(f"segments[{i}] has non-finite coordinates")
    allp = np.concatenate(segs)
    span = float(np.ptp(allp, axis=0).max())
    if span <= 0:
        raise ValueError("the outline has fewer than 3 distinct points")
    tol = 1e-7 * span
    S = len(segs)
    for i in range(S):
        j = (i + 1) % S
        gap = float(np.linalg.norm(segs[i][-1] - segs[j][0]))
        if gap > tol:
            what = "its own start (a single segment must be a closed polyline)" if S == 1 else \
                f"the start of segments[{j}]"
            raise ValueError(f"the segments do not form a closed loop: segments[{i}] ends at "
                             f"({segs[i][-1][0]:.6g}, {segs[i][-1][1]:.6g}), {gap:.3g} m from {what}")
    out = []
    for i in range(S):
        p = segs[i].copy()
        p[-1] = segs[(i + 1) % S][0]  # snap the shared corners
        # drop repeated points, keeping both corners
        keep = [0]
        for k in range(1, len(p)):
            if np.linalg.norm(p[k] - p[keep[-1]]) > tol:
                keep.append(k)
        if keep[-1] != len(p) - 1:
            if len(keep) > 1:
                keep[-1] = len(p) - 1
            else:
                keep.append(len(p) - 1)
        p = p[keep]
        if _polyline_length(p) <= tol:
            raise ValueError(f"segments[{i}] has zero length")
        out.append(p)
    total = sum(len(p) - 1 for p in out)
    if total < 3:
        raise ValueError(f"an outline needs at least 3 distinct points, got {total}")
    return out, tol


def _validate_counts(segment_counts, S: int) -> np.ndarray:
    try:
        counts = list(segment_counts)
    except TypeError:
        raise ValueError(f"segment_counts must be a list of {S} positive integers") from None
    if len(counts) != S:
        raise ValueError(f"segment_counts has {len(counts)} entries for {S} segments")
    for i, c in enumerate(counts):
        if isinstance(c, bool) or not isinstance(c, (int, np.integer)) or c < 1:
            raise ValueError(f"segment_counts[{i}] must be a positive integer, got {c!r}")
    return np.array(counts, np.int64)


def _polyline_length(p: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def _signed_area(P: np.ndarray) -> float:
    x, y = P[:, 0], P[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _sample_polyline(p: np.ndarray, n: int) -> np.ndarray:
    """(n + 1, 2) points at uniform arc length along polyline p, its end points exact."""
    d = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    s = np.arange(n + 1) * (d[-1] / n)
    k = np.clip(np.searchsorted(d, s, side="right") - 1, 0, len(p) - 2)
    t = ((s - d[k]) / (d[k + 1] - d[k]))[:, None]
    out = (1 - t) * p[k] + t * p[k + 1]
    out[0], out[-1] = p[0], p[-1]
    return out


# ---------------------------------------------------------------------- geometry predicates
def _orient(a, b, c):
    """Twice the signed area of (a, b, c), vectorised over leading axes."""
    return (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])


def _segments_touch(p, q, r, s, eps):
    """Segments p-q and r-s intersect or touch (closed segments), vectorised; eps: length tolerance [m]."""
    def sgn(o, a, b):
        scale = np.linalg.norm(b - a, axis=-1) * eps
        return np.where(o > scale, 1, np.where(o < -scale, -1, 0))
    d1 = sgn(_orient(r, s, p), r, s)
    d2 = sgn(_orient(r, s, q), r, s)
    d3 = sgn(_orient(p, q, r), p, q)
    d4 = sgn(_orient(p, q, s), p, q)
    crossing = (d1 * d2 <= 0) & (d3 * d4 <= 0)
    # the boxes must overlap too, which settles the collinear case (all four signs 0)
    lo1, hi1 = np.minimum(p, q) - eps, np.maximum(p, q) + eps
    lo2, hi2 = np.minimum(r, s) - eps, np.maximum(r, s) + eps
    box = np.all((lo1 <= hi2) & (lo2 <= hi1), axis=-1)
    return crossing & box


def _self_intersection(P: np.ndarray, tol: float):
    """A point where the closed polygon P (n, 2) meets itself, or None when it is simple."""
    n = len(P)
    A, B = P, np.roll(P, -1, axis=0)
    # fold-backs at a vertex (two consecutive edges overlap)
    e0, e1 = A - np.roll(A, 1, axis=0), B - A
    cr = e0[:, 0] * e1[:, 1] - e0[:, 1] * e1[:, 0]
    dot = np.einsum("ij,ij->i", e0, e1)
    fold = (np.abs(cr) <= 1e-12 * np.linalg.norm(e0, axis=1) * np.linalg.norm(e1, axis=1)) & (dot < 0)
    if np.any(fold):
        return P[np.flatnonzero(fold)[0]]
    if n <= 3:
        return None
    lo, hi = np.minimum(A, B) - tol, np.maximum(A, B) + tol
    order = np.argsort(lo[:, 0], kind="stable")
    lo_s, hi_s = lo[order], hi[order]
    # sweep along x: edge i can only meet edges whose x-interval starts before hi_i
    end = np.searchsorted(lo_s[:, 0], hi_s[:, 0], side="right")
    chunk = 4096
    start = 0
    while start < n:
        stop = min(n, start + chunk)
        cnt = end[start:stop] - np.arange(start, stop) - 1
        cnt = np.maximum(cnt, 0)
        ii = np.repeat(np.arange(start, stop), cnt)
        jj = ii + 1 + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
        a, b = order[ii], order[jj]
        ok = np.all((lo[a] <= hi[b]) & (lo[b] <= hi[a]), axis=1)
        adj = (np.abs(a - b) == 1) | (np.abs(a - b) == n - 1)
        a, b = a[ok & ~adj], b[ok & ~adj]
        if len(a):
            hitm = _segments_touch(A[a], B[a], A[b], B[b], tol)
            if np.any(hitm):
                k = np.flatnonzero(hitm)[0]
                return 0.5 * (A[a[k]] + B[a[k]])
        start = stop
    return None


def _point_segment_distance(p, a, b):
    ab = b - a
    t = np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def inside_polygon(points: np.ndarray, P: np.ndarray) -> np.ndarray:
    """(k,) bool: crossing-number point-in-polygon test of points (k, 2) against the closed polygon P."""
    A, B = P, np.roll(P, -1, axis=0)
    inside = np.zeros(len(points), bool)
    for s in range(0, len(points), 2048):
        q = points[s:s + 2048, None, :]
        cond = (A[None, :, 1] > q[..., 1]) != (B[None, :, 1] > q[..., 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            x = A[None, :, 0] + (q[..., 1] - A[None, :, 1]) * (B[None, :, 0] - A[None, :, 0]) \
                / (B[None, :, 1] - A[None, :, 1])
        inside[s:s + 2048] = (np.sum(cond & (q[..., 0] < x), axis=1) % 2) == 1
    return inside


# ---------------------------------------------------------------------- the per-level builder
class _Builder:
    def __init__(self, segs, counts, levels, h0, margin):
        self.segs, self.counts, self.levels, self.h0, self.margin = segs, counts, levels, h0, margin
        self.S = len(segs)
        top = (levels - 1) // 2
        # boundary samples at the finest resolution; coarser levels take every 2**k-th (exactly nested)
        self.fine = [_sample_polyline(p, int(c) * 2 ** top) for p, c in zip(segs, counts)]
        self.top = top
        allp = np.concatenate(segs)
        lo, hi = allp.min(axis=0), allp.max(axis=0)
        ncell = np.maximum(1, np.ceil((hi - lo) / h0 - 1e-9)).astype(np.int64)
        self.ncell = ncell  # base cells of the covering rectangle
        self.origin = 0.5 * (lo + hi) - 0.5 * ncell * h0
        self.M = levels // 2 + 1  # lattice keys are integers in units of h0 / 2**M
        self.unit = h0 / 2 ** self.M
        pts = (ncell[0] * 2 ** ((levels - 1) // 2 + 1) + 1) * (ncell[1] * 2 ** ((levels - 1) // 2 + 1) + 1)
        if pts > _MAX_LATTICE_POINTS:
            raise ValueError(f"spacing {h0:g} m is too fine for an outline of {float((hi - lo).max()):g} m at "
                             f"{levels} levels ({pts} lattice points); use a coarser spacing or fewer levels")
        self.keymaps = {}            # level -> (sorted lattice key codes, their vertex ids)
        self.internal_segments = {}  # level -> boundary_segments of the counter-clockwise loop

    # -- boundary
    def boundary(self, L):
        f = 2 ** (self.top - L // 2)
        loop, seg_idx = [], []
        off = 0
        for k in range(self.S):
            p = self.fine[k][::f]
            n = len(p) - 1
            loop.append(p[:-1])
            seg_idx.append(off + np.arange(n + 1))
            off += n
        m = off
        seg_idx[-1] = seg_idx[-1].copy()
        seg_idx[-1][-1] = 0
        for k in range(self.S - 1):
            assert seg_idx[k][-1] == seg_idx[k + 1][0]
        return np.concatenate(loop), [s.astype(np.int64) for s in seg_idx], m

    # -- lattice of level L: fine index grid (na+1) x (nb+1) with step f units
    def lattice(self, L):
        """The level's lattice: fine index grid (na + 1) x (nb + 1) with step f key units; point (a, b) has
        id a + NA * b (at odd levels only the points with a + b even exist: corners and cell centres)."""
        m = L // 2
        s = 2 ** (self.M - m)
        odd = L % 2 == 1
        f = s // 2 if odd else s
        r = s // f  # fine steps per cell
        nx, ny = int(self.ncell[0]) * 2 ** m, int(self.ncell[1]) * 2 ** m
        return dict(f=f, r=r, nx=nx, ny=ny, na=nx * r, nb=ny * r, NA=nx * r + 1, odd=odd)

    def lattice_triangles(self, lat, keep):
        """The lattice triangles, in (hyp_a, hyp_b, apex) form, whose three vertices are kept."""
        r, nx, ny, NA, odd = lat["r"], lat["nx"], lat["ny"], lat["NA"], lat["odd"]
        k2 = keep.reshape(lat["nb"] + 1, NA)
        corners = k2[0:-1:r, 0:-1:r].astype(np.int8) + k2[0:-1:r, r::r] + k2[r::r, 0:-1:r] + k2[r::r, r::r]
        cand = (corners >= 2) & k2[1::r, 1::r] if odd else corners >= 3  # cells that can hold a kept triangle
        cj, ci = np.nonzero(cand[:ny, :nx])
        a0, b0 = ci * r, cj * r
        v00 = a0 + NA * b0
        v10, v01, v11 = v00 + r, v00 + r * NA, v00 + r + r * NA
        if not odd:
            main = (ci + cj) % 2 == 0
            t1 = np.where(main[:, None], np.stack([v11, v00, v10], 1), np.stack([v01, v10, v11], 1))
            t2 = np.where(main[:, None], np.stack([v00, v11, v01], 1), np.stack([v10, v01, v00], 1))
            tris = np.concatenate([t1, t2])
        else:
            c = v00 + 1 + NA
            tris = np.concatenate([np.stack([v00, v10, c], 1), np.stack([v10, v11, c], 1),
                                   np.stack([v11, v01, c], 1), np.stack([v01, v00, c], 1)])
        tris = tris.astype(np.int64).reshape(-1, 3)
        return tris[np.all(keep[tris], axis=1)]

    def key_code(self, keys):
        """One int64 per lattice key (increasing with the vertex order of a level)."""
        return keys[:, 1] * (1 << 31) + keys[:, 0]

    def key_uv(self, keys):
        return self.origin + keys * self.unit

    def kept_mask(self, lat, Q, thr):
        f, na, nb = lat["f"], lat["na"], lat["nb"]
        step = f * self.unit
        ox, oy = self.origin
        A, B = Q, np.roll(Q, -1, axis=0)
        # inside: scanline crossings per lattice row
        inside = np.zeros((nb + 1, na + 1), bool)
        ys = oy + np.arange(nb + 1) * f * self.unit
        xs = ox + np.arange(na + 1) * f * self.unit
        ylo, yhi = np.minimum(A[:, 1], B[:, 1]), np.maximum(A[:, 1], B[:, 1])
        b_lo = np.clip(np.ceil((ylo - oy) / step - 1e-9).astype(np.int64) - 1, 0, nb + 1)
        b_hi = np.clip(np.floor((yhi - oy) / step + 1e-9).astype(np.int64) + 2, 0, nb + 1)
        cnt = np.maximum(b_hi - b_lo, 0)
        e = np.repeat(np.arange(len(A)), cnt)
        b = b_lo[e] + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))
        y = ys[b]
        cross = (A[e, 1] > y) != (B[e, 1] > y)
        e, b, y = e[cross], b[cross], y[cross]
        x = A[e, 0] + (y - A[e, 1]) * (B[e, 0] - A[e, 0]) / (B[e, 1] - A[e, 1])
        order = np.lexsort((x, b))
        b, x = b[order], x[order]
        starts = np.searchsorted(b, np.arange(nb + 2))
        for row in range(nb + 1):
            xr = x[starts[row]:starts[row + 1]]
            if len(xr):
                inside[row] = (np.searchsorted(xr, xs, side="left") % 2) == 1
        if lat["odd"]:  # only corners (even, even) and centres (odd, odd) exist
            inside[0::2, 1::2] = False
            inside[1::2, 0::2] = False
        # near: lattice points within thr of an edge, by a window around each edge
        a_lo = np.clip(np.floor((np.minimum(A[:, 0], B[:, 0]) - thr - ox) / step).astype(np.int64), 0, na)
        a_hi = np.clip(np.ceil((np.maximum(A[:, 0], B[:, 0]) + thr - ox) / step).astype(np.int64), 0, na)
        b_lo = np.clip(np.floor((ylo - thr - oy) / step).astype(np.int64), 0, nb)
        b_hi = np.clip(np.ceil((yhi + thr - oy) / step).astype(np.int64), 0, nb)
        wa, wb = a_hi - a_lo + 1, b_hi - b_lo + 1
        cnt = wa * wb
        e = np.repeat(np.arange(len(A)), cnt)
        loc = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        ia = a_lo[e] + loc % wa[e]
        ib = b_lo[e] + loc // wa[e]
        live = inside[ib, ia]
        e, ia, ib = e[live], ia[live], ib[live]
        p = np.stack([xs[ia], ys[ib]], 1)
        near = _point_segment_distance(p, A[e], B[e]) <= thr
        keep = inside.copy()
        keep[ib[near], ia[near]] = False
        return keep.ravel()  # index a + NA * b

    def level(self, L, prev):
        h = self.h0 * 2.0 ** (-L / 2)
        Q, seg_idx, m = self.boundary(L)
        span = float(np.ptp(Q, axis=0).max())
        if m < 3:
            raise ValueError(f"level {L} has only {m} boundary samples; give the segments larger counts")
        hit = _self_intersection(Q, 1e-9 * span)
        if hit is not None:
            raise ValueError(f"at level {L} the boundary sampled at the given counts intersects itself near "
                             f"({hit[0]:.6g}, {hit[1]:.6g}) m: the outline has features finer than the "
                             f"sampling; use a smaller spacing or larger segment_counts")
        if _signed_area(Q) <= 0:
            raise ValueError(f"at level {L} the boundary sampled at the given counts turns clockwise: the "
                             f"outline has features finer than the sampling; use a smaller spacing or "
                             f"larger segment_counts")
        lat = self.lattice(L)
        keep = self.kept_mask(lat, Q, self.margin * self.h0 * 2.0 ** (-(L // 2)))
        tris = self.lattice_triangles(lat, keep)
        NA = lat["NA"]
        keys_of = lambda pid: np.stack([pid % NA, pid // NA], 1) * lat["f"]  # noqa: E731
        uv_of = lambda pid: self.key_uv(keys_of(pid))  # noqa: E731
        tris = _clean_region(tris, uv_of, Q, span, _EDGE_CLEAR * self.margin * self.h0 * 2.0 ** (-(L // 2)))

        used = np.unique(tris)
        keys = keys_of(used)
        n = m + len(used)
        reg = (m + np.searchsorted(used, tris)).astype(np.int64).reshape(-1, 3)
        uv = np.concatenate([Q, self.key_uv(keys)]) if len(used) else Q.copy()

        # band: boundary polygon minus the kept region
        kept_loops = _region_loops(reg)
        band = _triangulate_band(uv, np.arange(m), kept_loops, span)
        triangles = np.concatenate([reg, band]).astype(np.int64) if len(band) else reg.astype(np.int64)
        regular = np.r_[np.ones(len(reg), bool), np.zeros(len(band), bool)]

        a = 0.5 * _orient(uv[triangles[:, 0]], uv[triangles[:, 1]], uv[triangles[:, 2]])
        if np.any(a <= 0) or abs(a.sum() - _signed_area(Q)) > 1e-9 * abs(_signed_area(Q)):
            raise RuntimeError(f"internal error: level {L} does not tile its boundary polygon")

        keymap = (self.key_code(keys), m + np.arange(len(keys)))  # sorted codes -> vertex ids
        if prev is None:
            parents, weights = identity_tables(n)
        else:
            parents, weights = self.prolongation(L, prev, uv, m, seg_idx, keys)
        self.keymaps[L] = keymap
        lev = OutlineLevel(uv=uv, triangles=triangles, parents=parents, weights=weights,
                           diamonds=np.full((n, 4), -1, np.int64), boundary_segments=seg_idx,
                           boundary_loop=np.arange(m, dtype=np.int64), regular=regular, spacing=h)
        self.internal_segments[L] = [s.copy() for s in seg_idx]
        return lev

    def prolongation(self, L, prev, uv, m, seg_idx, keys):
        n = len(uv)
        parents = np.full((n, 3), -1, np.int64)
        weights = np.zeros((n, 3))
        pseg = self.internal_segments[L - 1]
        for k in range(self.S):
            cur, old = seg_idx[k], pseg[k]
            if len(cur) == len(old):
                parents[cur, 0] = old
                weights[cur, 0] = 1.0
            else:
                assert len(cur) - 1 == 2 * (len(old) - 1)
                parents[cur[0::2], 0] = old
                weights[cur[0::2], 0] = 1.0
                parents[cur[1::2], 0], parents[cur[1::2], 1] = old[:-1], old[1:]
                weights[cur[1::2], :2] = 0.5
        codes, ids = self.keymaps[L - 1]
        mine = self.key_code(keys)
        pos = np.minimum(np.searchsorted(codes, mine), max(len(codes) - 1, 0))
        same = (codes[pos] == mine) if len(codes) else np.zeros(len(mine), bool)
        parents[m + np.flatnonzero(same), 0] = ids[pos[same]]
        weights[m + np.flatnonzero(same), 0] = 1.0
        todo = m + np.flatnonzero(~same)
        if len(todo):
            tri, bary = locate(prev.uv, prev.triangles, uv[todo])
            vid = prev.triangles[tri]
            bary[np.abs(bary) < 1e-13] = 0.0
            bary /= bary.sum(axis=1, keepdims=True)
            # live parents first
            order = np.argsort(bary == 0, axis=1, kind="stable")
            bary = np.take_along_axis(bary, order, 1)
            vid = np.take_along_axis(vid, order, 1)
            vid[bary == 0] = -1
            parents[todo], weights[todo] = vid, bary
        return parents, weights


# ---------------------------------------------------------------------- kept-region cleanup and loops
def _edge_table(tris):
    """Directed edges (3t, 2), their triangle (3t,), and the undirected use count of each (3t,)."""
    d = tris[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    big = int(tris.max()) + 1
    key = np.minimum(d[:, 0], d[:, 1]) * big + np.maximum(d[:, 0], d[:, 1])
    _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    return d, np.repeat(np.arange(len(tris)), 3), cnt[inv.reshape(-1)]


def _clean_region(tris, uv_of, Q, span, clear):
    """Drop lattice triangles until the region's boundary is simple loops that keep clear of polygon Q."""
    A, B = Q, np.roll(Q, -1, axis=0)
    eps = 1e-9 * span
    for _ in range(10_000):
        if len(tris) == 0:
            return tris
        d, owner, cnt = _edge_table(tris)
        bnd = cnt == 1
        # spikes and strips: triangles with two or three boundary edges
        nb = np.bincount(owner[bnd], minlength=len(tris))
        # isolated triangles, and 45-degree spikes (the hypotenuse, edge 0, and a leg on the boundary)
        bad = (nb >= 3) | ((nb == 2) & bnd[0::3])
        if np.any(bad):
            tris = tris[~bad]
            continue
        # pinch vertices: more than one boundary loop passes through them; keep the largest fan
        deg = np.bincount(d[bnd].ravel())
        pinch = np.flatnonzero(deg > 2)
        if len(pinch):
            drop = np.zeros(len(tris), bool)
            for v in pinch:
                fan = np.flatnonzero(np.any(tris == v, axis=1))
                groups = _fan_groups(tris[fan], v)
                big = max(groups, key=len)
                for g in groups:
                    if g is not big:
                        drop[fan[g]] = True
            tris = tris[~drop]
            continue
        # boundary edges that touch the polygon
        p, q = uv_of(d[bnd, 0]), uv_of(d[bnd, 1])
        hit = _edges_touching(p, q, A, B, eps, clear)
        if np.any(hit):
            drop = np.zeros(len(tris), bool)
            drop[owner[bnd][hit]] = True
            tris = tris[~drop]
            continue
        return tris
    raise RuntimeError("internal error: the kept region did not settle")


def _fan_groups(fan, v):
    """Edge-connected groups (lists of row indices) of the triangles `fan` around vertex v."""
    others = [set(int(x) for x in t if x != v) for t in fan]
    parent = list(range(len(fan)))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i
    for i in range(len(fan)):
        for j in range(i + 1, len(fan)):
            if others[i] & others[j]:
                parent[find(i)] = find(j)
    groups = {}
    for i in range(len(fan)):
        groups.setdefault(find(i), []).append(i)
    return list(groups.values())


def _edges_touching(p, q, A, B, eps, clear=0.0):
    """(k,) bool: segment p[i]-q[i] meets some segment A[j]-B[j] or passes within `clear` [m] of one."""
    out = np.zeros(len(p), bool)
    pad = eps + clear
    lo1, hi1 = np.minimum(p, q) - pad, np.maximum(p, q) + pad
    lo2, hi2 = np.minimum(A, B), np.maximum(A, B)
    for s in range(0, len(p), 1024):
        sl = slice(s, s + 1024)
        box = (lo1[sl, None, 0] <= hi2[None, :, 0]) & (lo2[None, :, 0] <= hi1[sl, None, 0]) & \
              (lo1[sl, None, 1] <= hi2[None, :, 1]) & (lo2[None, :, 1] <= hi1[sl, None, 1])
        i, j = np.nonzero(box)
        if len(i):
            a, b, c, d = p[sl][i], q[sl][i], A[j], B[j]
            t = _segments_touch(a, b, c, d, eps)
            if clear > 0:
                dist = np.minimum(np.minimum(_point_segment_distance(a, c, d), _point_segment_distance(b, c, d)),
                                  np.minimum(_point_segment_distance(c, a, b), _point_segment_distance(d, a, b)))
                t |= dist <= clear
            out[s + i[t]] = True
    return out


def _region_loops(tris):
    """Boundary loops of a triangle region whose boundary vertices have exactly two boundary edges: a list
    of int64 arrays, each in the region's counter-clockwise sense (outer loops ccw, holes cw)."""
    if len(tris) == 0:
        return []
    d, _, cnt = _edge_table(tris)
    nxt = {int(a): int(b) for a, b in d[cnt == 1]}
    loops, seen = [], set()
    for s in nxt:
        if s in seen:
            continue
        loop, v = [], s
        while v not in seen:
            seen.add(v)
            loop.append(v)
            v = nxt[v]
        loops.append(np.array(loop, np.int64))
    return loops


# ---------------------------------------------------------------------- band triangulation
def _triangulate_band(uv, outer, kept_loops, span):
    """Constrained Delaunay triangulation of polygon `outer` (ccw vertex ids) minus the kept region whose
    boundary is `kept_loops` (ccw outer loops, cw holes). Returns (t, 3) int64 ccw."""
    band_outer = [np.asarray(outer)]
    band_holes = []
    for lp in kept_loops:
        if _signed_area(uv[lp]) > 0:
            band_holes.append(lp[::-1])          # a kept component: a hole of the band (cw)
        else:
            band_outer.append(lp[::-1])          # a hole of the kept region: its own band piece (ccw)
    areas = [_signed_area(uv[o]) for o in band_outer]
    assign = [[] for _ in band_outer]
    for hole in band_holes:
        best = None
        for i, o in enumerate(band_outer):
            if inside_polygon(uv[hole[:1]], uv[o])[0] and (best is None or areas[i] < areas[best]):
                best = i
        if best is None:
            raise RuntimeError("internal error: a kept component lies outside the boundary polygon")
        assign[best].append(hole)
    constrained = set()
    for lp in band_outer + band_holes:
        for a, b in zip(lp, np.roll(lp, -1)):
            constrained.add((min(int(a), int(b)), max(int(a), int(b))))
    tris = []
    eps = 1e-10 * span
    for o, holes in zip(band_outer, assign):
        ring = _bridge_holes(uv, [int(x) for x in o], [[int(x) for x in h] for h in holes], eps)
        tris.extend(_earclip(uv, ring, eps))
    tris = _lawson(uv, tris, constrained)
    return np.array(tris, np.int64).reshape(-1, 3)


def _bridge_holes(uv, outer, holes, eps):
    """Join the cw `holes` to the ccw `outer` ring by zero-width slits: one weakly simple ring of ids."""
    ring = list(outer)
    if not holes:
        return ring
    loops = [np.array(outer)] + [np.array(h) for h in holes]
    edges = np.concatenate([np.stack([lp, np.roll(lp, -1)], 1) for lp in loops])
    allv = np.unique(np.concatenate(loops))
    for hole in sorted(holes, key=lambda hh: -max(uv[hh][:, 0])):
        h_ids = np.array(hole)
        counts = {}
        for v in ring:
            counts[v] = counts.get(v, 0) + 1
        r_ids = np.array([v for v in dict.fromkeys(ring) if counts[v] == 1])
        found = None
        for hv, ov in _bridge_candidates(uv, h_ids, r_ids):
            if _bridge_ok(uv, ov, hv, edges, allv, loops, eps):
                found = (ov, hv)
                break
        if found is None:
            raise RuntimeError("internal error: no bridge from a kept component to the boundary")
        ov, hv = found
        k = ring.index(ov)
        j = hole.index(hv)
        ring = ring[:k + 1] + hole[j:] + hole[:j + 1] + ring[k:]
        edges = np.concatenate([edges, [[ov, hv]]])
    return ring


def _bridge_candidates(uv, h_ids, r_ids, near=8, chunk=512):
    """(hole vertex, ring vertex) pairs, shortest first: first each hole vertex with its `near` nearest
    ring vertices, then (if none of those will do) every other pair."""
    k = min(near, len(r_ids))
    dist, hv, ov = [], [], []
    for s in range(0, len(h_ids), chunk):
        D = np.linalg.norm(uv[h_ids[s:s + chunk], None, :] - uv[None, r_ids, :], axis=2)
        j = np.argpartition(D, k - 1, axis=1)[:, :k]
        dist.append(np.take_along_axis(D, j, 1).ravel())
        hv.append(np.repeat(h_ids[s:s + chunk], k))
        ov.append(r_ids[j].ravel())
    dist, hv, ov = np.concatenate(dist), np.concatenate(hv), np.concatenate(ov)
    order = np.argsort(dist, kind="stable")
    tried = set()
    for i in order:
        tried.add((int(hv[i]), int(ov[i])))
        yield int(hv[i]), int(ov[i])
    for h in h_ids:
        D = np.linalg.norm(uv[r_ids] - uv[h], axis=1)
        for i in np.argsort(D, kind="stable"):
            if (int(h), int(r_ids[i])) not in tried:
                yield int(h), int(r_ids[i])


def _bridge_ok(uv, o, h, edges, allv, loops, eps):
    """The segment o-h meets no loop edge or vertex but at its ends and runs inside the band."""
    p, q = uv[o], uv[h]
    inc = (edges[:, 0] == o) | (edges[:, 1] == o) | (edges[:, 0] == h) | (edges[:, 1] == h)
    e = edges[~inc]
    if np.any(_segments_touch(np.broadcast_to(p, (len(e), 2)), np.broadcast_to(q, (len(e), 2)),
                              uv[e[:, 0]], uv[e[:, 1]], eps)):
        return False
    others = allv[(allv != o) & (allv != h)]
    if len(others) and np.any(_point_segment_distance(uv[others], np.broadcast_to(p, (len(others), 2)),
                                                      np.broadcast_to(q, (len(others), 2))) <= eps):
        return False
    mid = 0.5 * (p + q)[None]
    if not inside_polygon(mid, uv[loops[0]])[0]:
        return False
    return not any(inside_polygon(mid, uv[lp])[0] for lp in loops[1:])


def _earclip(uv, ring, eps):
    """Ear clipping of a weakly simple ccw ring of vertex ids (duplicates from hole bridges allowed).

    Ears are clipped best first (largest smallest angle), which keeps the result close to the Delaunay
    triangulation that _lawson then reaches; a plain scan finishes whatever the queue leaves."""
    n = len(ring)
    ids = np.array(ring, np.int64)
    P = uv[ids]
    prv = np.r_[n - 1, np.arange(n - 1)]
    nxt = np.r_[np.arange(1, n), 0]
    alive = np.ones(n, bool)
    scale = eps * eps * 1e4
    X, Y = P[:, 0].tolist(), P[:, 1].tolist()

    def convex(i):
        a, c = prv[i], nxt[i]
        return (X[i] - X[a]) * (Y[c] - Y[a]) - (Y[i] - Y[a]) * (X[c] - X[a]) > scale

    def quality(i):  # smallest angle of the ear at i
        a, c = prv[i], nxt[i]
        best = math.pi
        for p, q, r in ((a, i, c), (i, c, a), (c, a, i)):
            ux, uy, vx, vy = X[q] - X[p], Y[q] - Y[p], X[r] - X[p], Y[r] - Y[p]
            best = min(best, math.atan2(abs(ux * vy - uy * vx), ux * vx + uy * vy))
        return best

    def is_ear(i):
        if not cvx[i]:
            return False
        a, c = prv[i], nxt[i]
        cand = np.flatnonzero(alive & ~cvx)
        cand = cand[(ids[cand] != ids[a]) & (ids[cand] != ids[i]) & (ids[cand] != ids[c])]
        if not len(cand):
            return True
        q = P[cand]
        pa, pi, pc = P[a], P[i], P[c]
        inside = (_orient(pa, pi, q) >= -scale) & (_orient(pi, pc, q) >= -scale) & (_orient(pc, pa, q) >= -scale)
        return not np.any(inside)

    cvx = _orient(P[prv], P, P[nxt]) > scale
    tris = []
    remaining = n

    def drop(i):
        nonlocal remaining
        a, c = prv[i], nxt[i]
        nxt[a], prv[c] = c, a
        alive[i] = False
        remaining -= 1

    def tidy(i):
        # merge repeated ids and remove zero-width slits around position i; returns a live position
        changed = True
        while changed and remaining > 3:
            changed = False
            if ids[nxt[i]] == ids[i]:
                drop(nxt[i])
                changed = True
            elif ids[prv[i]] == ids[nxt[i]]:
                a = prv[i]
                drop(i)
                drop(nxt[a])
                i = a
                changed = True
        return i

    def clip(i):
        a, c = prv[i], nxt[i]
        tris.append((int(ids[a]), int(ids[i]), int(ids[c])))
        drop(i)
        a = tidy(a)
        touched = (prv[a], a, nxt[a])
        for j in touched:
            cvx[j] = convex(j)
        return a, touched

    stamp = np.zeros(n, np.int64)  # a heap entry is stale once its vertex's neighbourhood changed
    heap = [(-quality(i), i, 0) for i in range(n) if cvx[i]]
    heapq.heapify(heap)
    while heap and remaining > 3:
        _, i, st = heapq.heappop(heap)
        if not alive[i] or st != stamp[i] or not is_ear(i):
            continue
        _, touched = clip(i)
        for j in touched:
            stamp[j] += 1
            if alive[j] and cvx[j]:
                heapq.heappush(heap, (-quality(j), int(j), int(stamp[j])))
    i = int(np.flatnonzero(alive)[0])
    misses = 0
    while remaining > 3:
        if is_ear(i):
            a, _ = clip(i)
            i = nxt[a]
            misses = 0
        else:
            i = nxt[i]
            misses += 1
            if misses > 2 * remaining + 2:
                raise RuntimeError("internal error: ear clipping of the band found no ear")
    a, i, c = prv[i], i, nxt[i]
    if _orient(P[a], P[i], P[c]) > scale:
        tris.append((int(ids[a]), int(ids[i]), int(ids[c])))
    elif _orient(P[a], P[i], P[c]) < -scale:
        raise RuntimeError("internal error: ear clipping left an inverted triangle")
    return tris


def _lawson(uv, tris, constrained):
    """Flip the unconstrained edges of a triangulation until it is (constrained) Delaunay."""
    tris = [list(t) for t in tris]
    emap = {}
    for ti, t in enumerate(tris):
        for k in range(3):
            a, b = t[k], t[(k + 1) % 3]
            emap.setdefault((min(a, b), max(a, b)), []).append(ti)
    stack = [e for e, ts in emap.items() if len(ts) == 2 and e not in constrained]

    X, Y = uv[:, 0].tolist(), uv[:, 1].tolist()

    def angle(p, q, r):  # angle at p in triangle p, q, r
        ux, uy, vx, vy = X[q] - X[p], Y[q] - Y[p], X[r] - X[p], Y[r] - Y[p]
        return math.atan2(abs(ux * vy - uy * vx), ux * vx + uy * vy)

    def orient(a, b, c):
        return (X[b] - X[a]) * (Y[c] - Y[a]) - (Y[b] - Y[a]) * (X[c] - X[a])

    flips = 0
    while stack:
        e = stack.pop()
        ts = emap.get(e)
        if ts is None or len(ts) != 2 or e in constrained:
            continue
        t1, t2 = ts
        T1, T2 = tris[t1], tris[t2]
        k = next(k for k in range(3) if {T1[k], T1[(k + 1) % 3]} == set(e))
        p, q, c = T1[k], T1[(k + 1) % 3], T1[(k + 2) % 3]
        d = next(x for x in T2 if x != p and x != q)
        if angle(c, p, q) + angle(d, q, p) <= math.pi + 1e-10:
            continue
        if orient(p, d, c) <= 0 or orient(d, q, c) <= 0:
            continue
        tris[t1] = [p, d, c]
        tris[t2] = [d, q, c]
        del emap[e]
        emap[(min(c, d), max(c, d))] = [t1, t2]
        # the edges d-q (was in t2) and q-c (was in t1) swap owners
        for a, b, old, new in ((d, q, t2, t2), (q, c, t1, t2), (p, d, t2, t1), (c, p, t1, t1)):
            key = (min(a, b), max(a, b))
            lst = emap[key]
            lst[lst.index(old)] = new
            if len(lst) == 2 and key not in constrained:
                stack.append(key)
        flips += 1
        if flips > 100 * len(tris) + 1000:
            raise RuntimeError("internal error: Delaunay flipping did not converge")
    return tris


# ---------------------------------------------------------------------- point location
def locate(uv, tris, pts):
    """For each point (k, 2): the triangle of (uv, tris) that contains it, or else the nearest one, and the
    barycentric weights (k, 3) of the point (or of its closest point on that triangle); all >= 0, sum 1."""
    A, B, C = uv[tris[:, 0]], uv[tris[:, 1]], uv[tris[:, 2]]
    lo = np.minimum(np.minimum(A, B), C)
    hi = np.maximum(np.maximum(A, B), C)
    cell = float(np.max(hi - lo)) * (1 + 1e-9)
    org = np.minimum(lo.min(axis=0), pts.min(axis=0)) - cell
    ncx = int(np.floor((max(hi[:, 0].max(), pts[:, 0].max()) - org[0]) / cell)) + 2
    ilo = np.floor((lo - org) / cell).astype(np.int64)
    ihi = np.floor((hi - org) / cell).astype(np.int64)
    pairs_t, pairs_c = [], []
    for dx in (0, 1):
        for dy in (0, 1):
            cx, cy = ilo[:, 0] + dx, ilo[:, 1] + dy
            ok = (cx <= ihi[:, 0]) & (cy <= ihi[:, 1])
            pairs_t.append(np.flatnonzero(ok))
            pairs_c.append((cx + ncx * cy)[ok])
    pt = np.concatenate(pairs_t)
    pc = np.concatenate(pairs_c)
    o = np.argsort(pc, kind="stable")
    pt, pc = pt[o], pc[o]
    ip = np.floor((pts - org) / cell).astype(np.int64)
    qc = ip[:, 0] + ncx * ip[:, 1]
    s, e = np.searchsorted(pc, qc, "left"), np.searchsorted(pc, qc, "right")
    cnt = e - s
    qi = np.repeat(np.arange(len(pts)), cnt)
    ti = pt[np.repeat(s, cnt) + (np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt))]
    bary = _barycentric(A[ti], B[ti], C[ti], pts[qi])
    score = bary.min(axis=1)
    best_t = np.full(len(pts), -1, np.int64)
    best_s = np.full(len(pts), -np.inf)
    order = np.lexsort((score, qi))  # per point, the best score last
    last = np.r_[qi[order][1:] != qi[order][:-1], True] if len(order) else np.zeros(0, bool)
    sel = order[last]
    best_t[qi[sel]] = ti[sel]
    best_s[qi[sel]] = score[sel]
    out_b = np.zeros((len(pts), 3))
    inside = best_s >= -1e-12
    if np.any(inside):
        b = _barycentric(A[best_t[inside]], B[best_t[inside]], C[best_t[inside]], pts[inside])
        b = np.clip(b, 0, None)
        out_b[inside] = b / b.sum(axis=1, keepdims=True)
    for k in np.flatnonzero(~inside):  # outside the mesh: the nearest triangle (rare; brute force)
        p = pts[k]
        best = (np.inf, -1, None)
        for (P0, P1, w0, w1) in ((A, B, 0, 1), (B, C, 1, 2), (C, A, 2, 0)):
            d = P1 - P0
            t = np.clip(np.einsum("ij,ij->i", p - P0, d) / np.einsum("ij,ij->i", d, d), 0, 1)
            dist = np.linalg.norm(P0 + t[:, None] * d - p, axis=1)
            j = int(np.argmin(dist))
            if dist[j] < best[0]:
                w = np.zeros(3)
                w[w0], w[w1] = 1 - t[j], t[j]
                best = (dist[j], j, w)
        best_t[k] = best[1]
        out_b[k] = best[2]
    return best_t, out_b


def _barycentric(A, B, C, P):
    det = _orient(A, B, C)
    l0 = _orient(P, B, C) / det
    l1 = _orient(A, P, C) / det
    return np.stack([l0, l1, 1 - l0 - l1], 1)
