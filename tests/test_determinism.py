"""Same scene, same answer: a run repeated in another process gives the same state bit for bit.

Every loop runs in parallel here (TAICHI_CLOTH_PARALLEL_FROM=1; by default a small cloth's loops run in one thread,
where any order is fixed), so that a sum whose terms the threads add in the order they arrive would show: the
self-collision pass summed its pushes on a particle with float atomics, and two runs of the piling ribbon below
differed by up to 3 m after 40 frames, with either integrator family. The scene has a floor (a collider) and
self-collision; the run in this process and the one in a subprocess are compared.
"""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks.self_collision_stress import ribbon_pile

#: frames per integrator family: the explicit step takes about 70 substeps per frame
FRAMES = {"implicit": 45, "explicit": 6}

RUN = """
import sys
import numpy as np
from benchmarks.self_collision_stress import ribbon_pile
from taichi_cloth import runtime
runtime.init("cpu")
states = []
for integrator, frames in {frames!r}.items():
    scene, _ = ribbon_pile(True, small=True, integrator=integrator)
    scene.run(frames, progress=False)
    states.append(np.concatenate([scene.positions(), scene.velocities()]))
np.save(sys.argv[1], np.stack(states))
"""


def test_a_run_repeated_in_another_process_gives_the_same_state_bit_for_bit(tmp_path, monkeypatch):
    monkeypatch.setenv("TAICHI_CLOTH_PARALLEL_FROM", "1")
    here = []
    for integrator, frames in FRAMES.items():
        scene, _ = ribbon_pile(True, small=True, integrator=integrator)
        assert not scene.model.serial  # the loops run in parallel
        summary = scene.run(frames, progress=False)
        assert summary.stats["self-collision point-triangle contacts per step"] > 0  # the pass pushes
        here.append(np.concatenate([scene.positions(), scene.velocities()]))
    env = dict(os.environ)
    cache = env.get("TI_OFFLINE_CACHE_FILE_PATH", os.path.expanduser("~/.cache/taichi/ticache"))
    env["TI_OFFLINE_CACHE_FILE_PATH"] = f"{cache}-determinism"  # not the worker's: two processes fight over a lock
    out = tmp_path / "states.npy"
    done = subprocess.run([sys.executable, "-c", RUN.format(frames=FRAMES), str(out)], env=env, capture_output=True,
                          text=True, timeout=600, cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 0, done.stderr[-2000:]
    there = np.load(out)
    for k, integrator in enumerate(FRAMES):
        assert np.array_equal(here[k], there[k]), f"{integrator}: differs by up to {np.abs(here[k] - there[k]).max()}"
