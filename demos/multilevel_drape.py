"""A cotton square dropped onto a ball, simulated on a coarse 4-8 level first and refined level by level
(1 to 5) as the drape settles (demos/scenes/multilevel_drape.toml; Hsiao 2006 section 2.2).

    python demos/multilevel_drape.py [--out DIR] [--frames N] [--integrator NAME] [--dt H|auto] [--quality Q]
           [--arch cpu|gpu]

Writes DIR/multilevel_drape.rrd: the mesh topology changes at each level switch (an event marks it) and
metrics/cloth/level plots the level over time. Open it with `rerun DIR/multilevel_drape.rrd`.
"""
from _common import SCENES, arguments, ends
from taichi_cloth.cli import run_scene_file


def main(argv=None) -> int:
    run_scene_file(SCENES / "multilevel_drape.toml", arguments(__doc__, argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
