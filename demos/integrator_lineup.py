"""The integrator line-up: the same swinging sheet under all five integrators, side by side in one recording.

    python demos/integrator_lineup.py [--out DIR] [--frames N] [--integrator NAME ...] [--dt H] [--arch cpu|gpu]

Writes DIR/integrator_lineup.rrd: each integrator is logged under lineup/<name>, placed 1 m apart along x, with
its energy and strain under metrics/lineup/<name>. The unconditionally stable ones use the scene's dt (or --dt);
the explicit ones use 0.9 x their stable step from linear theory (docs/integrators.md), since the scene's step
would blow them up.
Prints one summary per integrator and a comparison table (wall time, steps, final shape vs implicit). The
implicit run at the scene's step is the line-up's common yardstick, not ground truth: backward Euler damps a
swing numerically at large steps, so a distance to it mixes both methods' errors.
"""
import argparse
import sys
from pathlib import Path

import numpy as np

SCENE = Path(__file__).resolve().parent / "scenes" / "lineup.toml"


def main(argv=None) -> int:
    import taichi_cloth as tc
    from taichi_cloth.cli import rerun_command
    from taichi_cloth.integrators import INTEGRATORS
    from taichi_cloth.paths import check_output_folder
    from taichi_cloth.run import load_scene_file

    p = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    p.add_argument("--out", default="out")
    p.add_argument("--frames", type=int, default=None)
    p.add_argument("--integrator", nargs="+", default=list(INTEGRATORS), choices=list(INTEGRATORS))
    p.add_argument("--dt", type=float, default=None, help="step [s] for the unconditionally stable integrators")
    p.add_argument("--arch", default="cpu", choices=("cpu", "gpu"))
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    out = check_output_folder(args.out)  # a folder that cannot be written: refused before any work
    rows, finals = [], {}
    with tc.Recorder(out / "integrator_lineup.rrd", recording_name="integrator line-up") as rec:
        for k, name in enumerate(args.integrator):
            cls = INTEGRATORS[name]
            overrides = argparse.Namespace(integrator=name, frames=args.frames, arch=args.arch,
                                           dt=args.dt if cls.unconditionally_stable else None)
            loaded = load_scene_file(SCENE, overrides)
            scene = loaded.scene
            if scene.stable_dt is not None:
                scene.dt = 0.9 * scene.stable_dt
            try:
                summary = scene.run(loaded.frames, recorder=rec, entity=f"lineup/{name}",
                                    translation=(1.0 * k, 0.0, 0.0), progress=not args.no_progress)
            except tc.BlowUpError as err:
                print(f"{name}: {err}", file=sys.stderr)
                continue
            print(summary.format())
            finals[name] = scene.positions()
            rows.append((name, scene.dt, summary.steps, summary.wall_step + summary.first_frame_wall,
                         summary.final.max_strain))
    ref = finals.get("implicit")
    print("\n| integrator | dt [s] | steps | wall [s] | max strain | max distance to implicit [mm] |")
    print("|---|---|---|---|---|---|")
    for name, dt, steps, wall, strain in rows:
        dist = f"{1e3 * np.abs(finals[name] - ref).max():.2f}" if ref is not None else "-"
        print(f"| {name} | {dt:.3g} | {steps} | {wall:.2f} | {100 * strain:.2f} % | {dist} |")
    print(f"\nopen the recording with:  {rerun_command()} {rec.path}")
    return 0


if __name__ == "__main__":
    from _common import ends  # the demos' end: an error or Ctrl-C as one line (taichi_cloth.cli.ends)

    sys.exit(ends(main))
