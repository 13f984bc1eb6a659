"""Cost at comparable accuracy against Taichi's shipped mass-spring example and NVIDIA Warp on the CPU (`bench peers`).

One scene for every engine: Taichi's shipped 3D mass-spring example (taichi/examples/ggui_examples/
mass_spring_3d_ggui.py): n x n particles of 1 kg in a 1 m square at y = 0.6 m, springs to every grid offset with
|di| + |dj| <= 2 (k = spring_Y / L0, kd = dashpot_damping x quad_size), gravity, air drag 1/s, dropped on a 0.3 m
ball at the origin (peer_taichi_example.ExamplePhysics; its start offset, random in the example, is fixed at
START_OFFSET, which breaks the sheet's symmetries: a perfectly centred sheet sits on an unstable symmetric fold).

For every size n (default 32 64 128, the same n for every engine):
  reference  our implicit integrator in float64, CG to 1e-7, at h = --ref-dt (5e-5 s) and at 2h and 4h; the
             reference is the Richardson extrapolation 2 x(h) - x(2h) (backward Euler is first order, so this
             cancels its leading error), and its own error is estimated as |R(h) - R(2h)| / 3 (R(2h) = 2 x(2h) -
             x(4h)): errors below that floor are not resolved. Cached in --out as reference_*.npz, keyed by every
             scene parameter, the sample times and the step.
  peers      - Taichi's example, headless, its own substep() kernel: at its shipped step 4e-2/n, then down a sqrt(2)
               ladder to the largest step that stays stable for the whole run, and at half that step;
             - Warp (optional: warp-lang 1.9.1), the same physics built with warp.sim (peer_warp.WarpSamePhysics):
               SemiImplicitIntegrator from 4 x our linear-theory stable step down the ladder, XPBDIntegrator
               (1 iteration, as warp's example) from 1/67 s down the ladder; each at its largest stable step and half;
             - Warp's own cloth example as shipped (euler / xpbd / vbd, its own scene: cost only, no error).
  ours       explicit, verlet and central-difference at 0.9 and 0.45 x their stable bound (scene.stable_dt);
             approx-implicit at spacing/4, /16, /64 and implicit (CG 1e-3) at spacing/4 .. /256, where spacing is
             the time between samples. Every step divides the sample spacing, so every run is sampled exactly at
             the reference's times (a sample off by half a step would add v dt / 2 to the error).
Each configuration: wall seconds per simulated second (compiles excluded), RMS and max distance to the reference
over every sample and particle (accuracy.compare). Ratios: for each peer configuration, its cost over the cost of
our cheapest configuration whose RMS error is at most the peer's ("comparable accuracy"), and the plain ratio of
its cost at its own largest stable step over our explicit integrator's at 0.9 x its bound (the same scheme).

Choices that keep the default run under ~10 minutes on 2 cores (first run; later runs reuse the references and
the Warp caches): 0.3 s simulated (the fall and the first 50 ms on the ball), 5 samples. Beyond ~0.35 s the
sheet folds over the ball and the fold pattern is sensitive: two float64 runs of the explicit scheme at 1e-5 s
and 2e-5 s end 5 mm apart at 0.4 s, so errors there would measure the folds, not the integrators. Warp's shipped
example is timed over 3 frames after a warm-up frame; its cloth builder (pure Python, 20-100 s at 128 x 128) is
cached in --out/warp_builder_cache.

Timing on a shared machine: between three runs of this bench on the 2-core VM, the Taichi side (ours and the
Taichi example alike) ran up to 2x slower per step in later runs, while Warp's timings held. Ratios against the
Taichi example held within ~30 % (both sides moved together); ratios against Warp moved with it. Compare two runs
before quoting a ratio against Warp.

Output in --out (default out/bench/peers): peers.md, peers.csv, peers.png (RMS error against cost, one panel per
size); the tables are printed too. Speed is measured here, never asserted in tests.
"""
from __future__ import annotations

import hashlib
import json
import math
import platform
import time
import warnings
from pathlib import Path

import numpy as np
import taichi as ti

