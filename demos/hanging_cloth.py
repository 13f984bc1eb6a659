"""The first demo: a cotton sheet hanging from its two top corners (demos/scenes/hanging_cloth.toml).

    python demos/hanging_cloth.py [--out DIR] [--frames N] [--integrator NAME] [--dt H|auto] [--quality Q]
           [--arch cpu|gpu]

Writes DIR/hanging_cloth.rrd (open it with `rerun DIR/hanging_cloth.rrd`) and the final mesh as .obj/.ply.
"""
import taichi_cloth as tc
from _common import SCENES, arguments, ends, load, opened_with, pictures


def main(argv=None) -> int:
    args = arguments(__doc__, argv)
    tc.init(args.arch)
    loaded = load(SCENES / "hanging_cloth.toml", args)
    scene = loaded.scene
    # the recording is closed, and kept, also when the run blows up
    with tc.Recorder(args.out / "hanging_cloth.rrd", recording_name="hanging_cloth") as rec:
        summary = scene.run(loaded.frames, recorder=rec, progress=not args.no_progress)
    summary.outputs += [str(rec.path)] + [str(scene.export_mesh(rec.path.with_suffix(s))) for s in (".obj", ".ply")]
    summary.outputs += pictures(scene, rec.path, args)  # --png: the final drape (and the pattern) as PNGs
    print(summary.format())
    print(opened_with(rec.path))
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
