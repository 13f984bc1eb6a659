"""Stability envelope: stable, unstable or refused over stiffness x time step x mass ratio, for every integrator.

For each integrator and mass ratio, one probe scene (taichi_cloth.stability_probes.probe_scene: a 6x6 sheet, two corners
pinned, no gravity, a checkerboard of light and heavy particles, air drag 0.1 1/s, spring damping kd/k = 1e-6 s)
is reused over the whole sweep: the stiffest spring is set to k through Model.set_stiffness and dt is passed,
so each kernel compiles once. Every cell (k, dt) is a run of --n-steps steps from a random perturbation (1 mm,
less on stiff cloth: probes.probe_amplitude), checked for a blow-up every --check-every steps, and classified:

  .  stable      ran all its steps
  X  unstable    a BlowUpError was raised (detected and reported; the CSV has the step it was caught at)
  r  refused     the step guard (step_guard = "refuse": dt above the damped closed-form bound at the estimated
                 highest frequency, stability.omega_max_estimate) would refuse it; run anyway it stayed stable (the guard is conservative here)
  R  refused     refused, and run anyway it blew up

Beside the grid, per stiffness: the guard's bound, the closed form at the exact highest frequency
(stability.omega_max_exact), the critical step measured by bisection on the highest mode (explicit integrators;
--no-critical skips it), a run at the geometric mean of the guard's bound and the measured (else exact) critical
step ("between": refused by the guard, stable when run, which shows by how much the guard is conservative), and
the automatic step (dt = "auto": taichi_cloth.adaptive's cap, frame-aligned at 60 fps), run for the same number
of steps. Writes stability.md, stability.csv and stability.png to --out.
"""
from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

from benchmarks import output_folder, write_csv
from taichi_cloth import runtime
from taichi_cloth.adaptive import AdaptiveOptions
from taichi_cloth.adaptive import frame_steps, step_cap
from taichi_cloth.errors import BlowUpError
from taichi_cloth.integrators import INTEGRATORS
from taichi_cloth.stability import omega_max_exact, stable_dt
from taichi_cloth.stability_probes import critical_step, probe_scene, set_max_stiffness
from taichi_cloth.stability_probes import probe_run

DEFAULT_STIFFNESS = [1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7]
DEFAULT_STEPS = [float(f"{10 ** (e / 2):.3g}") for e in range(-10, -1)]  # 1e-5, 3.16e-5, ..., 1e-1
DEFAULT_RATIOS = [1.0, 1e2, 1e4]
FPS = 60.0
SYMBOLS = {"stable": ".", "unstable": "X", "refused-stable": "r", "refused-unstable": "R"}
LEGEND = ("`.` stable (ran every step), `X` unstable (blow-up detected and reported), `r` refused by the step "
          "guard but stable when run anyway, `R` refused by the guard and unstable when run anyway")


def add_arguments(p) -> None:
    p.add_argument("--stiffness", type=float, nargs="+", default=DEFAULT_STIFFNESS,
                   help="stiffest spring constants k [N/m] (default 1e1 .. 1e7, decades)")
    p.add_argument("--steps", type=float, nargs="+", default=DEFAULT_STEPS,
                   help="time steps dt [s] (default 1e-5 .. 1e-1, half-decades)")
    p.add_argument("--mass-ratios", type=float, nargs="+", default=DEFAULT_RATIOS,
                   help="heavy / light particle mass in the checkerboard (default 1 1e2 1e4)")
    p.add_argument("--integrators", nargs="+", default=None, help="integrators to map (default: all five)")
    p.add_argument("--n-steps", type=int, default=200, help="steps per cell (default 200)")
    p.add_argument("--check-every", type=int, default=1,
                   help="blow-up check every this many steps (default 1: the CSV's caught_at_step is exact)")
    p.add_argument("--safety", type=float, default=None,
                   help="the automatic step's safety factor C (default: taichi_cloth.adaptive's, 0.8)")
    p.add_argument("--no-critical", action="store_true",
                   help="skip the measured critical steps (a bisection per explicit integrator, ratio and k)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random perturbations")
    p.add_argument("--arch", default="cpu", choices=("cpu", "gpu"))
    p.add_argument("--out", default="out/bench/stability", help="folder for stability.md, .csv, .png")


