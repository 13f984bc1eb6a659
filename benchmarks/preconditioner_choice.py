"""Where does the aggregation multigrid pay against Jacobi? The implicit step's two preconditioners for a cloth off
4-8 levels (`preconditioner = "auto"` picks aggregation from linear.policy.AGGREGATION_FROM particles), on three
scenes at about the same particle counts:

  held     a 1 m cotton square held by one edge, released (h = 1/120 s): a stiff, hanging cloth
  grid     the same square, level, dropped onto a 0.3 m ball (h = 1/60 s)
  disk     a 1 m cotton disk meshed as a pattern piece (the garment mesher: Delaunay, irregular), dropped onto the
           ball the same way

Each run: frame 1 (compiles), then `--frames` frames timed by the wall clock; the table gives ms per step and CG
iterations per step of each preconditioner and their ratio. One process, runs in turn: a busy machine moves the ms,
not the CG counts.

    python benchmarks/preconditioner_choice.py [--particles 2400 4900] [--frames 30] [--cg-tolerance 1e-3]

Writes out/bench/preconditioner_choice.csv.
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

import taichi_cloth as tc
from benchmarks import output_folder, write_csv
from taichi_cloth.garment.mesh import mesh_piece
from taichi_cloth.garment.pattern import PatternPiece, Segment

BALL = [{"type": "sphere", "center": [0.0, 0.4, 0.0], "radius": 0.3}]


def cloth(scene: str, particles: int):
    """(cloth, scene options) of `scene` with about `particles` particles."""
    if scene == "disk":
        r = 0.5
        piece = PatternPiece("disk", [Segment.arc((r, 0), (-r, 0), 1.0), Segment.arc((-r, 0), (r, 0), 1.0)])
        m = mesh_piece(piece, math.sqrt(math.pi * r * r / particles))
        x = np.column_stack([m.uv[:, 0], np.full(len(m.uv), 0.75), m.uv[:, 1]])
        return tc.ClothBuilder.triangle_mesh(x, m.triangles, "cotton"), dict(dt=1 / 60, colliders=BALL)
    n = int(round(math.sqrt(particles)))
    if scene == "grid":
        return (tc.ClothBuilder.grid((1.0, 1.0), (n, n), "cotton", center=(0, 0.75, 0), plane="xz"),
                dict(dt=1 / 60, colliders=BALL))
    sheet = tc.ClothBuilder.grid((1.0, 1.0), (n, n), "cotton", center=(0, 1.0, 0), plane="xz")
    return sheet, dict(dt=1 / 120, pins=[{"box": [[-0.6, 0.99, -0.51], [0.6, 1.01, -0.49]]}])


def measure(scene: str, particles: int, preconditioner: str, frames: int, tolerance: float) -> dict:
    c, options = cloth(scene, particles)
    sc = tc.Scene(c, integrator="implicit", integrator_options={"preconditioner": preconditioner,
                                                                "cg_tolerance": tolerance}, **options)
    sc.run(1, progress=False, until_rest=False)
    t0 = time.perf_counter()
    summary = sc.run(frames, progress=False, until_rest=False)
    wall = time.perf_counter() - t0
    return {"scene": scene, "particles": sc.model.data.n_particles, "preconditioner": preconditioner,
            "ms_per_step": round(1e3 * wall / summary.steps, 2),
            "cg_per_step": round(summary.stats["cg_iterations per step"], 1), "steps": summary.steps}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", nargs="+", default=["held", "grid", "disk"], choices=["held", "grid", "disk"])
    p.add_argument("--particles", nargs="+", type=int, default=[2400, 4900])
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--cg-tolerance", type=float, default=1e-3)
    p.add_argument("--out", type=Path, default=Path("out/bench"))
    args = p.parse_args(argv)
    out = output_folder(args.out)
    rows = []
    for n in args.particles:
        for scene in args.scenes:
            jacobi = measure(scene, n, "jacobi", args.frames, args.cg_tolerance)
            agg = measure(scene, n, "multigrid", args.frames, args.cg_tolerance)
            agg["vs_jacobi"] = round(agg["ms_per_step"] / jacobi["ms_per_step"], 2)
            for row in (jacobi, agg):
                rows.append(row)
                print("  ".join(f"{k} {v}" for k, v in row.items()), flush=True)
    write_csv(rows, out / "preconditioner_choice.csv")
    print(f"wrote {out / 'preconditioner_choice.csv'}")
    return 0


if __name__ == "__main__":
    from taichi_cloth.runtime import init

    init("cpu")
    sys.exit(main())
