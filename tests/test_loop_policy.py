"""Loops run in one thread only where the arch makes that faster: on the CPU, for cloths below a particle count
(taichi_cloth.runtime.serial_loops), and never on a GPU (runtime.one_thread_loops). TAICHI_CLOTH_GPU_LOOPS=1 makes
the CPU follow the GPU's policy, so its paths compile and run here: the multigrid's coarsest level is then
factored column by column and solved by its inverse (linear.dense), the voxel grid's prefix sum is blocked.
The aggregation multigrid's parallel cycle: tests/test_aggregation_rigid.py.

Not covered: self-collision, whose continuous stage answers the closing pairs in one thread, in a fixed order, by
design (docs/performance.md, "Loops in one thread").
"""
import numpy as np
import trimesh

import taichi_cloth as tc
from collision.body import MeshCollider
from taichi_cloth.runtime import OneThreadLoops, one_thread_loops, serial_loops


def sheet(n=8):
    return tc.ClothBuilder.grid((0.4, 0.4), (n, n), "cotton", center=(0.0, 1.0, 0.0), plane="xz")


BALL = {"type": "sphere", "center": [0, 0.7, 0], "radius": 0.2}


def levels_sheet():
    """A sheet on the implicit step's 4-8 multigrid, in float64 with CG to 1e-10, with a stretch limit, above a
    mesh collider."""
    cloth = tc.ClothBuilder.multilevel_grid((0.4, 0.4), (4, 4), 3, "cotton", center=(0.0, 1.0, 0.0), plane="xz",
                                            start_level=2)
    sc = tc.Scene(cloth, integrator="implicit", dt=1 / 60, pins=[{"near": [(-0.2, 1.0, -0.2), (0.2, 1.0, -0.2)]}],
                  precision="f64", multilevel={"refine": "none"}, colliders=[mesh_ball()],
                  stretch_limit={"max_strain": 0.1},
                  integrator_options={"preconditioner": "multigrid", "cg_tolerance": 1e-10, "cg_max_iterations": 500})
    assert "4-8 levels" in sc.integrator.detail
    return sc


def fused_sheet():
    """The explicit family's fused steps (one launch per frame on a small cloth on the CPU)."""
    return tc.Scene(sheet(), integrator="explicit", dt=2e-4, colliders=[BALL])


def mesh_ball():
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    return MeshCollider(ball.vertices + [0.0, 0.7, 0.0], ball.faces, thickness=0.005)


def test_on_the_cpu_a_small_cloth_runs_its_loops_in_one_thread():
    assert one_thread_loops() and serial_loops(100)
    with OneThreadLoops() as seen:
        fused_sheet().step(2)
    assert seen.sites == {"FusedSteps._serial_steps", "Diagnostics._measure"}  # a frame's steps in one launch
    with OneThreadLoops() as seen:
        sc = tc.Scene(sheet(64), integrator="explicit", dt=2e-5)
        assert not sc.model.serial  # 4,096 particles: the explicit steps run in parallel
        sc.step(1)
    assert seen.sites == {"Diagnostics._measure"}  # the frame's sums still in one thread, in a fixed order


def test_under_the_gpu_policy_no_loop_runs_in_one_thread_and_the_multigrid_gives_the_cpu_answer(monkeypatch):
    """The explicit steps, the implicit step's CG and Newton iterations, the 4-8 multigrid, the stretch limit and a
    mesh collider (the aggregation multigrid: tests/test_aggregation_rigid.py). The multigrid, its coarsest level
    factored in parallel and solved by its inverse, takes the same CG iterations to a tight tolerance and gives the
    same positions to round-off, in float64. Neither policy reads the device inside a step: under the GPU's, CG
    launches the iterations its plan (twice the last frame's largest solve, and a chunk) allows."""
    with OneThreadLoops() as seen:  # on the CPU: the whole solve and the stretch limit's passes, one launch each
        sc = levels_sheet()
        summary = sc.run(4, progress=False, until_rest=False)
        x, its = sc.positions(), sc.integrator.stats["cg_iterations"]
    assert {"PCG._solve_in_thread", "StretchLimit._passes_in_thread"} <= seen.sites
    assert summary.host_reads_steps == 0
    monkeypatch.setenv("TAICHI_CLOTH_GPU_LOOPS", "1")
    assert not one_thread_loops() and not serial_loops(100)
    with OneThreadLoops() as seen:
        sc = fused_sheet()
        assert not sc.model.serial
        sc.step(2)
        sc = levels_sheet()
        summary = sc.run(4, progress=False, until_rest=False)
        assert sc.integrator.planned_cg and sc.integrator._plan < 500  # planned from frame 1's solves from then on
        assert summary.host_reads_steps == 0 and summary.host_reads_frames == 3
        assert sc.integrator.stats["cg_unconverged_steps"] == 0  # the plan was enough
        assert sc.integrator.stats["cg_iterations"] == its
        assert np.abs(sc.positions() - x).max() < 1e-10
    assert seen.sites == set()


def test_a_cg_plan_too_short_is_counted_and_doubled(monkeypatch):
    monkeypatch.setenv("TAICHI_CLOTH_GPU_LOOPS", "1")
    sc = tc.Scene(sheet(), integrator="implicit", dt=1 / 60, pins=[{"indices": [0, 7]}],
                  integrator_options={"preconditioner": "jacobi"})
    sc.run(2, progress=False)
    before = sc.integrator.stats["cg_unconverged_steps"]
    sc.integrator._plan = 2  # Jacobi takes tens of iterations here
    sc.run(1, progress=False)
    assert sc.integrator.stats["cg_unconverged_steps"] > before  # stopped short of the tolerance, and counted so
    assert sc.integrator._plan == 4  # twice the plan that ran out
