"""Colliders on a scripted path (clothbase.keyframes): a moving collider's tests run in its own frame on each
particle's motion relative to it, and its contacts answer relative to its surface's velocity."""
import numpy as np
import pytest

import taichi_cloth as tc
from clothbase.keyframes import RigidMotion, rotation_xyz


#: [m] how far the sheet on the turntable may lie from its rest pose turned (measured 2026-11-27: 0.06 mm
#: implicit; the explicit step, which the Galilean test covers: 0.08 mm)
TURNTABLE_TOLERANCE = 1e-3


def sheet(y=0.02):
    """A level 0.3 m cotton sheet of 10 x 10 particles, y [m] above the origin."""
    return tc.ClothBuilder.grid((0.3, 0.3), (10, 10), "cotton", center=(0.0, y, 0.0), plane="xz")


def test_a_pose_and_its_inverse():
    m = RigidMotion(keyframes=[[0.0, 0, 0, 0], [2.0, 1.0, -2.0, 0.5]], rotation=[[1.0, 0, 0, 0], [2.0, 30, -40, 90]],
                    pivot=(0.1, 0.2, 0.3))
    pts = np.random.default_rng(1).normal(size=(20, 3))
    for t in (-1.0, 0.0, 1.5, 2.0, 3.0):
        np.testing.assert_allclose(m.to_rest(m.to_world(pts, t), t), pts, atol=1e-14)
    np.testing.assert_allclose(m.to_world(pts, 1.0), pts + [0.5, -1.0, 0.25], atol=1e-14)  # no turn before 1 s
    R = rotation_xyz([0, 0, 90])
    np.testing.assert_allclose(R @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-15)
    np.testing.assert_allclose(m.to_world([m.pivot], 2.0)[0], m.pivot + [1.0, -2.0, 0.5], atol=1e-14)  # the pivot


@pytest.mark.parametrize("integrator", ["implicit", "explicit"])
def test_a_sheet_on_a_plane_moving_at_constant_velocity_is_the_sheet_on_a_still_plane_in_its_frame(integrator):
    """Galilean invariance, friction included: a sheet landing on a plane that moves at constant velocity u (rising
    and sliding along itself), the sheet starting with the plane's velocity, is at every frame the same sheet on the
    still plane shifted by u t (no air drag: the air would be still in one frame only). float64."""
    u = np.array([0.4, 0.25, -0.3])
    frames = 20

    def run(moving: bool):
        plane = {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "friction": 0.5}
        if moving:
            plane["keyframes"] = [[0.0, 0, 0, 0], [10.0, *(10 * u)]]
        sc = tc.Scene(sheet(), integrator=integrator, dt=1 / 240 if integrator == "implicit" else "auto",
                      air_damping=0.0, precision="f64", colliders=[plane])
        if moving:
            sc.state.set(v=np.tile(u, (sc.model.data.n_particles, 1)))
        out = []
        for _ in range(frames):
            sc.run(1, progress=False, until_rest=False)
            out.append(sc.positions() - (u * sc.state.t if moving else 0.0))
        return np.array(out), sc

    still, _ = run(False)
    moved, sc = run(True)
    assert still[-1][:, 1].max() < 0.02 - 0.01  # it fell onto the plane and rests on it
    assert np.abs(moved - still).max() < 1e-9


def test_a_turntable_carries_the_sheet_resting_on_it(integrator="implicit"):
    """A plane turning about its normal (y) at 90 degrees per second from t = 0.2 s to 1.2 s, a sheet resting on it
    with friction 0.6: its centripetal acceleration (at most 0.3 m/s^2 here) is far below what friction holds (5.9
    m/s^2), so it turns with the table: at 1.3 s it lies where its rest pose at 0.2 s turned by 90 degrees lies.
    (A rotation's contact decisions are thresholds, so a turned collider is compared with the turn it makes, not
    with a collider built turned: the two differ at round-off, and a stick-slip decision can flip on it.)"""
    plane = {"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "friction": 0.6,
             "rotation": [[0.2, 0, 0, 0], [1.2, 0, 90, 0]]}
    sc = tc.Scene(sheet(0.004), integrator=integrator, dt=1 / 240 if integrator == "implicit" else "auto",
                  colliders=[plane])
    sc.run(12, progress=False, until_rest=False)
    rest = sc.positions()
    sc.run(66, progress=False, until_rest=False)
    turned = rest @ rotation_xyz([0, 90, 0]).T
    assert np.abs(sc.positions() - turned).max() < TURNTABLE_TOLERANCE
    assert np.abs(rest - turned).max() > 0.2  # what a table that does not carry it would leave


def sweep(sc, ball, until: float) -> tuple[float, float]:
    """Step `sc` until `until` [s]; (the smallest signed distance [m] of any particle to `ball` after any step, the
    farthest any particle got along z [m])."""
    deepest, reach = np.inf, 0.0
    while sc.state.t < until:
        sc.advance(1)
        x = sc.positions()
        deepest = min(deepest, ball.signed_distance(x).min())
        reach = max(reach, x[:, 2].max())
    return deepest, reach


