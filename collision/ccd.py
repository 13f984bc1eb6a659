"""Continuous collision tests for the self-collision guarantee: how far along a step's straight-line motion a
point-triangle or edge-edge pair can go before it comes closer than a fraction of its starting distance.

Additive CCD (Li, Kaufman and Jiang 2021, "Codimensional incremental potential contact", Algorithm 1): with the
pair's common translation removed, the distance of its closest points changes at most l_p per unit of the step
fraction t, where l_p bounds the relative displacement of any two points of the pair (the point's displacement plus
the largest of the triangle's, or the largest of each edge). So the pair may advance by d(t) / l_p without
touching; it advances by 0.9 of that, measures the distance again, and stops when the distance falls below s times
the starting one. The answer is conservative: it never steps past a contact, and in floating point it only stops
early.

With a floor xi the same runs on the distance beyond xi (IPC's thickness): a pair that starts more than xi apart
stays more than xi apart, so the gaps the test must resolve stay far above round-off. One that starts within 2 xi
(a push left it there) keeps at least half its distance: it can still slide, in ~ l_p / (0.45 d) iterations. A
pair sliding past at its contact distance takes ~ l_p / (0.9 d) iterations; `max_iterations` caps them, and a
capped pair stops where it got to (also safe).
"""
import taichi as ti

from .geometry import closest_point_on_triangle, closest_segment_params


@ti.func
def point_triangle_distance(p, a, b, c):
    """Distance [m] from point p to triangle (a, b, c)."""
    return (p - closest_point_on_triangle(p, a, b, c)).norm()


@ti.func
def edge_edge_distance(p1, q1, p2, q2):
    """Distance [m] between segments p1-q1 and p2-q2."""
    s, t = closest_segment_params(p1, q1, p2, q2)
    return ((p1 + s * (q1 - p1)) - (p2 + t * (q2 - p2))).norm()


@ti.func
def pair_distance(x0, x1, x2, x3, edge_edge: ti.template()):
    """Point x0 to triangle (x1, x2, x3), or with edge_edge, segment x0-x1 to segment x2-x3."""
    d = x0[0] * 0.0
    if ti.static(edge_edge):
        d = edge_edge_distance(x0, x1, x2, x3)
    else:
        d = point_triangle_distance(x0, x1, x2, x3)
    return d


@ti.func
def additive_ccd(x0, x1, x2, x3, p0, p1, p2, p3, s, xi, max_iterations, edge_edge: ti.template()):
    """The largest fraction t in [0, 1] of the displacements p0..p3 [m] that keeps the pair (x0..x3 [m] at the
    start; a point and a triangle, or with edge_edge two edges) at least f + s (d0 - f) apart [m], d0 its
    starting distance and f = min(xi, d0 / 2). Returns 1.0 where the pair never comes that close, and where it
    starts touching (d0 = 0: nothing left to keep)."""
    mean = (p0 + p1 + p2 + p3) * 0.25
    q0, q1, q2, q3 = p0 - mean, p1 - mean, p2 - mean, p3 - mean
    lp = x0[0] * 0.0
    if ti.static(edge_edge):
        lp = ti.max(q0.norm(), q1.norm()) + ti.max(q2.norm(), q3.norm())
    else:
        lp = q0.norm() + ti.max(q1.norm(), q2.norm(), q3.norm())
    raw = pair_distance(x0, x1, x2, x3, edge_edge)
    # a pair that starts within 2 xi keeps at least half its distance (and can still slide: see the docstring)
    floor = ti.min(xi, 0.5 * raw)
    d0 = raw - floor
    out = x0[0] * 0.0 + 1.0
    if lp > 0 and d0 > 0 and lp > (1.0 - s) * d0:  # else the pair cannot come that close in the whole step
        gap = s * d0
        t = x0[0] * 0.0
        step = (1.0 - s) * d0 / lp
        k = 0
        while True:
            d = pair_distance(x0 + (t + step) * q0, x1 + (t + step) * q1, x2 + (t + step) * q2,
                              x3 + (t + step) * q3, edge_edge) - floor
            if d < gap and t > 0:  # the first advance is safe by construction: no round-off stops the pair at 0
                out = t
                break
            t += step
            k += 1
            if t >= 1.0:
                break
            if k >= max_iterations:
                out = t
                break
            step = 0.9 * d / lp
    return out
