"""What the demo scripts share: the command line of a scene demo, and how a demo ends.

Exit codes: 0 done, 2 bad input (one `error:` line), 3 the run blew up (its summary is printed; the recording made
so far is kept).
"""
import argparse
import sys
from pathlib import Path

import taichi_cloth as tc
from taichi_cloth.cli import add_run_arguments, rerun_command
from taichi_cloth.guards import check_run_length

DEMOS = Path(__file__).resolve().parent
SCENES = DEMOS / "scenes"
GARMENTS = DEMOS / "garments"

__all__ = ["DEMOS", "GARMENTS", "SCENES", "arguments", "ends", "load", "opened_with", "pictures"]


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


def load(scene_file, args):
    """tc.load_scene with the demo's command-line overrides (--until-rest: the scene's runs end at rest)."""
    loaded = tc.load_scene(scene_file, frames=args.frames, integrator=args.integrator, dt=args.dt,
                           precision=args.precision, quality=args.quality, out=args.out)
    if getattr(args, "until_rest", False):
        loaded.scene.stop_at_rest = True
    check_run_length(loaded.scene, loaded.frames, confirmed=getattr(args, "yes", False), label=str(scene_file))
    return loaded


def pictures(scene, recording, args) -> list:
    """With --png: the still pictures of the run beside its recording (taichi_cloth.still.write_pictures: the
    final drape, front and side, and a garment's pattern); their paths as str, for the summary's outputs."""
    if not getattr(args, "png", False):
        return []
    from taichi_cloth.still import write_pictures

    return [str(p) for p in write_pictures(scene, Path(recording).with_suffix(""))]


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
