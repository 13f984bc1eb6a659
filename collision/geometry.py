"""Geometric tests as Taichi functions, inlined into the collision kernels (docs/algorithms.md, collision)."""
import taichi as ti

#: barycentric slack so that hits exactly on an edge or a vertex are not lost between two triangles
EDGE_SLACK = 1e-6


@ti.func
def segment_triangle(p, q, a, b, c):
    """Fan et al. 1998 eq. (15) by Moller-Trumbore: does the segment p -> q cross triangle (a, b, c)?

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
    """Is the projection of x along unit normal n inside triangle (a, b, c) (with the edge slack)? A degenerate
    triangle has nothing inside."""
    w = barycentric(x, a, b, c)  # zeros for a degenerate triangle, else summing to 1
    return w.sum() > 0.5 and w.min() >= -EDGE_SLACK


@ti.func
def collision_possibility(start_height, motion, n, reach_gate: ti.template()):
    """The fuzzy collision possibility mu of Hsiao 2006 (our reconstruction: the published formula is illegible in
    the copy we have):
    how directly the motion heads into the face, clamp(-motion . n / |motion|, 0, 1), and 0 when the particle
    moves along or away from the face, does not move, or cannot reach the face's plane this step
    (start_height = (p - a) . n above it, and the motion descends less than that) when reach_gate is set."""
    length = motion.norm()
    descent = -motion.dot(n)
    mu = 0.0
    if length > 1e-12 and descent > 0 and (not ti.static(reach_gate) or descent >= start_height):
        mu = ti.min(descent / length, 1.0)
    return mu


@ti.func
def closest_point_on_triangle(p, a, b, c):
    """The point of triangle (a, b, c) closest to p (Ericson, Real-Time Collision Detection, 5.1.5)."""
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = ab.dot(ap)
    d2 = ac.dot(ap)
    out = a
    if not (d1 <= 0.0 and d2 <= 0.0):
        bp = p - b
        d3 = ab.dot(bp)
        d4 = ac.dot(bp)
        cp = p - c
        d5 = ab.dot(cp)
        d6 = ac.dot(cp)
        vc = d1 * d4 - d3 * d2
        vb = d5 * d2 - d1 * d6
        va = d3 * d6 - d5 * d4
        if d3 >= 0.0 and d4 <= d3:
            out = b
        elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
            out = a + d1 / (d1 - d3) * ab
        elif d6 >= 0.0 and d5 <= d6:
            out = c
        elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
            out = a + d2 / (d2 - d6) * ac
        elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
            out = b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b)
        else:
            den = 1.0 / (va + vb + vc)
            out = a + ab * (vb * den) + ac * (vc * den)
    return out


@ti.func
def solid_angle(p, a, b, c):
    """Signed solid angle of triangle (a, b, c) seen from p (Van Oosterom and Strackee 1983); summed over a
    closed outward-wound mesh and divided by 4 pi it is the winding number: 1 inside, 0 outside."""
    ra = a - p
    rb = b - p
    rc = c - p
    la, lb, lc = ra.norm(), rb.norm(), rc.norm()
    num = ra.dot(rb.cross(rc))
    den = la * lb * lc + ra.dot(rb) * lc + ra.dot(rc) * lb + rb.dot(rc) * la
    return 2.0 * ti.atan2(num, den)


@ti.func
def barycentric(p, a, b, c):
    """Barycentric weights (w_a, w_b, w_c) of point p projected on the plane of triangle (a, b, c); zeros for a
    degenerate triangle."""
    e1 = b - a
    e2 = c - a
    w = p - a
    d00 = e1.dot(e1)
    d01 = e1.dot(e2)
    d11 = e2.dot(e2)
    d20 = w.dot(e1)
    d21 = w.dot(e2)
    den = d00 * d11 - d01 * d01
    out = p - p  # zeros of p's type
    if den > 0:
        v = (d11 * d20 - d01 * d21) / den
        u = (d00 * d21 - d01 * d20) / den
        out = ti.Vector([1.0 - v - u, v, u])
    return out


@ti.func
def carry_point(p, a0, b0, c0, a1, b1, c1):
    """Where point p goes when carried with triangle (a0, b0, c0) as it moves to (a1, b1, c1): the same barycentric
    weights in the triangle's plane and the same height along its unit normal. Exact for a rigid motion; for a
    deforming surface, its local motion near the triangle. A degenerate triangle carries p with its centroid."""
    n0 = (b0 - a0).cross(c0 - a0)
    n1 = (b1 - a1).cross(c1 - a1)
    w = barycentric(p, a0, b0, c0)  # zeros for a degenerate triangle
    out = p + ((a1 + b1 + c1) - (a0 + b0 + c0)) / 3.0
    if w.sum() > 0.5 and n1.norm() > 0:
        out = w[0] * a1 + w[1] * b1 + w[2] * c1 + (p - a0).dot(n0.normalized()) * n1.normalized()
    return out


@ti.func
def closest_segment_params(p1, q1, p2, q2):
    """Parameters (s, t) in [0, 1] of the closest points p1 + s (q1 - p1) and p2 + t (q2 - p2) of two segments
    (Ericson, Real-Time Collision Detection, 5.1.9); parallel segments give s = 0."""
    d1 = q1 - p1
    d2 = q2 - p2
    r = p1 - p2
    a = d1.dot(d1)
    e = d2.dot(d2)
    f = d2.dot(r)
    s = p1[0] * 0.0  # of p1's type
    t = p1[0] * 0.0
    if a > 1e-20 and e > 1e-20:
        c = d1.dot(r)
        b = d1.dot(d2)
        den = a * e - b * b
        if den > 1e-12 * a * e:
            s = ti.math.clamp((b * f - c * e) / den, 0.0, 1.0)
        t = (b * s + f) / e
        if t < 0.0:
            t = 0.0
            s = ti.math.clamp(-c / a, 0.0, 1.0)
        elif t > 1.0:
            t = 1.0
            s = ti.math.clamp((b - c) / a, 0.0, 1.0)
    return s, t
