"""What each approx-implicit variant (docs/algorithms.md, approximate implicit variants) does, measured against the implicit reference.

    python benchmarks/approx_implicit_variants.py [--out out/bench] [--arch cpu|gpu]

For the published form and each variant:
  fall:   centre-of-mass drop of an unpinned 16x16 cotton sheet (1 m) after 0.25 s at h = 1/120 s, as a
          fraction of g t^2 / 2 (1.0 = free fall; implicit gives 1.03 from its O(h) lag);
  static: max distance [mm] to the implicit drape of a 10x10 cotton sheet (0.4 m) hanging from two corners,
          after 6 s at h = 0.01 s with air drag 2/s (0 = statics right and settled);
  stable: whether that hanging run finished without a blow-up;
  ms/step on a 128x128 hanging sheet at h = 1/60 s.
Writes approx_implicit_variants.md and prints it.
"""
import argparse
import time
import warnings
from pathlib import Path

import numpy as np

import taichi_cloth as tc
from benchmarks.integrators import hanging_cloth, time_scene

VARIANTS = [
    ("as published (2 sweeps, from 0)", {}),
    ("jv_term", {"jv_term": True}),
    ("8 sweeps + jv_term", {"sweeps": 8, "jv_term": True}),
    ("32 sweeps + jv_term", {"sweeps": 32, "jv_term": True}),
    ("8 sweeps, no jv_term", {"sweeps": 8}),
    ("warm_start", {"warm_start": True}),
    ("warm_start + jv_term", {"warm_start": True, "jv_term": True}),
]


def fall_ratio(tc, integrator, opts):
    cloth = tc.ClothBuilder.grid((1, 1), (16, 16), "cotton", center=(0, 1, 0), plane="xz")
    sc = tc.Scene(cloth, integrator=integrator, dt=1 / 120, air_damping=0.0, integrator_options=opts, precision="f64")
    y0 = sc.positions()[:, 1].mean()
    try:
        sc.step(30)
    except tc.BlowUpError:
        return float("nan")
    return (y0 - sc.positions()[:, 1].mean()) / (0.5 * 9.81 * sc.state.t ** 2)


def hang(tc, integrator, opts, dt=0.01, steps=600):
    n = 10
    cloth = tc.ClothBuilder.grid((0.4, 0.4), (n, n), "cotton", center=(0, 1, 0), plane="xy")
    sc = tc.Scene(cloth, integrator=integrator, dt=dt, air_damping=2.0, precision="f64",
                  pins=[{"indices": [n * (n - 1), n * n - 1]}], integrator_options=opts)
    try:
        sc.step(steps)
        return sc.positions(), True
    except tc.BlowUpError:
        return None, False


def ms_per_step(tc, opts):
    return time_scene(hanging_cloth(128, "approx-implicit", **opts), 10)["ms_per_step"]


def main():
    p = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    p.add_argument("--out", default="out/bench")
    p.add_argument("--arch", default="cpu", choices=("cpu", "gpu"))
    args = p.parse_args()
    tc.init(args.arch)
    warnings.simplefilter("ignore")
    ref, _ = hang(tc, "implicit", {"cg_tolerance": 1e-8}, dt=0.05, steps=120)
    lines = ["| variant | fall / (g t^2/2) | static error [mm] | stable on the hanging sheet | ms/step 128x128 |",
             "|---|---|---|---|---|",
             f"| implicit (reference) | {fall_ratio(tc, 'implicit', {'cg_tolerance': 1e-6}):.3f} | 0 | yes | - |"]
    for label, opts in VARIANTS:
        t0 = time.perf_counter()
        x, ok = hang(tc, "approx-implicit", opts)
        err = f"{1e3 * np.abs(x - ref).max():.3g}" if ok else "-"
        lines.append(f"| {label} | {fall_ratio(tc, 'approx-implicit', opts):.4f} | {err} | {'yes' if ok else 'no: blow-up'}"
                     f" | {ms_per_step(tc, opts):.2f} |")
        print(lines[-1], f"({time.perf_counter() - t0:.1f} s)", flush=True)
    text = "\n".join(lines)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "approx_implicit_variants.md").write_text(text + "\n")
    print("\n" + text)


if __name__ == "__main__":
    main()
