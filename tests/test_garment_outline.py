"""Multilevel meshes of arbitrary pattern outlines (taichi_cloth.garment.outline; docs/algorithms.md, multilevel,
"Arbitrary outlines").

Pure numpy: nothing here touches Taichi.
"""
import numpy as np
import pytest

from multilevel.hierarchy import Hierarchy48, edge_use, valences
from taichi_cloth.garment.outline import OutlineHierarchy, OutlineLevel, outline_hierarchy

# smallest angle [deg] over all levels, as built: 24.8 (B-spline), 26.6 (L), 26.6 (trapezoid), 22.3 (dumbbell);
# over 150 random shapes, sizes, shifts and rotations the worst was 16.9 (a piece only ~2 h_0 wide)
MIN_ANGLE = 24.0
MIN_ANGLE_DUMBBELL = 22.0


# ---------------------------------------------------------------------- shapes
def bspline_loop(control: np.ndarray, per_span: int = 48) -> np.ndarray:
    """Closed uniform cubic B-spline through nothing in particular, densely sampled: (k + 1, 2), last = first."""
    t = np.arange(per_span) / per_span
    basis = np.stack([(1 - t) ** 3, 3 * t ** 3 - 6 * t ** 2 + 4, -3 * t ** 3 + 3 * t ** 2 + 3 * t + 1, t ** 3], 1) / 6
    m = len(control)
    pts = [basis @ control[[(i + k) % m for k in range(4)]] for i in range(m)]
    p = np.concatenate(pts)
    return np.concatenate([p, p[:1]])


def spline_piece():
    """A circle-like B-spline pattern piece (control points on an ellipse), cut into two halves at its
    left and right ends: two seam-like segments that get the same count."""
    th = np.arange(12) * 2 * np.pi / 12
    p = bspline_loop(np.stack([0.55 * np.cos(th), 0.36 * np.sin(th)], 1))
    k = len(p) // 2
    return [p[:k + 1], p[k:]]


def lshape():
    c = np.array([[0, 0], [0.6, 0], [0.6, 0.25], [0.25, 0.25], [0.25, 0.7], [0, 0.7]], float)
    return [np.stack([c[i], c[(i + 1) % 6]]) for i in range(6)]


def trapezoid():
    c = np.array([[0, 0], [0.7, 0], [0.55, 0.5], [0.15, 0.5]], float)
    return [np.stack([c[i], c[(i + 1) % 4]]) for i in range(4)]


def dumbbell():
    t = np.linspace(0, 2 * np.pi, 401)
    p = np.stack([0.5 * np.cos(t), 0.9 * (0.3 + 0.22 * np.cos(2 * t)) * np.sin(t)], 1)
    p[:, 1] *= 0.15 + 0.85 * np.abs(np.cos(t)) ** 0.7
    p[-1] = p[0]
    return [p]


CASES = {  # name: (segments, spacing h_0 [m], segment_counts)
    "spline": (spline_piece(), 0.1, [13, 13]),
    "lshape": (lshape(), 0.1, None),
    "trapezoid": (trapezoid(), 0.1, [7, 5, 4, 5]),  # the two slanted sides share a count, like a seam
}


@pytest.fixture(scope="module")
def hierarchies():
    return {name: outline_hierarchy(segs, 6, h, counts) for name, (segs, h, counts) in CASES.items()}


# ---------------------------------------------------------------------- checks
def areas(uv, tris):
    p = uv[tris]
    return 0.5 * ((p[:, 1, 0] - p[:, 0, 0]) * (p[:, 2, 1] - p[:, 0, 1]) - (p[:, 1, 1] - p[:, 0, 1]) * (p[:, 2, 0] - p[:, 0, 0]))


def polygon_area(P):
    return 0.5 * float(np.dot(P[:, 0], np.roll(P[:, 1], -1)) - np.dot(np.roll(P[:, 0], -1), P[:, 1]))


def min_angles(uv, tris):
    p = uv[tris]
    out = []
    for k in range(3):
        u, v = p[:, (k + 1) % 3] - p[:, k], p[:, (k + 2) % 3] - p[:, k]
        out.append(np.degrees(np.arctan2(np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]), (u * v).sum(1))))
    return np.min(out, axis=0)


