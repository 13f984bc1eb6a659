"""Sew and drape the T-shirt on the mannequin, then flatten every draped piece back to 2D (seed 004 section 3.2)
and compare with the pattern it was cut from and with seed 004's table 1.

    python demos/flatten_draped.py [--out DIR] [--frames N] [--arch cpu|gpu] [--no-progress]

Writes DIR/flatten_draped.rrd (the drape, and the flattened pieces beside the body coloured by their edge-length
error map), DIR/flatten_draped.dxf (the flattened outlines, corners named as in the pattern) and
DIR/flatten_draped.png (the error maps, the original pattern dashed behind), and prints the tables.
"""
import argparse
import time
from pathlib import Path

import numpy as np

SCENE = Path(__file__).resolve().parent / "scenes" / "sew_tshirt.toml"

#: seed 004 table 1, 3D -> 2D, per piece of a six-piece child's garment [%]
SEED_AREA = (0.025, 1.18)
SEED_BOUNDARY = (0.756, 1.72)


def main(argv=None) -> int:
    from taichi_cloth.cli import EXIT_BAD_INPUT, add_run_arguments, rerun_command, run_scene_file
    from taichi_cloth.errors import BlowUpError, MeshError, SceneError
    from taichi_cloth.flatten import flatten_pieces, plot_flat, write_flat_dxf
    from taichi_cloth.garment.metrics import draped_pieces, garment_quality
    from taichi_cloth.recorder import Recorder

    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    add_run_arguments(parser)
    args = parser.parse_args(argv)
    out = Path(args.out or "out")
    args.out = str(out)
    rec = Recorder(out / "flatten_draped.rrd", recording_name="flatten_draped")
    try:
        try:
            _, loaded = run_scene_file(SCENE, args, recorder=rec, entity="tshirt")
        except (SceneError, MeshError, BlowUpError) as exc:
            print(f"error: {exc}")
            return EXIT_BAD_INPUT
        scene = loaded.scene
        quality = garment_quality(scene).pieces
        started = time.perf_counter()
        flat = flatten_pieces(draped_pieces(scene))
        wall = time.perf_counter() - started
        patterns = [m.uv for m in scene.garment.meshes]
        layouts = [f.aligned_to(uv) for f, uv in zip(flat, patterns)]
        rec.log_flat_pieces("flattened", flat, layouts, translation=(0.6, 0.3, 0.0))
    finally:
        rec.close()

    print(f"\nflattened {len(flat)} pieces in {wall:.2f} s (kernels included)")
    print("| piece | 2D->3D area | 2D->3D boundary | 3D->2D area | 3D->2D boundary | max edge error | flipped | steps "
          "| flat vs pattern: area | outline RMS |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for q, f, uv, lay in zip(quality, flat, patterns, layouts):
        pattern_area = q.area_2d
        rms = float(np.sqrt(((lay - uv)[f.boundary] ** 2).sum(axis=1).mean()))
        print(f"| {f.name} | {100 * q.area_error:.2f} % | {100 * q.boundary_error:.2f} % | {100 * f.area_error:.3f} % "
              f"| {100 * f.boundary_error:.3f} % | {100 * np.abs(f.edge_error).max():.2f} % | {f.flipped} "
              f"| {f.iterations} | {100 * (f.area_2d / pattern_area - 1):+.2f} % | {1e3 * rms:.1f} mm |")
    print(f"seed 004 (3D->2D, six pieces): area {SEED_AREA[0]}-{SEED_AREA[1]} %, boundary "
          f"{SEED_BOUNDARY[0]}-{SEED_BOUNDARY[1]} %")
    dxf = write_flat_dxf(flat, out / "flatten_draped.dxf")
    png = plot_flat(flat, out / "flatten_draped.png", references=[uv[f.boundary] for f, uv in zip(flat, patterns)],
                    layouts=layouts)
    print(f"wrote {dxf} and {png}")
    print(f"open the recording with:  {rerun_command()} {rec.path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
