"""ms per step and real-time factor of every integrator (`python -m taichi_cloth bench [integrators]`).

On square grids: ms per step, compile time, and wall time per simulated second of a hanging cloth at each
integrator's largest stable step (the implicit one with Jacobi-preconditioned CG); the implicit integrator with its
multigrid preconditioner on the same grid by aggregation ("implicit aggregation") and on the same sheet built as a
4-8 hierarchy ((n+1) x (n+1) particles, on its finest level, "implicit multigrid"), where n allows one; and a
garment (the T-shirt of the demos, after its seams are joined) with both preconditioners.

"Largest stable step": 0.9 x the linear-theory bound for the explicit family (docs/algorithms.md, step limits);
1/60 s (one step per displayed frame) for the unconditionally stable ones. Times are wall clock after a
warm-up; the real-time factor is simulated seconds per wall second. Results: a table on stdout, plus
bench.csv, bench.md and bench.png in --out. Never asserted in tests: speed is measured, not tested.
"""
from __future__ import annotations

import csv
import re
import statistics
import time
from pathlib import Path

import taichi as ti
from taichi.lang import impl

from benchmarks import MIN_SIZE, output_folder, require, write_csv
from taichi_cloth import runtime
from taichi_cloth.builder import ClothBuilder
from taichi_cloth.errors import BlowUpError
from taichi_cloth.frame import scene_layout, scene_snapshot
from taichi_cloth.integrators import INTEGRATORS
from taichi_cloth.integrators.implicit import Implicit
from taichi_cloth.material import MATERIALS
from taichi_cloth.multilevel_cloth import multilevel_grid
from taichi_cloth.scene import Scene
from taichi_cloth.scenefile import load_scene, parse_scene

FRAME_DT = 1.0 / 60.0
#: the garment timed by default: the T-shirt demo's scene, where the project's demos are beside the package
GARMENT = Path(__file__).resolve().parents[1] / "demos" / "scenes" / "sew_tshirt.toml"


def add_arguments(p) -> None:
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128, 256], help="grid sizes n (n x n particles)")
    p.add_argument("--integrators", nargs="+", default=None, help="integrators to time (default: all five)")
    p.add_argument("--steps", type=int, default=20, help="steps per timed block (5 blocks, median reported)")
    p.add_argument("--material", default="cotton", help="material preset")
    p.add_argument("--no-multigrid", action="store_true",
                   help="skip the rows of the implicit integrator with its multigrid preconditioner (aggregation, 4-8)")
    p.add_argument("--garment", default=str(GARMENT) if GARMENT.exists() else "none",
                   help="scene file of a garment timed with the implicit integrator once its seams are joined "
                        "(default: the T-shirt demo's); none: skip")
    p.add_argument("--kernel-shares", action="store_true",
                   help="instead of the timings: each kernel's share of a step (Taichi's kernel profiler, which "
                        "slows every launch a little), to kernels.md and kernels.csv")
    p.add_argument("--arch", default="cpu", choices=("cpu", "gpu"))
    p.add_argument("--out", default="out/bench", help="folder for bench.csv, bench.md, bench.png")


def hanging_cloth(n: int, integrator: str, material: str = "cotton", dt: float | None = None, **options):
    """The benchmark scene: a 1 m square sheet of n x n particles pinned at its two top corners. dt [s] defaults
    to 1/60 s for the unconditionally stable integrators and 0.9 x the stable bound for the explicit ones."""
    cloth = ClothBuilder.grid((1.0, 1.0), (n, n), material, center=(0.0, 1.0, 0.0), plane="xy")
    top = [n * (n - 1), n * n - 1]
    scene = Scene(cloth, name=f"bench_{integrator}_{n}", integrator=integrator, dt=dt or FRAME_DT,
                  integrator_options=options, pins=[{"indices": top}], air_damping=0.2, step_guard="off")
    if dt is None and scene.stable_dt is not None:
        scene.dt = 0.9 * scene.stable_dt  # the largest step the theory keeps stable, with a margin
    return scene


