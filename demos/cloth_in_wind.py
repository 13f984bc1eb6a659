"""A silk flag on a pole in a gusting wind, with Provot stretch limiting (demos/scenes/cloth_in_wind.toml).

    python demos/cloth_in_wind.py [--out DIR] [--frames N] [--integrator NAME] [--dt H] [--arch cpu|gpu]

Writes DIR/cloth_in_wind.rrd (open it with `rerun DIR/cloth_in_wind.rrd`) and the final mesh.
"""
from _common import run_demo

if __name__ == "__main__":
    raise SystemExit(run_demo("cloth_in_wind.toml", __doc__))
