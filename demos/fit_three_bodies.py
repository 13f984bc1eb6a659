"""One skirt on three bodies: the mannequin morphed to small, medium and large girths (Zhang et al. 2017 blend shapes,
taichi_cloth.body), the same two-panel skirt (demos/garments/skirt.toml: waist 68 cm, hips 100 cm) placed, sewn
and draped on each, recorded side by side in one recording, with the per-piece area and strain table of each.

    python demos/fit_three_bodies.py [--out DIR] [--frames N] [--morph before|during] [--levels L]
                                     [--refine global|local] [--quality Q] [--arch cpu|gpu]

--morph before (default): each run starts on its fitted body. --morph during: each skirt is sewn on the shipped
body, which then morphs to the fitted one over 1 s while the skirt drapes (the collision grid is rebuilt as it
changes). --levels L (2..6): each skirt coarse to fine (Hsiao 2006 section 2.2; docs/multilevel.md): its pieces
meshed on L 4-8 levels (the finest at the garment's 2 cm), placed and sewn on level 1, refined as the drape
settles, everywhere (--refine global, the default) or where it folds or touches the body (--refine local); the
run summary lists the switches. Writes DIR/fit_three_bodies.rrd.
"""
import argparse
import tomllib

import taichi_cloth as tc
from _common import GARMENTS, SCENES, arguments, ends, opened_with
from taichi_cloth.body import default_body
from taichi_cloth.garment.metrics import garment_quality
from taichi_cloth.run import load_scene_file

#: girths [m] (tape measures) of the three bodies; the shipped mannequin measures waist 0.669, hips 0.955
BODIES = {"small": {"waist": 0.62, "hips": 0.90}, "medium": {"waist": 0.67, "hips": 0.96},
          "large": {"waist": 0.67, "hips": 1.01}}  # at waist 0.68 the 0.68 m waistband (4 mm off the body) cannot close
SPACING = 0.9  # [m] between the bodies in the viewer


def main(argv=None) -> int:
    args = arguments(__doc__, argv, extra=_options)
    scene_file = tomllib.loads((SCENES / "sew_skirt.toml").read_text(encoding="utf-8"))
    scene_file["cloth"]["garment"] = str(GARMENTS / "skirt.toml")
    if args.morph == "during":
        scene_file["frames"] = max(scene_file["frames"], 180)  # sewing (~0.6 s), the 1 s morph, then some drape
    if args.levels is not None:
        # sewing (~0.6 s), at most 1.5 s per coarse level, then the finest settles
        scene_file["multilevel"] = {"levels": args.levels, "start_level": 1, "refine": args.refine,
                                    "settle": {"max_time": 1.5}}
        scene_file["frames"] = max(scene_file["frames"], round(60 * (2 + 1.5 * (args.levels - 1))))
        # on the 4 cm level 1 the waistband of the fuller bodies holds its side seams 2-3 mm apart
        scene_file["sewing"] = dict(scene_file["sewing"], epsilon=0.004)
    tables = []
    with tc.Recorder(args.out / "fit_three_bodies.rrd", recording_name="fit_three_bodies") as rec:
        for k, (size, girths) in enumerate(BODIES.items()):
            print(f"--- {size} body: " + ", ".join(f"{g} {100 * v:.0f} cm" for g, v in girths.items()))
            loaded = load_scene_file(dict(scene_file, name=f"skirt_{size}", body=dict(girths, morph=args.morph)), args)
            scene = loaded.scene
            summary = scene.run(loaded.frames, recorder=rec, entity=size, translation=((k - 1) * SPACING, 0.0, 0.0),
                                progress=not args.no_progress)
            print(summary.format())
            refiner = scene.controller("refiner")
            if refiner is not None:
                print(f"levels: {' '.join(f'{s.level + 1} at {s.t:.2f} s' for s in refiner.switches)}; "
                      f"{scene.model.data.n_particles} particles at the end")
            tables.append((size, girths, scene, garment_quality(scene)))

    gauge = default_body()[1]  # measures any morph of the shipped mannequin
    print("\n| body | waist (target / measured) | hips (target / measured) | piece | area error | boundary error "
          "| max strain | mean strain | inside the body | largest seam gap |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for size, girths, sc, quality in tables:
        body = sc.controller("colliders").bodies[0].vertices_np
        measured = gauge.measure(body, names=list(girths))
        for j, p in enumerate(quality.pieces):
            head = (f"| {size} | {100 * girths['waist']:.1f} / {100 * measured['waist']:.1f} cm "
                    f"| {100 * girths['hips']:.1f} / {100 * measured['hips']:.1f} cm" if j == 0 else "| | |")
            print(f"{head} | {p.name} | {100 * p.area_error:.2f} % | {100 * p.boundary_error:.2f} % "
                  f"| {100 * p.max_strain:.1f} % | {100 * p.mean_strain:.2f} % | "
                  f"{quality.penetrations if j == 0 else ''} | {f'{1e3 * quality.seam_gap_max:.1f} mm' if j == 0 else ''} |")
    print(opened_with(rec.path))
    return 0


def _options(parser) -> None:
    parser.add_argument("--morph", choices=("before", "during"), default="before",
                        help="morph the body before the run (default) or during the drape")
    parser.add_argument("--levels", type=_levels, default=None,
                        help="coarse to fine on this many 4-8 levels (2..6; default: the finest only)")
    parser.add_argument("--refine", choices=("global", "local"), default="global",
                        help="with --levels: refine everywhere (default) or where the skirt folds or touches")


def _levels(text: str) -> int:
    if not text.isdigit() or not 2 <= int(text) <= 6:
        raise argparse.ArgumentTypeError(f"must be a whole number in 2..6, got {text!r}")
    return int(text)


if __name__ == "__main__":
    raise SystemExit(ends(main))