def _check(args) -> str | None:
    for name in args.integrators or []:
        if name not in INTEGRATORS:
            return f"--integrators: {name!r} is not one of: {', '.join(INTEGRATORS)}"
    for key, values in (("--stiffness", args.stiffness), ("--steps", args.steps), ("--mass-ratios", args.mass_ratios)):
        if not all(math.isfinite(v) and v > 0 for v in values):
            return f"{key}: every value must be a positive number, got {values}"
    if not all(r >= 1 for r in args.mass_ratios):
        return f"--mass-ratios: every ratio must be >= 1, got {args.mass_ratios}"
    if args.n_steps < 1 or args.check_every < 1:
        return "--n-steps and --check-every must be >= 1"
    if args.safety is not None and not 0 < args.safety <= 1:
        return f"--safety must lie in (0, 1], got {args.safety}"
    return None


def _outcome(scene, k: float, dt: float, rng, args) -> tuple[str, int | None, str]:
    """Run one cell: ("stable" | "unstable", step caught at or None, reason)."""
    try:
        probe_run(scene, k, dt, rng, steps=args.n_steps, check_every=args.check_every)
        return "stable", None, ""
    except BlowUpError as err:
        return "unstable", err.step, err.reason


def _refused(scene, dt: float) -> bool:
    """Whether the engine's step guard (Scene(step_guard="refuse")) refuses dt [s] on the scene's current
    stiffness: dt above the linear-theory stable step."""
    bound = scene.stable_dt
    return bound is not None and dt > bound


def _label(refused: bool, outcome: str) -> str:
    return f"refused-{outcome}" if refused else outcome


def map_integrator(name: str, ratio: float, args, rng) -> tuple[list[dict], list[dict]]:
    """(cells, bounds) of one integrator and mass ratio: a dict per (k, dt) cell and one per k."""
    scene = probe_scene(name, ratio)
    cls, air = type(scene.integrator), scene.forces.air_damping_value
    options = AdaptiveOptions() if args.safety is None else AdaptiveOptions(safety=args.safety)
    cells, bounds = [], []
    for k in args.stiffness:
        set_max_stiffness(scene.model, k)
        beta = scene.model.damping_ratio_max()
        exact = cls.max_stable_dt(omega_max_exact(scene.model), air, beta)
        guard = stable_dt(cls, scene.model, air)
        for dt in args.steps:
            refused = _refused(scene, dt)
            outcome, step, reason = _outcome(scene, k, dt, rng, args)
            cells.append({"kind": "cell", "integrator": name, "mass_ratio": ratio, "k": k, "dt": dt,
                          "outcome": _label(refused, outcome), "caught_at_step": step, "reason": reason})
        auto_dt = frame_steps(step_cap(guard, options, 1.0 / FPS), 1.0 / FPS)[1]
        auto, step, reason = _outcome(scene, k, auto_dt, rng, args)
        critical = None
        if exact is not None and not args.no_critical:
            try:
                critical = critical_step(scene, 0.5 * exact, 2.0 * exact, rel_tol=2e-3, steps=400, check_every=100)
            except ValueError:
                critical = float("nan")  # the bracket did not hold: shown as "-"
        between_dt, between = None, None
        if guard is not None:
            top = critical if critical is not None and not math.isnan(critical) else exact
            between_dt = math.sqrt(guard * top)
            between = _label(_refused(scene, between_dt), _outcome(scene, k, between_dt, rng, args)[0])
        bounds.append({"kind": "bounds", "integrator": name, "mass_ratio": ratio, "k": k, "guard_dt": guard,
                       "exact_dt": exact, "critical_dt": critical, "between_dt": between_dt,
                       "between_outcome": between, "auto_dt": auto_dt, "auto_outcome": auto,
                       "caught_at_step": step, "reason": reason})
    return cells, bounds


