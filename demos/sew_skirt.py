"""Sew the two-panel skirt onto the mannequin (demos/scenes/sew_skirt.toml, garment demos/garments/skirt.toml)
and drape it; prints the run summary and the quality table, writes DIR/sew_skirt.rrd.

    python demos/sew_skirt.py [--out DIR] [--frames N] [--integrator NAME] [--dt H|auto] [--quality Q]
           [--arch cpu|gpu]
"""
import taichi_cloth as tc
from _common import SCENES, arguments, ends, load, opened_with, pictures
from taichi_cloth.garment.metrics import garment_quality
from taichi_cloth.pattern_view import log_scene_pattern


def main(argv=None) -> int:
    args = arguments(__doc__, argv)
    tc.init(args.arch)
    loaded = load(SCENES / "sew_skirt.toml", args)
    scene = loaded.scene
    # the recording is closed, and kept, also when the run blows up
    with tc.Recorder(args.out / "sew_skirt.rrd", recording_name="sew_skirt") as rec:
        log_scene_pattern(rec, scene)  # the pattern's seam set-up, a 2D view under pattern/
        summary = scene.run(loaded.frames, recorder=rec, progress=not args.no_progress)
    summary.outputs += [str(rec.path)] + [str(scene.export_mesh(rec.path.with_suffix(s))) for s in (".obj", ".ply")]
    summary.outputs += pictures(scene, rec.path, args)  # --png: the final drape (and the pattern) as PNGs
    print(summary.format())
    print(garment_quality(scene).format())  # per piece: area, boundary and strain; seam gap, penetrations
    print(opened_with(rec.path))
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
