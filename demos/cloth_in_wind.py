"""A silk flag on a pole in a gusting wind, with Provot stretch limiting (demos/scenes/cloth_in_wind.toml).

    python demos/cloth_in_wind.py [--out DIR] [--frames N] [--integrator NAME] [--dt H|auto] [--quality Q]
           [--arch cpu|gpu]

Writes DIR/cloth_in_wind.rrd (open it with `rerun DIR/cloth_in_wind.rrd`) and the final mesh.
"""
import taichi_cloth as tc
from _common import SCENES, arguments, ends, load, opened_with, pictures


def main(argv=None) -> int:
    args = arguments(__doc__, argv)
    tc.init(args.arch)
    loaded = load(SCENES / "cloth_in_wind.toml", args)
    scene = loaded.scene
    # the recording is closed, and kept, also when the run blows up
    with tc.Recorder(args.out / "cloth_in_wind.rrd", recording_name="cloth_in_wind") as rec:
        summary = scene.run(loaded.frames, recorder=rec, progress=not args.no_progress)
    summary.outputs += [str(rec.path)] + [str(scene.export_mesh(rec.path.with_suffix(s))) for s in (".obj", ".ply")]
    summary.outputs += pictures(scene, rec.path, args)  # --png: the final drape (and the pattern) as PNGs
    print(summary.format())
    print(opened_with(rec.path))
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