def vertices_inside_edges(uv, tris):
    """Vertices lying strictly inside some edge (T-junctions), by brute force."""
    edges, _ = edge_use(tris)
    p, q = uv[edges[:, 0]], uv[edges[:, 1]]
    tol = 1e-9 * np.ptp(uv, axis=0).max()
    bad = set()
    for s in range(0, len(edges), 400):
        d = (q[s:s + 400] - p[s:s + 400])[:, None]
        w = uv[None] - p[s:s + 400, None]
        L = np.linalg.norm(d, axis=-1)
        t = (w * d).sum(-1) / L ** 2
        off = np.abs(d[..., 0] * w[..., 1] - d[..., 1] * w[..., 0]) / L
        bad |= set(np.nonzero((t > 1e-9) & (t < 1 - 1e-9) & (off < tol))[1].tolist())
    return bad


def check_level(lev: OutlineLevel) -> float:
    """Every invariant of one level; returns its smallest angle [deg]."""
    uv, T = lev.uv, lev.triangles
    n = len(uv)
    assert T.dtype == np.int64 and uv.dtype == np.float64 and T.shape[1] == 3
    assert len(np.unique(T)) == n, "every vertex is used"
    a = areas(uv, T)
    assert np.all(a > 0), "all triangles counter-clockwise with positive area"
    loop = lev.boundary_loop
    A = polygon_area(uv[loop])
    assert a.sum() == pytest.approx(A, rel=1e-12), "the triangles tile the boundary polygon exactly"
    edges, count = edge_use(T)
    assert count.max() <= 2, "conforming: every edge used by one or two triangles"
    once = {tuple(e) for e in edges[count == 1].tolist()}
    ring = {tuple(sorted(e)) for e in zip(loop.tolist(), np.roll(loop, -1).tolist())}
    assert once == ring, "the edges used once are exactly the boundary loop"
    assert not vertices_inside_edges(uv, T), "no hanging vertices"
    # regular triangles: right isosceles, legs h_L, in (hyp_a, hyp_b, apex) form
    R = T[lev.regular]
    if len(R):
        hyp = np.linalg.norm(uv[R[:, 1]] - uv[R[:, 0]], axis=1)
        legs = np.linalg.norm(uv[R[:, 2, None]] - uv[R[:, :2]], axis=2)
        assert np.allclose(legs, lev.spacing, rtol=1e-9) and np.allclose(hyp, np.sqrt(2) * lev.spacing, rtol=1e-9)
    assert lev.regular[:lev.regular.sum()].all(), "regular triangles come first"
    # valence 4 or 8 away from the band
    touch = np.zeros(n, bool)
    touch[T[~lev.regular].ravel()] = True
    touch[loop] = True
    assert set(np.unique(valences(T, n)[~touch]).tolist()) <= {4, 8}
    assert np.all(lev.diamonds == -1) and lev.diamonds.shape == (n, 4)
    return float(min_angles(uv, T).min())


# ---------------------------------------------------------------------- tests
@pytest.mark.parametrize("name", list(CASES))
def test_every_level_is_a_conforming_exact_tiling(hierarchies, name):
    H = hierarchies[name]
    assert isinstance(H, OutlineHierarchy) and isinstance(H, Hierarchy48) and len(H) == 6
    worst = min(check_level(lev) for lev in H.levels)
    assert worst > MIN_ANGLE, f"{name}: smallest angle {worst:.1f} deg"
    # the band is a thin strip: most triangles are regular at the fine levels
    assert H.finest.regular.mean() > 0.8
    assert [lev.spacing for lev in H.levels] == pytest.approx([0.1 * 2 ** (-L / 2) for L in range(6)])


