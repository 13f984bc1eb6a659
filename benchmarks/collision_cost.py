"""Collision cost on the mannequin against the voxel size (`python -m taichi_cloth bench collision`).

Hsiao 2006's voxel trade-off.

For n x n cloths (1.2 m square, silk) dropped over the mannequin with the implicit integrator, after a
settling period the benchmark records K consecutive steps (start and end positions, velocities) and
replays exactly those steps through mesh colliders of several voxel sizes and modes, so every
configuration sees the same motion. Reported per configuration: grid build time, triangle-cell pairs,
collision ms per step, candidates per query (= triangle tests if every triangle of the touched voxels
were tested), crossing tests per query (fuzzy mode as published; exact mode; fuzzy without the reach gate), the
ratio candidates / fuzzy tests, and the integrator's ms per step on the same scene for comparison
(implicit, and approx-implicit). Writes collision.md, collision.csv and collision.png to --out.
"""
from __future__ import annotations

import math
import statistics
import time
from pathlib import Path

import taichi as ti

from benchmarks import MIN_SIZE, output_folder, require, write_csv
from collision import MeshCollider
from taichi_cloth import runtime
from taichi_cloth.builder import ClothBuilder
from taichi_cloth.colliders import body_mesh
from taichi_cloth.integrators import ApproxImplicit
from taichi_cloth.scene import Scene

CELL_FACTORS = (0.75, 1.0, 1.5, 2.0, 3.0, 4.0)  # x the mannequin's mean edge


def add_arguments(p) -> None:
    p.add_argument("--sizes", type=int, nargs="+", default=[64, 128])
    p.add_argument("--steps", type=int, default=12, help="recorded steps replayed per configuration")
    p.add_argument("--settle", type=float, default=0.6, help="simulated seconds before recording [s]")
    p.add_argument("--cells", type=float, nargs="+", default=list(CELL_FACTORS), help="cell sizes / mean edge")
    p.add_argument("--arch", default="cpu", choices=("cpu", "gpu"))
    p.add_argument("--out", default="out/bench", help="folder for collision.md, collision.csv, collision.png")


def _record(n: int, settle: float, steps: int):
    v, t = body_mesh("mannequin")
    cloth = ClothBuilder.grid((1.2, 1.2), (n, n), "silk", center=(0.0, 1.73, 0.06), plane="xz")
    scene = Scene(cloth, integrator="implicit", dt=1 / 120, air_damping=0.3, integrator_options={"cg_tolerance": 1e-2},
                  colliders=[{"type": "mesh", "path": "mannequin", "thickness": 0.004, "friction": 0.4}])
    scene.step(int(round(settle / scene.dt)))
    frames = []
    for _ in range(steps):
        x0 = scene.positions()
        # the integrator's end state, before the collision stage, is what each replayed collider must resolve
        scene.substep(scene.dt, observe=lambda x0=x0: frames.append((x0, scene.positions(), scene.velocities())))
    return scene, (v, t), frames


def _time_integrator(scene, steps: int) -> float:
    per = []
    for _ in range(steps):
        t0 = time.perf_counter()
        scene.integrator.step(scene.state, scene.contacts, scene.dt)
        ti.sync()
        per.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(per)


def _replay(collider, scene, frames) -> tuple[float, dict]:
    collider.attach(scene.state.x, scene.state.v, scene.model.inv_mass, scene.model.n_particles)
    collider.reset_counters()
    per = []
    for x0, x1, v1 in frames:
        scene.state.set(x=x0)
        collider.begin_step()
        scene.state.set(x=x1, v=v1)
        ti.sync()
        t0 = time.perf_counter()
        collider.resolve(scene.dt)
        ti.sync()
        per.append(1e3 * (time.perf_counter() - t0))
    return statistics.median(per[1:] or per), collider.counter_values()


def check(args) -> None:
    """The arguments, before Taichi starts: TaichiClothError (one `error:` line) for a grid under MIN_SIZE, --steps
    under 1, a negative --settle or a cell size that is not positive."""
    require(all(n >= MIN_SIZE for n in args.sizes), f"--sizes: every n must be >= {MIN_SIZE} (n x n particles), "
                                                    f"got {' '.join(map(str, args.sizes))}")
    require(args.steps >= 1, f"--steps must be >= 1 (the steps replayed), got {args.steps}")
    require(math.isfinite(args.settle) and args.settle >= 0, f"--settle must be >= 0 s, got {args.settle}")
    require(all(math.isfinite(c) and c > 0 for c in args.cells), f"--cells: every cell size must be > 0, got "
                                                                 f"{' '.join(map(str, args.cells))}")


