"""One Taichi runtime (ti.cpu) for the whole session: re-initialising frees fields and costs seconds."""
import os

import numpy as np
import pytest

import taichi_cloth as tc

# The suite is mostly kernel compiles: without Taichi's own IR optimisations a scene compiles about 3 times faster and
# runs 5-15 % slower (docs/performance.md, the test suite). Set here, in the environment, so that the command-line
# runs the tests start as subprocesses compile the same way; TI_ADVANCED_OPTIMIZATION=1 tests the kernels exactly as
# users run them.
os.environ.setdefault("TI_ADVANCED_OPTIMIZATION", "0")


#: the longest test files, longest first (the sums of their --durations on a fresh clone, 2026-11-27): `make test`
#: gives each file to one of two workers, in the order collected; a long file handed out last keeps one worker busy
#: while the other waits, so these go first and the short ones fill in at the end
LONGEST_FIRST = ("test_collision.py", "test_implicit_multigrid.py", "test_physics.py", "test_self_collision_stress.py",
                 "test_demo_garments.py", "test_multilevel.py", "test_multilevel_garment.py", "test_rest.py",
                 "test_garmentcode.py", "test_self_collision.py", "test_aggregation_rigid.py", "test_stability.py",
                 "test_explicit_lean.py", "test_body_scene.py", "test_hardening.py", "test_moving_colliders.py",
                 "test_garment.py", "test_host_reads.py", "test_determinism.py", "test_demo_scenes.py",
                 "test_loop_policy.py", "test_quality.py", "test_adaptive_step.py", "test_implicit_newton.py",
                 "test_components.py", "test_recording_and_cli.py", "test_scenefile.py", "test_tradeoff.py",
                 "test_studio.py", "test_batch.py")


def pytest_collection_modifyitems(config, items):
    rank = {name: k for k, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONGEST_FIRST)))  # stable: a file keeps its order


@pytest.fixture(scope="session", autouse=True)
def taichi_cpu():
    options = {}
    worker = os.environ.get("PYTEST_XDIST_WORKER")  # `make test` runs the files on two workers (pytest-xdist)
    if worker:
        # one offline kernel cache per worker: two processes writing one cache fight over its lock
        base = os.environ.get("TI_OFFLINE_CACHE_FILE_PATH", os.path.expanduser("~/.cache/taichi/ticache"))
        options["offline_cache_file_path"] = f"{base}-{worker}"
    tc.init("cpu", **options)
    yield


def sliding_normals(contacts, n: int) -> np.ndarray:
    """(n,3) the contact normals the implicit solve filters: a particle's normal, or 0 where it has none or where
    the step released it from the body (Contacts.released)."""
    released = contacts.released.to_numpy()[:n] != 0
    return np.where(released[:, None], 0.0, contacts.normal.to_numpy()[:n])


def grid_top_corners(n: int) -> list[int]:
    """Indices of the two top corners of an n x n grid built in the xy plane (v up)."""
    return [n * (n - 1), n * n - 1]


def max_structural_strain(scene) -> float:
    d = scene.model.data
    x = scene.positions()
    sel = d.kind == tc.SpringKind.STRUCTURAL
    length = np.linalg.norm(x[d.springs[sel, 1]] - x[d.springs[sel, 0]], axis=1)
    return float((length / d.rest_length[sel] - 1).max())


def refine(scene) -> None:
    """Switch a multilevel scene to its next level now (the refiner's change, applied by the scene)."""
    scene.apply(scene.controller("refiner").refine())


def current_level(scene) -> int:
    """The current 4-8 level (0-based) of a multilevel scene."""
    return scene.controller("refiner").level


def damping_matrix(d, x) -> np.ndarray:
    """Dense (3P,3P) -df/dv of the springs of ClothData `d` at positions x: kd u u^T per spring and the viscous
    c I per mesh edge (stiffness_matrix with the rest length = the current length keeps only the u u^T term, with
    rest length 0 only the I term)."""
    from taichi_cloth.stability import stiffness_matrix

    length = np.linalg.norm(x[d.springs[:, 1]] - x[d.springs[:, 0]], axis=1)
    return stiffness_matrix(x, d.springs, d.damping, length) \
        + stiffness_matrix(x, d.springs, d.viscous_damping(), np.zeros(d.n_springs))


def spring_forces(d, x, v):
    """numpy spring forces with damping and the mesh edges' viscous dashpots, (P,3)."""
    a, b = d.springs[:, 0], d.springs[:, 1]
    diff = x[b] - x[a]
    length = np.linalg.norm(diff, axis=1)
    u = diff / length[:, None]
    mag = d.stiffness * (length - d.rest_length) + d.damping * np.einsum("si,si->s", v[b] - v[a], u)
    f = np.zeros_like(x)
    np.add.at(f, a, mag[:, None] * u)
    np.add.at(f, b, -mag[:, None] * u)
    viscous = d.viscous_damping()[:, None] * (v[b] - v[a])
    np.add.at(f, a, viscous)
    np.add.at(f, b, -viscous)
    return f, u
