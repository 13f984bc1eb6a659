"""The garment scenes of demos/scenes (tests/test_demo_scenes.py runs them as it runs every scene file: a few
frames, unrecorded), in a file of their own so that the two test workers share the demo scenes' compiles."""
import numpy as np
import pytest

from test_demo_scenes import assert_on_the_bodies, run


@pytest.mark.parametrize("name", ["sew_skirt", "fit_skirt", "sew_top", "sew_tshirt", "sew_tshirt_multilevel"])
def test_a_garment_is_pulled_together_around_the_body(name):
    """Gravity is off while sewing: the seams close (their rest lengths shrink by close_speed x t = 3.3 cm in the 4
    frames; the mean gap of every garment here followed by 2.9 cm), the pieces stay outside the mannequin they
    start near."""
    summary, scene, x0 = run(name)
    sewing = scene.controller("sewing")
    before, after = sewing.gaps(x0), sewing.gaps()
    assert after.mean() < before.mean() - 0.02
    assert_on_the_bodies(scene, x0)


def test_the_t_shirt_follows_the_body_that_moves(tmp_path):
    """tshirt_clip, its body the mannequin's clip (written as the demo writes it, at 10 frames/s) moving from the
    start instead of once sewn: in these 4 frames the body is the sequence at the scene's time (to float32), its
    hands have moved (by 15 mm), the seams close, and no particle is inside the body as it is now."""
    from clothbase.sequences import save_mesh_sequence
    from taichi_cloth.body.clip import mannequin_clip

    clip = save_mesh_sequence(tmp_path / "clip.npz", mannequin_clip(fps=10.0))
    summary, scene, x0 = run("tshirt_clip", sequence=str(clip), start=0.0)
    body = scene.controller("colliders").bodies[0]
    np.testing.assert_allclose(body.vertices.to_numpy(), body.sequence.at(scene.state.t), rtol=0, atol=1e-6)
    assert np.abs(body.vertices_np - body.sequence.frames[0]).max() > 0.01
    sewing = scene.controller("sewing")
    assert sewing.gaps().mean() < sewing.gaps(x0).mean() - 0.02
    assert body.signed_distance(scene.positions()).min() > 0.0
