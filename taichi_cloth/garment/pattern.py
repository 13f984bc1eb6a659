"""2D garment pattern pieces: closed outlines made of line, polyline, arc and B-spline segments.

Hsiao 2006 (section 3): piece outlines are B-spline curves. Chen 2013: closed DXF polylines, splines and
arcs become pieces (see `taichi_cloth.garment.dxf`). All coordinates are float64 METRES; constructors that take
user numbers take a `units` argument ("m", "cm", "mm", "in") and convert once, on the way in.

Pure numpy (no taichi): pieces are built and checked before any simulation exists.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from taichi_cloth.errors import PatternError

__all__ = [
    "UNITS",
    "PatternPiece",
    "Segment",
    "bspline_eval",
    "open_uniform_knots",
    "periodic_knots",
    "unit_scale",
]

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
SEGMENT_KINDS = ("line", "polyline", "bspline", "arc")


def unit_scale(units: str) -> float:
    """Metres per unit of `units` (one of UNITS' keys): "mm" -> 0.001."""
    try:
        return UNITS[units]
    except (KeyError, TypeError):
        raise PatternError(f"unknown length unit {units!r}: use one of {', '.join(UNITS)}") from None


# ----------------------------------------------------------------------------------------------------------
# B-splines
# ----------------------------------------------------------------------------------------------------------

def open_uniform_knots(k: int, degree: int) -> np.ndarray:
    """Clamped open-uniform knot vector on [0, 1] for k control points: (k + degree + 1,) float64.

    The first and last knots repeat degree + 1 times, so the curve starts at the first control point and ends
    at the last one."""
    if degree < 1 or k < degree + 1:
        raise PatternError(f"a degree-{degree} B-spline needs at least {degree + 1} control points, got {k}")
    interior = np.linspace(0.0, 1.0, k - degree + 1)[1:-1]
    return np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)])


def periodic_knots(m: int, degree: int) -> np.ndarray:
    """Uniform (unclamped) knot vector of a closed periodic B-spline with m distinct control points.

    The control polygon is wrapped (m + degree points: the first `degree` repeated at the end), so the knot
    vector has m + 2 * degree + 1 entries; the curve's domain [knots[degree], knots[m + degree]] is [0, 1].
    """
    k = m + degree
    return (np.arange(k + degree + 1, dtype=np.float64) - degree) / m


def _check_bspline(control, degree, knots, weights):
    """Validated (control (k, d) float64, degree, knots (k+degree+1,) float64, weights (k,) or None)."""
    pts = np.asarray(control, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] < 1:
        raise PatternError(f"B-spline control points must be a (k, 2) array, got shape {pts.shape}")
    if int(degree) != degree or degree < 1:
        raise PatternError(f"B-spline degree must be an integer >= 1, got {degree!r}")
    degree = int(degree)
    k = len(pts)
    if k < degree + 1:
        raise PatternError(f"a degree-{degree} B-spline needs at least {degree + 1} control points, got {k}")
    if knots is None:
        u = open_uniform_knots(k, degree)
    else:
        u = np.asarray(knots, dtype=np.float64).ravel()
        if len(u) != k + degree + 1:
            raise PatternError(f"a degree-{degree} B-spline with {k} control points needs {k + degree + 1} "
                               f"knots, got {len(u)}")
        if not np.all(np.isfinite(u)) or np.any(np.diff(u) < 0):
            raise PatternError("B-spline knots must be finite and non-decreasing")
        if not u[degree] < u[k]:
            raise PatternError(f"B-spline knot vector has an empty domain [{u[degree]}, {u[k]}]")
    w = None
    if weights is not None:
        w = np.asarray(weights, dtype=np.float64).ravel()
        if len(w) != k:
            raise PatternError(f"B-spline has {k} control points but {len(w)} weights")
        if not np.all(np.isfinite(w)) or np.any(w <= 0):
            raise PatternError("B-spline weights must be finite and > 0")
    return pts, degree, u, w


def _find_span(u: np.ndarray, degree: int, k: int, t: np.ndarray) -> np.ndarray:
    """Knot span index s (u[s] <= t < u[s+1], nonempty) for each t in the domain: (n,) int."""
    nonempty = np.nonzero(u[degree:k] < u[degree + 1:k + 1])[0] + degree
    s = np.searchsorted(u, t, side="right") - 1
    # t == domain end falls past the last nonempty span: evaluate it as that span's right end
    return np.clip(s, nonempty[0], nonempty[-1])


