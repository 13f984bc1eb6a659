"""Self-collision on cloth whose triangles change (a seam merge, a 4-8 level switch), and the exact count of
intersecting triangle pairs that measures it."""
import numpy as np
import pytest

import taichi_cloth as tc
from collision.intersections import _segment_pierces, count_intersecting_pairs, intersecting_pairs
from collision.self_collision import SelfCollision
from conftest import current_level, refine
from taichi_cloth.builder import multilevel_grid
from taichi_cloth.garment.garment import FreePlacement, GarmentSpec, build_garment
from taichi_cloth.garment.pattern import PatternPiece
from taichi_cloth.garment.seams import Seam, SeamSide


# ---------------------------------------------------------------------- the exact count
def test_two_triangles_intersect_exactly_when_an_edge_pierces_the_other():
    flat = [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    through = [[0.2, 0.2, -0.5], [0.3, 0.2, 0.5], [0.2, 0.4, 0.5]]  # an edge crosses the flat one at (0.25, 0.2)
    x = np.array(flat + through, float)
    assert count_intersecting_pairs(x, [[0, 1, 2], [3, 4, 5]]) == 1
    above = x.copy()
    above[3:, 2] += 0.51  # the lowest corner now 0.01 above the plane
    assert count_intersecting_pairs(above, [[0, 1, 2], [3, 4, 5]]) == 0
    beside = x.copy()
    beside[3:, 0] += 0.6  # the piercing point (0.85, 0.2) now lies beyond the hypotenuse x + y = 1
    assert count_intersecting_pairs(beside, [[0, 1, 2], [3, 4, 5]]) == 0
    # neighbours sharing a vertex always touch and are not counted, even folded through each other
    assert count_intersecting_pairs(x, [[0, 1, 2], [0, 4, 5]]) == 0


def test_the_broad_phase_misses_no_pair():
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 1, (90, 3))
    t = rng.permutation(90).reshape(30, 3)
    found = {tuple(p) for p in intersecting_pairs(x, t)}
    brute = set()
    for i in range(30):
        for j in range(i + 1, 30):
            a, b = x[t[i]], x[t[j]]
            hit = any(_segment_pierces(a[k][None], a[(k + 1) % 3][None], b[None])[0] for k in range(3)) or \
                any(_segment_pierces(b[k][None], b[(k + 1) % 3][None], a[None])[0] for k in range(3))
            if hit:
                brute.add((i, j))
    assert len(brute) > 10 and found == brute


def test_a_sheet_folded_through_itself_has_intersecting_pairs_and_a_flat_one_none():
    sheet = tc.ClothBuilder.grid((1.0, 1.0), (10, 10))
    x, t = sheet.positions.copy(), sheet.triangles
    assert count_intersecting_pairs(x, t) == 0
    # fold the half x > 0.1 back over the rest, 5 cm above it, then tilt it through the lower layer
    right = x[:, 0] > 0.1
    x[right, 0] = 0.2 - x[right, 0]
    x[right, 2] = 0.05 - 0.2 * (x[right, 0] + 0.4)
    assert count_intersecting_pairs(x, t) > 5


# ---------------------------------------------------------------------- a garment
def square(name, size=0.2):
    return PatternPiece.from_polygon(name, [[0, 0], [size, 0], [size, size], [0, size]],
                                     corner_names=["bl", "br", "tr", "tl"])


def pillowcase(spacing=0.02):
    """Two 0.2 m squares laid flat one above the other (4 cm apart, the upper one over a ball's top) and sewn along
    one side: the upper layer falls onto the lower one draped over the ball."""
    seam = Seam("side", SeamSide("A", "br", "tr"), SeamSide("B", "br", "tr"))
    down, left = (0.0, 0.0, 1.0), (1.0, 0.0, 0.0)
    spec = GarmentSpec("pillowcase", [square("A"), square("B")], [seam],
                       {"A": FreePlacement((0.0, 0.26, 0.0), left, down, at=(0.1, 0.1)),
                        "B": FreePlacement((0.0, 0.30, 0.0), left, down, at=(0.1, 0.1))}, spacing=spacing)
    return build_garment(spec)


def drape_pillowcase(self_collision: bool):
    sc = tc.Scene(pillowcase(), integrator="implicit", dt=1 / 240, air_damping=1.0,
                  integrator_options={"cg_tolerance": 1e-3}, self_collision=self_collision,
                  sewing=dict(close_speed=0.5, epsilon=0.002, gravity=True),
                  colliders=[{"type": "sphere", "center": [0, 0, 0], "radius": 0.25, "friction": 0.5}])
    sc.run(90, progress=False)  # 1.5 s
    return sc


@pytest.mark.slow
def test_self_collision_keeps_the_layers_of_a_sewn_garment_apart():
    without, with_ = drape_pillowcase(False), drape_pillowcase(True)
    for sc in (without, with_):
        assert sc.controller("sewing").joined  # the seam closed and merged with the layers held apart
        assert sc.model.data.n_particles == 2 * 121 - 11
    assert count_intersecting_pairs(without.positions(), without.model.data.triangles) > 10
    assert count_intersecting_pairs(with_.positions(), with_.model.data.triangles) == 0
    assert with_.controller("colliders").objects[-1].counter_values()["point-triangle contacts"] > 0