from taichi_cloth import runtime
from taichi_cloth.errors import BlowUpError

from . import MIN_SIZE, output_folder, require
from . import write_csv as write_rows
from . import peer_warp
from .accuracy import Trajectory, compare, pareto_front, run_sampled
from .peer_taichi_example import ExamplePhysics, ExampleUnavailable, TaichiExample, run_example
from .peer_taichi_example import __doc__ as example_doc
from .peer_warp import (EXAMPLE_INTEGRATORS, WARP_VERSION, ShippedExample, WarpSamePhysics, run_same_physics,
                        warp_status)

START_OFFSET = (0.03, 0.01)  # [m] x, z: the example's random start offset (uniform in +-0.05 m), fixed
REFERENCE_OPTIONS = {"cg_tolerance": 1e-7, "cg_max_iterations": 1000}
EXPLICIT = ("explicit", "verlet", "central-difference")
BOUND_FRACTIONS = (0.9, 0.45)
#: our unconditionally stable integrators: (integrator, options, steps as divisors of the sample spacing)
IMPLICIT_SWEEP = (("approx-implicit", {}, (4, 16, 64)), ("implicit", {}, (4, 16, 64, 256)))
LADDER = math.sqrt(2.0)
MAX_LADDER = 16  # tries down the ladder before giving up (a factor 256)
WARP_EXAMPLE_FRAMES = 3
OURS = "taichi-cloth"
TI_EXAMPLE = "taichi example"
WARP = "warp"
WARP_SHIPPED = "warp example (own scene)"


def add_arguments(p) -> None:
    p.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128], help="grid sizes n (n x n particles)")
    p.add_argument("--sim-time", type=float, default=0.3, help="simulated seconds per run (default 0.3)")
    p.add_argument("--samples", type=int, default=5, help="sample times, equally spaced up to --sim-time")
    p.add_argument("--ref-dt", type=float, default=5e-5, help="reference step [s] (also run at 2x and 4x)")
    p.add_argument("--arch", default="cpu", choices=("cpu", "gpu"), help="Taichi arch (Warp always runs on the CPU)")
    p.add_argument("--out", default="out/bench/peers", help="folder for peers.md, peers.csv, peers.png and caches")
    p.add_argument("--no-warp", action="store_true", help="skip NVIDIA Warp (both its example and the same physics)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


# ---------------------------------------------------------------------------------------------- helpers
def snap(dt: float, spacing: float) -> float:
    """The largest step [s] <= dt that divides `spacing` [s] into whole steps."""
    return spacing / math.ceil(spacing / dt - 1e-9)


def energy_scale(physics) -> float:
    """Weight times the sheet's diagonal [J]: the unit of the energy drift."""
    side = (physics.n - 1) * physics.quad_size
    return physics.n ** 2 * physics.mass * float(np.linalg.norm(physics.gravity)) * side * math.sqrt(2.0)


def _progress_bar(progress: bool, desc: str, total: float):
    """(tick(t), close()) of a tqdm bar over simulated seconds, or no-ops."""
    if not progress:
        return None, (lambda: None)
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit="sim s", leave=False,
               bar_format="{l_bar}{bar}| {n:.3f}/{total:.3f} sim s [{elapsed}]")
    done = [0.0]

    def tick(t):
        bar.update(max(t - done[0], 0.0))
        done[0] = t

    return tick, bar.close


