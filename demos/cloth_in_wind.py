"""A silk flag on a pole in a gusting wind, with Provot stretch limiting (demos/scenes/cloth_in_wind.toml).

    python demos/cloth_in_wind.py [--out DIR] [--frames N] [--integrator NAME] [--dt H|auto] [--quality Q]
           [--arch cpu|gpu]

Writes DIR/cloth_in_wind.rrd (open it with `rerun DIR/cloth_in_wind.rrd`) and the final mesh.
"""
from _common import SCENES, arguments, ends
from taichi_cloth.cli import run_scene_file


def main(argv=None) -> int:
    run_scene_file(SCENES / "cloth_in_wind.toml", arguments(__doc__, argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