def _de_boor(h: np.ndarray, degree: int, u: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Non-rational B-spline with control points h (k, d) at parameters t (n,): (n, d). No checks."""
    k = len(h)
    t = np.clip(t, u[degree], u[k])
    s = _find_span(u, degree, k, t)
    d = h[s[:, None] - degree + np.arange(degree + 1)]  # (n, degree+1, d) fancy index -> a copy
    for r in range(1, degree + 1):
        for j in range(degree, r - 1, -1):
            i = s - degree + j
            den = u[i + degree - r + 1] - u[i]
            alpha = np.where(den > 0, (t - u[i]) / np.where(den > 0, den, 1.0), 0.0)[:, None]
            d[:, j] = (1.0 - alpha) * d[:, j - 1] + alpha * d[:, j]
    return d[:, degree]


def _homogeneous(pts: np.ndarray, w: np.ndarray | None) -> np.ndarray:
    """Control points in homogeneous form (k, d+1) = (w*P, w); plain copy when non-rational."""
    if w is None:
        return pts.copy()
    return np.hstack([pts * w[:, None], w[:, None]])


def bspline_eval(control, degree: int, knots=None, weights=None, t=None) -> np.ndarray:
    """Evaluate a (rational) B-spline by de Boor's algorithm.

    control: (k, 2) float [m]; degree >= 1 with k >= degree + 1; knots: None (clamped open-uniform on [0, 1])
    or (k + degree + 1,) non-decreasing; weights: None or (k,) > 0 (NURBS); t: (n,) parameters, clipped to the
    domain [knots[degree], knots[k]] (required; keyword-friendly position kept from the spec).
    Returns (n, 2) float64 points.
    """
    if t is None:
        raise PatternError("bspline_eval needs the parameters t")
    pts, degree, u, w = _check_bspline(control, degree, knots, weights)
    t = np.atleast_1d(np.asarray(t, dtype=np.float64)).ravel()
    out = _de_boor(_homogeneous(pts, w), degree, u, t)
    if w is not None:
        out = out[:, :-1] / out[:, -1:]
    return out


def _derivative_ctrl(h: np.ndarray, degree: int, u: np.ndarray) -> tuple[np.ndarray, int, np.ndarray]:
    """Control points, degree and knots of the derivative of a non-rational B-spline (k-1, d), p-1, u[1:-1]."""
    den = u[degree + 1:len(h) + degree] - u[1:len(h)]
    scale = np.where(den > 0, degree / np.where(den > 0, den, 1.0), 0.0)
    return (h[1:] - h[:-1]) * scale[:, None], degree - 1, u[1:-1]


def _gauss(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Legendre nodes and weights on [0, 1]."""
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


# ----------------------------------------------------------------------------------------------------------
# Segment
# ----------------------------------------------------------------------------------------------------------

def _point(p, what: str = "point") -> np.ndarray:
    a = np.asarray(p, dtype=np.float64).reshape(-1)
    if a.shape != (2,):
        raise PatternError(f"{what} must be [x, y], got {p!r}")
    return a


@dataclass(frozen=True, eq=False)
class Segment:
    """One curve of an outline, from one corner to the next (metres).

    kind:   "line" | "polyline" | "bspline" | "arc"
    points: (k, 2) float64 [m], read-only
        line:     (2, 2) start, end
        polyline: (k>=2, 2) start, interior points..., end
        bspline:  (k>=degree+1, 2) control points; knots=None means clamped open-uniform (starts at points[0],
                  ends at points[-1]); given knots (len k+degree+1, non-decreasing) run the curve over
                  [knots[degree], knots[-degree-1]] and start/end are the evaluated curve ends
        arc:      (2, 2) start, end; `bulge` = tan(sweep/4) (DXF convention: > 0 counter-clockwise from start
                  to end, 0 = straight, 1 = half circle)
    degree:  B-spline degree (bspline only; ignored otherwise)
    knots:   tuple of floats or None (bspline only)
    bulge:   float (arc only)
    weights: tuple of floats > 0 or None: NURBS weights (bspline only; DXF arcs-as-splines use them)
    """

    kind: str
    points: np.ndarray
    degree: int = 3
    knots: tuple | None = None
    bulge: float = 0.0
    weights: tuple | None = None

    def __post_init__(self):
        if self.kind not in SEGMENT_KINDS:
            raise PatternError(f"unknown segment kind {self.kind!r}: use one of {', '.join(SEGMENT_KINDS)}")
        pts = np.array(self.points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 2:
            raise PatternError(f"{self.kind} segment points must be a (k, 2) array, got shape {pts.shape}")
        pts.setflags(write=False)
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "bulge", float(self.bulge))
        if self.kind in ("line", "arc") and len(pts) != 2:
            raise PatternError(f"{self.kind} segment needs exactly 2 points (start, end), got {len(pts)}")
        if self.kind == "polyline" and len(pts) < 2:
            raise PatternError(f"polyline segment needs at least 2 points, got {len(pts)}")
        if self.kind == "bspline":
            _, degree, _, _ = _check_bspline(pts, self.degree, self.knots, self.weights)
            object.__setattr__(self, "degree", degree)
            if self.knots is not None:
                object.__setattr__(self, "knots", tuple(float(x) for x in np.ravel(self.knots)))
            if self.weights is not None:
                object.__setattr__(self, "weights", tuple(float(x) for x in np.ravel(self.weights)))
        elif self.knots is not None or self.weights is not None:
            raise PatternError(f"{self.kind} segment takes no knots or weights (bspline only)")

    # -- constructors ------------------------------------------------------------------------------------
    @classmethod
    def line(cls, start, end) -> "Segment":
        return cls("line", np.array([_point(start), _point(end)]))

    @classmethod
    def arc(cls, start, end, bulge: float) -> "Segment":
        return cls("arc", np.array([_point(start), _point(end)]), bulge=bulge)

    # -- identity ----------------------------------------------------------------------------------------
    def __eq__(self, other):
        if not isinstance(other, Segment):
            return NotImplemented
        return (self.kind == other.kind and self.points.shape == other.points.shape
                and bool(np.array_equal(self.points, other.points)) and self.degree == other.degree
                and self.knots == other.knots and self.bulge == other.bulge and self.weights == other.weights)

    def __hash__(self):
        return hash((self.kind, self.points.tobytes(), self.degree, self.knots, self.bulge, self.weights))

    # -- B-spline internals ------------------------------------------------------------------------------
    def _spline(self):
        """(control (k,2), degree, knots array, weights array or None) of a bspline segment."""
        u = open_uniform_knots(len(self.points), self.degree) if self.knots is None else np.array(self.knots)
        w = None if self.weights is None else np.array(self.weights)
        return self.points, self.degree, u, w

    def _domain(self) -> tuple[float, float]:
        _, p, u, _ = self._spline()
        return float(u[p]), float(u[len(self.points)])

    def _clamped(self) -> tuple[bool, bool]:
        """Whether the curve starts at points[0] / ends at points[-1] exactly (knot multiplicity degree+1)."""
        if self.knots is None:
            return True, True
        _, p, u, _ = self._spline()
        return bool(np.all(u[:p + 1] == u[0])), bool(np.all(u[-p - 1:] == u[-1]))

    def _eval(self, t: np.ndarray) -> np.ndarray:
        pts, p, u, w = self._spline()
        out = _de_boor(_homogeneous(pts, w), p, u, np.asarray(t, dtype=np.float64))
        return out if w is None else out[:, :-1] / out[:, -1:]

    def _eval_d1(self, t: np.ndarray) -> np.ndarray:
        """Derivative dC/dt (n, 2) of a bspline segment (quotient rule for NURBS)."""
        pts, p, u, w = self._spline()
        h = _homogeneous(pts, w)
        dh, dp, du = _derivative_ctrl(h, p, u)
        a = _de_boor(h, p, u, t)
        da = _de_boor(dh, dp, du, t)
        if w is None:
            return da
        return (da[:, :2] * a[:, 2:] - a[:, :2] * da[:, 2:]) / a[:, 2:] ** 2

    def _spans(self) -> np.ndarray:
        """(m, 2) parameter intervals of the nonempty knot spans of a bspline segment."""
        _, p, u, _ = self._spline()
        k = len(self.points)
        dom = u[p:k + 1]
        uniq = np.unique(dom)
        return np.stack([uniq[:-1], uniq[1:]], axis=1)

    # -- arc internals -----------------------------------------------------------------------------------
    def _arc_geometry(self) -> tuple[np.ndarray, float, float, float]:
        """(centre (2,), radius, start angle, signed sweep) of an arc segment with nonzero bulge."""
        p0, p1 = self.points
        b = self.bulge
        chord = p1 - p0
        length = float(np.hypot(*chord))
        sweep = 4.0 * math.atan(b)
        left = np.array([-chord[1], chord[0]]) / length
        # centre offset along the chord's left normal: (L/2) cot(sweep/2) = L (1 - b^2) / (4 b)
        centre = 0.5 * (p0 + p1) + left * (length * (1.0 - b * b) / (4.0 * b))
        radius = length * (1.0 + b * b) / (4.0 * abs(b))
        a0 = math.atan2(p0[1] - centre[1], p0[0] - centre[0])
        return centre, radius, a0, sweep

    def _is_straight_arc(self) -> bool:
        return self.bulge == 0.0 or bool(np.array_equal(self.points[0], self.points[1]))

    # -- public geometry ---------------------------------------------------------------------------------
    @property
    def start(self) -> np.ndarray:
        """(2,) float64 first point of the curve [m]."""
        if self.kind != "bspline" or self._clamped()[0]:
            return self.points[0].copy()
        return self._eval(np.array([self._domain()[0]]))[0]

    @property
    def end(self) -> np.ndarray:
        """(2,) float64 last point of the curve [m]."""
        if self.kind != "bspline" or self._clamped()[1]:
            return self.points[-1].copy()
        return self._eval(np.array([self._domain()[1]]))[0]

    def sample(self, tolerance: float = 1e-4) -> np.ndarray:
        """Dense polyline (n >= 2, 2) float64 [m] from start to end whose chords stay within `tolerance` [m]
        of the true curve. Endpoints are exactly `start` and `end`."""
        if not tolerance > 0:
            raise PatternError(f"sampling tolerance must be > 0, got {tolerance!r}")
        if self.kind == "line":
            out = self.points.copy()
        elif self.kind == "polyline":
            out = self.points.copy()
        elif self.kind == "arc":
            out = self._sample_arc(tolerance)
        else:
            out = self._sample_bspline(tolerance)
        out[0], out[-1] = self.start, self.end
        return out

    def _sample_arc(self, tolerance: float) -> np.ndarray:
        if self._is_straight_arc():
            return self.points.copy()
        centre, radius, a0, sweep = self._arc_geometry()
        # the sagitta of a step of angle h is r (1 - cos(h/2)); keep it below the tolerance
        h = 2.0 * math.acos(max(1.0 - tolerance / radius, 0.0))
        n = max(1, math.ceil(abs(sweep) / h))
        ang = a0 + sweep * np.linspace(0.0, 1.0, n + 1)
        return centre + radius * np.stack([np.cos(ang), np.sin(ang)], axis=1)

    def _sample_bspline(self, tolerance: float) -> np.ndarray:
        """Adaptive bisection in parameter: split an interval while a probe at 1/4, 1/2 or 3/4 of it lies
        farther than half the tolerance from its chord (the half is a margin for unprobed points)."""
        spans = self._spans()
        # start from a few intervals per knot span so inflections inside a span are not missed
        f = np.linspace(0.0, 1.0, 5)
        t = np.unique(np.concatenate([a + (b - a) * f for a, b in spans]))
        lo, hi = t[:-1], t[1:]
        # the intervals always partition the domain, so their left ends plus the domain end are the samples
        done_lo = []
        probes = np.array([0.25, 0.5, 0.75])
        for _ in range(40):
            if len(lo) == 0:
                break
            ends = self._eval(np.concatenate([lo, hi]))
            a, b = ends[:len(lo)], ends[len(lo):]
            tp = lo[:, None] + (hi - lo)[:, None] * probes  # (m, 3)
            q = self._eval(tp.ravel()).reshape(len(lo), 3, 2)
            dev = _point_segment_distance(q, a[:, None, :], b[:, None, :]).max(axis=1)
            bad = (dev > 0.5 * tolerance) & (hi - lo > 1e-14 * max(1.0, abs(hi).max()))
            done_lo.append(lo[~bad])
            mid = 0.5 * (lo[bad] + hi[bad])
            lo, hi = np.concatenate([lo[bad], mid]), np.concatenate([mid, hi[bad]])
        done_lo.append(lo)
        t = np.unique(np.concatenate(done_lo + [np.array([spans[-1, 1]])]))
        return self._eval(t)

    def length(self, tolerance: float = 1e-5) -> float:
        """Arc length [m]: exact for lines, polylines and arcs; Gauss-Legendre quadrature of |C'| refined
        until two levels agree to `tolerance` [m] for B-splines."""
        if self.kind in ("line", "polyline"):
            return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum())
        if self.kind == "arc":
            if self._is_straight_arc():
                return float(np.linalg.norm(self.points[1] - self.points[0]))
            _, radius, _, sweep = self._arc_geometry()
            return abs(sweep) * radius
        x, w = _gauss(8)
        spans = self._spans()
        prev = None
        for level in range(12):
            n_sub = 2 ** level
            f = np.arange(n_sub + 1) / n_sub
            a = (spans[:, :1] + (spans[:, 1:] - spans[:, :1]) * f[None, :-1]).ravel()
            b = (spans[:, :1] + (spans[:, 1:] - spans[:, :1]) * f[None, 1:]).ravel()
            t = (a[:, None] + (b - a)[:, None] * x).ravel()
            speed = np.linalg.norm(self._eval_d1(t), axis=1).reshape(len(a), len(x))
            total = float(((b - a) * (speed @ w)).sum())
            if prev is not None and abs(total - prev) < tolerance:
                return total
            prev = total
        return prev

    def green_area(self) -> float:
        """Contribution of this curve to a loop's signed area, 1/2 * integral of (x dy - y dx) [m^2] (exact:
        closed form for lines and arcs, Gauss-Legendre of the polynomial integrand for B-splines)."""
        if self.kind in ("line", "polyline") or (self.kind == "arc" and self._is_straight_arc()):
            p = self.points
            return 0.5 * float(np.sum(p[:-1, 0] * p[1:, 1] - p[1:, 0] * p[:-1, 1]))
        if self.kind == "arc":
            (x0, y0), (x1, y1) = self.points
            _, radius, _, sweep = self._arc_geometry()
            # chord term plus the signed circular segment between the chord and the arc
            return 0.5 * (x0 * y1 - x1 * y0) + 0.5 * radius ** 2 * (sweep - math.sin(sweep))
        # x y' - y x' is a polynomial of degree 2p-1 per span (p+1 Gauss points are exact); NURBS are
        # rational, so use more points on sub-intervals (converges to round-off for sane weights)
        rational = self.weights is not None
        x, w = _gauss(self.degree + 1 if not rational else 16)
        n_sub = 1 if not rational else 8
        spans = self._spans()
        f = np.arange(n_sub + 1) / n_sub
        a = (spans[:, :1] + (spans[:, 1:] - spans[:, :1]) * f[None, :-1]).ravel()
        b = (spans[:, :1] + (spans[:, 1:] - spans[:, :1]) * f[None, 1:]).ravel()
        t = (a[:, None] + (b - a)[:, None] * x).ravel()
        c, d = self._eval(t), self._eval_d1(t)
        integrand = (c[:, 0] * d[:, 1] - c[:, 1] * d[:, 0]).reshape(len(a), len(x))
        return 0.5 * float(((b - a) * (integrand @ w)).sum())

    # -- transforms --------------------------------------------------------------------------------------
    def reversed(self) -> "Segment":
        """The same curve run from end to start (bspline: reversed control points and mirrored knots;
        arc: bulge negated)."""
        if self.kind == "bspline":
            knots = None
            if self.knots is not None:
                u = np.array(self.knots)
                knots = tuple((u[0] + u[-1]) - u[::-1])
            weights = None if self.weights is None else self.weights[::-1]
            return Segment("bspline", self.points[::-1], degree=self.degree, knots=knots, weights=weights)
        return Segment(self.kind, self.points[::-1], degree=self.degree, bulge=-self.bulge)

    def _with_points(self, pts: np.ndarray, bulge: float | None = None) -> "Segment":
        return Segment(self.kind, pts, degree=self.degree, knots=self.knots,
                       bulge=self.bulge if bulge is None else bulge, weights=self.weights)

    def scaled(self, s: float) -> "Segment":
        """Uniform scale about the origin by s != 0 (a negative s is a 180 degree turn: bulge unchanged)."""
        if not (s != 0 and math.isfinite(s)):
            raise PatternError(f"scale factor must be finite and nonzero, got {s!r}")
        return self._with_points(self.points * float(s))

    def translated(self, d) -> "Segment":
        """Shifted by d (2,) [m]."""
        return self._with_points(self.points + _point(d, "offset"))

    def mirrored_x(self) -> "Segment":
        """Reflected x -> -x. Reflection flips the turning sense, so an arc's bulge is negated; the direction
        of travel is kept (the piece-level mirror re-orients the loop)."""
        return self._with_points(self.points * np.array([-1.0, 1.0]), bulge=-self.bulge)

    def mapped(self, matrix, offset=(0.0, 0.0)) -> "Segment":
        """Moved by p -> matrix @ p + offset, matrix (2, 2) a rotation or a reflection (orthogonal). A reflection
        (det < 0) flips the turning sense: an arc's bulge is negated; the direction of travel is kept."""
        m = np.asarray(matrix, dtype=np.float64)
        return self._with_points(self.points @ m.T + _point(offset, "offset"),
                                 bulge=-self.bulge if np.linalg.det(m) < 0 else self.bulge)

    def _moved_end(self, which: int, p: np.ndarray) -> "Segment":
        """Copy with its start (which=0) or end (which=-1) moved to p; only for movable ends (see dxf)."""
        pts = self.points.copy()
        pts[which] = p
        return self._with_points(pts)

    def end_movable(self, which: int) -> bool:
        """Whether start (which=0) or end (which=-1) is a stored point that can be moved exactly."""
        if self.kind != "bspline":
            return True
        return self._clamped()[0 if which == 0 else 1]


