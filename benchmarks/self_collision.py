"""What self-collision costs and what it buys, on a shipped garment scene run until it rests.

For each setting (self-collision off, on) the scene runs from placement until the rest criterion holds (at most
--frames frames) and the table gives: the simulated time to rest, the wall time of the run after its first frame
(the first compiles the kernels), the share of that wall time spent in self-collision (its grid rebuild, gathering
and passes, timed with a device sync around each call), the exact count of intersecting triangle pairs at the end
(collision.intersections), the contacts it resolved and the strain.

    python benchmarks/self_collision.py [--scene demos/scenes/sew_tshirt.toml] [--frames 600]

Writes out/bench/self_collision.csv.
"""
from __future__ import annotations

import argparse
import sys
import time
import tomllib
from pathlib import Path

import taichi as ti

from benchmarks import write_csv
from collision.intersections import count_intersecting_pairs
from collision.self_collision import SelfCollision
from taichi_cloth import runtime
from taichi_cloth.scenefile import load_scene

ROOT = Path(__file__).resolve().parents[1]


def measure(scene_path: Path, self_collision: bool, frames: int) -> dict:
    with open(scene_path, "rb") as f:
        cfg = tomllib.load(f)
    cfg["self_collision"] = self_collision
    cfg.setdefault("rest", {})["stop"] = True
    scene = load_scene(cfg, frames=frames, base_dir=scene_path.parent).scene
    spent = [0.0]
    objects = [c for c in scene.controller("colliders").objects if isinstance(c, SelfCollision)]
    if objects:
        resolve = objects[0].resolve

        def timed(dt):
            ti.sync()
            t0 = time.perf_counter()
            resolve(dt)
            ti.sync()
            spent[0] += time.perf_counter() - t0

        objects[0].resolve = timed
    scene.run(1, progress=False)  # compiles every kernel
    spent[0] = 0.0
    t0 = time.perf_counter()
    summary = scene.run(frames - 1, progress=False)
    wall = time.perf_counter() - t0
    counters = objects[0].counter_values() if objects else {}
    return {"self_collision": "on" if self_collision else "off",
            "at_rest": summary.stopped_at_rest,
            "sim_time_s": round(scene.state.t, 3),
            "steps": summary.steps,
            "wall_s": round(wall, 2),
            "self_collision_share_pct": round(100 * spent[0] / wall, 1) if objects else 0.0,
            "self_collision_ms_per_step": round(1e3 * spent[0] / max(summary.steps, 1), 3) if objects else 0.0,
            "intersecting_pairs": count_intersecting_pairs(scene.positions(), scene.model.data.triangles),
            "triangles": len(scene.model.data.triangles),
            "point_triangle_contacts": counters.get("point-triangle contacts", 0),
            "edge_edge_contacts": counters.get("edge-edge contacts", 0),
            "max_strain_pct_end": round(100 * summary.final.max_strain, 2)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", type=Path, default=ROOT / "demos" / "scenes" / "sew_tshirt.toml")
    p.add_argument("--frames", type=int, default=600)
    p.add_argument("--out", type=Path, default=Path("out/bench"))
    args = p.parse_args(argv)
    runtime.init("cpu")
    rows = [measure(args.scene, on, args.frames) for on in (False, True)]
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "self_collision.csv"
    write_csv(rows, path)
    for row in rows:
        print("  ".join(f"{k} {v}" for k, v in row.items()))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
