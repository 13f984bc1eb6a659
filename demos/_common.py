"""What the demo scripts share: the command line of a scene demo, and how a demo ends. A demo of one scene
file runs it as `python -m taichi_cloth run` does (taichi_cloth.cli.run_scene_file); one that does more with the
scene loads it with taichi_cloth.run.load_scene_file.

Exit codes: 0 done, 2 bad input (one `error:` line), 3 the run blew up (its summary is printed; the recording made
so far is kept).
"""
import argparse
import sys
from pathlib import Path

import taichi_cloth as tc
from taichi_cloth.cli import add_run_arguments, rerun_command

DEMOS = Path(__file__).resolve().parent
SCENES = DEMOS / "scenes"
GARMENTS = DEMOS / "garments"

__all__ = ["DEMOS", "GARMENTS", "SCENES", "arguments", "ends", "opened_with"]


def arguments(doc: str, argv=None, extra=None) -> argparse.Namespace:
    """The demo's command line: --out, --frames, --integrator, --dt, --arch, --precision, --quality, --no-progress,
    --yes, --png (as `python -m taichi_cloth run`), plus what `extra(parser)` adds."""
    parser = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    add_run_arguments(parser)
    if extra is not None:
        extra(parser)
    args = parser.parse_args(argv)
    args.out = Path(args.out or "out")
    return args


def opened_with(path) -> str:
    """The line that says how to open a recording."""
    return f"open the recording with:  {rerun_command()} {path}"


def ends(main, argv=None) -> int:
    """Run a demo's main(argv) and turn the engine's errors into one line and an exit code."""
    try:
        return main(argv)
    except (tc.SceneError, tc.MeshError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except tc.BlowUpError as exc:
        summary = getattr(exc, "summary", None)
        if summary is not None:
            print(summary.format())
        print(f"error: {exc}; what was recorded is kept", file=sys.stderr)
        return 3


if __name__ == "__main__":
    sys.exit("run one of the demo scripts instead")
