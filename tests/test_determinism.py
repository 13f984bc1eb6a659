"""Same scene, same answer: a run repeated in another process gives the same state bit for bit.

Every loop runs in parallel here (TAICHI_CLOTH_PARALLEL_FROM=1; by default a small cloth's loops run in one thread,
where any order is fixed), so that a sum whose terms the threads add in the order they arrive would show: the
self-collision pass summed its pushes on a particle with float atomics, and two runs of the piling ribbon below
differed by up to 3 m after 40 frames, with either integrator family. The scene has a floor (a collider) and
self-collision; two runs, each in a process of its own, are compared.
"""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np


#: frames per integrator family: the explicit step takes about 70 substeps per frame
FRAMES = {"implicit": 45, "explicit": 6}

RUN = """
import sys
import numpy as np
from benchmarks.self_collision_stress import ribbon_pile
from taichi_cloth import runtime
runtime.init("cpu")
states, checks = [], []
for integrator, frames in {frames!r}.items():
    scene, _ = ribbon_pile(True, small=True, integrator=integrator)
    summary = scene.run(frames, progress=False)
    states.append(np.concatenate([scene.positions(), scene.velocities()]))
    checks.append([scene.model.serial, summary.stats["self-collision point-triangle contacts per step"]])
np.save(sys.argv[1], np.stack(states))
np.save(sys.argv[2], np.array(checks, dtype=np.float64))
"""


def run_in_a_process(tmp_path, name: str, env: dict):
    states, checks = tmp_path / f"{name}.npy", tmp_path / f"{name}-checks.npy"
    done = subprocess.run([sys.executable, "-c", RUN.format(frames=FRAMES), str(states), str(checks)], env=env,
                          capture_output=True, text=True, timeout=600, cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 0, done.stderr[-2000:]
    return np.load(states), np.load(checks)


def test_a_run_repeated_in_another_process_gives_the_same_state_bit_for_bit(tmp_path, monkeypatch):
    """Both runs in processes of their own, on one kernel cache: the first compiles, the second loads what the
    first compiled (a run is the same whether its kernels were compiled or read back)."""
    monkeypatch.setenv("TAICHI_CLOTH_PARALLEL_FROM", "1")
    env = dict(os.environ)
    cache = env.get("TI_OFFLINE_CACHE_FILE_PATH", os.path.expanduser("~/.cache/taichi/ticache"))
    env["TI_OFFLINE_CACHE_FILE_PATH"] = f"{cache}-determinism"  # not the worker's: two processes fight over a lock
    first, checks = run_in_a_process(tmp_path, "first", env)
    second, _ = run_in_a_process(tmp_path, "second", env)
    for k, integrator in enumerate(FRAMES):
        serial, contacts = checks[k]
        assert serial == 0  # the loops ran in parallel
        assert contacts > 0  # the self-collision pass pushed
        assert np.array_equal(first[k], second[k]), \
            f"{integrator}: differs by up to {np.abs(first[k] - second[k]).max()}"
