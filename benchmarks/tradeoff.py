"""Speed against accuracy of every integrator, step and 4-8 level, the Pareto front and the quality presets.

    python benchmarks/tradeoff.py [--scenes hanging sphere mannequin] [--variants ...] [--base 4] [--levels 5]
        [--levels-below 0 1 2] [--sim-time 2] [--samples 20] [--dt ...] [--fractions 0.9 0.45] [--ref-dt 1e-4]
        [--write-presets] [--arch cpu|gpu] [--out out/bench/tradeoff]

The same as `python -m taichi_cloth bench tradeoff` (this file only forwards to taichi_cloth.bench.tradeoff).
"""
import argparse
import sys

from taichi_cloth.bench.tradeoff import add_arguments, run

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    add_arguments(parser)
    sys.exit(run(parser.parse_args()))