def _point_segment_distance(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points q (..., 2) to segments a-b (..., 2) (broadcast): (...) float64."""
    ab = b - a
    den = np.sum(ab * ab, axis=-1)
    s = np.where(den > 0, np.sum((q - a) * ab, axis=-1) / np.where(den > 0, den, 1.0), 0.0)
    s = np.clip(s, 0.0, 1.0)
    return np.linalg.norm(q - (a + s[..., None] * ab), axis=-1)


# ----------------------------------------------------------------------------------------------------------
# PatternPiece
# ----------------------------------------------------------------------------------------------------------

_CORNER_KEYS = ("at", "name", "bspline", "polyline", "bulge", "degree")
_CURVE_KEYS = ("bspline", "polyline", "bulge")


@dataclass
class PatternPiece:
    """A closed outline of segments: segments[i].end == segments[i+1].start, and the last segment ends at the
    first one's start. Either direction is accepted (`orientation` tells which); corner i is segments[i].start.

    name: str; segments: list[Segment]; corner_names: list[str] (len == len(segments); default "c0", "c1", ...);
    grain, fold: the piece's grain line and fold (mirror) line as drawn, ((x0, y0), (x1, y1)) [m] or None: what
    `upright` turns v along and `unfolded` mirrors the piece across (the DXF reader sets them from AAMA layers 7
    and 6).

    The plain constructor does not validate (so broken pieces can be built and inspected); the from_*
    constructors and the DXF reader call `validate()`.
    """

    name: str
    segments: list
    corner_names: list = field(default_factory=list)
    grain: tuple | None = None
    fold: tuple | None = None

    def __post_init__(self):
        self.name = str(self.name)
        self.segments = list(self.segments)
        for i, s in enumerate(self.segments):
            if not isinstance(s, Segment):
                raise PatternError(f"pattern piece '{self.name}': segment {i} is a {type(s).__name__}, "
                                   f"not a Segment")
        if not self.corner_names:
            self.corner_names = [f"c{i}" for i in range(len(self.segments))]
        self.corner_names = [str(n) for n in self.corner_names]
        if len(self.corner_names) != len(self.segments):
            raise PatternError(f"pattern piece '{self.name}': {len(self.corner_names)} corner names for "
                               f"{len(self.segments)} segments")

    # -- constructors ------------------------------------------------------------------------------------
    @classmethod
    def from_corners(cls, name: str, corners: Sequence[Mapping[str, Any]], units: str = "m") -> "PatternPiece":
        """Piece from a TOML-style corner list. Each corner is a dict:
            "at": [x, y] (required), "name": str (optional), and at most one of
            "bspline": [[x, y], ...] interior control points to the next corner (clamped; "degree" optional,
                       default 3, lowered to len(control) - 1 when there are few points),
            "polyline": [[x, y], ...] interior points to the next corner,
            "bulge": b, an arc to the next corner (b = tan(sweep/4), > 0 counter-clockwise; 0 = a line);
        otherwise a straight line to the next corner. Coordinates in `units`; the piece is in metres."""
        scale = unit_scale(units)
        where = f"pattern piece '{name}'"
        if isinstance(corners, (str, bytes)) or not isinstance(corners, Sequence) or len(corners) == 0:
            raise PatternError(f"{where}: 'corners' must be a non-empty list of corner tables")
        parsed = [_parse_corner(where, i, c, scale) for i, c in enumerate(corners)]
        segments, names = [], []
        for i, (at, cname, curve) in enumerate(parsed):
            nxt = parsed[(i + 1) % len(parsed)][0]
            segments.append(_corner_segment(where, i, at, nxt, curve))
            names.append(cname if cname is not None else f"c{i}")
        piece = cls(name, segments, names)
        piece.validate()
        return piece

    @classmethod
    def from_polygon(cls, name: str, points, units: str = "m", corner_names=None) -> "PatternPiece":
        """Piece of straight lines through points (n, 2) in `units` (not repeated at the end)."""
        pts = _points_array(points, f"pattern piece '{name}': polygon") * unit_scale(units)
        if len(pts) >= 2 and np.array_equal(pts[0], pts[-1]):
            pts = pts[:-1]  # a closing duplicate would make a zero-length segment
        segs = [Segment("line", np.array([pts[i], pts[(i + 1) % len(pts)]])) for i in range(len(pts))]
        piece = cls(name, segs, list(corner_names) if corner_names is not None else [])
        piece.validate()
        return piece

    @classmethod
    def from_bspline(cls, name: str, control_points, degree: int = 3, units: str = "m") -> "PatternPiece":
        """Piece whose whole outline is ONE closed periodic uniform B-spline (Hsiao 2006) through the control
        polygon control_points (m, 2) in `units` (not repeated at the end): a single "bspline" segment with
        the first `degree` control points wrapped to the end and an unclamped uniform knot vector, so
        start == end and the curve is C^(degree-1) everywhere, the seam included. One corner, "c0"."""
        where = f"pattern piece '{name}'"
        pts = _points_array(control_points, f"{where}: control points") * unit_scale(units)
        if int(degree) != degree or degree < 1:
            raise PatternError(f"{where}: B-spline degree must be an integer >= 1, got {degree!r}")
        degree = int(degree)
        if len(pts) < max(3, degree + 1):
            raise PatternError(f"{where}: a closed degree-{degree} B-spline needs at least "
                               f"{max(3, degree + 1)} control points, got {len(pts)}")
        wrapped = np.vstack([pts, pts[:degree]])
        seg = Segment("bspline", wrapped, degree=degree, knots=tuple(periodic_knots(len(pts), degree)))
        piece = cls(name, [seg], ["c0"])
        piece.validate()
        return piece

    # -- corners -----------------------------------------------------------------------------------------
    @property
    def n_corners(self) -> int:
        return len(self.segments)

    @property
    def corners(self) -> np.ndarray:
        """(n, 2) float64 corner positions [m] (corner i = segments[i].start)."""
        return np.array([s.start for s in self.segments]).reshape(-1, 2)

    def corner_index(self, ref) -> int:
        """Index of a corner given by name (str) or index (int, negative counts from the end)."""
        n = len(self.segments)
        if isinstance(ref, (int, np.integer)) and not isinstance(ref, bool):
            if -n <= ref < n:
                return int(ref) % n
            raise PatternError(f"pattern piece '{self.name}': corner index {ref} out of range (it has {n} "
                               f"corners)")
        if isinstance(ref, str) and ref in self.corner_names:
            return self.corner_names.index(ref)
        raise PatternError(f"pattern piece '{self.name}': no corner {ref!r}; corners are: "
                           f"{', '.join(self.corner_names)}")

    # -- geometry ----------------------------------------------------------------------------------------
    def size(self) -> float:
        """Diagonal of the bounding box of all stored points [m] (scale for relative tolerances)."""
        pts = np.vstack([s.points for s in self.segments])
        return float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))

    def polylines(self, tolerance: float = 1e-4) -> list:
        """One sampled polyline (n_i >= 2, 2) float64 [m] per segment (see Segment.sample), snapped so that
        polyline i starts exactly at corner i and ends exactly at corner i+1."""
        corners = self.corners
        out = []
        for i, seg in enumerate(self.segments):
            p = seg.sample(tolerance)
            p[0], p[-1] = corners[i], corners[(i + 1) % len(corners)]
            out.append(p)
        return out

    def outline(self, tolerance: float = 1e-4) -> np.ndarray:
        """Closed sampled outline (n, 2) float64 [m] in loop order, each point once (the first point, corner 0,
        is not repeated at the end): the polylines() joined."""
        return np.vstack([p[:-1] for p in self.polylines(tolerance)])

    def signed_area(self) -> float:
        """Signed area [m^2]: > 0 counter-clockwise, < 0 clockwise (exact Green's theorem per segment)."""
        return float(sum(s.green_area() for s in self.segments))

    def area(self) -> float:
        """Enclosed area [m^2], positive."""
        return abs(self.signed_area())

    def perimeter(self, tolerance: float = 1e-6) -> float:
        """Outline length [m]."""
        return float(sum(s.length(tolerance) for s in self.segments))

    @property
    def orientation(self) -> int:
        """+1 counter-clockwise, -1 clockwise (0 for a zero-area outline)."""
        a = self.signed_area()
        return int(np.sign(a))

    # -- checks ------------------------------------------------------------------------------------------
    def validate(self, tolerance: float | None = None) -> None:
        """Raise PatternError (one message naming the piece) for: no segments, non-finite coordinates,
        duplicate corner names, an open outline (gap above `tolerance` [m], default 1e-6 * size), a
        self-intersecting outline, or zero area."""
        where = f"pattern piece '{self.name}'"
        n = len(self.segments)
        if n < 1:
            raise PatternError(f"{where}: the outline has no segments")
        for i, s in enumerate(self.segments):
            values = [s.points.ravel(), [s.bulge], s.knots or (), s.weights or ()]
            if not all(np.all(np.isfinite(np.asarray(v, dtype=np.float64))) for v in values):
                raise PatternError(f"{where}: segment {i} (from corner '{self.corner_names[i]}') has "
                                   f"non-finite coordinates")
        seen = {}
        for i, cname in enumerate(self.corner_names):
            if not cname:
                raise PatternError(f"{where}: corner {i} has an empty name")
            if cname in seen:
                raise PatternError(f"{where}: duplicate corner name '{cname}' (corners {seen[cname]} and {i})")
            seen[cname] = i
        size = self.size()
        tol = 1e-6 * size if tolerance is None else float(tolerance)
        for i, s in enumerate(self.segments):
            j = (i + 1) % n
            gap = float(np.linalg.norm(s.end - self.segments[j].start))
            if gap > tol:
                raise PatternError(
                    f"{where}: the outline is open: segment {i} (corner '{self.corner_names[i]}' -> "
                    f"'{self.corner_names[j]}') ends {gap * 1e3:.4g} mm away from the start of segment {j} "
                    f"(corner '{self.corner_names[j]}'), tolerance {tol * 1e3:.3g} mm")
        if size == 0:
            raise PatternError(f"{where}: the outline has zero area (all its points coincide)")
        hit = self._self_intersection(min(1e-4, 1e-3 * size), size)
        if hit is not None:
            raise PatternError(f"{where}: the outline intersects itself near ({hit[0]:.6g}, {hit[1]:.6g}) m")
        if self.area() <= 1e-12 * size * size:
            raise PatternError(f"{where}: the outline has zero area")

    def _self_intersection(self, tolerance: float, size: float):
        """Approximate point (2,) where the sampled outline crosses or touches itself, or None."""
        poly = self.outline(tolerance)
        # drop (near-)repeated points: a zero-length edge would make its two neighbours look crossing
        keep = np.ones(len(poly), dtype=bool)
        last = poly[0]
        for i in range(1, len(poly)):
            if np.linalg.norm(poly[i] - last) <= 1e-9 * size:
                keep[i] = False
            else:
                last = poly[i]
        poly = poly[keep]
        if len(poly) > 1 and np.linalg.norm(poly[-1] - poly[0]) <= 1e-9 * size:
            poly = poly[:-1]
        return _polygon_self_intersection(poly, 1e-12 * size * size)

    # -- transforms --------------------------------------------------------------------------------------
    def transformed(self, scale: float = 1.0, offset=(0.0, 0.0), mirror: bool = False,
                    name: str | None = None) -> "PatternPiece":
        """Copy mapped by p -> scale * (mirror ? (-x, y) : p) + offset. A mirror flips the loop direction,
        so the loop is then re-run backwards (corner 0 stays corner 0; names follow their corners) to keep
        the orientation sign."""
        if not (scale > 0 and math.isfinite(scale)):
            raise PatternError(f"pattern piece '{self.name}': scale must be finite and > 0, got {scale!r}")
        segs = [s.scaled(scale) for s in self.segments]
        names = list(self.corner_names)
        if mirror:
            segs = [s.mirrored_x() for s in segs]
            n = len(segs)
            # reversed segment j runs old segment n-1-j backwards, so it starts at old corner (n-j) % n
            segs = [segs[n - 1 - j].reversed() for j in range(n)]
            names = [names[(n - j) % n] for j in range(n)]
        segs = [s.translated(offset) for s in segs]

        def move(line):
            return None if line is None else _line(scale * np.asarray(line) * ([-1.0, 1.0] if mirror else 1.0)
                                                   + _point(offset, "offset"))

        return PatternPiece(self.name if name is None else name, segs, names, move(self.grain), move(self.fold))

    def rotated(self, angle: float) -> "PatternPiece":
        """Copy turned by `angle` [deg] counter-clockwise about the origin (grain and fold lines with it)."""
        a = math.radians(float(angle))
        m = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])

        def turn(line):
            return None if line is None else _line(np.asarray(line) @ m.T)

        return PatternPiece(self.name, [s.mapped(m) for s in self.segments], list(self.corner_names),
                            turn(self.grain), turn(self.fold))

    def upright(self, rotate: float | None = None) -> "PatternPiece":
        """The piece turned so that its grain line runs along +v (from the line's first point to its second),
        or by `rotate` [deg] counter-clockwise when given; unchanged without either. Pattern CAD often lays a
        piece on its side: its grain line, not its outline, says which way is up."""
        if rotate is not None:
            return self.rotated(rotate)
        if self.grain is None:
            return self
        (x0, y0), (x1, y1) = self.grain
        return self.rotated(90.0 - math.degrees(math.atan2(y1 - y0, x1 - x0)))

    def inset(self, distance: float, tolerance: float = 1e-4) -> "PatternPiece":
        """The outline moved `distance` [m] inwards, square to itself: a cut line with its seam allowance taken
        off gives the sew line. Straight edges stay lines; curves become polylines through their points sampled
        within `tolerance` [m], each moved along the mean of its two edges' normals (a mitre, exact for straight
        edges); each corner moves to where its two moved edges meet. PatternError naming the piece when the
        allowance is not a length >= 0 or leaves no outline (the piece is narrower than twice it)."""
        if not (math.isfinite(distance) and distance >= 0):
            raise PatternError(f"pattern piece '{self.name}': a seam allowance must be a length >= 0, got {distance!r}")
        if distance == 0:
            return self
        lines = self.polylines(tolerance)
        starts = np.cumsum([0] + [len(p) - 1 for p in lines])
        pts = np.vstack([p[:-1] for p in lines])
        edge = np.roll(pts, -1, axis=0) - pts
        normal = np.c_[-edge[:, 1], edge[:, 0]] / np.linalg.norm(edge, axis=1, keepdims=True)
        normal *= self.orientation  # inwards: left of a counter-clockwise loop
        before = np.roll(normal, 1, axis=0)  # the normal of the edge that ends at each point
        moved = pts + distance * (normal + before) / (1.0 + np.einsum("ij,ij->i", normal, before))[:, None]
        segs = []
        for i, seg in enumerate(self.segments):
            run = moved[np.arange(starts[i], starts[i + 1] + 1) % len(moved)]
            segs.append(Segment("line", run) if seg.kind == "line" else Segment("polyline", run))
        piece = PatternPiece(self.name, segs, list(self.corner_names), self.grain, self.fold)
        if piece.orientation != self.orientation or piece.area() >= self.area():
            raise PatternError(f"pattern piece '{self.name}': a seam allowance of {100 * distance:g} cm leaves no "
                               f"outline")
        try:
            piece.validate()
        except PatternError as exc:
            raise PatternError(f"pattern piece '{self.name}': with a seam allowance of {100 * distance:g} cm taken "
                               f"off: {str(exc).split(': ', 1)[-1]}") from None
        return piece

    def unfolded(self, tolerance: float | None = None) -> "PatternPiece":
        """The whole piece of a half drawn on a fold: the outline without its edge on the fold line, then its
        mirror image across that line (corner `name` mirrored as `name_mirror`; the two corners on the fold keep
        their names). PatternError naming the piece when it has no fold line or the line is not an edge of it.
        tolerance [m]: how far an edge's ends may lie off the fold line (default 1e-6 of the piece's size)."""
        if self.fold is None:
            raise PatternError(f"pattern piece '{self.name}' has no fold line to unfold")
        a, b = (np.asarray(p, dtype=np.float64) for p in self.fold)
        d = (b - a) / max(np.linalg.norm(b - a), 1e-300)
        normal = np.array([-d[1], d[0]])
        tol = 1e-6 * self.size() if tolerance is None else tolerance
        n = len(self.segments)
        on = [s.kind in ("line", "polyline") and bool(np.all(np.abs((s.points - a) @ normal) <= tol))
              for s in self.segments]
        if not any(on) or all(on):
            raise PatternError(f"pattern piece '{self.name}': its fold line from {tuple(np.round(a, 4))} to "
                               f"{tuple(np.round(b, 4))} m is not an edge of its outline")
        # the run of edges on the fold, cyclically: from corner p (its start) to corner q (its end)
        start = next(i for i in range(n) if on[i] and not on[i - 1])
        end = start
        while on[(end + 1) % n]:
            end = (end + 1) % n
        if sum(on) != (end - start) % n + 1:
            raise PatternError(f"pattern piece '{self.name}': its outline meets the fold line in more than one "
                               f"stretch, so it is not a half on a fold")
        first = (end + 1) % n
        order = [(first + k) % n for k in range(n - sum(on))]
        half = [self.segments[i] for i in order]
        names = [self.corner_names[i] for i in order]
        mirror = np.eye(2) - 2.0 * np.outer(normal, normal)
        offset = a - mirror @ a
        back = [s.mapped(mirror, offset).reversed() for s in reversed(half)]
        # the fold's two corners are shared: make the junctions exact
        back[0] = back[0]._moved_end(0, half[-1].end) if back[0].end_movable(0) else back[0]
        back[-1] = back[-1]._moved_end(-1, half[0].start) if back[-1].end_movable(-1) else back[-1]
        back_names = [self.corner_names[start]] + [f"{nm}_mirror" for nm in reversed(names[1:])]
        return PatternPiece(self.name, half + back, names + back_names, self.grain, None)