def run(args) -> int:
    check(args)
    out = output_folder(args.out)
    runtime.init(args.arch)
    rows = []
    for n in args.sizes:
        t0 = time.perf_counter()
        scene, (v, t), frames = _record(n, args.settle, args.steps)
        print(f"{n}x{n}: recorded {len(frames)} steps after {args.settle} s ({time.perf_counter() - t0:.0f} s)", flush=True)
        implicit_ms = _time_integrator(scene, 4)

        approx = ApproxImplicit(scene.model, scene.state, scene.forces, contacts=scene.contacts)
        approx.step(scene.state, scene.contacts, scene.dt)
        approx_ms = statistics.median([_timed(lambda: approx.step(scene.state, scene.contacts, scene.dt))
                                       for _ in range(8)])
        mean_edge = scene.controller("colliders").objects[0].mean_edge
        for factor in args.cells:
            for mode, gate in (("fuzzy", True), ("exact", True), ("fuzzy", False)):
                if (mode, gate) != ("fuzzy", True) and factor != 1.5:
                    continue  # the mode comparison at the default cell size only
                t0 = time.perf_counter()
                col = MeshCollider(v, t, thickness=0.004, friction=0.4, cell_size=factor * mean_edge, mode=mode,
                                   reach_gate=gate, source="mannequin")
                build_s = time.perf_counter() - t0
                ms, c = _replay(col, scene, frames)
                q = max(c["queries"], 1)
                rows.append({"n": n, "cell_factor": factor, "cell_mm": 1e3 * factor * mean_edge, "mode": mode,
                             "reach_gate": gate, "build_s": build_s, "pairs": col.grid.n_pairs,
                             "collision_ms": ms, "implicit_ms": implicit_ms, "approx_implicit_ms": approx_ms,
                             "candidates_per_query": c["candidates"] / q, "tests_per_query": c["crossing_tests"] / q,
                             "tests_saved_x": c["candidates"] / max(c["crossing_tests"], 1),
                             "overflows": c["candidate_overflows"], "queries": c["queries"]})
                print(_fmt(rows[-1]), flush=True)
    _write(rows, out)
    return 0


def _timed(fn) -> float:
    t0 = time.perf_counter()
    fn()
    ti.sync()
    return 1e3 * (time.perf_counter() - t0)


COLS = [("n", "{}"), ("cell_mm", "{:.1f}"), ("mode", "{}"), ("reach_gate", "{}"), ("build_s", "{:.2f}"),
        ("pairs", "{}"), ("collision_ms", "{:.2f}"), ("implicit_ms", "{:.1f}"), ("approx_implicit_ms", "{:.2f}"),
        ("candidates_per_query", "{:.2f}"), ("tests_per_query", "{:.2f}"), ("tests_saved_x", "{:.1f}"),
        ("overflows", "{}")]


def _fmt(r: dict) -> str:
    return " | ".join(f.format(r[k]) for k, f in COLS)


def _write(rows, out: Path) -> None:
    lines = ["| " + " | ".join(k for k, _ in COLS) + " |", "|" + "---|" * len(COLS)]
    lines += [f"| {_fmt(r)} |" for r in rows]
    text = "\n".join(lines)
    (out / "collision.md").write_text(text + "\n")
    write_csv(rows, out / "collision.csv")
    print("\n" + text)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for n in sorted({r["n"] for r in rows}):
        rs = [r for r in rows if r["n"] == n and r["mode"] == "fuzzy" and r["reach_gate"]]
        ax[0].plot([r["cell_mm"] for r in rs], [r["collision_ms"] for r in rs], "o-", label=f"{n}x{n} collision")
        ax[0].axhline(rs[0]["approx_implicit_ms"], ls=":", color=ax[0].lines[-1].get_color(),
                      label=f"{n}x{n} approx-implicit step")
        ax[1].plot([r["cell_mm"] for r in rs], [r["candidates_per_query"] for r in rs], "o-", label=f"{n}x{n} candidates")
        ax[1].plot([r["cell_mm"] for r in rs], [r["tests_per_query"] for r in rs], "s--", label=f"{n}x{n} fuzzy tests")
    ax[0].set(xlabel="voxel size [mm]", ylabel="ms per step", title="collision cost vs voxel size")
    ax[1].set(xlabel="voxel size [mm]", ylabel="per particle query", title="triangle tests")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "collision.png", dpi=110)
    print(f"wrote {out / 'collision.md'}, {out / 'collision.csv'}, {out / 'collision.png'}")