def reference(physics, start: np.ndarray, times: np.ndarray, h: float, cache: Path | None, progress=False):
    """The reference Trajectory of `physics` from `start` (P,3) [m] at `times` [s], and its floor.

    Our implicit integrator in float64 (REFERENCE_OPTIONS) at h, 2h and 4h [s]; the reference is the Richardson
    extrapolation R(h) = 2 x(h) - x(2h). floor: rms_error and max_error [m] of |R(h) - R(2h)| / 3 (the estimated
    error of R(h) if it converges at second order) and be_rms [m], the RMS of |x(h) - x(2h)| (the error of plain
    backward Euler at h). Each run is cached as .npz in `cache`, keyed by the scene, the times and the step."""
    key = hashlib.sha1(json.dumps([physics.key(), np.asarray(start).round(12).tolist(), list(map(float, times)),
                                   REFERENCE_OPTIONS, "peers-reference-1"], default=str).encode()).hexdigest()[:12]
    runs = []
    for k in (1, 2, 4):
        path = None if cache is None else cache / f"reference_n{physics.n}_{key}_{k * h:.4g}.npz"
        if path is not None and path.exists():
            runs.append(Trajectory.load(path))
            continue
        tick, close = _progress_bar(progress, f"n={physics.n}: reference h={k * h:.3g} s", float(times[-1]))
        scene = physics.scene("implicit", k * h, "f64", REFERENCE_OPTIONS, positions=start, name="peers_reference")
        traj = run_sampled(scene, times, progress=tick)
        close()
        if not traj.stable:
            raise RuntimeError(f"the reference at n = {physics.n} went unstable: {traj.message}")
        if path is not None:
            traj.save(path)
        runs.append(traj)
    x1, x2, x4 = (r.positions for r in runs)
    r1, r2 = 2 * x1 - x2, 2 * x2 - x4
    ref = Trajectory(runs[0].times, r1, 2 * runs[0].energy - runs[1].energy, runs[0].max_strain, runs[0].wall,
                     runs[0].sim_time, runs[0].steps)
    d = np.linalg.norm(r1 - r2, axis=2) / 3.0
    be = np.linalg.norm(x1 - x2, axis=2)
    floor = {"rms_error": float(np.sqrt(np.mean(d ** 2))), "max_error": float(d.max()),
             "be_rms": float(np.sqrt(np.mean(be ** 2))), "wall": sum(r.wall for r in runs), "h": h}
    return ref, floor


def _warm(scene, dt: float) -> None:
    """One frame at dt [s], then reset: the scene's kernels are compiled and the threads awake before the clock
    of the first configuration starts (the first timed run of a process was up to 2x slow without it)."""
    scene.dt = dt
    scene.reset()
    try:
        scene.step(scene.substeps)
    except BlowUpError:
        pass  # the sweep records it
    scene.reset()


def _row(n, engine, integrator, step, traj: Trajectory, ref, scale, **extra) -> dict:
    errors = compare(traj, ref, scale)
    status = "ok" if traj.stable else f"unstable at t = {traj.sim_time:.3g} s"
    return {"n": n, "engine": engine, "integrator": integrator, "step": step, "dt": extra.pop("dt"),
            "ms_per_step": 1e3 * traj.wall / max(traj.steps, 1), **errors, "status": status,
            "message": traj.message, **extra}


def _ladder(run_at, start_dt: float, spacing: float, label: str, log) -> list[dict]:
    """Run at snap(start_dt), then down the sqrt(2) ladder until a run is stable; then once more at half that step.
    run_at(dt, step_label) -> row. Rows of the unstable tries are kept (they show where the step fails)."""
    rows = []
    dt = snap(start_dt, spacing)
    for k in range(MAX_LADDER + 1):
        row = run_at(dt, f"{label}" if k == 0 else f"{label} / sqrt2^{k}")
        rows.append(row)
        log(row)
        if row["stable"]:
            row["largest_stable"] = True
            row["step"] += " (largest stable)"
            half = run_at(snap(dt / 2, spacing), "largest stable / 2")
            rows.append(half)
            log(half)
            break
        dt = snap(dt / LADDER, spacing)
    return rows