# ----------------------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------------------

def _line(points) -> tuple:
    """((x0, y0), (x1, y1)) of a (2, 2) array, as plain floats."""
    (x0, y0), (x1, y1) = np.asarray(points, dtype=np.float64)
    return (float(x0), float(y0)), (float(x1), float(y1))


def _points_array(value, where: str) -> np.ndarray:
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise PatternError(f"{where}: expected a list of [x, y] pairs, got {value!r}") from None
    if a.ndim != 2 or a.shape[1] != 2:
        raise PatternError(f"{where}: expected a list of [x, y] pairs, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise PatternError(f"{where}: coordinates must be finite")
    return a


def _parse_corner(where: str, i: int, c, scale: float):
    """(at (2,) [m], name or None, curve) of one corner table; curve = None | (key, value)."""
    if not isinstance(c, Mapping):
        raise PatternError(f"{where}: corner {i} must be a table with 'at', got {c!r}")
    for key in c:
        if key not in _CORNER_KEYS:
            raise PatternError(f"{where}: corner {i}: unknown key '{key}' (allowed: {', '.join(_CORNER_KEYS)})")
    if "at" not in c:
        raise PatternError(f"{where}: corner {i}: missing key 'at'")
    at = _points_array([c["at"]], f"{where}: corner {i}: 'at'")[0] * scale
    name = c.get("name")
    if name is not None and (not isinstance(name, str) or not name):
        raise PatternError(f"{where}: corner {i}: 'name' must be a non-empty string, got {name!r}")
    curves = [k for k in _CURVE_KEYS if k in c]
    if len(curves) > 1:
        raise PatternError(f"{where}: corner {i}: give at most one of {', '.join(_CURVE_KEYS)}, got "
                           f"{', '.join(curves)}")
    if "degree" in c and "bspline" not in c:
        raise PatternError(f"{where}: corner {i}: 'degree' is only meaningful with 'bspline'")
    curve = None
    if curves:
        key = curves[0]
        if key == "bulge":
            b = c["bulge"]
            if isinstance(b, bool) or not isinstance(b, (int, float)) or not math.isfinite(b):
                raise PatternError(f"{where}: corner {i}: 'bulge' must be a finite number, got {b!r}")
            curve = ("bulge", float(b))
        else:
            pts = c[key]
            interior = (np.zeros((0, 2)) if isinstance(pts, (list, tuple)) and len(pts) == 0
                        else _points_array(pts, f"{where}: corner {i}: '{key}'"))
            degree = c.get("degree", 3)
            if isinstance(degree, bool) or not isinstance(degree, int) or degree < 1:
                raise PatternError(f"{where}: corner {i}: 'degree' must be an integer >= 1, got {degree!r}")
            curve = (key, interior * scale, degree)
    return at, name, curve


def _corner_segment(where: str, i: int, at: np.ndarray, nxt: np.ndarray, curve) -> Segment:
    if curve is None or (curve[0] == "bulge" and curve[1] == 0.0):
        return Segment("line", np.array([at, nxt]))
    if curve[0] == "bulge":
        return Segment("arc", np.array([at, nxt]), bulge=curve[1])
    key, interior, degree = curve
    ctrl = np.vstack([at, interior, nxt])
    if key == "polyline":
        return Segment("polyline", ctrl)
    return Segment("bspline", ctrl, degree=min(degree, len(ctrl) - 1))


def _polygon_self_intersection(poly: np.ndarray, eps: float):
    """First crossing/touching of two non-adjacent edges of the closed polygon poly (n, 2): point or None.

    Sweep on x: edges sorted by min x only meet edges whose min x lies inside their x range, so the
    candidate pairs are generated per sorted edge and then tested exactly (orientation signs, with |o| <= eps
    taken as zero so touching counts)."""
    n = len(poly)
    if n < 4:
        return None
    a, b = poly, np.roll(poly, -1, axis=0)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.argsort(lo[:, 0], kind="stable")
    xmin_sorted = lo[order, 0]
    stop = np.searchsorted(xmin_sorted, hi[order, 0], side="right")
    chunk_starts = range(0, n, 256)
    for c0 in chunk_starts:
        pos = np.arange(c0, min(c0 + 256, n))
        counts = np.maximum(stop[pos] - (pos + 1), 0)
        if counts.sum() == 0:
            continue
        first = np.repeat(pos, counts)
        offs = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        second = first + 1 + offs
        i, j = order[first], order[second]
        d = np.abs(i - j)
        sel = (d != 1) & (d != n - 1)
        sel &= (lo[i, 1] <= hi[j, 1]) & (lo[j, 1] <= hi[i, 1]) & (lo[j, 0] <= hi[i, 0])
        i, j = i[sel], j[sel]
        if len(i) == 0:
            continue
        p, q, r, s = a[i], b[i], a[j], b[j]

        def orient(u, v, w):
            o = (v[:, 0] - u[:, 0]) * (w[:, 1] - u[:, 1]) - (v[:, 1] - u[:, 1]) * (w[:, 0] - u[:, 0])
            return np.where(np.abs(o) <= eps, 0.0, np.sign(o))

        hit = ((orient(p, q, r) * orient(p, q, s) <= 0) & (orient(r, s, p) * orient(r, s, q) <= 0))
        if np.any(hit):
            k = int(np.nonzero(hit)[0][0])
            return _crossing_point(p[k], q[k], r[k], s[k])
    return None


def _crossing_point(p, q, r, s) -> np.ndarray:
    """Intersection of lines p-q and r-s, or the midpoint of the closest endpoints when parallel."""
    d1, d2 = q - p, s - r
    den = d1[0] * d2[1] - d1[1] * d2[0]
    if abs(den) > 1e-300:
        t = ((r[0] - p[0]) * d2[1] - (r[1] - p[1]) * d2[0]) / den
        return p + t * d1
    cands = [(np.linalg.norm(x - y), 0.5 * (x + y)) for x in (p, q) for y in (r, s)]
    return min(cands, key=lambda c: c[0])[1]

