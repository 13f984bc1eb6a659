"""The contact filter of the implicit solve (taichi_cloth.contacts): on one face a particle keeps its motion in the
face's plane; in a crease of the body, where its contact alternates between two faces, it keeps the motion along
the crease's line only, and a top that fluttered under the arm (a 2-cycle between the two faces) comes to rest."""
from pathlib import Path

import numpy as np
import pytest
import taichi as ti

import taichi_cloth as tc
from taichi_cloth.batch.jobs import make_jobs
from taichi_cloth.batch.spec import load_spec
from taichi_cloth.scenefile import load_scene

ROOT = Path(__file__).resolve().parents[1]


def filter_of(normal, crease, stuck: int = 0) -> np.ndarray:
    """The 3x3 filter S of a particle with contact normal `normal` and crease normal `crease` (0: none), as the
    solve applies it (Contacts.filter), column by column."""
    sc = tc.Scene(tc.ClothBuilder.grid((0.02, 0.02), (2, 2)), integrator="implicit",
                  colliders=[{"type": "plane", "point": [0.0, -1.0, 0.0], "normal": [0.0, 1.0, 0.0]}])
    c = sc.contacts
    c.normal[0] = list(normal)
    c.crease[0] = list(crease)
    c.stuck[0] = stuck
    out = ti.Vector.field(3, ti.f64, 3)

    @ti.kernel
    def columns():
        for k in range(3):
            e = ti.Vector.zero(c.model.fp, 3)
            e[k] = 1.0
            out[k] = ti.cast(c.filter(0, e), ti.f64)

    columns()
    return out.to_numpy().T


def test_on_one_face_the_filter_removes_the_normal_only():
    n = np.array([0.6, 0.8, 0.0])
    S = filter_of(n, [0.0, 0.0, 0.0])
    assert np.allclose(S, np.eye(3) - np.outer(n, n), atol=1e-7)


def test_in_a_crease_the_filter_passes_the_crease_line_only():
    """Two faces 34 degrees apart (the normals under the arm where a top fluttered): S is the projector on the line
    a x b, symmetric and idempotent, whichever face is the contact's."""
    a = np.array([0.784, -0.403, -0.471])
    b = np.array([0.334, -0.755, -0.564])
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    line = np.cross(a, b) / np.linalg.norm(np.cross(a, b))
    for n, p in ((a, b), (b, a)):
        S = filter_of(n, p)
        assert np.allclose(S, np.outer(line, line), atol=1e-6)
        assert np.allclose(S, S.T, atol=1e-7) and np.allclose(S @ S, S, atol=1e-6)
    assert np.allclose(filter_of(a, b, stuck=1), 0.0)  # static friction holds it in every direction


@pytest.mark.slow
def test_a_top_that_fluttered_under_the_arm_comes_to_rest():
    """The silk top on the body of chest 84 cm (the garment matrix's job): a particle under the arm went 0.1 mm to
    and fro between two faces of the body at 20-30 mm/s every step, and the top never came to rest (16 mm/s at
    5 s). Held in the crease, the particles there slide along its line and the top rests within the matrix's 5 s."""
    spec = load_spec(ROOT / "demos" / "batch" / "garment_matrix.toml", None)
    job = next(j for j in make_jobs(spec) if j.label == "top_T84_silk")
    cfg = dict(job.scene)
    cfg.pop("output", None)
    scene = load_scene(cfg, base_dir=Path(job.base_dir), frames=300).scene
    scene.stop_at_rest = True  # as the batch runs it (until_rest)
    summary = scene.run(300, progress=False)
    assert scene.controller("sewing").joined
    assert summary.stopped_at_rest and scene.state.t <= 5.0
    n = scene.model.data.n_particles
    assert np.linalg.norm(scene.velocities()[:n], axis=1).max() < 1e-3  # [m/s] the flutter was 16-25 mm/s
    assert (np.linalg.norm(scene.contacts.crease.to_numpy()[:n], axis=1) > 0).sum() >= 1
