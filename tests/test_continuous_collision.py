"""The self-collision guarantee's test: additive CCD on its own, on analytic cases (the stress scenes:
tests/test_self_collision_stress.py)."""
import numpy as np
import taichi as ti

from collision.ccd import additive_ccd, pair_distance


@ti.kernel
def _ccd(x: ti.types.ndarray(), p: ti.types.ndarray(), s: ti.f64, xi: ti.f64, edge_edge: ti.template()) -> ti.f64:
    v = [ti.Vector([x[k, 0], x[k, 1], x[k, 2]], ti.f64) for k in ti.static(range(4))]
    d = [ti.Vector([p[k, 0], p[k, 1], p[k, 2]], ti.f64) for k in ti.static(range(4))]
    return additive_ccd(v[0], v[1], v[2], v[3], d[0], d[1], d[2], d[3], s, xi, 32, edge_edge)


@ti.kernel
def _distance(x: ti.types.ndarray(), edge_edge: ti.template()) -> ti.f64:
    v = [ti.Vector([x[k, 0], x[k, 1], x[k, 2]], ti.f64) for k in ti.static(range(4))]
    return pair_distance(v[0], v[1], v[2], v[3], edge_edge)


TRIANGLE = np.array([[0.3, 0.01, 0.3], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def test_a_point_falling_through_a_triangle_stops_short_of_it():
    """A point 1 cm above a triangle moves 3 cm straight down (it reaches the plane at t = 1/3): CCD stops it before,
    at least s d0 = 1 mm above; the same point moving sideways by 3 cm, or up, takes the whole step."""
    down = np.zeros((4, 3))
    down[0, 1] = -0.03
    t = _ccd(TRIANGLE, down, 0.1, 0.0, False)
    assert 0.0 < t < 1.0 / 3.0
    assert 0.01 - 0.03 * t >= 0.001 * (1 - 1e-12)
    assert _distance(TRIANGLE + t * down, False) >= 0.001 * (1 - 1e-12)
    for motion in ([0.03, 0.0, 0.0], [0.0, 0.03, 0.0]):
        p = np.zeros((4, 3))
        p[0] = motion
        assert _ccd(TRIANGLE, p, 0.1, 0.0, False) == 1.0


def test_the_floor_keeps_a_pair_above_it_and_a_pair_within_twice_of_it_at_half_its_distance():
    """With a floor xi the point stops at least xi + s (d0 - xi) above; a pair that starts within 2 xi keeps at
    least d0 / 2 + s d0 / 2."""
    down = np.zeros((4, 3))
    down[0, 1] = -0.03
    t = _ccd(TRIANGLE, down, 0.1, 0.004, False)
    assert 0 < t and 0.01 - 0.03 * t >= 0.004 + 0.1 * 0.006 - 1e-12
    t = _ccd(TRIANGLE, down, 0.1, 0.02, False)
    assert 0 < t and 0.01 - 0.03 * t >= 0.55 * 0.01 - 1e-12


def test_two_edges_passing_through_each_other_stop_apart():
    """Edge (0,0,0)-(1,0,0) and edge (0.5,-0.5,0.02)-(0.5,0.5,0.02) 2 cm above it moving 4 cm down: they would
    touch at t = 1/2; CCD stops them 2 mm apart or more. Moved together (one translation) they never close."""
    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, -0.5, 0.02], [0.5, 0.5, 0.02]])
    p = np.zeros((4, 3))
    p[2:, 2] = -0.04
    t = _ccd(x, p, 0.1, 0.0, True)
    assert 0.0 < t < 0.5
    assert _distance(x + t * p, True) >= 0.002 * (1 - 1e-12)
    p[:, 0] = 0.3
    p[:, 2] = -0.04
    assert _ccd(x, p, 0.1, 0.0, True) == 1.0
