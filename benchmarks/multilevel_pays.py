"""Does multilevel pay? Hsiao 2006's claim, measured: coarse-to-fine versus finest-level-only.

Scene: a 1 m cotton square held horizontally by one edge (--pins edge, the default) or by two corners, released,
and left to come to rest (a 4-8
hierarchy on a base of B x B cells, L levels; the finest has (B 2^((L-1)/2) + 1)^2 particles for odd L).
Rest = the settle criterion on the finest level (max speed < 2 mm/s and a relative energy change
< 1e-6 over 10 frames). For each integrator the table gives the wall time and the steps to rest, and the
final shape's distance to the finest-only run (max and RMS over the particles, as a fraction of the cloth
size); "vs ref" is the distance to the implicit finest-only rest shape (the accurate answer). Held by one
edge, the sheet has one rest shape; held by two corners it folds, and fold patterns depend on the path, so
two correct runs may differ by a few cm there.

    python benchmarks/multilevel_pays.py [--integrators implicit approx-implicit] [--base 8] [--levels 5]

Writes out/bench/multilevel_pays.csv and out/bench/multilevel_pays.png (the level against wall time).
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from pathlib import Path

import numpy as np

import taichi_cloth as tc
from taichi_cloth.multilevel_cloth import multilevel_grid

SETTLE = dict(max_speed=0.002, energy_change=1e-6, window=10, max_time=30.0)

#: the integrators compared: name -> (integrator, options)
VARIANTS = {"implicit": ("implicit", {"cg_tolerance": 1e-3}),
            "approx-implicit": ("approx-implicit", {})}


PINS = {"edge": dict(box=((-0.6, 0.99, -0.51), (0.6, 1.01, -0.49))),
        "corners": dict(near=[[-0.5, 1, -0.5], [0.5, 1, -0.5]])}


def run_to_rest(variant: str, base: int, levels: int, start: int, dt_growth: float, max_frames: int,
                pins: str = "edge", settle: dict = SETTLE):
    """Simulate until the finest level is settled; returns a dict of figures and the final positions."""
    integrator, options = VARIANTS[variant]
    cloth = multilevel_grid((1.0, 1.0), (base, base), levels, "cotton", center=(0, 1, 0), plane="xz",
                            start_level=start)
    scene = tc.Scene(cloth, integrator=integrator, dt=1 / 120, integrator_options=options, air_damping=0.5,
                     pins=[PINS[pins]],
                     multilevel=dict(settle, dt_growth=dt_growth), step_guard="off")
    refiner = scene.controller("refiner")
    for level in range(start, levels):  # compile every kernel once, outside the timing
        scene.step(1)
        if level < levels - 1:
            scene.apply(refiner.refine())
    scene.reset()
    trace = [(0.0, refiner.level + 1)]
    t0 = time.perf_counter()
    frames = 0
    while frames < max_frames and not (refiner.at_finest and refiner.settled):
        level = refiner.level
        scene.run(1, progress=False)
        frames += 1
        if refiner.level != level:
            trace.append((time.perf_counter() - t0, refiner.level + 1))
    wall = time.perf_counter() - t0
    trace.append((wall, refiner.level + 1))
    stats = scene.integrator.stats
    return dict(cg_per_step=stats.get("cg_iterations", 0) / max(scene.steps_taken, 1), wall=wall, steps=scene.steps_taken, sim_time=scene.state.t, settled=refiner.settled,
                switches=[(s.level + 1, s.t) for s in refiner.switches], trace=trace), scene.positions()


def distance(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Max and RMS particle distance [m]; NaN when a run ended before reaching the finest level."""
    if a.shape != b.shape:
        return float("nan"), float("nan")
    d = np.linalg.norm(a - b, axis=1)
    return float(d.max()), float(np.sqrt(np.mean(d ** 2)))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--integrators", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    p.add_argument("--base", type=int, default=8, help="base cells per side")
    p.add_argument("--levels", type=int, default=5)
    p.add_argument("--max-frames", type=int, default=6000)
    p.add_argument("--pins", choices=list(PINS), default="edge")
    p.add_argument("--rest-speed", type=float, default=SETTLE["max_speed"], help="rest: max speed below this [m/s]")
    p.add_argument("--arch", default="cpu")
    p.add_argument("--out", default="out/bench")
    args = p.parse_args(argv)
    tc.init(args.arch)
    settle = dict(SETTLE, max_speed=args.rest_speed)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    modes = [("finest only", args.levels - 1, 1.0), ("coarse-to-fine", 0, 1.0),
             ("coarse-to-fine, dt x sqrt2/level", 0, math.sqrt(2))]
    rows, ref = [], None
    for integrator in args.integrators:
        fine = None
        for mode, start, growth in modes:
            r, x = run_to_rest(integrator, args.base, args.levels, start, growth, args.max_frames, args.pins, settle)
            if fine is None:
                fine = x
            if ref is None:
                ref = x  # the first integrator's finest-only rest shape (implicit by default)
            r.update(integrator=integrator, mode=mode, particles=len(x))
            r["diff_max"], r["diff_rms"] = distance(x, fine)
            r["ref_max"], r["ref_rms"] = distance(x, ref)
            rows.append(r)
            print(f"{integrator:15s} {mode:33s} wall {r['wall']:7.2f} s  steps {r['steps']:6d}  sim {r['sim_time']:6.2f} s"
                  f"  settled {r['settled']!s:5s}  levels {' '.join(f'{lv}@{t:.1f}' for lv, t in r['switches'])}",
                  flush=True)

    print(f"\n4-8 hierarchy: base {args.base}x{args.base} cells, {args.levels} levels, finest {rows[0]['particles']} "
          f"particles; held by the {args.pins}; cloth size 1 m; rest = {settle}")
    head = (f"{'integrator':15s} {'mode':33s} {'wall s':>7s} {'steps':>6s} {'speed-up':>8s} {'max diff':>8s} "
            f"{'rms diff':>8s} {'max vs ref':>10s}")
    print(head)
    print("-" * len(head))
    for r in rows:
        fine = next(q for q in rows if q["integrator"] == r["integrator"] and q["mode"] == "finest only")
        r["speedup"] = fine["wall"] / r["wall"]
        print(f"{r['integrator']:15s} {r['mode']:33s} {r['wall']:7.2f} {r['steps']:6d} {r['speedup']:7.2f}x "
              f"{100 * r['diff_max']:7.2f}% {100 * r['diff_rms']:7.2f}% {100 * r['ref_max']:9.2f}%"
              + ("" if r["settled"] else "  (not settled)"))
    keys = ["integrator", "mode", "particles", "wall", "steps", "sim_time", "settled", "speedup", "diff_max",
            "diff_rms", "ref_max", "ref_rms"]
    with open(out / "multilevel_pays.csv", "w", newline="") as f:
        w = csv.DictWriter(f, keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return 0
    fig, axes = plt.subplots(1, len(args.integrators), figsize=(6 * len(args.integrators), 4), squeeze=False)
    for ax, integrator in zip(axes[0], args.integrators):
        for r in rows:
            if r["integrator"] == integrator:
                t, lv = zip(*r["trace"])
                ax.step(t, lv, where="post", label=f"{r['mode']} ({r['wall']:.1f} s)")
        ax.set_xlabel("wall time to rest [s]")
        ax.set_ylabel("level")
        ax.set_title(integrator)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "multilevel_pays.png", dpi=120)
    print(f"wrote {out / 'multilevel_pays.csv'} and {out / 'multilevel_pays.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
