"""A scene builds and compiles only what it names; changing a parameter never recompiles."""
import numpy as np
import pytest
import taichi as ti

import taichi_cloth as tc
from taichi_cloth.frame import scene_snapshot


def names(counter):
    return " ".join(counter.names())


def grid():
    return tc.ClothBuilder.grid((0.4, 0.4), (6, 6), "cotton", center=(0.0, 1.0, 0.0))


def test_unnamed_components_are_never_built_or_compiled():
    with tc.CompileCounter() as cc:
        sc = tc.Scene(grid(), integrator="approx-implicit", dt=0.005, pins=[{"indices": [30, 35]}])
        sc.step(3)
    assert [c.name for c in sc.controllers] == ["pins"] and not sc.controller("pins").moving
    assert sc.forces.sources == () and sc.contacts is None
    compiled = cc.names()
    for absent in ("Wind", "VertexNormals", "StretchLimit", "PinDriver", "Implicit", "FusedSteps"):
        assert not any(name.split(".")[0] == absent for name in compiled), compiled
    assert "ApproxImplicit._sweeps" in compiled


def test_named_components_compile_their_kernels():
    with tc.CompileCounter() as cc:
        sc = tc.Scene(grid(), integrator="explicit", dt=1e-4, wind={"velocity": (0, 0, 3.0)},
                      stretch_limit={"max_strain": 0.1},
                      pins=[{"indices": [30], "keyframes": [[0, 0, 0, 0], [1, 0.1, 0, 0]]}])
        sc.step(2)
    compiled = names(cc)
    for present in ("VertexNormals.compute", "StretchLimit._passes", "PinDriver._place", "FusedSteps._step"):
        assert present in compiled
    assert "ApproxImplicit" not in compiled


def test_changing_parameters_does_not_recompile():
    sc = tc.Scene(grid(), integrator="approx-implicit", dt=0.005, pins=[{"indices": [30, 35]}])
    sc.step(2)
    with tc.CompileCounter() as cc:
        sc.dt = 0.002
        sc.model.set_stiffness(3 * sc.model.data.stiffness)
        sc.model.set_mass(2 * sc.model.data.mass)
        sc.forces.set_gravity((0.0, -1.0, 0.0))
        sc.forces.set_air_damping(0.7)
        sc.reset()
        sc.step(5)
    assert cc.total == 0, cc.compiled


@pytest.mark.slow
def test_field_blocks_of_dead_owners_are_recycled():
    """Taichi crashes after ~500 SNode trees; blocks of collected owners are destroyed before that happens."""
    import gc

    import numpy as np

    from clothbase import fields

    class Owner:
        """Anything whose lifetime a block follows."""

    for k in range(700):
        owner = Owner()
        blk = fields.FieldBlock()
        f = blk.scalar(ti.f32, 8)
        blk.finalize(owner)
        if k % 25 == 0 or k == 699:  # each new field compiles its own copy kernels (~0.1 s): use a sample
            f.from_numpy(np.arange(8, dtype=np.float32))
            assert f.to_numpy()[7] == 7.0
        del owner, blk, f  # the owner dies here (no cycle): its finalizer retires the tree
        if k % 100 == 0:
            gc.collect()  # a full collection costs ~0.1 s late in a session full of scenes
    assert fields.live_trees() <= fields.LIVE_TREE_LIMIT + 2


def test_a_feature_is_a_controller_added_without_touching_the_loop():
    """A controller of one's own: it counts steps, switches gravity off after frame 3 (its change is applied by the
    scene and noted as an event) and records a scalar; the loop runs it without knowing it."""
    from taichi_cloth.control import Controller, ModelChange

    class ZeroGravity(Controller):
        name = "zero_g"

        def __init__(self, forces):
            self.forces, self.steps, self.frames = forces, 0, []

        def after_step(self, t, dt):
            self.steps += 1

        def after_frame(self, frame):
            self.frames.append(frame.frame)
            if frame.frame == 3:
                self.forces.set_gravity((0.0, 0.0, 0.0))
                return ModelChange(event="gravity off")
            return None

        def record(self, frame):
            frame.scalars["zero_g/steps"] = self.steps

    sc = tc.Scene(grid(), dt=1 / 120)
    zero_g = ZeroGravity(sc.forces)
    sc.add_controller(zero_g)
    assert sc.controller("zero_g") is zero_g
    summary = sc.run(5, progress=False)
    assert zero_g.steps == 10 and zero_g.frames == [1, 2, 3, 4, 5] and summary.events == ["gravity off"]
    assert scene_snapshot(sc, 5, sc.measure()).scalars["zero_g/steps"] == 10
    v = sc.velocities()  # free flight from frame 3 on: every particle keeps its velocity (drag aside)
    sc.run(1, progress=False)
    np.testing.assert_allclose(sc.velocities(), v * (1 - 0.1 / 120) ** 2, rtol=1e-3, atol=1e-5)
    assert np.abs(v[:, 1]).min() > 0.3  # it was falling (1/20 s of gravity)


def test_the_kernels_a_process_compiled_are_in_the_offline_cache_after_it_exits(tmp_path):
    """Taichi writes its offline cache only when its runtime is finalised; `tc.init` does that at exit, so the
    next run loads a scene's kernels instead of compiling them (12-13 s against 3 s for the 4-8 T-shirt)."""
    import subprocess
    import sys

    cache = tmp_path / "ticache"
    script = ("import taichi_cloth as tc\n"
              f"tc.init('cpu', offline_cache_file_path={str(cache)!r})\n"
              "cloth = tc.ClothBuilder.grid(size=(0.2, 0.2), resolution=(4, 4), material='cotton', plane='xz')\n"
              "tc.Scene(cloth, integrator='explicit', dt=1e-3).step(1)\n")
    subprocess.run([sys.executable, "-c", script], check=True, capture_output=True, timeout=300)
    assert list(cache.rglob("*.tic")), sorted(p.name for p in cache.rglob("*"))


def test_a_step_refuses_a_state_its_kernels_were_not_built_for():
    """A Taichi kernel binds the fields it reads when it compiles: the integrator and the collision stage step only
    the state and contacts they were built with, and say so for another."""
    a = tc.Scene(grid(), integrator="explicit", dt=5e-4, colliders=[{"type": "sphere", "center": [0, 0, 0],
                                                                      "radius": 0.1}])
    b = tc.Scene(grid(), integrator="explicit", dt=5e-4, colliders=[{"type": "sphere", "center": [0, 0, 0],
                                                                      "radius": 0.1}])
    with pytest.raises(ValueError, match="built for another state"):
        a.integrator.step(b.state, a.contacts, 5e-4)
    with pytest.raises(ValueError, match="built for another contacts"):
        a.integrator.step(a.state, b.contacts, 5e-4)
    with pytest.raises(ValueError, match="built for another state"):
        a.collision.collide(b.state, a.contacts, 5e-4)
    a.substep(5e-4)  # its own state: one step as a run takes it
    assert a.state.t == pytest.approx(5e-4) and a.steps_taken == 1
