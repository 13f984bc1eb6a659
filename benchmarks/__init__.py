"""The benchmarks: speed and speed/accuracy measurements, printed as tables and plots (speed is never asserted in
tests). The one home of benchmark code; it imports the engine, and the engine never imports it.

Suites of `python -m taichi_cloth bench SUITE` (each with add_arguments(parser) and run(args) -> exit code):

    integrators  ms per step and real-time factor of every integrator
    collision    collision cost on the mannequin against the voxel size (collision_cost.py: the name `collision`
                 would shadow the collision package for the scripts run from this folder)
    tradeoff     error against cost of every integrator, step and 4-8 level; the quality presets
    stability    the stability map over stiffness, step and mass ratio
    peers        against Taichi's own mass-spring example and NVIDIA Warp (peer_taichi_example, peer_warp)

accuracy: sampled runs and their distance to a reference, shared by tradeoff and peers. Each suite checks its
arguments before any work (require, output_folder): a bad one is one `error:` line, never a traceback.

Standalone scripts (`.venv/bin/python benchmarks/NAME.py`): approx_implicit_variants, moving_body,
multilevel_garment, multilevel_pays, preconditioner_choice, self_collision, self_collision_stress; and
`python -m benchmarks.gpu_check`, the whole GPU measurement in one command (on a GPU machine lent for a few minutes).
"""
import csv
from pathlib import Path

from taichi_cloth.errors import TaichiClothError
from taichi_cloth.paths import check_output_folder

#: the smallest grid a suite runs (n x n particles)
MIN_SIZE = 4


def require(ok: bool, message: str) -> None:
    """A suite's check of its arguments, made before any work: unless `ok`, TaichiClothError(message), which the
    command line prints as one `error:` line on stderr with exit code 2 (taichi_cloth.cli.ends)."""
    if not ok:
        raise TaichiClothError(message)


def output_folder(path) -> Path:
    """A suite's --out folder, made (with its parents) once it is known that it can be written: an OSError naming it
    otherwise (a file, below a file, read-only), before any work."""
    folder = check_output_folder(path)
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def write_csv(rows: list[dict], path, keys: list[str] | None = None) -> None:
    """Write `rows` (dicts) to the CSV file `path`: the columns `keys` (other keys are left out), or one per key in
    the order the keys first appear."""
    keys = list(dict.fromkeys(k for r in rows for k in r)) if keys is None else keys
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