@pytest.mark.parametrize("name", list(CASES))
def test_exact_segment_counts_and_corners(hierarchies, name):
    H = hierarchies[name]
    segs, _, counts = CASES[name]
    base = H.base_counts
    if counts is not None:
        assert base.tolist() == counts
    S = len(segs)
    for L, lev in enumerate(H.levels):
        bs = lev.boundary_segments
        assert len(bs) == S
        for i in range(S):
            assert len(bs[i]) == base[i] * 2 ** (L // 2) + 1 == H.segment_count(L, i) + 1
            assert bs[i][-1] == bs[(i + 1) % S][0], "consecutive segments share their corner vertex"
            assert np.array_equal(lev.uv[bs[i][0]], segs[i][0]), "corners are kept exactly"
            # samples run along the segment at uniform arc length (chords of a dense polyline: nearly equal)
            chord = np.linalg.norm(np.diff(lev.uv[bs[i]], axis=0), axis=1)
            assert chord.max() < 1.05 * chord.min() + 1e-12
        loop = np.concatenate([b[:-1] for b in bs])
        assert np.array_equal(loop, lev.boundary_loop)
    if name == "trapezoid":  # sides 1 and 3 were given the same count: equal at every level (seam partners)
        assert all(len(lev.boundary_segments[1]) == len(lev.boundary_segments[3]) for lev in H.levels)
    if name == "spline":
        assert all(len(lev.boundary_segments[0]) == len(lev.boundary_segments[1]) for lev in H.levels)


@pytest.mark.parametrize("name", list(CASES))
def test_boundary_samples_are_nested(hierarchies, name):
    H = hierarchies[name]
    for L in range(1, len(H)):
        for old, new in zip(H[L - 1].boundary_segments, H[L].boundary_segments):
            step = (len(new) - 1) // (len(old) - 1)
            assert step == (2 if L % 2 == 0 else 1)
            assert np.array_equal(H[L].uv[new[::step]], H[L - 1].uv[old])


def curvature_bound(name):
    """max |midpoint of an old boundary chord - new sample| / chord^2 allowed: kappa_max / 8 (+5 %)."""
    if name != "spline":
        return 0.0  # straight segments: new samples are chord midpoints exactly
    P = np.concatenate([s[:-1] for s in CASES["spline"][0]])
    a, b, c = P, np.roll(P, -1, 0), np.roll(P, -2, 0)
    k = 2 * np.abs(np.cross(b - a, c - a)) / (np.linalg.norm(b - a, axis=1) * np.linalg.norm(c - b, axis=1) * np.linalg.norm(c - a, axis=1))
    return 1.05 * k.max() / 8


@pytest.mark.parametrize("name", list(CASES))
def test_prolongation_tables(hierarchies, name):
    H = hierarchies[name]
    f = lambda uv: 0.3 + 2.0 * uv[:, 0] - 5.0 * uv[:, 1]  # noqa: E731  any linear function of uv
    kb = curvature_bound(name)
    n0 = H[0].n_vertices
    assert np.array_equal(H[0].parents[:, 0], np.arange(n0)) and np.all(H[0].weights[:, 0] == 1)
    for L in range(1, len(H)):
        prev, lev = H[L - 1], H[L]
        P, W = lev.parents, lev.weights
        assert P.shape == W.shape == (lev.n_vertices, 3) and P.dtype == np.int64
        assert np.allclose(W.sum(1), 1, atol=1e-14) and np.all(W >= 0)
        assert np.all((P >= 0) == (W > 0)), "weights exactly on the live parents"
        assert np.all(P < prev.n_vertices)
        exact = f(lev.uv)
        err = np.abs(lev.prolong(f(prev.uv)) - exact)
        boundary = np.zeros(lev.n_vertices, bool)
        boundary[lev.boundary_loop] = True
        assert err[~boundary].max() < 1e-12, "interior: barycentric weights reproduce linear functions exactly"
        # boundary: nested samples copy, new ones are chord midpoints (off by the boundary's sagitta)
        uv_err = np.linalg.norm(lev.prolong(prev.uv) - lev.uv, axis=1)
        for old, new in zip(prev.boundary_segments, lev.boundary_segments):
            chord = np.linalg.norm(np.diff(prev.uv[old], axis=0), axis=1).max()
            assert uv_err[new].max() <= kb * chord ** 2 + 1e-12
        # a vertex at the place of a previous one copies it
        where = {tuple(p): i for i, p in enumerate(prev.uv.tolist())}
        same = [(k, where[tuple(p)]) for k, p in enumerate(lev.uv.tolist()) if tuple(p) in where]
        assert len(same) >= prev.n_vertices // 2
        for k, j in same:
            assert P[k, 0] == j and W[k, 0] == 1.0


def test_regular_part_is_the_rectangle_hierarchy():
    """Inside, each level is a piece of the 4-8 rectangle hierarchy (same triangles, same hypotenuses)."""
    square = [np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0]])]
    H = outline_hierarchy(square, 5, 0.25)
    R = Hierarchy48.rectangle(size=(2.0, 2.0), base_cells=(8, 8), levels=5)

    def keyset(uv, tris):
        return {tuple(np.round(uv[t], 9).ravel().tolist()) for t in tris}
    for L in range(5):
        mine = keyset(H[L].uv, H[L].triangles[H[L].regular])
        assert len(mine) > 0.5 * R[L].n_triangles
        assert mine <= keyset(R[L].uv, R[L].triangles)


def test_two_interior_components_and_clockwise_input():
    """A dumbbell whose kept interior falls apart into two pieces at the neck; given clockwise."""
    segs = [s[::-1] for s in dumbbell()[::-1]]
    H = outline_hierarchy(segs, 4, 0.05)
    worst = min(check_level(lev) for lev in H.levels)
    assert worst > MIN_ANGLE_DUMBBELL
    for lev in H.levels:
        bs = lev.boundary_segments[0]
        assert bs[0] == bs[-1] == 0
        # boundary_segments run in the caller's (clockwise) direction
        assert polygon_area(lev.uv[bs[:-1]]) < 0
        assert np.array_equal(lev.uv[bs[1]], lev.uv[lev.boundary_loop[-1]])