def test_no_particle_is_ever_inside_a_fast_sphere(speed=5.0, dt="auto"):
    """A 0.15 m sphere moving through a hanging 1 m sheet (32 x 32) at 5 m/s with the steps the engine chooses (at 2
    m/s with 1/60 s steps: the deforming ball below, which also grows): at every step every particle is outside the
    sphere (exact distance, at least the collider's thickness less round-off), and the sheet was carried forward (it
    wraps the sphere). 2 m/s with 1/60 s steps passed the same (measured 2026-11-27), and runs as a mesh below."""
    cloth = tc.ClothBuilder.grid((1.0, 1.0), (32, 32), "cotton", center=(0, 1.0, 0), plane="xy")
    sphere = {"type": "sphere", "center": [0, 1.0, -0.5], "radius": 0.15,
              "keyframes": [[0.0, 0, 0, 0], [1.0 / speed, 0, 0, 1.0]]}
    sc = tc.Scene(cloth, integrator="implicit", dt=dt, pins=[{"near": [(-0.5, 1.5, 0), (0.5, 1.5, 0)]}],
                  colliders=[sphere])
    ball = sc.controller("colliders").objects[0]
    deepest, reach = sweep(sc, ball, 1.0 / speed + 0.1)
    assert deepest > 0.003 - 1e-4  # the thickness, less float32 round-off
    assert reach > 0.3  # carried forward by the sphere (its front ends at z = 0.65)
    sc.reset()  # back where it started
    assert ball.signed_distance([[0.0, 1.0, -0.5]])[0] == pytest.approx(-0.15)


def test_a_recording_places_a_moving_collider_at_every_frame(tmp_path):
    """A moving ball is logged once as built and placed by its pose (a transform) at every recorded frame."""
    from test_recording_and_cli import rows_by_entity

    ball = {"type": "sphere", "center": [0, -0.2, 0], "radius": 0.1, "keyframes": [[0.0, 0, 0, 0], [1.0, 0, 0.5, 0]]}
    scene = tc.Scene(sheet(), integrator="implicit", dt=1 / 120, colliders=[ball])
    rec = tc.Recorder(tmp_path / "ball.rrd")
    scene.run(5, recorder=rec, progress=False)
    rec.close()
    got = rows_by_entity(tmp_path / "ball.rrd")
    static, frames, columns = got["/cloth/colliders"]
    assert sorted(frames) == [0, 1, 2, 3, 4, 5]  # the start and five frames
    assert any("Transform3D" in c for c in columns)
    assert got["/cloth/colliders/spheres"][0] == 1  # the ball itself, once


# ---------------------------------------------------------------------------------------------- a deforming body
def ball_sequence(speed: float, fps: float = 30.0, radius=(0.15, 0.15)):
    """An icosphere (642 vertices) crossing z = -0.5 .. 0.5 at `speed` [m/s] at y = 1 m, its radius [m] going
    linearly from radius[0] to radius[1] meanwhile, as a mesh sequence at fps."""
    import trimesh

    from clothbase.sequences import MeshSequence

    ico = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    times = np.arange(0.0, 1.0 / speed + 0.5 / fps, 1.0 / fps)
    s = np.clip(times * speed, 0.0, 1.0)
    frames = [np.asarray(ico.vertices) * (radius[0] + f * (radius[1] - radius[0])) + [0.0, 1.0, -0.5 + f] for f in s]
    return MeshSequence(np.stack(frames), ico.faces, fps, "ball")


def test_a_mesh_sequence_interpolates_exactly_at_its_frames_and_reads_back_from_its_files(tmp_path):
    """At k / fps the sequence is frame k exactly, halfway it is the mean of two frames, outside it is held; a .npz
    and a folder of OBJ frames (numbered 1, 2, ..., 10: read in number order) give the same frames back."""
    import trimesh

    from clothbase.sequences import load_mesh_sequence, save_mesh_sequence

    seq = ball_sequence(2.0, fps=20.0, radius=(0.1, 0.2))
    assert seq.n_frames == 11 and seq.duration == pytest.approx(0.5)
    for k in range(seq.n_frames):
        assert np.array_equal(seq.at(k / seq.fps), seq.frames[k])
    np.testing.assert_allclose(seq.at(2.5 / seq.fps), 0.5 * (seq.frames[2] + seq.frames[3]), rtol=0, atol=1e-15)
    assert np.array_equal(seq.at(-1.0), seq.frames[0]) and np.array_equal(seq.at(9.0), seq.frames[-1])
    back = load_mesh_sequence(save_mesh_sequence(tmp_path / "ball.npz", seq))
    assert back.fps == 20.0 and np.array_equal(back.triangles, seq.triangles)
    np.testing.assert_allclose(back.frames, seq.frames, rtol=0, atol=1e-6)  # float32 in the file
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, v in enumerate(seq.frames):
        trimesh.Trimesh(v, seq.triangles, process=False).export(folder / f"ball_{k + 1}.obj")
    back = load_mesh_sequence(folder, fps=20.0)
    np.testing.assert_allclose(back.frames, seq.frames, rtol=0, atol=1e-6)


