"""Sew a T-shirt onto the mannequin (demos/scenes/sew_tshirt.toml, garment demos/garments/tshirt.toml): front,
back and two sleeves are placed around the body, pulled together along ten seams with gravity off, merged when
every seam pair is closer than 2 mm and the elastic energy has settled, then draped under gravity.

    python demos/sew_tshirt.py [--out DIR] [--frames N] [--integrator NAME] [--dt H|auto] [--quality Q]
           [--arch cpu|gpu]

Writes DIR/sew_tshirt.rrd (the strain map as vertex colours, the seam gap under metrics/, an event when the
seams merge) and the final mesh as .obj/.ply; prints the run summary and the quality table (per piece: area and
boundary-length error between the 2D pattern and the 3D drape, edge strain; seam gap, body penetrations, static
equilibrium).
"""
from _common import SCENES, arguments, ends
from taichi_cloth.cli import run_scene_file


def main(argv=None) -> int:
    run_scene_file(SCENES / "sew_tshirt.toml", arguments(__doc__, argv))
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
