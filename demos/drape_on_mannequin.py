"""A silk sheet dropped over the shipped CC0 mannequin (demos/scenes/drape_on_mannequin.toml).

    python demos/drape_on_mannequin.py [--out DIR] [--frames N] [--integrator NAME] [--dt H|auto] [--quality Q]
           [--arch cpu|gpu]

Writes DIR/drape_on_mannequin.rrd (the body logged once) and the final mesh, and prints the collision
counters: triangle tests done by the fuzzy ranking against the candidates in the touched voxels.
"""
import taichi_cloth as tc
from _common import SCENES, arguments, ends, load, opened_with, pictures


def main(argv=None) -> int:
    args = arguments(__doc__, argv)
    tc.init(args.arch)
    loaded = load(SCENES / "drape_on_mannequin.toml", args)
    scene = loaded.scene
    # the recording is closed, and kept, also when the run blows up
    with tc.Recorder(args.out / "drape_on_mannequin.rrd", recording_name="drape_on_mannequin") as rec:
        summary = scene.run(loaded.frames, recorder=rec, progress=not args.no_progress)
    summary.outputs += [str(rec.path)] + [str(scene.export_mesh(rec.path.with_suffix(s))) for s in (".obj", ".ply")]
    summary.outputs += pictures(scene, rec.path, args)  # --png: the final drape (and the pattern) as PNGs
    print(summary.format())
    print(opened_with(rec.path))
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