def test_clockwise_is_the_mirror_of_counter_clockwise():
    segs, h, counts = CASES["trapezoid"]
    ccw = outline_hierarchy(segs, 3, h, counts)
    cw = outline_hierarchy([s[::-1] for s in segs[::-1]], 3, h, counts[::-1])
    for a, b in zip(ccw.levels, cw.levels):
        assert np.array_equal(a.uv, b.uv) and np.array_equal(a.triangles, b.triangles)
        for i in range(4):
            assert np.array_equal(b.boundary_segments[3 - i], a.boundary_segments[i][::-1])


def test_default_counts_follow_the_length():
    H = outline_hierarchy(lshape(), 2, 0.07)
    assert H.base_counts.tolist() == [9, 4, 5, 6, 4, 10]  # round(length / spacing)
    tiny = outline_hierarchy(trapezoid(), 1, 1.0)
    assert tiny.base_counts.tolist() == [1, 1, 1, 1]  # at least 1
    assert check_level(tiny[0]) > 0 and not tiny[0].regular.any()  # no interior at all: band only


BOWTIE = [np.array([[0, 0], [1, 1], [1, 0], [0, 1], [0, 0]], float)]


@pytest.mark.parametrize("args, match", [
    ((BOWTIE, 2, 0.1), "intersects itself"),
    (([np.array([[0, 0], [1, 0], [0.5, 0.5], [1, 0.2], [0, 0.6], [0, 0]], float)], 2, 0.1), "intersects itself"),
    (([np.array([[0, 0], [1, 0], [0, 0]], float)], 2, 0.1), "at least 3 distinct points"),
    (([np.array([[0, 0], [1, 0]], float), np.array([[1, 0], [0, 0]], float)], 2, 0.1), "at least 3 distinct points"),
    (([np.array([[0, 0], [1, 0]], float)], 2, 0.1), "closed"),
    (([np.array([[0, 0], [1, 0]], float), np.array([[1, 0.1], [0, 1], [0, 0]], float)], 2, 0.1), "closed loop"),
    (([np.array([[0, 0], [1, 0], [1, 1], [0, 0.5]], float)], 2, 0.1), "closed"),
    (([np.zeros((1, 2))], 2, 0.1), "at least 2 points"),
    (([np.zeros((3, 3))], 2, 0.1), r"shape \(k, 2\)"),
    (([], 2, 0.1), "empty"),
    (([np.array([[0, 0], [1, 0], [2, 0], [0, 0]], float)], 2, 0.1), "no area|intersects itself"),
    ((lshape(), 0, 0.1), "levels"),
    ((lshape(), 7, 0.1), "levels"),
    ((lshape(), 2.0, 0.1), "levels"),
    ((lshape(), True, 0.1), "levels"),
    ((lshape(), 2, 0.0), "spacing"),
    ((lshape(), 2, -0.1), "spacing"),
    ((lshape(), 2, float("nan")), "spacing"),
    ((lshape(), 2, 0.1, [1, 2, 3]), "6 segments"),
    ((lshape(), 2, 0.1, [1, 2, 3, 0, 1, 1]), r"segment_counts\[3\]"),
    ((lshape(), 2, 0.1, [1, 2, 3, 1.5, 1, 1]), r"segment_counts\[3\]"),
])
def test_bad_input_is_one_clear_value_error(args, match):
    with pytest.raises(ValueError, match=match):
        outline_hierarchy(*args)


def test_sampling_coarser_than_the_outline_is_refused():
    """A crescent whose outer arc, sampled with one interval, cuts through the inner arc."""
    t = np.linspace(-1.2, 1.2, 60)
    outer = np.stack([np.cos(t), np.sin(t)], 1)  # unit circle, right side, upwards
    c = np.array([-0.5, 0.0])  # inner arc: a larger circle through the same end points, downwards
    a0, r = np.arctan2(outer[-1, 1] - c[1], outer[-1, 0] - c[0]), np.linalg.norm(outer[-1] - c)
    u = np.linspace(a0, -a0, 60)
    inner = c + r * np.stack([np.cos(u), np.sin(u)], 1)
    inner[0], inner[-1] = outer[-1], outer[0]
    segs = [outer, inner]
    outline_hierarchy(segs, 1, 0.05)  # fine enough: fine
    with pytest.raises(ValueError, match="features finer than the sampling"):
        outline_hierarchy(segs, 1, 0.05, [1, 40])
