"""The Cusick drape test (BS 5058 / ISO 9073-9) in the model, for the measured fabric presets: a 30 cm disk clamped
between two 18 cm disks (the particles within r <= 9 cm held), the rest settling under gravity with the garment
scenes' implicit settings until at rest; DC = (shadow - pedestal area) / (disk area - pedestal area), the shadow the
projected area of the draped mesh rasterised on 0.5 mm cells (taichi_cloth.fabrics). Each preset's DC is printed
against its fabric's published range (docs/fabrics.md), at each spacing, over the plain start and `--seeds` starts
moved by 1e-7 m (taichi_cloth.perturb).

    .venv/bin/python -m benchmarks.cusick_drape [--spacings 0.02 0.01] [--seeds 1 2 3] [--fabrics silk denim]
    .venv/bin/python -m benchmarks.cusick_drape --calibrate [--spacings 0.02 0.01]   # rerun the bend calibration
    .venv/bin/python -m benchmarks.cusick_drape --bending quadratic --membrane orthotropic   # the model options

With --bending quadratic a fabric's `bend` is its measured rigidity B (no calibration: taichi_cloth.bending); with
--membrane orthotropic its stretch and shear are the square grid's along the pattern's axes (mesh_cloth).

Writes out/bench/cusick_drape.csv and out/bench/cusick_drape.png (a top view of each preset's draped disk, its DC in
the title; with a model option the names end -BENDING-MEMBRANE); --calibrate writes out/bench/cusick_calibration.csv.
"""
from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from benchmarks import output_folder, write_csv
from taichi_cloth import runtime
from taichi_cloth.fabrics import (CUSICK_PEDESTAL, CUSICK_SPECIMEN, DC_RANGES, FABRICS, calibrate_bend,
                                  cantilever_angle, cusick_drape)
from taichi_cloth.material import BENDING_MODELS, MATERIALS, MEMBRANE_MODELS, Material


def model_material(name: str, bending: str, membrane: str) -> Material:
    """The preset `name` with the bending model and membrane named: with quadratic bending its bend is the fabric's
    measured rigidity."""
    base = MATERIALS[name] if bending == "springs" else FABRICS[name].material(FABRICS[name].rigidity)
    return base.replace(bending=bending, membrane=membrane)


def calibrate(spacings, names, out, bending: str = "springs", membrane: str = "isotropic") -> int:
    rows = []
    print(f"{'fabric':9s} {'h [cm]':>6s} {'c [cm]':>7s} {'B [N m]':>9s} {'bend':>9s} {'bend/B':>7s} "
          f"{'angle':>6s} {'target':>6s} {'c model':>7s} tries")
    for name in names:
        f = FABRICS[name]
        for h in spacings:
            t0 = time.perf_counter()
            bend, tries = calibrate_bend(f, h, bending=bending, membrane=membrane)
            best = min(tries, key=lambda bt: abs(bt[0] - bend))[1]
            target = cantilever_angle(best.overhang / f.bending_length)
            row = dict(fabric=name, spacing=h, bending_length=f.bending_length, rigidity=f.rigidity, bend=bend,
                       overhang=best.overhang, angle=best.angle, target_angle=target,
                       model_bending_length=best.bending_length, tries=len(tries),
                       wall=time.perf_counter() - t0)
            rows.append(row)
            print(f"{name:9s} {100 * h:6.1f} {100 * f.bending_length:7.2f} {f.rigidity:9.3g} {bend:9.3g} "
                  f"{bend / f.rigidity:7.3g} {best.angle:6.1f} {target:6.1f} {100 * best.bending_length:7.2f} "
                  f"{len(tries)}", flush=True)
    write_csv(rows, out / ("cusick_calibration" + ("" if (bending, membrane) == ("springs", "isotropic")
                                                   else f"-{bending}-{membrane}") + ".csv"))
    return 0


def picture(results, path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    n = len(results)
    fig, axes = plt.subplots(1, n, figsize=(2.2 * n, 2.5))
    for ax, (name, d) in zip(np.atleast_1d(axes), results):
        xz = d.positions[:, [0, 2]]
        ax.add_collection(PolyCollection(xz[d.triangles], facecolors="#4a7bb7", edgecolors="none", alpha=0.35))
        for r, style in ((0.5 * CUSICK_SPECIMEN, "--"), (0.5 * CUSICK_PEDESTAL, ":")):
            t = np.linspace(0, 2 * math.pi, 200)
            ax.plot(r * np.cos(t), r * np.sin(t), style, color="0.4", lw=0.7)
        ax.set_xlim(-0.16, 0.16)
        ax.set_ylim(-0.16, 0.16)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"{name}\nDC {d.dc:.2f}", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--spacings", type=float, nargs="+", default=[0.02, 0.01], help="mesh spacings [m]")
    p.add_argument("--fabrics", nargs="+", default=list(FABRICS), choices=list(FABRICS))
    p.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3], help="starts moved by 1e-7 m (plus the plain)")
    p.add_argument("--max-time", type=float, default=10.0, help="simulated seconds at most per drape")
    p.add_argument("--calibrate", action="store_true", help="rerun the cantilever calibration of bend instead")
    p.add_argument("--bending", choices=BENDING_MODELS, default="springs",
                   help="the bending model: springs (the presets' calibrated bend) or quadratic (the measured B)")
    p.add_argument("--membrane", choices=MEMBRANE_MODELS, default="isotropic", help="the triangle membrane")
    p.add_argument("--out", default="out/bench")
    args = p.parse_args(argv)
    out = output_folder(args.out)
    runtime.init("cpu")
    if args.calibrate:
        return calibrate(args.spacings, args.fabrics, out, args.bending, args.membrane)
    rows, shown = [], []
    print(f"{'fabric':9s} {'h [cm]':>6s} {'DC':>6s} {'min':>6s} {'max':>6s} {'range':>11s} {'in':>3s} "
          f"{'t [s]':>6s} {'rest':>4s} {'wall [s]':>8s}")
    for name in args.fabrics:
        lo, hi = DC_RANGES[name]
        for h in args.spacings:
            runs = []
            for seed in [0, *args.seeds]:
                t0 = time.perf_counter()
                d = cusick_drape(model_material(name, args.bending, args.membrane), h, args.max_time,
                                 perturb=1e-7 if seed else 0.0, seed=seed)
                runs.append((seed, d, time.perf_counter() - t0))
                rows.append(dict(fabric=name, spacing=h, seed=seed, dc=d.dc, shadow=d.shadow, specimen=d.specimen,
                                 time=d.time, at_rest=d.at_rest, wall=runs[-1][2], range_lo=lo, range_hi=hi))
            dcs = [d.dc for _, d, _ in runs]
            d0 = runs[0][1]
            inside = all(lo <= x <= hi for x in dcs)
            print(f"{name:9s} {100 * h:6.1f} {d0.dc:6.3f} {min(dcs):6.3f} {max(dcs):6.3f} {lo:5.2f}-{hi:<5.2f} "
                  f"{'yes' if inside else 'NO':>3s} {d0.time:6.2f} {'yes' if d0.at_rest else 'no':>4s} "
                  f"{sum(w for *_, w in runs) / len(runs):8.1f}", flush=True)
            if h == args.spacings[0]:
                shown.append((name, d0))
    stem = "cusick_drape" + ("" if (args.bending, args.membrane) == ("springs", "isotropic")
                             else f"-{args.bending}-{args.membrane}")
    write_csv(rows, out / f"{stem}.csv")
    picture(shown, out / f"{stem}.png")
    print(f"wrote {out / f'{stem}.csv'} and {out / f'{stem}.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