def multigrid_cloth(n: int, material: str = "cotton"):
    """The benchmark sheet as a 4-8 hierarchy on its finest level, (n+1) x (n+1) particles, for the implicit
    integrator's multigrid preconditioner; None unless n = b x 2^j cells, b in 2, 3, 4, 8 and j >= 1."""
    for base in (4, 3, 2, 8):  # 8 x 2^5 = 256 cells: 4 x 2^6 would need 13 levels, one more than a hierarchy holds
        j = (n // base).bit_length() - 1
        if n % base == 0 and n // base == 1 << j and 2 * j + 1 <= 12 and j >= 1:
            return multilevel_grid((1.0, 1.0), (base, base), 2 * j + 1, material, center=(0.0, 1.0, 0.0),
                                   plane="xy", start_level=2 * j)
    return None


def hanging_multigrid(n: int, material: str = "cotton"):
    """hanging_cloth's scene on multigrid_cloth(n) (pinned at its two top corners, h = 1/60 s), or None."""
    cloth = multigrid_cloth(n, material)
    if cloth is None:
        return None
    return Scene(cloth, name=f"bench_implicit_multigrid_{n}", integrator="implicit", dt=FRAME_DT,
                 integrator_options={"preconditioner": "multigrid"}, multilevel={"refine": False},
                 pins=[{"box": ((sx - 0.01, 1.49, -0.01), (sx + 0.01, 1.51, 0.01))} for sx in (-0.5, 0.5)],
                 air_damping=0.2, step_guard="off")


def time_scene(scene, steps: int, blocks: int = 5) -> dict:
    """First-step time (compile or cache load), then the median over `blocks` blocks of `steps` steps of the
    ms per step, after 3 warm-up steps. The median resists the noise of a shared 2-core machine."""
    t0 = time.perf_counter()
    scene.advance(1)
    ti.sync()
    first = time.perf_counter() - t0
    scene.advance(3)
    ti.sync()
    per_block = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        scene.advance(steps)
        ti.sync()
        per_block.append(1e3 * (time.perf_counter() - t0) / steps)
    ms = statistics.median(per_block)
    try:
        scene.check()
        stable = True
    except BlowUpError:
        stable = False
    per_sim_s = ms * 1e-3 / scene.dt
    return {"first_step_s": first, "ms_per_step": ms, "dt": scene.dt, "wall_per_sim_s": per_sim_s,
            "realtime_factor": 1.0 / per_sim_s, "stable": stable,
            **{k: v / (blocks * steps + 4) for k, v in scene.integrator.stats.items()}}


def time_recorder(scene, out: Path, frames: int = 10) -> float:
    """ms per recorded frame (positions + normals + scalars) for this scene's cloth; NaN without rerun-sdk (a GPU
    machine given only the solver's packages: benchmarks/gpu_check.py)."""
    try:
        from taichi_cloth.recorder import Recorder
    except ImportError:
        return float("nan")

    with Recorder(out / "recorder_timing.rrd", overwrite=True) as rec:
        rec.begin_cloth("cloth", scene_layout(scene))
        m = scene.measure()
        rec.log_frame("cloth", scene_snapshot(scene, 0, m))
        t0 = time.perf_counter()
        for f in range(1, frames + 1):
            rec.log_frame("cloth", scene_snapshot(scene, f, m))  # the snapshot (a copy out of the fields) is part of the cost
        ms = 1e3 * (time.perf_counter() - t0) / frames
    (out / "recorder_timing.rrd").unlink(missing_ok=True)
    return ms


def kernel_shares(scene, steps: int) -> dict:
    """{kernel name: ms per step inside that kernel} over `steps` steps after 4 warm-up ones. Needs Taichi started
    with kernel_profiler=True. Launch and host time is not in it: the profiler itself adds per-task overhead on the
    CPU (a fused explicit step at 64x64 took 20 ms per step under it, 0.27 without), so compare the kernels' sum
    with the plain bench's ms per step to see the launch and host share."""
    scene.advance(4)
    ti.sync()
    ti.profiler.clear_kernel_profiler_info()
    scene.advance(steps)
    ti.sync()
    shares: dict[str, float] = {}
    for record in impl.get_runtime().prog.get_kernel_profiler_records():
        # "<kernel>_c<id>_<instance>_kernel_<task>_<kind>": one record per offloaded task of a launch
        name = re.sub(r"_c\d+_\d+_kernel_.*$", "", record.name)
        shares[name] = shares.get(name, 0.0) + record.kernel_time / steps
    return shares


def _kernel_table(scenes, steps: int, out: Path) -> None:
    rows = []
    for label, _, scene in scenes:
        n = round(scene.model.data.n_particles ** 0.5)
        shares = kernel_shares(scene, steps)
        total = sum(shares.values())
        for kernel, ms in sorted(shares.items(), key=lambda kv: -kv[1]):
            if ms >= 0.005 * total:  # the kernels under half a per cent make no row
                rows.append({"integrator": label, "n": n, "kernel": kernel, "ms_per_step": ms, "share": ms / total})
        print(f"{label} {n}: {total:.3f} ms per step in kernels, "
              + ", ".join(f"{r['kernel']} {100 * r['share']:.0f} %" for r in rows if r["integrator"] == label
                          and r["n"] == n), flush=True)
    lines = ["| integrator | n | kernel | ms per step | share of the kernels' time |", "|---|---|---|---|---|"]
    lines += [f"| {r['integrator']} | {r['n']} | {r['kernel']} | {r['ms_per_step']:.3g} | {100 * r['share']:.1f} % |"
              for r in rows]
    (out / "kernels.md").write_text("\n".join(lines) + "\n")
    write_csv(rows, out / "kernels.csv")
    print(f"wrote {out / 'kernels.md'}, {out / 'kernels.csv'}")


def garment_scene(path, preconditioner: str, frames: int = 90):
    """The garment scene file at `path` with the implicit integrator, `preconditioner` and CG to the integrator's
    default tolerance (1e-3; the T-shirt demo's 1e-2 leaves its seams a few tenths of a millimetre short of joining
    with the aggregation multigrid), run for `frames` frames (the T-shirt's seams join after about 0.75 s)."""
    tolerance = Implicit.OPTIONS["cg_tolerance"].default
    scene = load_scene(path, integrator="implicit",
                       integrator_options={"preconditioner": preconditioner, "cg_tolerance": tolerance}).scene
    scene.run(frames, progress=False)
    scene.integrator.stats = dict.fromkeys(scene.integrator.stats, 0)  # the timed steps' figures only
    return scene


def _scenes(args, names):
    """(label, size n, scene) for every size and integrator named (the implicit one with Jacobi), then, where the
    implicit integrator is named, the same grid with the aggregation multigrid and the multigrid sheet of that size
    ((n+1)^2 particles) where there is one; last the garment with both preconditioners."""
    mg = not args.no_multigrid and "implicit" in names
    for n in args.sizes:
        for name in names:
            yield name, n, hanging_cloth(n, name, args.material, **({"preconditioner": "jacobi"}
                                                                     if name == "implicit" else {}))
        if mg:
            yield "implicit aggregation", n, hanging_cloth(n, "implicit", args.material, preconditioner="multigrid")
        sheet = hanging_multigrid(n, args.material) if mg else None
        if sheet is not None:
            yield "implicit multigrid", n, sheet
    if args.garment != "none" and "implicit" in names:
        for pre, label in (("jacobi", "garment implicit"), ("multigrid", "garment implicit aggregation")):
            scene = garment_scene(args.garment, pre)
            yield label, round(scene.model.data.n_particles ** 0.5), scene


def check(args) -> None:
    """The arguments, before Taichi starts: TaichiClothError (one `error:` line) for a grid under MIN_SIZE, an
    unknown integrator or material, --steps under 1, a garment scene file that is missing or malformed."""
    require(all(n >= MIN_SIZE for n in args.sizes), f"--sizes: every n must be >= {MIN_SIZE} (n x n particles), "
                                                    f"got {' '.join(map(str, args.sizes))}")
    for name in args.integrators or []:
        require(name in INTEGRATORS, f"--integrators: unknown integrator {name!r}; choose from "
                                     f"{', '.join(INTEGRATORS)}")
    require(args.material in MATERIALS, f"--material: unknown material {args.material!r}; choose from "
                                        f"{', '.join(MATERIALS)}")
    require(args.steps >= 1, f"--steps must be >= 1, got {args.steps}")
    if args.garment != "none":  # a file named is checked even when no implicit row will time it: a typo is a typo
        parse_scene(Path(args.garment), label=f"--garment {args.garment}")  # SceneError: missing, a folder, bad


def run(args) -> int:
    check(args)
    out = output_folder(args.out)
    runtime.init(args.arch, kernel_profiler=args.kernel_shares)
    names = args.integrators or list(INTEGRATORS)
    if args.kernel_shares:
        _kernel_table(_scenes(args, names), args.steps, out)
        return 0
    rows, record_ms = [], {}
    for label, size, scene in _scenes(args, names):
        r = time_scene(scene, args.steps)
        if size not in record_ms:  # the recorder's cost per frame, once per size
            record_ms[size] = time_recorder(scene, out)
        particles = scene.model.data.n_particles
        rows.append({"integrator": label, "n": round(particles ** 0.5), "particles": particles,
                     "springs": scene.model.data.n_springs, **r, "record_ms_per_frame": record_ms[size]})
        print(_row_text(rows[-1]), flush=True)
    _write(rows, out, args)
    return 0


COLUMNS = [("integrator", "{}"), ("n", "{}"), ("dt", "{:.3g}"), ("ms_per_step", "{:.3f}"),
           ("first_step_s", "{:.2f}"), ("wall_per_sim_s", "{:.3g}"), ("realtime_factor", "{:.3g}"),
           ("cg_iterations", "{:.1f}"), ("record_ms_per_frame", "{:.2f}"), ("stable", "{}")]


def _row_text(r: dict) -> str:
    return " | ".join(fmt.format(r[k]) if k in r else "-" for k, fmt in COLUMNS)


def _write(rows: list[dict], out: Path, args) -> None:
    header = " | ".join(k for k, _ in COLUMNS)
    table = [f"| {header} |", "|" + "---|" * len(COLUMNS)] + [f"| {_row_text(r)} |" for r in rows]
    text = "\n".join(table)
    (out / "bench.md").write_text(text + "\n")
    keys = sorted({k for r in rows for k in r})
    with open(out / "bench.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        w.writerows(rows)
    print("\n" + text)
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not installed: no plot")
        return
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.8))
    for name in dict.fromkeys(r["integrator"] for r in rows):
        rs = [r for r in rows if r["integrator"] == name]
        style = dict(marker="*", ms=11, ls="none") if name.startswith("garment") else dict(marker="o")
        axes[0].loglog([r["particles"] for r in rs], [r["ms_per_step"] for r in rs], label=name, **style)
        axes[1].loglog([r["particles"] for r in rs], [r["realtime_factor"] for r in rs], label=name, **style)
    axes[0].set(xlabel="particles", ylabel="ms per step", title="cost of one step")
    axes[1].axhline(1.0, color="k", lw=0.8, ls="--")
    axes[1].set(xlabel="particles", ylabel="simulated s per wall s",
                title="hanging cloth at the largest stable step")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=5, fontsize=8)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    fig.savefig(out / "bench.png", dpi=110)
    print(f"wrote {out / 'bench.md'}, {out / 'bench.csv'}, {out / 'bench.png'}")
