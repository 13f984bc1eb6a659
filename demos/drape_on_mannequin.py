"""A silk sheet dropped over the shipped CC0 mannequin (demos/scenes/drape_on_mannequin.toml).

    python demos/drape_on_mannequin.py [--out DIR] [--frames N] [--integrator NAME] [--dt H|auto] [--quality Q]
           [--arch cpu|gpu]

Writes DIR/drape_on_mannequin.rrd (the body logged once) and the final mesh, and prints the collision
counters: the crossing tests done against the candidates in the touched voxels (docs/collision.md, cost).
"""
from _common import SCENES, arguments, ends
from taichi_cloth.cli import run_scene_file


def main(argv=None) -> int:
    run_scene_file(SCENES / "drape_on_mannequin.toml", arguments(__doc__, argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
