"""Does coarse-to-fine pay on a garment? The T-shirt on the mannequin from placement to rest, three ways:

* finest:         the pieces meshed on 3 levels, placed, sewn and draped on the finest (2 cm) only
                  ([multilevel] start_level = 3 of demos/scenes/sew_tshirt_multilevel.toml);
* finest (noise): the same with the placed positions moved by 1e-7 m of noise: how far two runs that differ by
                  round-off end apart (the spread the coarse-to-fine rest shape is judged against);
* coarse-to-fine: placed and sewn on level 1 (4 cm), refined to level 2 and 3 as the drape settles (the scene as
                  it is); and the same with the coarse levels stepping sqrt(2) times larger per level
                  ([multilevel] dt_growth; the finest keeps the scene's step);
* local:          placed and sewn on level 1, then refined locally ([multilevel] refine = "local",
                  taichi_cloth.garment.local): each switch gives the next level's vertices only to the triangles
                  that fold (dihedral angle over [multilevel] angle) or touch the body;
* 5 levels:       (with --modes) the same finest mesh meshed on 5 levels, sewn on level 3 (4 cm) and refined to
                  level 5, with CG preconditioned by Jacobi ("5 levels, jacobi") or by V-cycles over the garment's
                  own levels ("5 levels, multigrid": on 3 levels the coarsest, 358 particles, is too large for
                  the cycle's dense coarse solve; on 5 it has 97).

"At rest" is the scene's rest criterion (taichi_cloth.rest, as `run --until-rest`; a run is busy until it reaches
its finest level). For each: wall time from placement to rest (kernels loaded from Taichi's offline cache; run
once beforehand to fill it), the same without frame 1 (which loads or compiles the kernels), simulated time,
particles at rest, the speed-up after frame 1 against the finest run, the RMS symmetric surface distance of
the rest shape to the finest run's and to the coarse-to-fine run's (vertices of each to the other's surface,
both ways), the largest difference of the garment quality table (area and boundary errors, max and mean strain,
per piece) in percentage points and which entry it is, the same without the max strain (one edge's), and the
particles inside the body. The wall times include the run's closing check (exact distances of every particle
to the body's 26,756 triangles, for the summary's "no particle inside" line: about 0.7 s).

With --resolution (draft, fit or fine: 2 cm, 1 cm, 5 mm) the T-shirt is meshed at that preset and on its levels
(taichi_cloth.garment.garment.RESOLUTIONS; --levels overrides): "finest" starts on the last of them, coarse to fine
on the first, and "5 levels" means the preset's levels.

    python benchmarks/multilevel_garment.py [--frames 1800] [--arch cpu|gpu] [--modes NAME ...]
                                            [--resolution draft|fit|fine] [--levels N]

Writes out/bench/multilevel_garment.csv (multilevel_garment-RESOLUTION.csv with --resolution).
"""
from __future__ import annotations

import argparse
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

import taichi_cloth as tc
from benchmarks import write_csv
from collision.distance import unsigned_distance
from taichi_cloth.garment.garment import RESOLUTIONS
from taichi_cloth.garment.metrics import garment_quality
from taichi_cloth.scenefile import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "demos" / "scenes" / "sew_tshirt_multilevel.toml"


#: the runs: run_to_rest's arguments by name
RUNS = {
    "finest": dict(start_level=-1),
    "finest (noise)": dict(start_level=-1, noise=1e-7),
    "coarse-to-fine": dict(start_level=1),
    "coarse-to-fine, dt x sqrt(2) per level": dict(start_level=1, dt_growth=2 ** 0.5),
    "local": dict(start_level=1, refine="local"),
    "5 levels, jacobi": dict(start_level=3, levels=5, preconditioner="jacobi"),
    "5 levels, multigrid": dict(start_level=3, levels=5, preconditioner="multigrid"),
}
DEFAULT_MODES = ["finest", "finest (noise)", "coarse-to-fine", "coarse-to-fine, dt x sqrt(2) per level", "local"]


def run_to_rest(start_level: int, frames: int, noise: float = 0.0, dt_growth: float = 1.0, refine: str = "global",
                levels: int = 3, preconditioner: str = "auto", resolution: str | None = None):
    """(figures dict, rest positions (P,3), triangles (T,3)) of the T-shirt (at the `resolution` preset, if named)
    run from start_level (1-based; -1: the finest) of `levels`, refined `refine` ("global" or "local"), CG
    preconditioned by `preconditioner`."""
    cfg = tomllib.loads(SCENE.read_text())
    if resolution is not None:
        cfg["cloth"]["resolution"] = resolution
    cfg["multilevel"]["levels"] = levels
    cfg["multilevel"]["start_level"] = levels if start_level == -1 else start_level
    cfg["multilevel"]["dt_growth"] = dt_growth
    cfg["multilevel"]["refine"] = refine
    cfg["integrator"]["preconditioner"] = preconditioner
    cfg["frames"] = frames
    loaded = load_scene(cfg, base_dir=SCENE.parent, out=ROOT / "out" / "bench")
    scene = loaded.scene
    if noise:
        x = scene.positions()
        scene.state.set(x=x + np.random.default_rng(1).normal(0.0, noise, x.shape))
    t0 = time.perf_counter()
    summary = scene.run(frames, progress=False, until_rest=True)
    wall = time.perf_counter() - t0
    q = garment_quality(scene)
    refiner = scene.controller("refiner")
    steps = max(scene.steps_taken, 1)
    return dict(wall=wall, after_first=wall - summary.first_frame_wall, sim=scene.state.t,
                at_rest=summary.stopped_at_rest, rest=summary.rest, solver=scene.integrator.detail,
                cg_per_step=scene.integrator.stats["cg_iterations"] / steps, ms_per_step=1e3 * wall / steps,
                particles=scene.model.data.n_particles,
                levels=" ".join(f"{s.level + 1}@{s.t:.2f}s" for s in refiner.switches), quality=q,
                inside=q.penetrations), scene.positions(), scene.model.data.triangles.copy()


