"""Does the approximate-implicit step's multigrid serve anything the implicit step does not? Both on the same 4-8
sheet, on its finest level, at the same step: approx-implicit with `multigrid_cycles = 2` (the option's usual value),
approx-implicit with its published two Jacobi sweeps, and implicit with its default preconditioner (V-cycles over the
same 4-8 levels), against a reference (implicit, CG to 1e-8, a tenth of the step).

Scene: a 1 m cotton square held horizontally by one edge, released; after `--time` s the positions are compared
(RMS and max distance to the reference [mm]) and the wall time per step (compiles excluded) is given.

    python benchmarks/approx_multigrid_vs_implicit.py [--base 2] [--levels 11] [--time 1.0] [--dt 0.016667]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import taichi_cloth as tc
from taichi_cloth.multilevel_cloth import multilevel_grid

EDGE = dict(box=((-0.6, 0.99, -0.51), (0.6, 1.01, -0.49)))
VARIANTS = {"approx-implicit, multigrid_cycles = 2": ("approx-implicit", {"multigrid_cycles": 2}, 1),
            "approx-implicit, 2 sweeps": ("approx-implicit", {}, 1),
            "implicit, 4-8 V-cycles, CG 1e-3": ("implicit", {"cg_tolerance": 1e-3}, 1),
            "reference: implicit, CG 1e-8, dt / 10": ("implicit", {"cg_tolerance": 1e-8, "cg_max_iterations": 2000},
                                                      10)}


def run(integrator: str, options: dict, substeps: int, args) -> tuple[np.ndarray, float]:
    """Positions after args.time s [m] and the wall time per step [ms] (one step first, to compile)."""
    cloth = multilevel_grid((1.0, 1.0), (args.base, args.base), args.levels, "cotton", center=(0, 1, 0), plane="xz",
                            start_level=args.levels - 1)
    dt = args.dt / substeps
    sc = tc.Scene(cloth, integrator=integrator, dt=dt, integrator_options=options, air_damping=0.5, pins=[EDGE],
                  multilevel={"refine": False}, step_guard="off")
    sc.step(1)
    steps = round(args.time / dt) - 1
    t0 = time.perf_counter()
    sc.step(steps)
    sc.positions()  # waits for the device
    return sc.positions(), 1e3 * (time.perf_counter() - t0) / steps


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--base", type=int, default=2)
    p.add_argument("--levels", type=int, default=9, help="9 on a 2 x 2 base: 33 x 33 particles on the finest")
    p.add_argument("--time", type=float, default=1.0)
    p.add_argument("--dt", type=float, default=1 / 60)
    args = p.parse_args()
    results = {name: run(*spec, args) for name, spec in VARIANTS.items()}
    ref = results.pop("reference: implicit, CG 1e-8, dt / 10")[0]
    print(f"| variant | ms/step | RMS to reference [mm] | max [mm] |\n|---|---|---|---|")
    for name, (x, ms) in results.items():
        d = np.linalg.norm(x - ref, axis=1) * 1e3
        print(f"| {name} | {ms:.2f} | {np.sqrt((d ** 2).mean()):.1f} | {d.max():.1f} |", flush=True)


if __name__ == "__main__":
    main()
