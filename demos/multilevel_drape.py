"""A cotton square dropped onto a ball, simulated on a coarse 4-8 level first and refined level by level
(1 to 5) as the drape settles (demos/scenes/multilevel_drape.toml; Hsiao 2006 section 2.2).

    python demos/multilevel_drape.py [--out DIR] [--frames N] [--integrator NAME] [--dt H|auto] [--quality Q]
           [--arch cpu|gpu]

Writes DIR/multilevel_drape.rrd: the mesh topology changes at each level switch (an event marks it) and
metrics/cloth/level plots the level over time. Open it with `rerun DIR/multilevel_drape.rrd`.
"""
import taichi_cloth as tc
from _common import SCENES, arguments, ends, load, opened_with, pictures


def main(argv=None) -> int:
    args = arguments(__doc__, argv)
    tc.init(args.arch)
    loaded = load(SCENES / "multilevel_drape.toml", args)
    scene = loaded.scene
    # the recording is closed, and kept, also when the run blows up
    with tc.Recorder(args.out / "multilevel_drape.rrd", recording_name="multilevel_drape") as rec:
        summary = scene.run(loaded.frames, recorder=rec, progress=not args.no_progress)
    summary.outputs += [str(rec.path)] + [str(scene.export_mesh(rec.path.with_suffix(s))) for s in (".obj", ".ply")]
    summary.outputs += pictures(scene, rec.path, args)  # --png: the final drape (and the pattern) as PNGs
    print(summary.format())
    print(opened_with(rec.path))
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
