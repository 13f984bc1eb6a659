"""The automatic step, Scene(dt="auto") (taichi_cloth.adaptive; docs/algorithms.md, step limits "Adaptive step").

An explicit integrator on auto runs stable where a frame-sized step blows up; its steps stay at or below
safety x the stable bound and fill whole frames; the bound follows the model (set_stiffness, a 4-8 level switch);
changing the step compiles nothing; fast motion near a collider halves the step; a blow-up the theory missed is
rolled back. Scene files take dt = "auto" and an [integrator] adaptive table, with one-line errors.
"""
import math

import numpy as np
import pytest

import taichi_cloth as tc
from taichi_cloth.adaptive import AdaptiveOptions
from taichi_cloth.scenefile import load_scene
from conftest import refine

FRAME = 1.0 / 60.0
SAFETY = AdaptiveOptions.safety


def stiff_cloth(n: int = 10):
    """A 0.5 m denim square hanging from two corners: its stable explicit step (~3e-4 s) is far below a frame."""
    cloth = tc.ClothBuilder.grid((0.5, 0.5), (n, n), "denim", center=(0.0, 1.0, 0.0), plane="xy")
    return cloth, [n * (n - 1), n * n - 1]


def assert_frame_aligned(scene):
    assert scene.substeps * scene.dt == pytest.approx(FRAME, rel=1e-12)


@pytest.mark.filterwarnings(r"ignore:dt = 0\.0167 s exceeds the stable step .* of integrator 'explicit'"
                            ":clothbase.errors.EngineWarning")  # the fixed frame step it shows blowing up
def test_auto_runs_stable_where_a_frame_step_blows_up():
    cloth, top = stiff_cloth()
    fixed = tc.Scene(cloth, integrator="explicit", dt=FRAME, pins=[{"indices": top}])
    with pytest.raises(tc.BlowUpError):
        fixed.run(3, progress=False)

    scene = tc.Scene(cloth, integrator="explicit", dt="auto", pins=[{"indices": top}], step_guard="refuse")
    bound = scene.stable_dt
    assert bound < FRAME / 40  # the scene really is stiff
    summary = scene.run(12, progress=False)
    assert summary.blowup is None and summary.final.nonfinite == 0
    # every step at or below safety x the bound, and the largest such step that fills a frame evenly
    assert summary.dt_max <= SAFETY * bound * (1 + 1e-12)
    assert scene.substeps == math.ceil(FRAME / (SAFETY * bound))
    assert_frame_aligned(scene)
    assert summary.sim_time == pytest.approx(12 * FRAME, rel=1e-9)
    assert "dt = auto (0.8 x the stable step)" in summary.format()
    assert f"{summary.dt_min:.3g} .. {summary.dt_max:.3g} s" in summary.format()
    # the sheet hangs: it fell under gravity at the physical rate (not frozen by a tiny step)
    assert summary.final.max_strain < 0.05


def test_auto_follows_the_model_and_never_recompiles():
    cloth, top = stiff_cloth(8)
    scene = tc.Scene(cloth, integrator="verlet", dt="auto", pins=[{"indices": top}])
    scene.run(2, progress=False)  # compiles
    dt0, n0 = scene.dt, scene.substeps
    with tc.CompileCounter() as cc:
        scene.model.set_stiffness(4.0 * scene.model.data.stiffness)  # bound / 2
        stiff_bound = scene.stable_dt
        summary = scene.run(2, progress=False)
        scene.model.set_mass(4.0 * scene.model.data.mass)  # bound x 2 again
        scene.run(1, progress=False)
    assert cc.total == 0, cc.compiled
    # the stiffer model's step: the largest frame divisor at or below safety x its bound, about half the first
    assert summary.dt_min == summary.dt_max == pytest.approx(FRAME / math.ceil(FRAME / (SAFETY * stiff_bound)))
    assert 0.45 * dt0 < summary.dt_max < 0.55 * dt0
    assert scene.dt == pytest.approx(dt0, rel=1e-9) and scene.substeps == n0  # set_mass undid it
    assert_frame_aligned(scene)


