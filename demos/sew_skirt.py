"""Sew the two-panel skirt onto the mannequin (demos/scenes/sew_skirt.toml, garment demos/garments/skirt.toml)
and drape it; prints the run summary and the quality table, writes DIR/sew_skirt.rrd.

    python demos/sew_skirt.py [--out DIR] [--frames N] [--integrator NAME] [--dt H] [--arch cpu|gpu]
"""
from _common import run_demo

if __name__ == "__main__":
    raise SystemExit(run_demo("sew_skirt.toml", __doc__))
