"""A cotton square dropped onto a ball on the floor (demos/scenes/drape_on_sphere.toml).

    python demos/drape_on_sphere.py [--out DIR] [--frames N] [--integrator NAME] [--dt H|auto] [--quality Q]
           [--arch cpu|gpu]

Writes DIR/drape_on_sphere.rrd (the ball and floor logged once) and the final mesh.
"""
from _common import SCENES, arguments, ends
from taichi_cloth.cli import run_scene_file


def main(argv=None) -> int:
    run_scene_file(SCENES / "drape_on_sphere.toml", arguments(__doc__, argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
