"""The first demo: a cotton sheet hanging from its two top corners (demos/scenes/hanging_cloth.toml).

    python demos/hanging_cloth.py [--out DIR] [--frames N] [--integrator NAME] [--dt H] [--arch cpu|gpu]

Writes DIR/hanging_cloth.rrd (open it with `rerun DIR/hanging_cloth.rrd`) and the final mesh as .obj/.ply.
"""
from _common import run_demo

if __name__ == "__main__":
    raise SystemExit(run_demo("hanging_cloth.toml", __doc__))