# ---------------------------------------------------------------------------------------------- one size
def measure_size(n: int, args, warp_reason: str | None, warp_example_reason: str | None, log) -> tuple[list, dict]:
    """Every configuration at size n: (rows, reference info)."""
    spacing = args.sim_time / args.samples
    times = spacing * np.arange(1, args.samples + 1)
    progress = not args.no_progress
    shipped_dt = 4e-2 / n
    example, example_reason = None, None
    try:
        example = TaichiExample(n, snap(shipped_dt, spacing))
        physics = example.physics
    except ExampleUnavailable as err:
        example_reason = str(err)
        print(f"skipped: Taichi's shipped example ({err})")
        physics = ExamplePhysics(n)
    start = physics.start_positions(START_OFFSET)
    scale = energy_scale(physics)
    t0 = time.perf_counter()
    ref, floor = reference(physics, start, times, spacing / (4 * math.ceil(spacing / (4 * args.ref_dt) - 1e-9)),
                           Path(args.out), progress)
    print(f"n = {n}: reference ready ({time.perf_counter() - t0:.1f} s); its own error (est.): RMS "
          f"{1e3 * floor['rms_error']:.3g} mm, max {1e3 * floor['max_error']:.3g} mm (plain backward Euler at h: RMS "
          f"{1e3 * floor['be_rms']:.3g} mm)", flush=True)
    rows: list[dict] = []

    # ---- ours
    bound_rows = {}
    for name in EXPLICIT:
        scene = physics.scene(name, spacing, positions=start)
        bound = scene.stable_dt
        _warm(scene, snap(0.5 * bound, spacing))
        for f in BOUND_FRACTIONS:
            scene.dt = snap(f * bound, spacing)
            scene.reset()
            traj = run_sampled(scene, times)
            row = _row(n, OURS, name, f"{f:g} x bound", traj, ref, scale, dt=scene.dt, stable_dt=bound)
            rows.append(row)
            log(row)
            bound_rows[(name, f)] = row
    for name, options, divisors in IMPLICIT_SWEEP:
        scene = physics.scene(name, spacing, options=options, positions=start)
        _warm(scene, spacing / divisors[-1])
        for k in divisors:
            scene.dt = spacing / k
            scene.reset()
            before = dict(scene.integrator.stats)
            traj = run_sampled(scene, times)
            extra = {}
            if "cg_iterations" in before:  # the warm-up step counts too: steps + 1
                used = scene.integrator.stats["cg_iterations"] - before["cg_iterations"]
                extra["cg_iterations"] = used / (traj.steps + 1)
            rows.append(_row(n, OURS, name, f"spacing/{k}", traj, ref, scale, dt=scene.dt, **extra))
            log(rows[-1])
    explicit_bound = bound_rows[("explicit", 0.9)]["stable_dt"]

    # ---- Taichi's shipped example
    if example is not None:
        cache = {}

        def run_ti(dt, label):
            ex = example if abs(dt - example.dt) < 1e-15 else cache.get(dt) or TaichiExample(n, dt)
            cache[dt] = ex
            traj, _ = run_example(n, dt, times, start=start, example=ex)
            return _row(n, TI_EXAMPLE, "symplectic Euler (its substep)", label, traj, ref, scale, dt=dt)

        rows += _ladder(run_ti, shipped_dt, spacing, "shipped 4e-2/n", log)

    # ---- Warp, the same physics
    if warp_reason is None:
        for integ, start_dt, label in (("semi-implicit", 4 * explicit_bound, "4 x our bound"),
                                       ("xpbd", spacing / 4, "spacing/4")):
            sim = WarpSamePhysics(physics, integ, spacing, iterations=1, start=start)

            def run_warp(dt, lab, sim=sim, integ=integ):
                sim.dt = dt
                traj = run_same_physics(sim, times, start)
                return _row(n, WARP, f"{integ} (same physics)", lab, traj, ref, scale, dt=dt)

            rows += _ladder(run_warp, start_dt, spacing, label, log)

    # ---- Warp's own example, as shipped (its scene: cost only)
    if warp_example_reason is None:
        for integ in EXAMPLE_INTEGRATORS:
            t1 = time.perf_counter()
            shipped = ShippedExample(n, integ, cache_dir=Path(args.out) / "warp_builder_cache")
            r = shipped.time_frames(WARP_EXAMPLE_FRAMES)
            row = {"n": n, "engine": WARP_SHIPPED, "integrator": integ, "step": "as shipped (32 substeps/frame)",
                   "dt": r["dt"], "ms_per_step": r["ms_per_step"], "wall_per_sim_s": r["wall_per_sim_s"],
                   "stable": r["finite"], "status": "ok" if r["finite"] else "non-finite",
                   "build_s": r["build_s"], "first_frame_s": r["first_frame_s"], "particles": r["particles"]}
            rows.append(row)
            log(row)
            del shipped
            print(f"    (warp example {integ}: built in {r['build_s']:.1f} s, first frame {r['first_frame_s']:.1f} s, "
                  f"{time.perf_counter() - t1:.1f} s in all)", flush=True)
    info = {"floor": floor, "explicit_bound": explicit_bound, "times": times, "example_reason": example_reason,
            "ref": ref}
    return rows, info


