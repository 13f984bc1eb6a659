"""The first demo: a cotton sheet hanging from its two top corners (demos/scenes/hanging_cloth.toml).

    python demos/hanging_cloth.py [--out DIR] [--frames N] [--integrator NAME] [--dt H|auto] [--quality Q]
           [--arch cpu|gpu]

Writes DIR/hanging_cloth.rrd (open it with `rerun DIR/hanging_cloth.rrd`) and the final mesh as .obj/.ply.
"""
from _common import SCENES, arguments, ends
from taichi_cloth.cli import run_scene_file


def main(argv=None) -> int:
    run_scene_file(SCENES / "hanging_cloth.toml", arguments(__doc__, argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
