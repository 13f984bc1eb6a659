"""Shared command line of the demo scripts: each runs one scene file through taichi_cloth.cli."""
import argparse
import sys
from pathlib import Path

SCENES = Path(__file__).resolve().parent / "scenes"


def run_demo(scene_file: str, doc: str, argv=None) -> int:
    from taichi_cloth.cli import _cmd_run, add_run_arguments

    parser = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    add_run_arguments(parser)
    args = parser.parse_args(argv)
    args.scene = str(SCENES / scene_file)
    return _cmd_run(args)


if __name__ == "__main__":
    sys.exit("run one of the demo scripts instead")
