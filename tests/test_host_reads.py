"""The host reads the device once per frame in steady state: the measurement, which also carries what the
controllers need (taichi_cloth.hostreads). Inside the steps, no read: CG, Newton, the stretch limit decide on the
device. Each case runs a few frames to its steady state, then counts the reads of 4 frames exactly. Every
integrator, on a sphere and a mesh: tests/test_collision.py (drop_cloth).

Not covered: a cloth forced parallel on the CPU (TAICHI_CLOTH_PARALLEL_FROM), whose CG reads once per chunk of
iterations and whose self-collision reads the count of closing pairs after each continuous test: docs/performance.md,
"Host reads". The GPU's policy: tests/test_loop_policy.py.
"""
import numpy as np
import pytest

import taichi_cloth as tc
from taichi_cloth.hostreads import HostReads

FRAMES = 4


def sheet():
    """A horizontal 0.4 m sheet of 8 x 8 particles at y = 1 m (held by two corners of one edge in most cases)."""
    return tc.ClothBuilder.grid((0.4, 0.4), (8, 8), "cotton", center=(0.0, 1.0, 0.0), plane="xz")


def steady_reads(scene, warm: int = 3):
    """The summary of FRAMES frames after `warm` ones (frames 2.. of the counted run are in its host-read figures:
    the run adds a frame first so that all FRAMES are counted)."""
    scene.run(warm, progress=False, until_rest=False)
    return scene.run(FRAMES + 1, progress=False, until_rest=False)


def assert_one_read_per_frame(summary):
    assert summary.host_reads_steps == 0, summary.format()
    assert summary.host_reads_frames == FRAMES, summary.format()


def test_the_4_8_multigrid_and_the_refiner_read_once_per_frame():
    cloth = tc.ClothBuilder.multilevel_grid((0.4, 0.4), (4, 4), 3, "cotton", center=(0.0, 1.0, 0.0), plane="xz",
                                            start_level=2)
    sc = tc.Scene(cloth, integrator="implicit", dt=1 / 120, pins=[{"near": [(-0.2, 1.0, -0.2), (0.2, 1.0, -0.2)]}],
                  integrator_options={"preconditioner": "multigrid"}, multilevel={"refine": "none"})
    assert "4-8 levels" in sc.integrator.detail
    assert_one_read_per_frame(steady_reads(sc))


def test_the_implicit_step_and_the_controllers_read_nothing_more():
    """A moving pin, gusting wind, the stretch limit, a plane, a capsule and the adaptive step together (the
    explicit family runs the same controllers' kernels), on the implicit step with its aggregation multigrid (the
    cycle inside CG's one launch; Jacobi's: the sewing case below) iterating Newton to a tight tolerance: several
    Newton iterations per step, each decided on the device."""
    path = [[0.0, -0.2, 1.0, 0.0], [2.0, 0.2, 1.1, 0.0]]
    sc = tc.Scene(sheet(), integrator="implicit", dt="auto",
                  pins=[{"indices": [0]}, {"indices": [7], "keyframes": path}],
                  wind={"velocity": (0.0, 0.0, 2.0), "gust": 0.5}, stretch_limit={"max_strain": 0.1},
                  colliders=[{"type": "plane", "point": [0, 0.5, 0], "normal": [0, 1, 0]},
                             {"type": "capsule", "a": [-0.2, 0.8, 0.1], "b": [0.2, 0.8, 0.1], "radius": 0.05}],
                  integrator_options={"preconditioner": "multigrid", "newton_converge": True,
                                      "newton_tolerance": 1e-6})
    assert "aggregation" in sc.integrator.detail
    summary = steady_reads(sc)
    assert_one_read_per_frame(summary)
    assert summary.stats["newton_iterations per step"] > 1.5  # more than one, as the options ask


def test_sewing_reads_its_seam_gaps_with_the_measurement():
    from test_garment import two_squares

    from taichi_cloth.garment.garment import build_garment

    g = build_garment(two_squares())
    sc = tc.Scene(g, integrator="implicit", dt=1 / 240, gravity=(0, 0, 0), sewing=dict(close_speed=0.05))
    summary = steady_reads(sc)
    assert_one_read_per_frame(summary)
    sewing = sc.controller("sewing")
    assert sewing.active  # still sewing: the gaps were measured on the device every frame
    x = sc.positions()
    pairs = g.seam_pairs
    exact = np.linalg.norm(x[pairs[:, 1]] - x[pairs[:, 0]], axis=1)
    assert sewing.history[-1].max == exact.max()  # the same float64 arithmetic on the same float32 positions
    assert sewing.history[-1].mean == pytest.approx(exact.mean(), rel=1e-12)


def test_the_counter_names_every_kind_of_read():
    sc = tc.Scene(sheet(), integrator="explicit", dt=2e-4)
    with HostReads() as reads:
        sc.model.n_particles[None]   # a scalar field's element
        sc.forces.gravity[None].to_list()  # a vector field's element: one read per entry
        sc.state.x.to_numpy()        # a whole field
        sc.measure()                 # a to_numpy inside the engine
    assert reads.total == 1 + 3 + 1 + 1
    assert reads.by_site["Diagnostics.measure"] == 1
    with HostReads() as writes:
        sc.forces.gravity[None] = [0.0, -9.81, 0.0]
        sc.state.x.from_numpy(sc.state.x.to_numpy())
    assert writes.total == 1  # the to_numpy; writes wait for nothing


def test_self_collision_reads_nothing_inside_the_steps():
    """The jerked sheet (benchmarks/self_collision_stress.py, 16 x 16) on the explicit step folds over itself: in the
    counted frames the passes push its layers apart, on the device; the grid's capacity check travels with the
    measurement. (The implicit step on the same sheet, whose continuous stage merges impact zones in most frames,
    reads nothing inside its steps either: tests/test_self_collision_stress.py.)"""
    from benchmarks.self_collision_stress import jerked_sheet

    scene, _ = jerked_sheet(True, small=True, integrator="explicit", step="fixed")
    obj = scene.controller("colliders").self_collision
    scene.run(6, progress=False, until_rest=False)
    before = obj.counter_values()
    summary = scene.run(FRAMES + 1, progress=False, until_rest=False)
    assert_one_read_per_frame(summary)
    after = obj.counter_values()
    assert after["point-triangle contacts"] > before["point-triangle contacts"]
    assert after["edge-edge contacts"] > before["edge-edge contacts"]
