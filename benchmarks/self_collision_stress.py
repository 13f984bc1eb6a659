"""Self-collision under stress: four scenes counted exactly at every frame, with self-collision off and on.

  ribbon  a cotton ribbon with a gentle wave across it, dropped edge-down onto the floor: it buckles and piles
  towel   a towel on the floor folded three times by pins
  twist   a square sheet whose two pinned edges turn opposite ways at pi/3 rad/s (the pace of Newton's
          cloth_twist example), no gravity
  jerk    a hanging sheet whose two pinned corners move 1 m sideways in 0.05 s; also compared after 10 s with
          the same sheet hung at the final corners from the start (RMS distance, triangles turned over, elastic
          energy)

For each scene and setting the table gives the largest and the final count of intersecting triangle pairs
(collision.intersections, exact, independent of the collision code), the frames with any, the continuous stage's
counters (closing pairs, impact zones, unresolved pairs), the largest strain and the wall time; a run that blows up
says when. The `implicit` integrator at 1/60 s (the jerk at 1/240 s), unless --integrator (the explicit ones take
dt = "auto"); with --step auto the implicit ones take dt = "auto" with that step as the longest, which the motion
rule halves while the cloth moves fast (taichi_cloth.adaptive): the jerk then unfolds where the fixed step locks it.

    python benchmarks/self_collision_stress.py [--scenes ribbon towel twist jerk] [--small] [--integrator NAME]
                                               [--step fixed|auto]

--small runs the sizes the tests use (8 x 32 ribbon, 20 x 15 towel, 20 x 20 twisted sheet, 16 x 16 jerked
sheet). Writes out/bench/self_collision_stress.csv.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import taichi_cloth as tc
from benchmarks import write_csv
from collision.intersections import count_intersecting_pairs
from taichi_cloth import runtime
from taichi_cloth.errors import BlowUpError

FLOOR = [{"type": "plane", "point": [0, 0, 0], "normal": [0, 1, 0], "friction": 0.5}]
IMPLICIT = ("implicit", "approx-implicit")


def _step(integrator: str, step: str = "fixed", fixed: float = 1 / 60) -> dict:
    """The Scene's dt options: the implicit integrators at `fixed` [s], or (step "auto") at dt = "auto" with `fixed`
    as the longest step, which the motion rule halves while the cloth moves fast (taichi_cloth.adaptive); the
    explicit ones at dt = "auto"."""
    if integrator not in IMPLICIT:
        return {"dt": "auto"}
    if step == "auto":
        return {"dt": "auto", "adaptive": {"dt_max": fixed}}
    return {"dt": fixed}


def ribbon_pile(self_collision, small: bool = False, integrator: str = "implicit", step: str = "fixed"):
    """A cotton ribbon (0.4 x 1.6 m, 16 x 64 particles; small: 0.3 x 1.2 m, 8 x 32) with a wave of 3 cm across it,
    its lower edge 1 cm above the floor. Returns (scene, frames): 3 s (small: 1.5 s)."""
    (w, h), res = ((0.3, 1.2), (8, 32)) if small else ((0.4, 1.6), (16, 64))
    cloth = tc.ClothBuilder.grid((w, h), res, "cotton", center=(0.0, h / 2 + 0.01, 0.0), plane="xy")
    cloth.positions[:, 2] += 0.03 * np.sin(2 * np.pi * cloth.positions[:, 1] / 0.4)
    scene = tc.Scene(cloth, integrator=integrator, **_step(integrator, step), self_collision=self_collision,
                     colliders=FLOOR)
    return scene, 90 if small else 180


def towel_folded_three_times(self_collision, small: bool = False, integrator: str = "implicit", step: str = "fixed"):
    """A 1.2 x 0.9 m cotton towel (40 x 30 particles; small: 20 x 15) on the floor, folded three times by pins: the
    +x third over the middle (0-1 s), the -x third over it (1.2-2.2 s), then the +z third of the stack over to -z
    (2.4-3.4 s; its pins lift the bottom layer's +z edge, and the flaps' pins hold only their -z two thirds, so no
    two pins fight). Returns (scene, frames): 4.5 s (small: 4 s)."""
    L, W = 1.2, 0.9
    cloth = tc.ClothBuilder.grid((L, W), (20, 15) if small else (40, 30), "cotton", center=(0.0, 0.003, 0.0),
                                 plane="xz")
    x = cloth.positions

    def fold(t0, axis, length, height=0.15, lift=0.03):
        keys = [[0.0, 0.0, 0.0, 0.0]] if t0 > 0 else []
        for s in np.linspace(0.0, 1.0, 13):
            d = [0.0, height * np.sin(np.pi * s) + lift * s, 0.0]
            d[axis] = length * (1 - np.cos(np.pi * s)) / 2
            keys.append([t0 + s, *d])
        return keys

    held = x[:, 2] < W / 6
    pins = [{"indices": np.nonzero((x[:, 0] > L / 2 - 1e-6) & held)[0].tolist(), "keyframes": fold(0.0, 0, -(L / 2 - 0.01))},
            {"indices": np.nonzero((x[:, 0] < -L / 2 + 1e-6) & held)[0].tolist(), "keyframes": fold(1.2, 0, L / 2 - 0.01)},
            {"indices": np.nonzero((x[:, 2] > W / 2 - 1e-6) & (np.abs(x[:, 0]) < L / 4 - 0.02))[0].tolist(),
             "keyframes": fold(2.4, 2, -(2 * W / 3), height=0.2, lift=0.06)}]
    scene = tc.Scene(cloth, integrator=integrator, **_step(integrator, step), air_damping=1.0,
                     self_collision=self_collision, pins=pins, colliders=FLOOR)
    return scene, 240 if small else 270


def twisted_sheet(self_collision, small: bool = False, integrator: str = "implicit", step: str = "fixed"):
    """A 1 m cotton sheet (50 x 50 particles; small: 20 x 20) hanging in the xy plane without gravity, its two
    side edges pinned and turned about the sheet's horizontal axis, opposite ways, at pi/3 rad/s for 6 s (one
    turn each). Returns (scene, frames): 6.5 s."""
    n = 20 if small else 50
    cloth = tc.ClothBuilder.grid((1.0, 1.0), (n, n), "cotton", center=(0.0, 1.0, 0.0), plane="xy")
    x = cloth.positions
    pins = []
    for side, turn in ((x[:, 0] < -0.5 + 1e-6, 1.0), (x[:, 0] > 0.5 - 1e-6, -1.0)):
        for i in np.nonzero(side)[0]:
            y0, z0 = x[i, 1] - 1.0, x[i, 2]

            def path(t, y0=y0, z0=z0, turn=turn):
                a = turn * np.pi / 3 * min(t, 6.0)
                return np.array([0.0, y0 * np.cos(a) - z0 * np.sin(a) - y0, y0 * np.sin(a) + z0 * np.cos(a) - z0])
            pins.append({"indices": [int(i)], "keyframes": path})
    scene = tc.Scene(cloth, integrator=integrator, **_step(integrator, step), gravity=(0.0, 0.0, 0.0),
                     air_damping=1.0, self_collision=self_collision, pins=pins)
    return scene, 390


def jerked_sheet(self_collision, small: bool = False, integrator: str = "implicit", step: str = "fixed",
                 jerk: bool = True):
    """A 1 m cotton sheet (32 x 32 particles; small: 16 x 16) hanging in the xy plane from its two top corners,
    which move 1 m along +x in 0.05 s (20 m/s); `implicit` at 1/240 s. With jerk=False the sheet hangs at the final
    corners from the start (the reference). Returns (scene, frames): 10 s."""
    n = 16 if small else 32
    cloth = tc.ClothBuilder.grid((1.0, 1.0), (n, n), "cotton", center=(0.0 if jerk else 1.0, 1.0, 0.0), plane="xy")
    path = [[0.0, 0.0, 0.0, 0.0], [0.05, 1.0, 0.0, 0.0]] if jerk else None
    scene = tc.Scene(cloth, integrator=integrator, **_step(integrator, step, 1 / 240), self_collision=self_collision,
                     pins=[{"indices": [n * (n - 1), n * n - 1], "keyframes": path}])
    return scene, 600


def against_hung(scene, small: bool, integrator: str) -> dict:
    """The jerked sheet against the same sheet hung at the final corners for as long (at the fixed step): RMS
    distance [mm], triangles turned over (normals opposite), elastic energy [J] of each."""
    ref, frames = jerked_sheet(False, small, integrator, jerk=False)
    ref.step(frames * ref.substeps)
    x, y = scene.positions(), ref.positions()
    t = scene.model.data.triangles

    def normals(p):
        return np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]])
    return {"rms_mm": round(1e3 * float(np.sqrt(np.mean(np.sum((x - y) ** 2, axis=1)))), 1),
            "turned_over": int(np.sum(np.einsum("ij,ij->i", normals(x), normals(y)) < 0)),
            "elastic_J": round(scene.measure().elastic, 4), "elastic_hung_J": round(ref.measure().elastic, 4),
            "max_strain_hung_pct": round(100 * ref.measure().max_strain, 2)}


SCENES = {"ribbon": ribbon_pile, "towel": towel_folded_three_times, "twist": twisted_sheet, "jerk": jerked_sheet}


def crossings_per_frame(scene, frames: int, stop_at_first: bool = False) -> list[int]:
    """The exact count of intersecting triangle pairs after each of `frames` frames (up to the first nonzero one
    with stop_at_first). A BlowUpError propagates with the counts so far as its `.counts`."""
    counts: list[int] = []
    try:
        for _ in range(frames):
            scene.step(scene.substeps)
            counts.append(count_intersecting_pairs(scene.positions(), scene.model.data.triangles))
            if stop_at_first and counts[-1]:
                break
    except BlowUpError as err:
        err.counts = counts
        raise
    return counts


def measure(name: str, self_collision: bool, small: bool, integrator: str, step: str) -> dict:
    scene, frames = SCENES[name](self_collision, small, integrator, step)
    t0 = time.perf_counter()
    blew = ""
    try:
        counts = crossings_per_frame(scene, frames)
    except BlowUpError as err:
        counts, blew = err.counts, f"blew up at t = {scene.state.t:.2f} s ({err.reason})"
    wall = time.perf_counter() - t0
    obj = scene.controller("colliders").self_collision if scene.controller("colliders") else None
    c = obj.counter_values() if obj is not None else {}
    return {"scene": name, "size": "small" if small else "full", "integrator": integrator, "step": step,
            "self_collision": "on" if self_collision else "off", "frames": len(counts),
            "max_pairs": max(counts, default=0), "final_pairs": counts[-1] if counts else 0,
            "frames_with_pairs": sum(1 for k in counts if k), "closing_pairs": c.get("closing pairs", ""),
            "impact_zones": c.get("impact zones", ""), "unresolved_pairs": c.get("unresolved pairs", ""),
            "max_strain_pct": round(100 * scene.measure().max_strain, 2) if not blew else "",
            "wall_s": round(wall, 1), "note": blew,
            **(against_hung(scene, small, integrator) if name == "jerk" and not blew else {})}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", nargs="+", choices=tuple(SCENES), default=["ribbon", "towel", "twist"])
    p.add_argument("--small", action="store_true", help="the sizes the tests use")
    p.add_argument("--integrator", default="implicit")
    p.add_argument("--step", choices=("fixed", "auto"), default="fixed",
                   help="the implicit integrators' step: fixed (1/60 s; the jerk 1/240 s), or auto with that step as "
                        "the longest (the motion rule halves it while the cloth moves fast)")
    p.add_argument("--out", type=Path, default=Path("out/bench"))
    args = p.parse_args(argv)
    runtime.init("cpu")
    rows = []
    for name in args.scenes:
        for on in (False, True):
            row = measure(name, on, args.small, args.integrator, args.step)
            rows.append(row)
            print("  ".join(f"{k} {v}" for k, v in row.items() if v != ""), flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "self_collision_stress.csv"
    write_csv(rows, path)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