# ---------------------------------------------------------------------- a 4-8 cloth: a level switch
def test_self_collision_follows_a_level_switch_without_compiling():
    cloth = multilevel_grid((0.6, 0.6), (4, 4), 3, "cotton", center=(0.0, 0.3, 0.0), plane="xz")
    sc = tc.Scene(cloth, integrator="implicit", dt=1 / 120, self_collision=True, multilevel={"refine": False},
                  colliders=[{"type": "sphere", "center": [0, 0, 0], "radius": 0.2}])
    obj = sc.controller("colliders").objects[-1]
    assert isinstance(obj, SelfCollision)
    coarse = obj.thickness
    sc.step(12)
    refine(sc)
    assert current_level(sc) == 1
    assert obj.thickness == pytest.approx(coarse / np.sqrt(2), rel=0.05)  # a quarter of the new level's edge
    with tc.CompileCounter() as cc:
        sc.step(12)
        refine(sc)
        sc.step(12)
    assert cc.total == 0, cc.compiled
    assert sc.model.data.n_particles == len(cloth.levels[2].positions)
    assert count_intersecting_pairs(sc.positions(), sc.model.data.triangles) == 0


# ---------------------------------------------------------------------- the count in the summary and the recording
class _Snapshots:
    """A recorder that keeps the snapshots it is given (the Recorder's interface, nothing written)."""

    def __init__(self):
        self.layout, self.snaps = None, []

    def begin_cloth(self, entity, layout, translation=None):
        self.layout = layout

    def log_frame(self, entity, frame):
        self.snaps.append(frame)

    def log_events(self, entity, frame, t, events):
        """Events are not what these tests look at."""

    def flush(self):
        """Nothing is written."""


def folded_sheet():
    """A 10 x 10 sheet folded through itself, its rest shape that folded shape: 35 intersecting pairs."""
    sheet = tc.ClothBuilder.grid((1.0, 1.0), (10, 10))
    x = sheet.positions.copy()
    right = x[:, 0] > 0.1
    x[right, 0] = 0.2137 - x[right, 0]
    x[right, 1] += 0.0096
    x[right, 2] = 0.05 - 0.2 * (x[right, 0] + 0.4)
    a, b = sheet.springs[:, 0], sheet.springs[:, 1]
    sheet.positions, sheet.rest_length = x, np.linalg.norm(x[b] - x[a], axis=1)
    return sheet


def test_the_run_summary_and_the_recording_count_the_intersecting_pairs():
    """A sheet folded through itself, its rest shape that folded shape, no gravity: it stays put, so every count of
    the run, in the recording every quarter second (15 frames at 60 fps) and in the summary at the end, is the exact
    count of its pose (35 pairs; the folded half is shifted off the grid below it, so that no edge grazes a triangle
    and the count is the same at any jitter under 1e-5 m)."""
    sheet = folded_sheet()
    x = sheet.positions
    crossing = count_intersecting_pairs(x, sheet.triangles)
    assert crossing == 35
    sc = tc.Scene(sheet, integrator="explicit", dt=1 / 2400, gravity=(0.0, 0.0, 0.0), fps=60)
    rec = _Snapshots()
    summary = sc.run(30, recorder=rec, progress=False)
    assert summary.intersections == summary.intersections_max == crossing
    assert (f"self-intersection: {crossing} intersecting triangle pairs now, at most {crossing} (t = 0.000 s), "
            f"{crossing} at the start; counted every 0.25 s and at the end") in summary.format()
    assert "intersections" in rec.layout.series
    assert {s.frame: s.scalars["intersections"] for s in rec.snaps if "intersections" in s.scalars} == \
        {0: crossing, 15: crossing, 30: crossing}
    assert not any("starts with" in w for w in summary.warnings)  # no self-collision: nothing to warn about


def test_a_run_with_self_collision_that_starts_crossed_says_so():
    """The same folded sheet with self-collision: the run warns that it starts with 35 intersecting pairs that
    self-collision cannot pull apart."""
    sheet = folded_sheet()
    sc = tc.Scene(sheet, integrator="implicit", dt=1 / 60, gravity=(0.0, 0.0, 0.0), self_collision=True)
    summary = sc.run(2, progress=False)
    assert ("the cloth starts with 35 intersecting triangle pairs: self-collision keeps every layer on the side it "
            "starts on and cannot pull these apart (place the pieces apart before the run)") in summary.warnings


def test_the_largest_count_is_kept_with_its_time():
    """A run's count keeps the largest of its counts and when it was seen, and counts every quarter second."""
    from taichi_cloth.self_intersection import IntersectionCount

    tri = np.array([[0, 1, 2], [3, 4, 5]])
    crossed = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, -0.5], [0.3, 0.2, 0.5], [0.2, 0.3, 0.5]])
    apart = crossed + np.array([[0, 0, 0]] * 3 + [[0, 0, 2]] * 3)
    counts = IntersectionCount(fps=60)
    assert counts.every == 15 and [f for f in range(1, 46) if counts.due(f)] == [15, 30, 45] and counts.now is None
    assert counts.count(apart, tri, 0.25) == 0 and (counts.largest, counts.t_largest) == (0, 0.25)
    assert counts.count(crossed, tri, 0.5) == 1
    assert counts.count(apart, tri, 0.75) == 0
    assert (counts.now, counts.largest, counts.t_largest, counts.counted) == (0, 1, 0.5, 3)
