"""What the demo scripts share: the command line of a scene demo, and how a demo ends. A demo of one scene
file runs it as `python -m taichi_cloth run` does (taichi_cloth.cli.run_scene_file); one that does more with the
scene loads it with taichi_cloth.run.load_scene_file.

Exit codes: 0 done, 2 bad input or a file that cannot be read or written (one `error:` line), 3 the run blew up (its
summary is printed; the recording made so far is kept), 130 stopped by Ctrl-C (one `interrupted:` line; what was
written is kept).
"""
import argparse
import sys
from pathlib import Path

from taichi_cloth import cli
from taichi_cloth.cli import add_run_arguments, rerun_command
from taichi_cloth.paths import check_output_folder

DEMOS = Path(__file__).resolve().parent
SCENES = DEMOS / "scenes"
GARMENTS = DEMOS / "garments"

__all__ = ["DEMOS", "GARMENTS", "SCENES", "arguments", "ends", "opened_with"]


def arguments(doc: str, argv=None, extra=None) -> argparse.Namespace:
    """The demo's command line: --out, --frames, --integrator, --dt, --arch, --precision, --quality, --no-progress,
    --yes, --png (as `python -m taichi_cloth run`), plus what `extra(parser)` adds. An --out that cannot be written
    to raises OSError (taichi_cloth.paths.check_output_folder)."""
    parser = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    add_run_arguments(parser)
    if extra is not None:
        extra(parser)
    args = parser.parse_args(argv)
    args.out = check_output_folder(args.out or "out")  # a folder that cannot be written: refused before any work
    return args


def opened_with(path) -> str:
    """The line that says how to open a recording."""
    return f"open the recording with:  {rerun_command()} {path}"


def ends(main, argv=None) -> int:
    """Run a demo's main(argv) and end it as `python -m taichi_cloth` ends a command (taichi_cloth.cli.ends): the
    engine's errors, a file or folder that cannot be written and Ctrl-C each as one line and an exit code."""
    return cli.ends(lambda: main(argv))


if __name__ == "__main__":
    sys.exit("run one of the demo scripts instead")
