"""A scene builds and compiles only what it names; changing a parameter never recompiles."""
import pytest
import taichi as ti

import taichi_cloth as tc


def names(counter):
    return " ".join(counter.names())


def grid():
    return tc.ClothBuilder.grid((0.4, 0.4), (6, 6), "cotton", center=(0.0, 1.0, 0.0))


def test_unnamed_components_are_never_built_or_compiled():
    with tc.CompileCounter() as cc:
        sc = tc.Scene(grid(), integrator="approx-implicit", dt=0.005, pins=[{"indices": [30, 35]}])
        sc.step(3)
    assert [c.name for c in sc.controllers] == ["pins"] and not sc.controller("pins").moving
    assert sc.forces.sources == () and sc.state.contacts is None
    compiled = cc.names()
    for absent in ("Wind", "VertexNormals", "StretchLimit", "PinDriver", "Implicit", "SymplecticEuler", "HistoryIntegrator"):
        assert not any(name.split(".")[0] == absent for name in compiled), compiled
    assert "ApproxImplicit._sweeps" in compiled


def test_named_components_compile_their_kernels():
    with tc.CompileCounter() as cc:
        sc = tc.Scene(grid(), integrator="explicit", dt=1e-4, wind={"velocity": (0, 0, 3.0)},
                      stretch_limit={"max_strain": 0.1}, pins=[{"indices": [30], "path": [[0, 0, 0, 0], [1, 0.1, 0, 0]]}])
        sc.step(2)
    compiled = names(cc)
    for present in ("VertexNormals.compute", "StretchLimit._project", "PinDriver._place", "SymplecticEuler._advance"):
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
        del owner, blk, f
        gc.collect()
    assert fields.live_trees() <= fields.LIVE_TREE_LIMIT + 2
