"""Sew and drape the T-shirt on the mannequin, then flatten every draped piece back to 2D (Fan et al. 1998 section 3.2)
and compare with the pattern it was cut from and with Fan et al. 1998's table 1.

    python demos/flatten_draped.py [--out DIR] [--frames N] [--arch cpu|gpu] [--no-progress]

Writes DIR/flatten_draped.rrd (the drape, and the flattened pieces beside the body coloured by their edge-length
error map), DIR/flatten_draped.dxf (the flattened outlines, corners named as in the pattern) and
DIR/flatten_draped.png (the error maps, the original pattern dashed behind), every draped piece as
DIR/flatten_draped_<piece>.obj (what `python -m taichi_cloth flatten` takes), and prints the tables.
"""
import time

import meshio
import numpy as np

import taichi_cloth as tc
from _common import SCENES, arguments, ends, opened_with
from taichi_cloth.flatten import flatten_pieces, plot_flat, write_flat_dxf
from taichi_cloth.garment.metrics import draped_pieces, garment_quality
from taichi_cloth.run import load_scene_file

#: Fan et al. 1998 table 1, 3D -> 2D, per piece of a six-piece child's garment [%]
PAPER_AREA = (0.025, 1.18)
PAPER_BOUNDARY = (0.756, 1.72)


def main(argv=None) -> int:
    args = arguments(__doc__, argv)
    loaded = load_scene_file(SCENES / "sew_tshirt.toml", args)
    scene = loaded.scene
    with tc.Recorder(args.out / "flatten_draped.rrd", recording_name="flatten_draped") as rec:
        summary = scene.run(loaded.frames, recorder=rec, entity="tshirt", progress=not args.no_progress)
        print(summary.format())
        quality = garment_quality(scene).pieces
        pieces = draped_pieces(scene)
        for name, vertices, triangles, _ in pieces:  # each draped piece as a mesh: `taichi_cloth flatten` reads these
            path = rec.path.with_name(f"{rec.path.stem}_{name}.obj")
            meshio.write(path, meshio.Mesh(vertices, [("triangle", triangles)]))
        started = time.perf_counter()
        flat = flatten_pieces(pieces)
        wall = time.perf_counter() - started
        patterns = [m.uv for m in scene.controller("sewing").garment.meshes]
        layouts = [f.aligned_to(uv) for f, uv in zip(flat, patterns)]
        rec.log_flat_pieces("flattened", flat, layouts, translation=(0.6, 0.3, 0.0))

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
    print(f"Fan et al. 1998 (3D->2D, six pieces): area {PAPER_AREA[0]}-{PAPER_AREA[1]} %, boundary "
          f"{PAPER_BOUNDARY[0]}-{PAPER_BOUNDARY[1]} %")
    dxf = write_flat_dxf(flat, rec.path.with_suffix(".dxf"))
    png = plot_flat(flat, rec.path.with_suffix(".png"), references=[uv[f.boundary] for f, uv in zip(flat, patterns)],
                    layouts=layouts)
    print(f"wrote {dxf} and {png}")
    print(opened_with(rec.path))
    return 0


if __name__ == "__main__":
    raise SystemExit(ends(main))
