"""A scene with body measurements: the mannequin fitted before the run (the garment placed on it, the collider
built from it) or morphed during the drape (the collider rebuilt as it changes, the garment following)."""
from pathlib import Path

import numpy as np
import pytest

import taichi_cloth as tc
from taichi_cloth.body import default_body, fit_body
from taichi_cloth.errors import SceneError
from taichi_cloth.garment.garment import build_garment
from taichi_cloth.garment.garmentfile import load_garment
from taichi_cloth.garment.metrics import garment_quality
from taichi_cloth.scenefile import load_scene, parse_scene

DEMOS = Path(__file__).resolve().parent.parent / "demos"
MANNEQUIN = {"type": "mesh", "path": "mannequin", "thickness": 0.004, "friction": 0.4}


def skirt_scene(**body) -> dict:
    return {"name": "skirt", "frames": 0, "air_damping": 1.0,
            "cloth": {"garment": str(DEMOS / "garments" / "skirt.toml")},
            "integrator": {"name": "implicit", "dt": 1 / 120, "cg_tolerance": 1e-2},
            "sewing": {"energy_tolerance": 0.05}, "colliders": [dict(MANNEQUIN)], "body": body,
            "output": {"record": False, "mesh": False}}


@pytest.mark.parametrize("body, colliders, message", [
    ({"morph": "before"}, True, "names no girth"),
    ({"waist": 0.7}, False, "add [[colliders]]"),
    ({"waist": 0.7, "morph": "later"}, True, "'later' is not one of"),
    ({"waistline": 0.7}, True, "did you mean 'waist'"),
])
def test_body_table_errors_name_the_problem(body, colliders, message):
    cfg = skirt_scene(**body)
    if not colliders:
        cfg["colliders"] = []
    with pytest.raises(SceneError, match=message.replace("[", r"\[")):
        parse_scene(cfg)


def test_out_of_reach_girth_is_refused_with_the_range():
    with pytest.raises(SceneError) as err:
        load_scene(skirt_scene(waist=1.20))
    msg = str(err.value)
    assert "[body]" in msg and "waist" in msg and "reachable range" in msg and "\n" not in msg


def test_body_fitted_before_the_run_carries_the_collider_and_the_placement():
    loaded = load_scene(skirt_scene(waist=0.63, hips=0.92))
    scene = loaded.scene
    fit = fit_body({"waist": 0.63, "hips": 0.92})
    np.testing.assert_array_equal(scene.controller("colliders").objects[0].vertices_np, fit.vertices)
    assert scene.controller("body_morph") is None
    body = scene.controller("sewing").garment.body
    np.testing.assert_array_equal(body.vertices, fit.vertices)
    # placement analysed the fitted body: its hull girths moved with the targets (0.669 / 0.955 on the base)
    assert body.girths["waist"] == pytest.approx(0.63, abs=0.01)
    assert body.girths["hips"] == pytest.approx(0.92, abs=0.01)


def sewn_skirt(body_morph=None):
    spec = load_garment(DEMOS / "garments" / "skirt.toml")
    spec.spacing = 0.03
    return tc.Scene(build_garment(spec), integrator="implicit", dt=1 / 120, integrator_options={"cg_tolerance": 1e-2},
                    air_damping=1.0, colliders=[dict(MANNEQUIN)], stretch_limit=dict(max_strain=0.1, iterations=20),
                    sewing=dict(energy_tolerance=0.05), body_morph=body_morph)


