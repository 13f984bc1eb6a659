"""A cotton square dropped onto a ball on the floor (demos/scenes/drape_on_sphere.toml).

    python demos/drape_on_sphere.py [--out DIR] [--frames N] [--integrator NAME] [--dt H] [--arch cpu|gpu]

Writes DIR/drape_on_sphere.rrd (the ball and floor logged once) and the final mesh.
"""
from _common import run_demo

if __name__ == "__main__":
    raise SystemExit(run_demo("drape_on_sphere.toml", __doc__))
