"""Sew a T-shirt onto the mannequin (demos/scenes/sew_tshirt.toml, garment demos/garments/tshirt.toml): front,
back and two sleeves are placed around the body, pulled together along ten seams with gravity off, merged when
every seam pair is closer than 2 mm and the elastic energy has settled, then draped under gravity.

    python demos/sew_tshirt.py [--out DIR] [--frames N] [--integrator NAME] [--dt H|auto] [--quality Q]
           [--arch cpu|gpu]

Writes DIR/sew_tshirt.rrd (the strain map as vertex colours, the seam gap under metrics/, an event when the
seams merge) and the final mesh as .obj/.ply; prints the run summary and the quality table (per piece: area and
boundary-length error between the 2D pattern and the 3D drape, edge strain; seam gap, body penetrations, static
equilibrium).
"""
import taichi_cloth as tc
from _common import SCENES, arguments, ends, load, opened_with, pictures
from taichi_cloth.garment.metrics import garment_quality
from taichi_cloth.pattern_view import log_scene_pattern


def main(argv=None) -> int:
    args = arguments(__doc__, argv)
    tc.init(args.arch)
    loaded = load(SCENES / "sew_tshirt.toml", args)
    scene = loaded.scene
    # the recording is closed, and kept, also when the run blows up
    with tc.Recorder(args.out / "sew_tshirt.rrd", recording_name="sew_tshirt") as rec:
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
