"""Cost at comparable accuracy against Taichi's shipped mass-spring example and NVIDIA Warp on the CPU.

    python benchmarks/peers.py [--sizes 32 64 128] [--sim-time 0.3] [--samples 5] [--ref-dt 5e-5]
                               [--arch cpu|gpu] [--out out/bench/peers] [--no-warp] [--no-progress]

The same as `python -m taichi_cloth bench peers` (this file only forwards to taichi_cloth.bench.peers).
Warp is optional: `pip install 'taichi-cloth[peers]'` (warp-lang 1.9.1, usd-core).
"""
import argparse
import sys

from taichi_cloth.bench.peers import add_arguments, run

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    add_arguments(parser)
    sys.exit(run(parser.parse_args()))