@pytest.mark.slow
def test_a_skirt_sewn_coarse_to_fine_follows_a_body_that_grows_through_its_level_switches():
    """The body morph on a garment on 4-8 levels: sewn on level 1 of 3, the body grows (0.5 s) while the refiner
    switches to levels 2 and 3; the collider ends as the fitted body, the seams stay closed, nothing is inside."""
    from taichi_cloth.garment.levels import multilevel_garment

    blend, gauge = default_body()
    base_girths = gauge.measure(blend.base, names=["waist", "hips"])
    fit = fit_body({"waist": base_girths["waist"] + 0.03, "hips": base_girths["hips"] + 0.05})
    spec = load_garment(DEMOS / "garments" / "skirt.toml")
    spec.spacing, spec.levels = 0.03, 3
    scene = tc.Scene(multilevel_garment(spec), integrator="implicit", dt=1 / 120,
                     integrator_options={"cg_tolerance": 1e-2}, air_damping=1.0, colliders=[dict(MANNEQUIN)],
                     stretch_limit=dict(max_strain=0.1, iterations=20), sewing=dict(energy_tolerance=0.05),
                     body_morph={"weights": fit.weights, "duration": 0.5}, multilevel=dict(max_time=0.2))
    morph, refiner, sewing = scene.controller("body_morph"), scene.controller("refiner"), scene.controller("sewing")
    while not (morph.done and refiner.at_finest) and scene.state.t < 3.0:
        scene.run(6, progress=False)
    assert morph.done and refiner.at_finest and len(refiner.switches) == 3  # the start level, 2 and 3
    switched = [s.t for s in refiner.switches[1:]]
    assert any(morph.begin < t < morph.begin + 0.5 for t in switched), (morph.begin, switched)  # while it grows
    scene.run(12, progress=False)
    np.testing.assert_array_equal(scene.controller("colliders").objects[0].vertices_np, fit.vertices)
    assert sewing.gaps().max() == 0.0
    assert scene.model.data.n_particles == scene.controller("refiner").cloth.levels[2].n_particles
    assert garment_quality(scene).penetrations == 0


@pytest.mark.slow
def test_skirt_follows_a_body_that_grows_during_the_drape():
    blend, gauge = default_body()
    base_girths = gauge.measure(blend.base, names=["waist", "hips"])
    fit = fit_body({"waist": base_girths["waist"] + 0.03, "hips": base_girths["hips"] + 0.05})
    scene = sewn_skirt({"weights": fit.weights, "duration": 0.5})
    morph = scene.controller("body_morph")
    while not scene.controller("sewing").joined:  # the morph waits for the seams ("sewn")
        assert morph.begin is None
        np.testing.assert_array_equal(scene.controller("colliders").objects[0].vertices_np, blend.base)
        t_open = scene.state.t
        scene.run(6, progress=False)
        assert scene.state.t < 2.0
    assert morph.begin is None or morph.begin > t_open
    scene.run(int(round((1.6 - scene.state.t) * 60)), progress=False)  # the 0.5 s morph, then drape to t = 1.6 s
    assert morph.done
    np.testing.assert_array_equal(scene.controller("colliders").objects[0].vertices_np, fit.vertices)
    assert garment_quality(scene).penetrations == 0
    # the same skirt on the unchanged body, to the same time, rests on the hips: measured against the grown body
    # (5 cm more hip girth, 8 mm of radius) dozens of its particles lie inside, where the morphed drape has none
    # (the skirt went out with the body rather than through it). Any band average of the radius would be blurred
    # by the sway of a drape that is not yet at rest.
    control = sewn_skirt()
    control.run(int(round(scene.state.t * 60)), progress=False)
    grown_body = scene.controller("colliders").objects[0]
    inside = int(np.count_nonzero(grown_body.signed_distance(control.positions()) < 0.0))
    assert inside >= 10, inside


def test_a_morph_faster_than_the_collider_can_follow_is_refused():
    fit = fit_body({"hips": 1.05})
    cloth = tc.ClothBuilder.grid((0.1, 0.1), (4, 4), center=(0.0, 2.0, 0.0))
    with pytest.raises(ValueError, match="make morph_time at least"):
        tc.Scene(cloth, dt=1 / 120, colliders=[dict(MANNEQUIN)], body_morph={"weights": fit.weights, "duration": 0.01})
