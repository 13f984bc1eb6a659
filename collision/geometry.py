"""Geometric tests as Taichi functions, inlined into the collision kernels (ALGORITHMS.md section 3)."""
import taichi as ti

#: barycentric slack so that hits exactly on an edge or a vertex are not lost between two triangles
EDGE_SLACK = 1e-6


@ti.func
def segment_triangle(p, q, a, b, c):
    """Seed 004 eq. (15) by Moller-Trumbore: does the segment p -> q cross triangle (a, b, c)?

    Returns (hit, t) with t in [0, 1] the fraction of the segment at the crossing. A segment parallel to
    the plane (|det| below 1e-12 |e1||e2||d|) is no crossing: the proximity test handles it."""
    e1 = b - a
    e2 = c - a
    d = q - p
    pv = d.cross(e2)
    det = e1.dot(pv)
    hit = False
    t = 1.0
    if ti.abs(det) > 1e-12 * e1.norm() * e2.norm() * d.norm():
        inv = 1.0 / det
        s = p - a
        u = s.dot(pv) * inv
        qv = s.cross(e1)
        v = d.dot(qv) * inv
        t = e2.dot(qv) * inv
        hit = (t >= 0.0 and t <= 1.0 and u >= -EDGE_SLACK and v >= -EDGE_SLACK and u + v <= 1.0 + EDGE_SLACK)
    return hit, t


@ti.func
def inside_triangle(x, a, b, c, n):
    """Is the projection of x along unit normal n inside triangle (a, b, c) (with the edge slack)?"""
    e1 = b - a
    e2 = c - a
    w = x - a
    d00 = e1.dot(e1)
    d01 = e1.dot(e2)
    d11 = e2.dot(e2)
    d20 = w.dot(e1)
    d21 = w.dot(e2)
    den = d00 * d11 - d01 * d01
    inside = False
    if den > 0:
        v = (d11 * d20 - d01 * d21) / den
        u2 = (d00 * d21 - d01 * d20) / den
        inside = v >= -EDGE_SLACK and u2 >= -EDGE_SLACK and v + u2 <= 1.0 + EDGE_SLACK
    return inside


@ti.func
def collision_possibility(motion, n):
    """The fuzzy collision possibility mu of seed 000 (our reconstruction): how directly the motion heads into
    the face, clamp(-motion . n / |motion|, 0, 1); 0 when moving along or away from it, or not moving."""
    length = motion.norm()
    mu = 0.0
    if length > 1e-12:
        mu = ti.min(ti.max(-motion.dot(n) / length, 0.0), 1.0)
    return mu
