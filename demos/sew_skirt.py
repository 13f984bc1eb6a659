"""Sew the two-panel skirt onto the mannequin (demos/scenes/sew_skirt.toml, garment demos/garments/skirt.toml)
and drape it; prints the run summary and the quality table, writes DIR/sew_skirt.rrd.

    python demos/sew_skirt.py [--out DIR] [--frames N] [--integrator NAME] [--dt H|auto] [--quality Q]
           [--arch cpu|gpu]
"""
from _common import SCENES, arguments, ends
from taichi_cloth.cli import run_scene_file


def main(argv=None) -> int:
    run_scene_file(SCENES / "sew_skirt.toml", arguments(__doc__, argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
