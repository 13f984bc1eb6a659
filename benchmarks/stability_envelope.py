"""Stability envelope: stable, unstable or refused over stiffness x time step x mass ratio, for every integrator.

    python benchmarks/stability_envelope.py [--stiffness 1e1 ... 1e7] [--steps 1e-5 ... 1e-1] [--mass-ratios 1 1e2 1e4]
        [--integrators NAME ...] [--n-steps 200] [--check-every 1] [--safety 0.8] [--no-critical] [--arch cpu|gpu]
        [--out out/bench/stability]

The same as `python -m taichi_cloth bench stability` (this file only forwards to taichi_cloth.bench.stability).
"""
import argparse
import sys

from taichi_cloth.bench.stability import add_arguments, run

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    add_arguments(parser)
    sys.exit(run(parser.parse_args()))