# ---------------------------------------------------------------------------------------------- ratios
def add_ratios(rows: list[dict]) -> None:
    """For each peer row: `ours_at_error` (our cheapest configuration with RMS error <= the peer's), `ratio`
    (peer cost / that cost) and, for a peer's largest stable step, `plain_ratio` (peer cost / our explicit at 0.9 x
    its bound). Our rows get `front` (Pareto front of our configurations at that size)."""
    for n in sorted({r["n"] for r in rows}):
        ours = [r for r in rows if r["n"] == n and r["engine"] == OURS]
        front = pareto_front([r["wall_per_sim_s"] for r in ours], [r["rms_error"] for r in ours])
        for r, f in zip(ours, front):
            r["front"] = bool(f)
        base = next((r for r in ours if r["integrator"] == "explicit" and r["step"] == "0.9 x bound"), None)
        for r in rows:
            if r["n"] != n or r["engine"] == OURS or not r.get("stable"):
                continue
            if base is not None and (r.get("largest_stable") or r["engine"] == WARP_SHIPPED):
                r["plain_ratio"] = r["wall_per_sim_s"] / base["wall_per_sim_s"]
            err = r.get("rms_error", float("nan"))
            if not np.isfinite(err):
                continue
            ok = [o for o in ours if o["stable"] and o["rms_error"] <= err]
            if ok:
                best = min(ok, key=lambda o: o["wall_per_sim_s"])
                r["ours_at_error"] = f"{best['integrator']} {best['step']}"
                r["ours_cost"], r["ours_rms"] = best["wall_per_sim_s"], best["rms_error"]
                r["ratio"] = r["wall_per_sim_s"] / best["wall_per_sim_s"]


# ---------------------------------------------------------------------------------------------- output
COLUMNS = [("n", "{}"), ("engine", "{}"), ("integrator", "{}"), ("step", "{}"), ("dt", "{:.3g}"),
           ("ms_per_step", "{:.3g}"), ("wall_per_sim_s", "{:.3g}"), ("rms_error", "{:.3g}"), ("max_error", "{:.3g}"),
           ("status", "{}")]
RATIO_COLUMNS = [("n", "{}"), ("engine", "{}"), ("integrator", "{}"), ("step", "{}"), ("dt", "{:.3g}"),
                 ("wall_per_sim_s", "{:.3g}"), ("rms_error", "{:.3g}"), ("ours_at_error", "{}"),
                 ("ours_cost", "{:.3g}"), ("ours_rms", "{:.3g}"), ("ratio", "{:.3g}"), ("plain_ratio", "{:.3g}")]


def _fmt(r: dict, key: str, fmt: str) -> str:
    v = r.get(key)
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    return fmt.format(v)