def test_auto_adapts_at_a_multilevel_level_switch():
    cloth = tc.ClothBuilder.multilevel_grid((0.6, 0.6), (4, 4), 3, "denim", center=(0.0, 1.0, 0.0), plane="xy")
    scene = tc.Scene(cloth, integrator="explicit", dt="auto", pins=[{"near": [(-0.3, 1.3, 0.0), (0.3, 1.3, 0.0)]}],
                     multilevel={"refine": "none"})
    scene.run(1, progress=False)
    coarse_dt, coarse_bound = scene.dt, scene.stable_dt
    refine(scene)  # a new model: on auto, the step is re-planned from the finer level's bound
    fine_bound = scene.stable_dt
    assert fine_bound < 0.9 * coarse_bound  # a finer level has a smaller stable step
    assert scene.dt == pytest.approx(FRAME / math.ceil(FRAME / (SAFETY * fine_bound))) and scene.dt < coarse_dt
    with tc.CompileCounter() as cc:
        summary = scene.run(2, progress=False)  # the same kernels, another dt
    assert cc.total == 0, cc.compiled
    assert summary.blowup is None and summary.dt_max <= SAFETY * fine_bound
    assert_frame_aligned(scene)


def test_unconditionally_stable_integrators_take_one_step_per_frame():
    cloth, top = stiff_cloth(6)
    scene = tc.Scene(cloth, integrator="approx-implicit", dt="auto", pins=[{"indices": top}])
    assert scene.stable_dt is None and scene.substeps == 1 and scene.dt == pytest.approx(FRAME)
    scene = tc.Scene(cloth, integrator="approx-implicit", dt="auto", adaptive={"dt_max": 0.004},
                     pins=[{"indices": top}])
    assert scene.substeps == 5 and scene.dt == pytest.approx(FRAME / 5)  # the largest step <= dt_max


@pytest.mark.slow
def test_fast_motion_near_a_collider_halves_the_step_and_calm_regrows_it():
    """A sheet falls onto a sphere with one implicit step per frame: at 1/60 s and ~1 m/s a particle moves
    17 mm per step, beyond half the 3 mm thickness, so the motion rule halves the step until it is not; once
    the sheet rests on the sphere the step regrows by 1.25 per 50 calm steps up to a frame."""
    cloth = tc.ClothBuilder.grid((0.4, 0.4), (8, 8), "cotton", center=(0.0, 0.3, 0.0), plane="xz")
    scene = tc.Scene(cloth, integrator="implicit", dt="auto", air_damping=2.0,
                     colliders=[{"type": "sphere", "center": (0.0, 0.0, 0.0), "radius": 0.2, "thickness": 0.003}])
    limit = 0.5 * 0.003
    a = scene.clock
    assert a.max_move == pytest.approx(limit) and scene.substeps == 1
    for _ in range(12):  # falling: the step planned after each frame keeps its end speed within the limit (x the
        m = scene.run(1, progress=False).final  # regrowth factor: a regrown step is checked again next frame)
        a.refresh()
        assert m.max_speed * scene.dt <= limit * a.options.growth
    assert a.halvings >= 3 and scene.dt <= FRAME / 8
    summary = scene.run(40, progress=False)  # landed and slowing: calm steps regrow it
    assert "halvings on fast motion" in summary.format() or "regrowths" in summary.format()
    assert a.regrowths > 0 and scene.dt > summary.dt_min
    assert summary.blowup is None
    assert_frame_aligned(scene)