def surface_distance(xa, ta, xb, tb) -> float:
    """RMS symmetric surface distance [m]: every vertex of A to B's surface and every vertex of B to A's (exact up
    to 0.2 m, clipped beyond)."""
    d = np.concatenate([unsigned_distance(xa, xb[tb], 0.2), unsigned_distance(xb, xa[ta], 0.2)])
    return float(np.sqrt(np.mean(d ** 2)))


def quality_difference(qa, qb, keys=("area_error", "boundary_error", "max_strain", "mean_strain")) -> tuple[float, str]:
    """Largest difference [percentage points] between two quality tables' per-piece `keys` (errors and strains),
    and which entry it is ("piece quantity")."""
    return max((100 * abs(getattr(pa, k) - getattr(pb, k)), f"{pa.name} {k}")
               for pa, pb in zip(qa.pieces, qb.pieces) for k in keys)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=1800, help="the most frames a run may take (60 a second)")
    ap.add_argument("--arch", choices=("cpu", "gpu"), default="cpu")
    ap.add_argument("--modes", nargs="+", choices=list(RUNS), default=DEFAULT_MODES,
                    help="the runs (finest and coarse-to-fine always: the others are compared with them)")
    ap.add_argument("--resolution", choices=tuple(RESOLUTIONS), help="the T-shirt at this preset (default: the "
                    "garment file's 2 cm on 3 levels)")
    ap.add_argument("--levels", type=int, help="coarse-to-fine levels (default: the preset's, else 3)")
    args = ap.parse_args(argv)
    levels = args.levels or (RESOLUTIONS[args.resolution][1] if args.resolution else 3)

    tc.init(args.arch)
    always = ["finest", "coarse-to-fine"]
    modes = always + [m for m in RUNS if m in args.modes and m not in always]
    results = {}
    for name in modes:
        run = dict(RUNS[name], resolution=args.resolution)
        if "levels" not in run or args.resolution:
            run["levels"] = levels
        results[name] = run_to_rest(frames=args.frames, **run)
        r = results[name][0]
        print(f"{name}: {r['wall']:.1f} s wall, {r['sim']:.2f} s simulated, at rest {r['at_rest']}, levels "
              f"{r['levels']}, {r['ms_per_step']:.1f} ms and {r['cg_per_step']:.0f} CG iterations per step "
              f"({r['solver']}); {r['rest']}", flush=True)
    ref, xr, tr = results["finest"]
    _, xg, tg = results["coarse-to-fine"]
    rows = []
    print("| mode | wall time to rest [s] | the same after frame 1 [s] | simulated [s] | speed-up after frame 1 "
          "| particles at rest | RMS distance to finest [mm] | to coarse-to-fine [mm] | quality table vs finest [pp] "
          "| the same without max strain [pp] | inside the body | levels (entered at) | ms/step | CG iterations/step |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, (r, x, t) in results.items():
        dist, dist_g = surface_distance(x, t, xr, tr), surface_distance(x, t, xg, tg)
        dq, where = quality_difference(r["quality"], ref["quality"])
        # a piece's max strain is one edge's; without it, the table's measures of the whole piece
        dq_whole, _ = quality_difference(r["quality"], ref["quality"], ("area_error", "boundary_error", "mean_strain"))
        rows.append(dict(mode=name, wall_s=r["wall"], after_first_frame_s=r["after_first"], sim_s=r["sim"],
                         at_rest=r["at_rest"], particles=r["particles"], rms_distance_mm=1e3 * dist,
                         rms_distance_coarse_to_fine_mm=1e3 * dist_g, quality_pp=dq, quality_largest=where,
                         quality_without_max_strain_pp=dq_whole, inside=r["inside"],
                         levels=r["levels"], ms_per_step=r["ms_per_step"], cg_per_step=r["cg_per_step"]))
        print(f"| {name} | {r['wall']:.1f}{'' if r['at_rest'] else ' (not at rest)'} | {r['after_first']:.1f} | "
              f"{r['sim']:.2f} | {ref['after_first'] / r['after_first']:.2f}x | {r['particles']} | {1e3 * dist:.2f} | "
              f"{1e3 * dist_g:.2f} | {dq:.2f} ({where}) | {dq_whole:.2f} | {r['inside']} | {r['levels']} | "
              f"{r['ms_per_step']:.1f} | {r['cg_per_step']:.0f} |")
    out = ROOT / "out" / "bench"  # the csv beside the scenes' recordings
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / f"multilevel_garment{'-' + args.resolution if args.resolution else ''}.csv"
    write_csv(rows, csv_path)
    print(f"wrote {csv_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