def markdown_table(rows: list[dict], columns) -> str:
    lines = ["| " + " | ".join(k for k, _ in columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(_fmt(r, k, f) for k, f in columns) + " |" for r in rows]
    return "\n".join(lines)


def _row_text(r: dict) -> str:
    text = "  " + " | ".join(_fmt(r, k, f) for k, f in COLUMNS)
    return text + ("" if r.get("stable", True) else f"  ({r.get('message', '')[:90]})")


def report(rows: list[dict], infos: dict, settings: dict, skipped: list[str]) -> str:
    """peers.md: settings, reference floors, the ratios, every configuration, the shipped Warp example, notes."""
    lines = ["# taichi-cloth against its peers (`bench peers`)", "",
             f"Machine: {settings['machine']}. Taichi {settings['taichi']} on `{settings['arch']}`; "
             f"Warp {settings['warp'] or 'not run'} on the CPU (single-threaded).", "",
             f"Scene: Taichi's shipped mass_spring_3d_ggui example (n x n particles, 1 kg each, k = spring_Y / L0, "
             f"kd = dashpot_damping x quad_size, drag 1/s, the 0.3 m ball), start offset {START_OFFSET} m. "
             f"{settings['samples']} samples up to {settings['sim_time']} s. Cost: wall seconds per simulated second "
             f"(compiles excluded). Errors: metres, RMS / max distance to the reference over every sample and "
             f"particle.",
             "", "Reference: our implicit integrator, float64, CG 1e-7, Richardson-extrapolated from h and 2h; its "
             "error estimated from h, 2h, 4h:", "",
             "| n | h [s] | its RMS error (est.) [m] | max [m] | plain backward Euler at h, RMS [m] "
             "| stepping wall, 3 runs [s] |",
             "|---|---|---|---|---|---|"]
    for n, info in infos.items():
        f = info["floor"]
        lines.append(f"| {n} | {f['h']:.3g} | {f['rms_error']:.3g} | {f['max_error']:.3g} | {f['be_rms']:.3g} | "
                     f"{f['wall']:.1f} |")
    if skipped:
        lines += ["", "Skipped:", ""] + [f"- {s}" for s in skipped]
    peer_rows = [r for r in rows if r["engine"] != OURS and r["engine"] != WARP_SHIPPED and r.get("stable")]
    lines += ["", "## Ratios", "",
              "`ratio`: the peer's cost over the cost of our cheapest configuration whose RMS error is at most the "
              "peer's (`ours_at_error`); `plain_ratio` (at a peer's largest stable step): its cost over our "
              "explicit integrator's at 0.9 x its stable bound. Above 1: we are faster.", "",
              markdown_table(peer_rows, RATIO_COLUMNS)]
    shipped = [r for r in rows if r["engine"] == WARP_SHIPPED]
    if shipped:
        lines += ["", "## Warp's own cloth example, as shipped (its scene, not ours: cost only)", "",
                  "`plain_ratio`: its cost over our explicit integrator's on our scene of the same n.", "",
                  markdown_table(shipped, [("n", "{}"), ("integrator", "{}"), ("particles", "{}"), ("dt", "{:.3g}"),
                                           ("ms_per_step", "{:.3g}"), ("wall_per_sim_s", "{:.3g}"),
                                           ("plain_ratio", "{:.3g}"), ("build_s", "{:.1f}"),
                                           ("first_frame_s", "{:.1f}")])]
    lines += ["", "## Every configuration", "",
              markdown_table([r for r in rows if r["engine"] != WARP_SHIPPED], COLUMNS),
              "", "## How the engines differ", "", "```", example_doc.strip(), "```"]

    lines += ["", "```", peer_warp.__doc__.strip(), "```"]
    return "\n".join(lines) + "\n"


def write_csv(rows: list[dict], path: Path) -> None:
    """The comparison's rows, its COLUMNS first."""
    columns = [k for k, _ in COLUMNS]
    write_rows(rows, path, columns + sorted({k for r in rows for k in r} - set(columns)))


def plot(rows: list[dict], infos: dict, path: Path) -> Path | None:
    """RMS error against cost, log-log, one panel per size: a line per engine and integrator through its steps,
    the reference's own error as a dotted line."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    sizes = list(infos)
    fig, axes = plt.subplots(1, len(sizes), figsize=(5.4 * len(sizes), 4.6), squeeze=False)
    series = list(dict.fromkeys((r["engine"], r["integrator"]) for r in rows if r["engine"] != WARP_SHIPPED))
    colors = {s: plt.cm.tab10(i % 10) for i, s in enumerate(series)}
    for ax, n in zip(axes[0], sizes):
        for s in series:
            pts = sorted((r["wall_per_sim_s"], r["rms_error"]) for r in rows
                         if r["n"] == n and (r["engine"], r["integrator"]) == s and r.get("stable")
                         and np.isfinite(r.get("rms_error", np.nan)))
            if not pts:
                continue
            style = "o-" if s[0] == OURS else ("s--" if s[0] == TI_EXAMPLE else "^:")
            ax.loglog(*zip(*pts), style, color=colors[s], label=f"{s[0]}: {s[1]}", ms=5)
        ax.axhline(infos[n]["floor"]["rms_error"], color="k", ls=":", lw=0.8, label="reference's own error")
        ax.set(xlabel="wall s per simulated s", ylabel="RMS error [m]", title=f"{n} x {n} particles")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# ---------------------------------------------------------------------------------------------- entry point
def check(args) -> None:
    """The arguments, before any work: TaichiClothError (one `error:` line on stderr) for a grid under MIN_SIZE, a
    --sim-time, --ref-dt or --samples out of range, a reference step that does not fit the sample spacing."""
    require(all(n >= MIN_SIZE for n in args.sizes), f"--sizes: every n must be >= {MIN_SIZE}")
    require(args.sim_time > 0 and args.samples >= 1 and args.ref_dt > 0,
            "--sim-time and --ref-dt must be > 0 and --samples >= 1")
    require(args.ref_dt * 4 <= args.sim_time / args.samples,
            f"--ref-dt: 4 x {args.ref_dt:g} s must fit in the sample spacing {args.sim_time / args.samples:g} s")


def run(args) -> int:
    check(args)
    out = output_folder(args.out)

    skipped = []
    if args.no_warp:
        warp_reason = warp_example_reason = "--no-warp"
    else:
        warp_reason, warp_example_reason = warp_status()
        if warp_reason is not None:
            skipped.append(f"NVIDIA Warp: {warp_reason}")
        elif warp_example_reason is not None:
            skipped.append(f"Warp's shipped cloth example: {warp_example_reason}")
        for line in skipped:
            print(f"skipped: {line}")
    runtime.init(args.arch)
    t_start = time.perf_counter()

    def log(row):
        print(_row_text(row), flush=True)

    print(" | ".join(k for k, _ in COLUMNS))
    rows, infos = [], {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # step-guard and deprecation notices: the table says what happened
        for n in args.sizes:
            r, info = measure_size(n, args, warp_reason, warp_example_reason, log)
            rows += r
            infos[n] = info
            if info["example_reason"]:
                skipped.append(f"Taichi's shipped example: {info['example_reason']}")
    add_ratios(rows)
    warp_version = None
    if warp_reason is None:
        import warp

        warp_version = warp.__version__
    settings = {"machine": f"{platform.machine()}, {__import__('os').cpu_count()} cores, {platform.system()}",
                "taichi": ".".join(map(str, ti.__version__)), "arch": args.arch, "warp": warp_version,
                "sim_time": args.sim_time, "samples": args.samples}
    text = report(rows, infos, settings, sorted(set(skipped)))
    (out / "peers.md").write_text(text)
    write_csv(rows, out / "peers.csv")
    png = plot(rows, infos, out / "peers.png")
    peer_rows = [r for r in rows if r["engine"] != OURS and r["engine"] != WARP_SHIPPED and r.get("stable")]
    print("\nratios (above 1: taichi-cloth is faster):\n" + markdown_table(peer_rows, RATIO_COLUMNS))
    shipped = [r for r in rows if r["engine"] == WARP_SHIPPED]
    if shipped:
        print("\nWarp's own example (its scene):\n" + markdown_table(
            shipped, [("n", "{}"), ("integrator", "{}"), ("ms_per_step", "{:.3g}"), ("wall_per_sim_s", "{:.3g}"),
                      ("plain_ratio", "{:.3g}")]))
    print(f"\n{len(rows)} configurations in {time.perf_counter() - t_start:.0f} s; wrote {out / 'peers.md'}, "
          f"{out / 'peers.csv'}" + (f", {png}" if png else ""))
    if warp_reason is None and warp_version != WARP_VERSION:
        print(f"note: measured with warp {warp_version}; the extra pins {WARP_VERSION}")
    return 0