def test_a_blow_up_the_theory_missed_is_rolled_back_with_a_halved_step():
    """The spring constants are raised in the field behind the model's back (what the linear bound does not
    see, like a stiff contact): the planned step is then 3x beyond the real limit. Auto mode rolls each frame that
    blows up back to its start, halves the step and goes on; the summary lists the rollbacks."""
    cloth, top = stiff_cloth(8)
    scene = tc.Scene(cloth, integrator="explicit", dt="auto", pins=[{"indices": top}])
    scene.run(1, progress=False)
    k = scene.model.data.stiffness
    scene.model.stiffness.from_numpy((30.0 * k).astype(np.float32))  # data (and so the bound) unchanged
    scene.model.stiffness_sum.from_numpy((30.0 * scene.model.stiffness_sum_np()).astype(np.float32))
    dt0 = scene.dt
    summary = scene.run(5, progress=False)
    assert summary.blowup is None and summary.final.nonfinite == 0
    assert scene.clock.rollbacks >= 1 and any("rolled back" in e for e in summary.events)
    assert summary.dt_max <= 0.5 * dt0 * (1 + 1e-12)  # only halved steps were kept
    assert summary.sim_time == pytest.approx(5 * FRAME, rel=1e-9)  # no frame lost (the run started at one frame)
    # without rollback the same run stops with the usual report
    scene = tc.Scene(cloth, integrator="explicit", dt="auto", adaptive={"rollback": False}, pins=[{"indices": top}])
    scene.model.stiffness.from_numpy((30.0 * k).astype(np.float32))
    with pytest.raises(tc.BlowUpError, match="suggested stable step"):
        scene.run(3, progress=False)


def scene_dict(**integrator):
    return {"cloth": {"grid": {"size": [0.3, 0.3], "resolution": [6, 6]}},
            "integrator": {"name": "explicit", **integrator}}


def test_scene_file_takes_dt_auto_and_an_adaptive_table():
    loaded = load_scene(scene_dict(dt="auto", adaptive={"safety": 0.5, "calm_steps": 20}))
    a = loaded.scene.clock
    assert a.options.safety == 0.5 and a.options.calm_steps == 20 and a.options.growth == 1.25
    assert loaded.scene.dt <= 0.5 * loaded.scene.stable_dt
    assert load_scene(scene_dict(dt="auto"), dt=0.0001).scene.clock.auto is False  # --dt replaces auto
    assert load_scene(scene_dict(dt=0.0001), dt="auto").scene.clock.auto


@pytest.mark.parametrize("integrator, message", [
    ({"dt": "fast"}, '[integrator] dt: must be a number of seconds or "auto", got \'fast\''),
    ({"dt": 0}, "[integrator] dt: must be > 0, got 0"),
    ({"dt": 0.001, "adaptive": {"safety": 0.5}}, '[integrator] adaptive: needs dt = "auto" (dt is 0.001)'),
    ({"dt": "auto", "adaptive": {"safety": 1.5}}, "[integrator.adaptive] safety: must lie in (0, 1], got 1.5"),
    ({"dt": "auto", "adaptive": {"saftey": 0.5}},
     "[integrator.adaptive]: unknown key 'saftey' (did you mean 'safety'?)"),
    ({"dt": "auto", "adaptive": {"calm_steps": 0}}, "[integrator.adaptive] calm_steps: must be >= 1, got 0"),
])
def test_scene_file_errors_name_the_key(integrator, message):
    with pytest.raises(tc.SceneError) as err:
        load_scene(scene_dict(**integrator))
    assert str(err.value) == f"scene: {message}"


@pytest.mark.parametrize("kwargs, message", [
    ({"dt": "Auto"}, "dt must be a positive number of seconds or 'auto', got 'Auto'"),
    ({"dt": -1.0}, "dt must be a positive number of seconds or 'auto', got -1.0"),
    ({"dt": 0.001, "adaptive": {}}, "adaptive options need dt = 'auto'"),
    ({"dt": "auto", "adaptive": {"grow": 2}}, "adaptive has no option 'grow'"),
    ({"dt": "auto", "adaptive": {"growth": 1.0}}, "adaptive growth must be > 1, got 1.0"),
    ({"dt": "auto", "adaptive": {"dt_min": 0.1}}, "adaptive dt_min = 0.1 s must be below the frame time"),
    ({"dt": "auto", "adaptive": {"dt_min": 1e-3, "dt_max": 1e-4}}, "adaptive dt_max must be > dt_min = 0.001 s"),
])
def test_python_api_errors(kwargs, message):
    cloth, _ = stiff_cloth(4)
    with pytest.raises(tc.SceneError, match=message.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")):
        tc.Scene(cloth, integrator="explicit", **kwargs)
