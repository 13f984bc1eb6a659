"""Loops run in one thread only where the arch makes that faster: on the CPU, for cloths below a particle count
(taichi_cloth.runtime.serial_loops), and never on a GPU (runtime.one_thread_loops). TAICHI_CLOTH_GPU_LOOPS=1 makes
the CPU follow the GPU's policy, so its paths compile and run here: the multigrid's coarsest level is then
factored column by column and solved by its inverse (linear.dense), the voxel grid's prefix sum is blocked.

Not covered: self-collision, whose continuous stage answers the closing pairs in one thread, in a fixed order, by
design (docs/performance.md, "Loops in one thread").
"""
import numpy as np
import trimesh

import taichi_cloth as tc
from collision.body import MeshCollider
from taichi_cloth.integrators.fused import FusedSteps
from taichi_cloth.linear import PCG
from taichi_cloth.stretch_limit import StretchLimit
from taichi_cloth.runtime import OneThreadLoops, one_thread_loops, serial_loops


def sheet(n=8):
    return tc.ClothBuilder.grid((0.4, 0.4), (n, n), "cotton", center=(0.0, 1.0, 0.0), plane="xz")


BALL = {"type": "sphere", "center": [0, 0.7, 0], "radius": 0.2}


def multigrid(cloth: str):
    """A sheet on the implicit step's multigrid (aggregation, or its 4-8 levels), in float64 with CG to 1e-10."""
    if cloth == "aggregation":
        c, pins, extra = sheet(10), [{"indices": [0, 9]}], {}
    else:
        c = tc.ClothBuilder.multilevel_grid((0.4, 0.4), (2, 2), 3, "cotton", center=(0.0, 1.0, 0.0), plane="xz")
        pins, extra = [{"near": [(-0.2, 1.0, -0.2), (0.2, 1.0, -0.2)]}], {"multilevel": {"refine": "none"}}
    sc = tc.Scene(c, integrator="implicit", dt=1 / 60, pins=pins, precision="f64", **extra,
                  integrator_options={"preconditioner": "multigrid", "cg_tolerance": 1e-10, "cg_max_iterations": 500})
    assert cloth in sc.integrator.detail
    return sc


def scenes():
    """The components with a one-thread path on the CPU: the fused explicit steps, the implicit step's solve (both
    preconditioners' cycles), the stretch limit, a mesh collider's voxel grid."""
    yield tc.Scene(sheet(), integrator="explicit", dt=2e-4, colliders=[BALL])
    yield tc.Scene(sheet(), integrator="implicit", dt=1 / 120, pins=[{"indices": [0, 7]}], colliders=[BALL],
                   stretch_limit={"max_strain": 0.1}, integrator_options={"preconditioner": "jacobi"})
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    yield tc.Scene(sheet(), integrator="explicit", dt=2e-4,
                   colliders=[MeshCollider(ball.vertices + [0.0, 0.7, 0.0], ball.faces, thickness=0.005)])


def test_on_the_cpu_a_small_cloth_runs_its_loops_in_one_thread():
    assert one_thread_loops() and serial_loops(100)
    with OneThreadLoops() as seen:
        for sc in scenes():
            sc.step(2)
    # the fused explicit frame, the whole CG solve and the stretch limit's passes, each one launch
    assert {"FusedSteps._serial_steps", "PCG._solve_in_thread", "StretchLimit._passes_in_thread"} <= seen.sites


def test_under_the_gpu_policy_no_loop_runs_in_one_thread_and_the_multigrid_gives_the_cpu_answer(monkeypatch):
    """The multigrid with its coarsest level factored in parallel and solved by its inverse: the same CG
    iterations to a tight tolerance, the same positions to round-off, in float64."""
    cpu = {}
    for cloth in ("aggregation", "4-8 levels"):
        sc = multigrid(cloth)
        sc.step(3)
        cpu[cloth] = (sc.positions(), sc.integrator.stats["cg_iterations"])
    monkeypatch.setenv("TAICHI_CLOTH_GPU_LOOPS", "1")
    assert not one_thread_loops() and not serial_loops(100)
    for chunked in (FusedSteps, PCG, StretchLimit):  # one step or iteration per launch: the same loops, unrolled
        monkeypatch.setattr(chunked, "CHUNK", 1)   # once, compile in a fraction of the time
    with OneThreadLoops() as seen:
        for sc in scenes():
            assert not sc.model.serial
            sc.step(2)
        for cloth, (x, its) in cpu.items():
            sc = multigrid(cloth)
            sc.step(3)
            assert sc.integrator.stats["cg_iterations"] == its
            assert np.abs(sc.positions() - x).max() < 1e-10
    assert seen.sites == set()
