"""What does a moving body cost? The 2 cm T-shirt sewn on the mannequin (demos/scenes/tshirt_clip.toml), then timed
over the 3 s of the mannequin's clip (arms down, torso twist: a deforming mesh sequence), against the same garment on
the still mannequin over the same frames.

Each step's time is split into the body's pose (the sequence interpolated on the device, the normals, the voxel
grid refilled when a step leaves its window of frames), the body collision (the particles' tests against it), and
the rest (the implicit solve, the stretch limit, the controllers). Both scenes run in one process, in turn, after
their compiles; a busy machine moves the milliseconds, not the counts.

    python benchmarks/moving_body.py [--frames 180] [--fps 30] [--body still|moving|both]

Writes out/bench/moving_body.csv.
"""
from __future__ import annotations

import argparse
import sys
import time
import tomllib
from pathlib import Path

import taichi as ti

from benchmarks import output_folder, write_csv
from clothbase.sequences import save_mesh_sequence
from taichi_cloth import runtime
from taichi_cloth.body.clip import mannequin_clip
from taichi_cloth.cli import add_run_arguments
from taichi_cloth.run import load_scene_file

SCENES = Path(__file__).resolve().parents[1] / "demos" / "scenes"


class Stopwatch:
    """Seconds spent in a method of an object (wrapped in place), kernels finished (ti.sync)."""

    def __init__(self, owner, method: str):
        self.seconds, inner = 0.0, getattr(owner, method)

        def timed(*args, **kwargs):
            ti.sync()
            t0 = time.perf_counter()
            out = inner(*args, **kwargs)
            ti.sync()
            self.seconds += time.perf_counter() - t0
            return out

        setattr(owner, method, timed)


def measure(kind: str, clip: Path, frames: int, out: Path) -> dict:
    cfg = tomllib.loads((SCENES / "tshirt_clip.toml").read_text(encoding="utf-8"))
    body = cfg["colliders"][0]
    if kind == "still":
        for key in ("sequence", "fps", "start"):
            body.pop(key)
        body["path"] = "mannequin"
    else:
        body["sequence"] = str(clip)
    parser = argparse.ArgumentParser()
    add_run_arguments(parser)
    scene = load_scene_file(cfg, parser.parse_args(["--out", str(out), "--no-progress"]), SCENES).scene
    sewing = scene.controller("sewing")
    scene.run(int(cfg["fps"]), progress=False, until_rest=False)  # 1 s: compiles, seams joined at 0.73 s
    if sewing.active:
        raise RuntimeError("the T-shirt was not sewn after 1 s")
    collide = scene.controller("colliders")
    pose, contact = Stopwatch(collide.bodies[0], "move"), Stopwatch(collide, "collide")
    steps0 = scene.steps_taken
    t0 = time.perf_counter()
    summary = scene.run(frames, progress=False, until_rest=False)
    wall = time.perf_counter() - t0
    steps = scene.steps_taken - steps0
    ms = 1e3 / steps
    return {"body": kind, "steps": steps, "ms_per_step": wall * ms, "pose_ms": pose.seconds * ms,
            "collision_ms": contact.seconds * ms, "rest_ms": (wall - pose.seconds - contact.seconds) * ms,
            "cg_iterations": summary.stats.get("cg_iterations per step", float("nan")),
            "real_time": frames / float(cfg["fps"]) / wall}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("--frames", type=int, default=180, help="frames timed after the sewing (default 180: 3 s)")
    ap.add_argument("--fps", type=float, default=30.0, help="frames per second of the clip's sequence")
    ap.add_argument("--arch", default="cpu", choices=("cpu", "gpu"))
    ap.add_argument("--out", type=Path, default=Path("out/bench"))
    ap.add_argument("--body", choices=("still", "moving", "both"), default="both", help="the scenes to time")
    args = ap.parse_args(argv)
    runtime.init(args.arch)
    out = output_folder(args.out)
    clip = save_mesh_sequence(out / "mannequin_clip.npz", mannequin_clip(args.fps))
    kinds = ("still", "moving") if args.body == "both" else (args.body,)
    rows = [measure(kind, clip, args.frames, out) for kind in kinds]
    print(f"{'body':<8} {'steps':>6} {'ms/step':>8} {'pose':>7} {'collision':>10} {'rest':>7} {'CG it':>7} "
          f"{'x real time':>11}")
    for r in rows:
        print(f"{r['body']:<8} {r['steps']:>6} {r['ms_per_step']:8.2f} {r['pose_ms']:7.2f} {r['collision_ms']:10.2f} "
              f"{r['rest_ms']:7.2f} {r['cg_iterations']:7.1f} {r['real_time']:11.2f}")
    if len(rows) == 2:
        print(f"moving / still per step: {rows[1]['ms_per_step'] / rows[0]['ms_per_step']:.2f}")
    write_csv(rows, out / "moving_body.csv")
    print(f"wrote {out / 'moving_body.csv'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
