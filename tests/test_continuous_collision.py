"""The self-collision guarantee: additive CCD on its own (analytic cases), and stress scenes counted exactly at every
frame (a ribbon piling on the floor, a towel folded three times by pins, a sheet twisted by its pinned edges)."""
import numpy as np
import pytest
import taichi as ti

from benchmarks.self_collision_stress import (crossings_per_frame, jerked_sheet, ribbon_pile, towel_folded_three_times,
                                             twisted_sheet)
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


# ---------------------------------------------------------------------- stress scenes, counted at every frame
@pytest.mark.parametrize("build, frames, step", [(ribbon_pile, 90, "fixed"), (towel_folded_three_times, 240, "fixed"),
                                                 (twisted_sheet, 90, "auto")],
                         ids=["ribbon pile", "towel folded three times", "twisted sheet"])
def test_the_cloth_never_crosses_itself_at_any_frame(build, frames, step):
    """The small stress scenes (benchmarks/self_collision_stress.py): without self-collision the cloth passes
    through itself (the ribbon within 30 frames, the towel by its second fold, the twisted sheet at 1.27 s); with it,
    no two triangles intersect at any of the frames (1.5 s of the ribbon, 4 s of the towel, the twist's first 1.5 s at
    the adaptive step), the continuous stage left no pair unresolved, and no impact zone holds the cloth in the last
    second."""
    without, _ = build(False, small=True, step=step)
    assert crossings_per_frame(without, frames, stop_at_first=True)[-1] > 0
    scene, n = build(True, small=True, step=step)
    assert n >= frames
    assert max(crossings_per_frame(scene, frames)) == 0
    obj = scene.controller("colliders").self_collision
    assert obj.counter_values()["unresolved pairs"] == 0
    assert obj.zones_in_last(1.0) == 0  # nothing held at the end


def test_a_run_still_held_by_impact_zones_at_its_end_says_so():
    """The small jerked sheet (16 x 16) at its fixed step of 1/240 s folds over itself in its own plane; the fold
    cannot open without crossing, so impact zones hold it in every frame after the first few, and the summary of a
    third of a second warns, with the adaptive step as the way out (the stress scenes above end with none)."""
    jerked, _ = jerked_sheet(True, small=True, step="fixed")
    summary = jerked.run(20, progress=False)
    held = [w for w in summary.warnings if w.startswith("self-collision held parts of the cloth in")]
    assert len(held) == 1
    assert 'dt = "auto" in [integrator], with adaptive = { dt_max = 0.00417 }' in held[0]  # the way out (below)


def test_a_jerked_sheet_at_the_adaptive_step_does_not_lock():
    """The same jerk at dt = "auto" with 1/240 s as the longest step: the motion rule halves the step while the sheet
    moves fast, so the continuous stage's responses stay small, and after 2 s the sheet hangs with its springs back
    near the hung sheet's 0.88 % strain and no impact zone in the last second (at the fixed step above it locks with
    over 100 % strain)."""
    scene, _ = jerked_sheet(True, small=True, step="auto")
    crossings = crossings_per_frame(scene, 120)
    assert max(crossings) == 0
    assert scene.measure().max_strain < 0.015
    assert scene.controller("colliders").self_collision.zones_in_last(1.0) == 0