def test_a_mesh_sequence_that_is_not_one_mesh_is_refused_naming_the_file(tmp_path):
    import trimesh

    from clothbase.errors import MeshError
    from clothbase.sequences import load_mesh_sequence

    folder = tmp_path / "frames"
    folder.mkdir()
    trimesh.creation.icosphere(subdivisions=1).export(folder / "f1.obj")
    trimesh.creation.icosphere(subdivisions=2).export(folder / "f2.obj")
    with pytest.raises(MeshError, match="f2.obj: not the topology of f1.obj"):
        load_mesh_sequence(folder, fps=30)
    with pytest.raises(MeshError, match="needs its frame rate"):
        load_mesh_sequence(folder)
    np.savez(tmp_path / "clip.npz", vertices=np.zeros((2, 3, 3)), triangles=np.array([[0, 1, 2]]))
    with pytest.raises(MeshError, match="clip.npz: no frame rate"):
        load_mesh_sequence(tmp_path / "clip.npz")


@pytest.mark.parametrize("spec, words", [
    ({"type": "mesh", "path": "mannequin", "sequence": "clip.npz"}, "'path' .* or 'sequence' .*, not both"),
    ({"type": "mesh", "path": "mannequin", "fps": 30}, "fps: belongs to a mesh sequence"),
    ({"type": "mesh", "sequence": "clip.npz", "keyframes": [[0, 0, 0, 0]]}, "moves itself"),
    ({"type": "mesh", "sequence": "clip.npz", "start": "later"}, 'a time >= 0 \\[s\\] or "sewn"'),
])
def test_a_mesh_sequence_key_out_of_place_is_refused(spec, words):
    from taichi_cloth.errors import SceneError
    from taichi_cloth.specs import collider_table

    with pytest.raises(SceneError, match=words):
        collider_table(spec, "[[colliders]] #1")


def test_no_particle_is_ever_inside_a_fast_growing_deforming_ball():
    """The hanging sheet of the fast-sphere test against a mesh sequence: a ball crossing it at 2 m/s with 1/60 s
    steps while its radius grows from 0.12 to 0.15 m (its surface sweeps the cloth at up to 2.03 m/s): at every step
    every particle is outside the frame's mesh (exact signed distance, at least the thickness less round-off), and
    the sheet was carried forward. The recorder gets the body's surface whenever it moved."""
    from taichi_cloth.frame import FrameSnapshot

    speed = 2.0
    cloth = tc.ClothBuilder.grid((1.0, 1.0), (32, 32), "cotton", center=(0, 1.0, 0), plane="xy")
    sc = tc.Scene(cloth, integrator="implicit", dt=1 / 60, pins=[{"near": [(-0.5, 1.5, 0), (0.5, 1.5, 0)]}],
                  colliders=[{"type": "mesh", "sequence": ball_sequence(speed, radius=(0.12, 0.15))}])
    collide = sc.controller("colliders")
    ball = collide.objects[0]
    deepest, reach = sweep(sc, ball, 1.0 / speed + 0.1)
    assert deepest > 0.003 - 1e-4  # the thickness, less float32 round-off
    assert reach > 0.3
    np.testing.assert_allclose(ball.vertices.to_numpy(), ball.sequence.frames[-1], rtol=0, atol=1e-6)
    frame = FrameSnapshot(0, 0.0, np.zeros((0, 3)), None, np.zeros((0, 3), int), 0)
    collide.record(frame)
    assert set(frame.meshes) == {0} and not frame.poses
    sc.reset()  # back to the first frame
    np.testing.assert_allclose(ball.vertices.to_numpy(), ball.sequence.frames[0], rtol=0, atol=1e-6)


def test_the_skinned_mannequin_is_the_rest_body_at_zero_angles_and_turns_rigidly_with_its_root():
    """Linear-blend skinning with no rotation gives the shipped body back; turning the root (the hips) turns the
    whole body rigidly about the pelvis joint (every bone follows its parent, every weight row sums to 1); the clip
    starts at the rest pose and is 3 s long."""
    from clothbase.keyframes import rotation_xyz
    from taichi_cloth.body.clip import clip_rotations
    from taichi_cloth.body.skinning import SkinnedBody

    body = SkinnedBody.mannequin()
    np.testing.assert_allclose(body.weights.sum(1), 1.0, rtol=0, atol=1e-12)
    assert np.abs(body.pose() - body.vertices).max() < 1e-12
    assert np.abs(body.pose(clip_rotations(0.0)) - body.vertices).max() < 1e-12
    R, c = rotation_xyz([10.0, -25.0, 40.0]), body.skeleton.joints["pelvis"]
    assert np.abs(body.pose({"hips": R}) - ((body.vertices - c) @ R.T + c)).max() < 1e-12
    arms = body.pose(clip_rotations(1.0))
    hands = body.weights[:, body.skeleton.names.index("l-hand")] > 0.99
    assert arms[hands, 0].mean() < body.vertices[hands, 0].mean() - 0.05  # the left hand came in towards the side
