"""ms per step of every integrator on square grids and real-time factor at each one's largest stable step.

    python benchmarks/bench_integrators.py [--sizes 32 64 128 256] [--steps 20] [--arch cpu|gpu] [--out out/bench]

The same as `python -m taichi_cloth bench` (this file only forwards to taichi_cloth.bench.integrators).
"""
import argparse
import sys

from taichi_cloth.bench.integrators import add_arguments, run

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    add_arguments(parser)
    sys.exit(run(parser.parse_args()))