def run(args) -> int:
    problem = _check(args)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    out = output_folder(args.out)
    runtime.init(args.arch)
    names = args.integrators or list(INTEGRATORS)
    rng = np.random.default_rng(args.seed)
    cells, bounds = [], []
    t_start = time.perf_counter()
    for name in names:
        for ratio in args.mass_ratios:
            t0 = time.perf_counter()
            c, b = map_integrator(name, ratio, args, rng)
            cells += c
            bounds += b
            counts = {o: sum(r["outcome"] == o for r in c) for o in SYMBOLS}
            print(f"{name}, mass ratio {ratio:g}: " + ", ".join(f"{n} {o}" for o, n in counts.items() if n)
                  + f"; auto step {'all stable' if all(r['auto_outcome'] == 'stable' for r in b) else 'NOT all stable'}"
                  f" ({time.perf_counter() - t0:.1f} s)", flush=True)
    wall = time.perf_counter() - t_start

    safety = AdaptiveOptions.safety if args.safety is None else args.safety
    text = markdown(cells, bounds, args, wall, safety)
    (out / "stability.md").write_text(text)
    write_csv(cells + bounds, out / "stability.csv")
    wrote = [out / "stability.md", out / "stability.csv"]
    if plot(cells, bounds, args, out / "stability.png"):
        wrote.append(out / "stability.png")
    print("\n" + text)
    print("wrote " + ", ".join(map(str, wrote)))
    silent = [r for r in cells if r["outcome"].endswith("unstable") and not r["reason"]]
    return 1 if silent else 0


def _g(v, fmt="{:.3g}") -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v)


def markdown(cells: list[dict], bounds: list[dict], args, wall: float, safety: float) -> str:
    """The map as markdown: per integrator and mass ratio a k x dt grid of symbols, then the bounds."""
    lines = ["# Stability envelope", "",
             f"Probe: 6x6 sheet, checkerboard mass ratio, air drag 0.1 1/s, kd/k = 1e-6 s; {args.n_steps} steps per "
             f"cell, blow-up check every {args.check_every}; {wall:.0f} s on this machine.", "",
             "Legend: " + LEGEND + ".", "",
             "Bounds [s]: *guard* = the step guard's (damped closed form at the estimated highest frequency, a Lanczos estimate 1 % above the exact one), "
             "*exact* = the closed form at the exact highest frequency, *measured* = bisection on the highest mode "
             "(growth within 400 steps), *between* = a run at the geometric mean of guard and measured (refused by "
             "the guard; its symbol as in the grid), *auto* = the automatic step (dt = \"auto\": "
             f"{safety:g} x guard, at most 1/{FPS:g} s, frame-aligned), run for the same steps "
             "(`.` stable, `X` not).", ""]
    steps = args.steps
    for name in dict.fromkeys(r["integrator"] for r in cells):
        for ratio in dict.fromkeys(r["mass_ratio"] for r in cells if r["integrator"] == name):
            lines += [f"## {name}, mass ratio {ratio:g}", "",
                      "| k [N/m] \\ dt [s] | " + " | ".join(f"{dt:.3g}" for dt in steps)
                      + " | guard | exact | measured | measured / guard | between | auto |",
                      "|---|" + "---|" * (len(steps) + 6)]
            for b in (r for r in bounds if r["integrator"] == name and r["mass_ratio"] == ratio):
                row = {r["dt"]: SYMBOLS[r["outcome"]] for r in cells
                       if r["integrator"] == name and r["mass_ratio"] == ratio and r["k"] == b["k"]}
                margin = (b["critical_dt"] / b["guard_dt"] if b["critical_dt"] and b["guard_dt"]
                          and not math.isnan(b["critical_dt"]) else None)
                lines.append(f"| {b['k']:.0e} | " + " | ".join(row[dt] for dt in steps)
                             + f" | {_g(b['guard_dt'])} | {_g(b['exact_dt'])} | {_g(b['critical_dt'])} | "
                               f"{_g(margin, '{:.2f}')} | "
                               + (f"{b['between_dt']:.3g} {SYMBOLS[b['between_outcome']]}" if b["between_dt"] else "-")
                               + f" | {b['auto_dt']:.3g} {'.' if b['auto_outcome'] == 'stable' else 'X'} |")
            lines.append("")
    caught = [r for r in cells if r["outcome"].endswith("unstable")]
    if caught:
        first = [r["caught_at_step"] for r in caught]
        refused = sum(r["outcome"] == "refused-unstable" for r in caught)
        lines.append(f"{len(caught)} cells blew up when run ({refused} of them refused by the guard first), every one "
                     f"stopped by a BlowUpError naming the integrator, the step and a stable step (caught at step "
                     f"{min(first)} .. {max(first)}, median {int(np.median(first))}); no run ended with an unreported "
                     "NaN.")
    spared = [r for r in cells + bounds if "refused-stable" in (r.get("outcome"), r.get("between_outcome"))]
    auto_bad = [r for r in bounds if r["auto_outcome"] != "stable"]
    lines.append(f"{len(spared)} runs were refused by the guard yet stable; the automatic step ran stable in "
                 f"{len(bounds) - len(auto_bad)} of {len(bounds)} (integrator, mass ratio, k).")
    return "\n".join(lines) + "\n"


def plot(cells: list[dict], bounds: list[dict], args, path: Path) -> bool:
    """One panel per integrator x mass ratio: log k vs log dt, cells coloured by outcome, the bound lines and the
    automatic step. False when matplotlib is missing."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.colors import ListedColormap
    except ImportError:
        print("matplotlib not installed: no plot")
        return False
    names = list(dict.fromkeys(r["integrator"] for r in cells))
    ratios = list(dict.fromkeys(r["mass_ratio"] for r in cells))
    ks, dts = np.log10(sorted(args.stiffness)), np.log10(sorted(args.steps))
    edges = lambda v: np.concatenate([[v[0] - 0.5 * (v[1] - v[0] if len(v) > 1 else 1)],  # noqa: E731
                                      0.5 * (v[1:] + v[:-1]),
                                      [v[-1] + 0.5 * (v[-1] - v[-2] if len(v) > 1 else 1)]])
    codes = {o: i for i, o in enumerate(SYMBOLS)}
    cmap = ListedColormap(["#8fd18f", "#e05a4f", "#f3c56b", "#b5651d"])
    fig, axes = plt.subplots(len(names), len(ratios), figsize=(max(3.6 * len(ratios), 9.0), 2.9 * len(names)),
                             squeeze=False, sharex=True, sharey=True)
    for i, name in enumerate(names):
        for j, ratio in enumerate(ratios):
            ax = axes[i][j]
            grid = np.full((len(dts), len(ks)), np.nan)
            for r in cells:
                if r["integrator"] == name and r["mass_ratio"] == ratio:
                    row, col = np.searchsorted(dts, np.log10(r["dt"])), np.searchsorted(ks, np.log10(r["k"]))
                    grid[row, col] = codes[r["outcome"]]
            ax.pcolormesh(edges(ks), edges(dts), grid, cmap=cmap, vmin=-0.5, vmax=len(SYMBOLS) - 0.5)
            b = sorted((r for r in bounds if r["integrator"] == name and r["mass_ratio"] == ratio),
                       key=lambda r: r["k"])
            lk = np.log10([r["k"] for r in b])
            for key, style, label in (("guard_dt", "k--", "guard (estimate)"),
                                      ("exact_dt", "k-", "exact closed form"),
                                      ("critical_dt", "wo", "measured critical")):
                v = np.array([r[key] if r[key] is not None else np.nan for r in b], dtype=float)
                if np.isfinite(v).any():
                    ax.plot(lk, np.log10(v), style, lw=1.2, ms=3.5, mec="k", label=label)
            mid = [(math.log10(r["k"]), math.log10(r["between_dt"]), codes[r["between_outcome"]]) for r in b
                   if r["between_dt"]]
            if mid:
                mk, md, mc = zip(*mid)
                ax.scatter(mk, md, c=[cmap(c) for c in mc], marker="s", s=22, edgecolors="k", linewidths=0.6,
                           zorder=3, label="between guard and critical")
            auto = np.log10([r["auto_dt"] for r in b])
            ax.plot(lk, auto, "-", color="#1f4e9c", lw=1.4, label="auto step")
            ok = np.array([r["auto_outcome"] == "stable" for r in b])
            ax.plot(lk[ok], auto[ok], "o", color="#1f4e9c", ms=4)
            ax.plot(lk[~ok], auto[~ok], "x", color="#1f4e9c", ms=6)
            ax.set_xlim(edges(ks)[0], edges(ks)[-1])
            ax.set_ylim(edges(dts)[0], edges(dts)[-1])
            ax.set_title(f"{name}, mass ratio {ratio:g}", fontsize=9)
            if i == len(names) - 1:
                ax.set_xlabel("log10 k [N/m]")
            if j == 0:
                ax.set_ylabel("log10 dt [s]")
    from matplotlib.patches import Patch

    handles = [Patch(color=cmap(codes[o]), label=o) for o in SYMBOLS]
    lines = {}
    for ax in axes.ravel():
        for h, label in zip(*ax.get_legend_handles_labels()):
            lines.setdefault(label, h)
    fig.legend(handles + list(lines.values()), list(SYMBOLS) + list(lines), loc="lower center", ncol=4, fontsize=8,
               frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True
