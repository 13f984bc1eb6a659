"""Speed against accuracy of every integrator, step and 4-8 level (`python -m taichi_cloth bench tradeoff`).

The study behind the quality presets. Three standard scenes (taichi_cloth.study_scenes), each a square sheet on
a 4-8 hierarchy (`--base` cells, `--levels` levels; the finest level carries the reference):
  hanging   1 m cotton sheet held level by one edge, released: it swings down and hangs (one rest shape)
  sphere    1 m cotton sheet dropped 15 cm onto a 0.3 m ball on the floor
  mannequin 1.2 x 1.0 m silk sheet dropped over the shipped mannequin's head and shoulders (voxel collision,
            stretch limit 10 %, as demos/scenes/drape_on_mannequin.toml)
Reference: the implicit integrator in float64, CG to a relative residual of 1e-6, at `--ref-dt` on the finest
level; it is run a second time at twice that step, and the distance between the two estimates its own error
(backward Euler is first order: the error of the step h is about the difference between h and 2h). That
estimate stays under FLOOR (1 mm) only until the first fold or contact (0.2-0.4 s here): from there on a drape's
fold pattern depends on perturbations as small as the step's own error, so vertex distances to the reference
stop measuring accuracy (ours grew from 0.1 mm to 2-4 cm within 0.2 s of contact, and do not shrink with the
step). The vertex errors are therefore taken over that resolved window only, and the final shape is compared by
its symmetric surface distance, with the reference's own figure beside it.

Every configuration (integrator variant x step x level) runs the same scene from rest and is sampled at the
same simulated times (`--samples` times up to `--sim-time`); a coarser level is compared on the vertices it
shares with the finest (the 4-8 hierarchy is nested). Reported per configuration: wall time per simulated
second (kernels compiled beforehand), RMS and max vertex distance over the resolved window, the final shape's RMS
and max surface distance, the energy drift (max |E - E_ref| over the samples / (weight x size)), the energy
growth above the start in the same unit, the peak strain, and whether it went unstable (and when) or gained
energy (more than ENERGY_GROWTH: a cloth released from rest can only lose energy; such a run stays in the table
but is not on the front). The explicit integrators run at fractions of their linear-theory stable step on each
level (and at frame-sized steps, which they cannot take: recorded as unstable); the others at the `--dt` ladder.

Output in --out (default out/bench/tradeoff): tradeoff.csv, tradeoff.md, tradeoff.png (RMS error against
cost, one curve per integrator variant, the Pareto front of each scene marked, plus the front over all
scenes with the presets), tradeoff.rrd (the table, the plot, and the reference beside the three presets'
shapes on the sim_time timeline), and presets.toml: `preview`, `balanced` and `accurate`, the cheapest
configurations whose worst RMS error over the scenes stays under 5 cm, 1 cm and 1 mm (or the most accurate
one measured). `--write-presets` also installs them as the shipped presets (taichi_cloth/data/
quality_presets.toml) that `run --quality` reads. References are cached in --out (reference_*.npz).
"""
from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from multilevel.hierarchy import Hierarchy48
from taichi_cloth import runtime
from taichi_cloth.integrators import integrator_class
from taichi_cloth.quality import PRESETS_PATH
from taichi_cloth.study_scenes import SCENES, StudyScene, energy_scale

from . import output_folder, require
from . import write_csv as write_rows
from .accuracy import Trajectory, compare, pareto_front, run_sampled, sample_errors

#: integrator variants: label -> (integrator, options). The approx-implicit variants are docs/algorithms.md, approximate implicit variants's.
VARIANTS: dict[str, tuple[str, dict]] = {
    "explicit": ("explicit", {}),
    "verlet": ("verlet", {}),
    "central-difference": ("central-difference", {}),
    "approx-implicit": ("approx-implicit", {}),
    "approx-implicit jv": ("approx-implicit", {"jv_term": True}),
    "approx-implicit 8 sweeps": ("approx-implicit", {"sweeps": 8, "jv_term": True}),
    "approx-implicit warm start": ("approx-implicit", {"warm_start": True}),
    "implicit": ("implicit", {"cg_tolerance": 1e-2}),
    "implicit cg 1e-4": ("implicit", {"cg_tolerance": 1e-4}),
    # the classical step: one linearised solve, no further Newton iterations when it gains energy
    "implicit single solve": ("implicit", {"cg_tolerance": 1e-2, "newton_iterations": 1, "line_search": False}),
}
#: variants measured to show what they cost, never offered as a preset: known to gain energy or blow up at some
#: step (a preset carries over to other scenes and steps)
NOT_PRESETS = ("approx-implicit warm start", "implicit single solve")
#: steps [s] of the integrators without a step limit (and the frame-sized steps the explicit ones are tried at)
DT_LADDER = (1 / 30, 1 / 60, 1 / 120, 1 / 240, 1 / 480)
EXPLICIT_TRIED = (1 / 60, 1 / 240)
#: the explicit integrators' steps as fractions of their stable step on the level
BOUND_FRACTIONS = (0.9, 0.45)
REFERENCE = ("implicit", {"cg_tolerance": 1e-6, "cg_max_iterations": 1000})
#: [m] the vertex errors are taken over the leading samples where the reference's own error stays under this
FLOOR = 1e-3
#: a run whose total energy rises more than this (x weight x size) above its start failed: a cloth released from
#: rest only loses energy (healthy runs measure exactly 0; what rises is energy a coarse CG solve or a contact
#: projection fighting the solve put in)
ENERGY_GROWTH = 0.05
#: the presets: worst RMS error over the scenes [m] each may have (accurate: the most accurate if none meets it)
PRESET_ERRORS = {"preview": 0.05, "balanced": 0.01, "accurate": 0.001}


@dataclass
class Config:
    """One point of the sweep: variant, 4-8 level (0-based), and the step: `dt` [s], or for an explicit
    integrator `bound_fraction` x its stable step on that level."""

    variant: str
    level: int
    dt: float | None = None
    bound_fraction: float | None = None

    @property
    def step_label(self) -> str:
        return f"{self.bound_fraction:g} x bound" if self.bound_fraction is not None else f"1/{1 / self.dt:.0f} s"

    @property
    def key(self) -> tuple:
        """Identifies the configuration across scenes (an explicit step differs per scene, its fraction not)."""
        return (self.variant, self.level, self.dt if self.bound_fraction is None else None, self.bound_fraction)


@dataclass
class Study:
    """What `bench tradeoff` measures. rows: one dict per (scene, config), the columns of COLUMNS;
    references: scene -> Reference; shapes: (scene, variant, level, step) ->
    (Trajectory, triangles) of the runs kept for the recording."""

    rows: list[dict] = field(default_factory=list)
    references: dict = field(default_factory=dict)
    shapes: dict = field(default_factory=dict)
    settings: dict = field(default_factory=dict)


COLUMNS = [("scene", "{}"), ("variant", "{}"), ("level", "{}"), ("particles", "{}"), ("step", "{}"),
           ("dt", "{:.3g}"), ("wall_per_sim_s", "{:.3g}"), ("rms_error", "{:.3g}"), ("max_error", "{:.3g}"),
           ("final_rms", "{:.3g}"), ("final_max", "{:.3g}"), ("energy_drift", "{:.3g}"), ("energy_growth", "{:.3g}"),
           ("max_strain", "{:.3g}"),
           ("status", "{}"), ("front", "{}")]


def configs(variants, levels, dts=DT_LADDER, fractions=BOUND_FRACTIONS, explicit_tried=EXPLICIT_TRIED) -> list[Config]:
    """The sweep: every variant at every level (0-based); the step ladder for the integrators without a step
    limit, bound fractions and a few frame-sized steps for the explicit ones."""
    out = []
    for level in levels:
        for v in variants:
            integrator, opts = VARIANTS[v]
            if integrator_class(integrator).unconditionally_stable:
                out += [Config(v, level, dt=h) for h in dts]
            else:
                out += [Config(v, level, dt=h) for h in explicit_tried]
                out += [Config(v, level, bound_fraction=f) for f in fractions]
    return out


@dataclass
class Reference:
    """The reference of one scene. traj: the implicit float64 run at ref_dt on the finest level; triangles (T,3);
    sample_floor (S,) [m]: RMS vertex distance to the run at 2 ref_dt at each sample, the reference's own error;
    window: how many leading samples have sample_floor <= FLOOR (the vertex errors are taken over those);
    floor: compare() of the 2 ref_dt run (its rms_error over the window, its final surface distance ...)."""

    traj: Trajectory
    triangles: np.ndarray
    sample_floor: np.ndarray
    window: int
    floor: dict

    @property
    def window_time(self) -> float:
        """[s] the last sample time of the resolved window."""
        return float(self.traj.times[self.window - 1])


def reference(spec: StudyScene, base: int, finest: int, ref_dt: float, times, cache: Path | None,
              progress=None) -> Reference:
    """The Reference of `spec` on the finest level: runs at ref_dt and 2 ref_dt, cached as .npz in `cache` (keyed
    by every input). Backward Euler is first order, so their distance estimates the ref_dt run's own error; where
    it exceeds FLOOR (after the first fold or contact: a drape's fold pattern is not unique) the vertex errors of
    a configuration no longer measure its accuracy, and only the leading samples under it are used."""
    integrator, opts = REFERENCE
    key = hashlib.sha1(json.dumps([asdict(spec), base, finest, ref_dt, list(map(float, times)), opts],
                                  default=str).encode()).hexdigest()[:12]
    runs = []
    for h in (ref_dt, 2 * ref_dt):
        path = None if cache is None else cache / f"reference_{spec.name}_{key}_{h:.3g}.npz"
        if path is not None and path.exists():
            runs.append(Trajectory.load(path))
            continue
        scene = spec.build(base, finest, integrator, h, "f64", opts)
        traj = run_sampled(scene, times, progress=progress)
        if not traj.stable:
            raise RuntimeError(f"the reference of scene {spec.name!r} went unstable: {traj.message}")
        if path is not None:
            traj.save(path)
        runs.append(traj)
    tri = Hierarchy48.rectangle(spec.size, (base, base), finest + 1).levels[-1].triangles
    sample_floor = sample_errors(runs[1], runs[0])
    window = max(1, int(np.argmax(np.append(sample_floor, np.inf) > FLOOR)))
    floor = compare(runs[1], runs[0], energy_scale(spec), window, (tri, tri))
    return Reference(runs[0], tri, sample_floor, window, floor)


def run_study(scene_names, variants, levels_below=(0, 1, 2), base: int = 4, n_levels: int = 5,
              sim_time: float = 2.0, samples: int = 20, ref_dt: float = 1e-4, dts=DT_LADDER,
              fractions=BOUND_FRACTIONS, explicit_tried=EXPLICIT_TRIED, cache: Path | None = None,
              keep_shapes: bool = True, progress: bool = True, log=print) -> Study:
    """Measure every configuration on every scene. `levels_below`: levels counted down from the finest (0 = the
    finest of `n_levels`); times: `samples` equally spaced sample times ending at `sim_time` [s]."""
    from tqdm import tqdm

    finest = n_levels - 1
    levels = sorted({finest - d for d in levels_below if finest - d >= 0}, reverse=True)
    times = np.linspace(sim_time / samples, sim_time, samples)
    study = Study(settings=dict(scenes=list(scene_names), variants=list(variants), levels=[lv + 1 for lv in levels],
                                base=base, n_levels=n_levels, sim_time=sim_time, samples=samples, ref_dt=ref_dt))
    sweep = configs(variants, levels, dts, fractions, explicit_tried)
    for name in scene_names:
        spec = SCENES[name]
        t0 = time.perf_counter()
        bar = tqdm(total=2 * sim_time, desc=f"{name}: reference", unit="sim s", leave=False, disable=not progress,
                   bar_format="{l_bar}{bar}| {n:.2f}/{total:.2f} sim s [{elapsed}]")
        done = [0.0]

        def tick(t, bar=bar, done=done):
            bar.update(t - done[0] if t >= done[0] else t)
            done[0] = t

        ref = reference(spec, base, finest, ref_dt, times, cache, progress=tick)
        bar.close()
        study.references[name] = ref
        log(f"{name}: reference ready ({time.perf_counter() - t0:.1f} s); its own error (h vs 2h) stays under "
            f"{1e3 * FLOOR:g} mm up to t = {ref.window_time:.2f} s; final shape {1e3 * ref.floor['final_rms']:.1f} mm")
        scale = energy_scale(spec)
        scenes = {}
        for cfg in tqdm(sweep, desc=name, unit="run", leave=False, disable=not progress):
            sk = (cfg.variant, cfg.level)
            if sk not in scenes:  # one scene per variant and level: dt changes compile nothing
                try:
                    integrator, opts = VARIANTS[cfg.variant]
                    scenes = {sk: spec.build(base, cfg.level, integrator, DT_LADDER[0], options=opts)}
                except ValueError as err:  # a combination the engine refuses
                    scenes = {sk: err}
            scene = scenes[sk]
            if isinstance(scene, ValueError):
                study.rows.append({"scene": name, "variant": cfg.variant, "level": cfg.level + 1, "particles": None,
                                   "step": cfg.step_label, "dt": cfg.dt, "wall_per_sim_s": math.nan,
                                   "rms_error": math.nan, "stable": False, "status": f"refused: {scene}",
                                   "key": cfg.key})
                continue
            bound = scene.stable_dt
            scene.dt = cfg.dt if cfg.bound_fraction is None else cfg.bound_fraction * bound
            scene.reset()
            traj = run_sampled(scene, times)
            row = {"scene": name, "variant": cfg.variant, "level": cfg.level + 1,
                   "particles": scene.model.data.n_particles, "step": cfg.step_label, "dt": scene.dt,
                   "stable_dt": bound, "steps": traj.steps, "sim_time": traj.sim_time, "wall": traj.wall,
                   **compare(traj, ref.traj, scale, ref.window, (scene.model.data.triangles, ref.triangles)),
                   "status": "ok" if traj.stable else f"unstable at t = {traj.sim_time:.3g} s",
                   "key": cfg.key}
            if row["stable"] and row["energy_growth"] > ENERGY_GROWTH:
                row["stable"] = False
                row["status"] = f"energy grew by {row['energy_growth']:.3g} x weight x size"
            study.rows.append(row)
            if keep_shapes and traj.stable:
                study.shapes[(name,) + cfg.key] = (traj, scene.model.data.triangles.copy())
        front = pareto_front([r["wall_per_sim_s"] for r in study.rows if r["scene"] == name],
                             [r["rms_error"] if r["stable"] else math.nan for r in study.rows if r["scene"] == name])
        for r, f in zip([r for r in study.rows if r["scene"] == name], front):
            r["front"] = bool(f)
        log(f"{name}: {len(sweep)} configurations in {time.perf_counter() - t0:.1f} s; "
            f"{sum(not r['stable'] for r in study.rows if r['scene'] == name)} unstable")
    return study


def aggregate(study: Study) -> list[dict]:
    """One row per configuration over all scenes of the study: worst (max) RMS and final errors, summed cost,
    stable only if stable on every scene; with the aggregate Pareto front."""
    scenes = study.settings["scenes"]
    by_key: dict[tuple, list[dict]] = {}
    for r in study.rows:
        by_key.setdefault(r["key"], []).append(r)
    out = []
    for key, rows in by_key.items():
        if len(rows) != len(scenes):
            continue
        stable = all(r["stable"] for r in rows)
        worst = (lambda k: max(r[k] for r in rows)) if stable else (lambda k: float("nan"))
        out.append({"variant": key[0], "level": key[1] + 1, "dt": key[2], "bound_fraction": key[3],
                    "step": rows[0]["step"], "particles": rows[0]["particles"],
                    "wall_per_sim_s": sum(r["wall_per_sim_s"] for r in rows) if stable else float("nan"),
                    "rms_error": worst("rms_error"), "final_rms": worst("final_rms"), "max_error": worst("max_error"),
                    "energy_drift": worst("energy_drift"), "stable": stable})
    front = pareto_front([r["wall_per_sim_s"] for r in out], [r["rms_error"] for r in out])
    for r, f in zip(out, front):
        r["front"] = bool(f)
    return out


def derive_presets(agg: list[dict], n_levels: int) -> dict[str, dict]:
    """preview / balanced / accurate: the cheapest configuration on the front of the variants that may be presets
    (all but NOT_PRESETS) whose worst RMS error is under PRESET_ERRORS (accurate: the most accurate configuration
    if none is). Each preset: integrator, options, dt [s] or dt_bound_fraction, level (relative to the finest: 0,
    -1, ...), and what was measured."""
    candidates = [r for r in agg if r["variant"] not in NOT_PRESETS]
    front_flags = pareto_front([r["wall_per_sim_s"] for r in candidates], [r["rms_error"] for r in candidates])
    front = sorted((r for r, f in zip(candidates, front_flags) if f), key=lambda r: r["wall_per_sim_s"])
    if not front:
        raise RuntimeError("no configuration was stable on every scene: no presets")
    presets = {}
    for name, limit in PRESET_ERRORS.items():
        ok = [r for r in front if r["rms_error"] <= limit]
        r = ok[0] if ok else min(front, key=lambda r: r["rms_error"])
        integrator, options = VARIANTS[r["variant"]]
        p = {"integrator": integrator, "options": dict(options), "level": r["level"] - n_levels,
             "variant": r["variant"], "target_rms_error": limit, "met": bool(ok),
             "measured": {"worst_rms_error_m": r["rms_error"], "worst_final_rms_m": r["final_rms"],
                          "wall_per_sim_s_all_scenes": r["wall_per_sim_s"], "particles": r["particles"]}}
        if r["bound_fraction"] is not None:
            p["dt_bound_fraction"] = r["bound_fraction"]
        else:
            p["dt"] = r["dt"]
        presets[name] = p
    return presets


# ---------------------------------------------------------------------------------------------- output
def _fmt(r: dict, key: str, fmt: str) -> str:
    v = r.get(key)
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if key == "front":
        return "**front**" if v else ""
    return fmt.format(v)


def markdown_table(rows: list[dict], columns=COLUMNS) -> str:
    head = "| " + " | ".join(k for k, _ in columns) + " |"
    lines = [head, "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(_fmt(r, k, f) for k, f in columns) + " |" for r in rows]
    return "\n".join(lines)


AGG_COLUMNS = [("variant", "{}"), ("level", "{}"), ("particles", "{}"), ("step", "{}"),
               ("wall_per_sim_s", "{:.3g}"), ("rms_error", "{:.3g}"), ("final_rms", "{:.3g}"),
               ("energy_drift", "{:.3g}"), ("stable", "{}"), ("front", "{}")]


def report(study: Study, agg: list[dict], presets: dict) -> str:
    """The markdown report: settings, reference floors, presets, the front over all scenes, the full table."""
    s = study.settings
    lines = [f"# Speed/accuracy study ({', '.join(s['scenes'])})", "",
             f"4-8 hierarchy of {s['base']}x{s['base']} base cells, {s['n_levels']} levels (levels {s['levels']} run); "
             f"{s['samples']} samples up to {s['sim_time']} s; reference: implicit, float64, CG 1e-6, "
             f"h = {s['ref_dt']:g} s. Errors in metres, cost in wall seconds per simulated second.", "",
             f"The reference's own error (its distance to the run at twice its step) stays under {FLOOR:g} m up to "
             "the time below; rms_error and max_error are taken over those samples, the final-shape errors "
             "(symmetric surface distance) at the end, where the reference is only good to the last column.", "",
             "| scene | resolved up to [s] | reference's own RMS error there [m] | its final-shape RMS error [m] "
             "| peak strain |", "|---|---|---|---|---|"]
    for name, ref in study.references.items():
        lines.append(f"| {name} | {ref.window_time:.2f} | {ref.floor['rms_error']:.3g} | {ref.floor['final_rms']:.3g} "
                     f"| {ref.traj.max_strain:.3g} |")
    lines += ["", "## Presets (`run --quality NAME`)", "",
              "| preset | variant | level | step | worst RMS error [m] | target | wall s per sim s (all scenes) |",
              "|---|---|---|---|---|---|---|"]
    for name, p in presets.items():
        step = f"{p['dt_bound_fraction']:g} x bound" if "dt_bound_fraction" in p else f"{p['dt']:.4g} s"
        lines.append(f"| {name} | {p['variant']} | {p['level']:+d} | {step} | {p['measured']['worst_rms_error_m']:.3g} "
                     f"| {p['target_rms_error']:g}{'' if p['met'] else ' (not met)'} | "
                     f"{p['measured']['wall_per_sim_s_all_scenes']:.3g} |")
    front = sorted((r for r in agg if r["front"]), key=lambda r: r["wall_per_sim_s"])
    lines += ["", "## The front over all scenes (worst error, summed cost)", "", markdown_table(front, AGG_COLUMNS),
              "", "## Unstable configurations (blown up, or energy grew)", ""]
    bad = [r for r in study.rows if not r["stable"]]
    lines += [f"- {r['scene']}: {r['variant']}, level {r['level']}, {r['step']}: {r['status']}" for r in bad] or ["none"]
    lines += ["", "## Every configuration", "", markdown_table(study.rows)]
    return "\n".join(lines) + "\n"


def write_csv(rows: list[dict], path: Path) -> None:
    """The study's rows, its COLUMNS first."""
    columns = [k for k, _ in COLUMNS]
    write_rows(rows, path, columns + sorted({k for r in rows for k in r} - set(columns) - {"key"}))


def plot(study: Study, agg: list[dict], presets: dict, path: Path) -> Path | None:
    """Error against cost: one panel per scene and one for all scenes; a curve per variant through its steps
    (solid: finest level, dashed: coarser levels), the Pareto front as a black staircase, the reference's
    own error as a dotted line, the presets ringed on the all-scenes panel."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    names = list(study.references)
    cols = 2 if len(names) >= 2 else len(names) + 1
    rows_ = math.ceil((len(names) + 1) / cols)
    fig, axes = plt.subplots(rows_, cols, figsize=(6.2 * cols, 4.6 * rows_), squeeze=False)
    for ax in axes.flat[len(names) + 1:]:
        ax.set_visible(False)
    colors = {v: plt.cm.tab20(i % 20) for i, v in enumerate(VARIANTS)}  # more variants than tab10 has colours
    markers = ["o", "s", "^", "D", "v"]
    finest = study.settings["n_levels"]
    panels = [(name, [r for r in study.rows if r["scene"] == name]) for name in names] + [("all scenes", agg)]
    for ax, (title, rows) in zip(axes.flat, panels):
        for v in VARIANTS:
            for level in sorted({r["level"] for r in rows}, reverse=True):
                pts = sorted(((r["wall_per_sim_s"], r["rms_error"]) for r in rows
                              if r["variant"] == v and r["level"] == level and r["stable"]))
                if not pts:
                    continue
                x, y = zip(*pts)
                ax.plot(x, y, ls="-" if level == finest else "--", marker=markers[(finest - level) % len(markers)],
                        color=colors[v], ms=4, lw=1, label=v if level == finest else None)
        fr = sorted((r["wall_per_sim_s"], r["rms_error"]) for r in rows if r.get("front"))
        if fr:
            ax.step(*zip(*fr), where="post", color="k", lw=1.6, alpha=0.7, label="Pareto front")
            ax.plot(*zip(*fr), "o", mfc="none", mec="k", ms=9, mew=1.2)
        if title in study.references:
            ax.axhline(study.references[title].floor["rms_error"], color="grey", ls=":", lw=1,
                       label="reference's own error")
        else:
            for pname, p in presets.items():
                ax.annotate(pname, (p["measured"]["wall_per_sim_s_all_scenes"], p["measured"]["worst_rms_error_m"]),
                            xytext=(6, 6), textcoords="offset points", fontsize=9, weight="bold")
        ax.set(xscale="log", yscale="log", xlabel="wall s per simulated s", title=title,
               ylabel="RMS vertex error [m]" + (" (worst scene)" if title == "all scenes" else ""))
        ax.grid(True, which="both", alpha=0.25)
    axes[0][0].legend(fontsize=7, loc="best")
    fig.suptitle("error against cost (solid: finest level; dashed, other markers: coarser 4-8 levels)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_presets(presets: dict, path: Path, settings: dict) -> Path:
    """presets.toml: one table per preset (integrator, dt or dt_bound_fraction, level, options, measured)."""
    lines = ["# Quality presets derived from the measured speed/accuracy front.",
             f"# Written by `python -m taichi_cloth bench tradeoff` on {time.strftime('%Y-%m-%d')} with "
             f"{json.dumps(settings)}.",
             "# level: 4-8 levels relative to the finest the scene names (0 = as named, -2 = half the resolution);",
             "# dt [s], or dt_bound_fraction x the explicit integrator's linear-theory stable step.", ""]
    for name, p in presets.items():
        lines.append(f"[{name}]")
        lines.append(f'integrator = "{p["integrator"]}"')
        if "dt" in p:
            lines.append(f"dt = {p['dt']!r}")
        else:
            lines.append(f"dt_bound_fraction = {p['dt_bound_fraction']!r}")
        lines.append(f"level = {p['level']}")
        lines.append("options = {" + ", ".join(f"{k} = {json.dumps(v)}" for k, v in p["options"].items()) + "}")
        lines.append(f'variant = "{p["variant"]}"')
        lines.append(f"target_rms_error = {p['target_rms_error']!r}  # [m]; met = {str(p['met']).lower()}")
        lines.append("measured = {" + ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}"
                                                for k, v in p["measured"].items()) + "}")
        lines.append("")
    path.write_text("\n".join(lines))
    return path


def record(study: Study, presets: dict, text: str, png: Path | None, path: Path) -> Path:
    """tradeoff.rrd: the report and the plot, and per scene the reference's samples beside each preset's run."""
    from taichi_cloth.recorder import Recorder

    with Recorder(path, recording_name="tradeoff") as rec:
        rec.log_document("tradeoff/report", text)
        if png is not None:
            rec.log_image_file("tradeoff/plot", png)
        for k, name in enumerate(study.references):
            ref = study.references[name]
            offset = np.array([0.0, 0.0, 2.5 * k])
            rec.log_samples(f"tradeoff/{name}/reference", ref.traj.times, ref.traj.positions, ref.triangles, offset)
            for j, (pname, p) in enumerate(presets.items()):
                key = (name, p["variant"], p["level"] + study.settings["n_levels"] - 1, p.get("dt"),
                       p.get("dt_bound_fraction"))
                if key in study.shapes:
                    traj, tri = study.shapes[key]
                    rec.log_samples(f"tradeoff/{name}/{pname}", traj.times, traj.positions, tri,
                                    offset + [1.6 * (j + 1), 0.0, 0.0])
    return path


def add_arguments(p) -> None:
    p.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), metavar="VARIANT",
                   help="integrator variants (default all): " + ", ".join(f"'{v}'" for v in VARIANTS))
    p.add_argument("--base", type=int, default=4, help="base cells of the 4-8 hierarchy (default 4)")
    p.add_argument("--levels", type=int, default=5, help="4-8 levels; the finest carries the reference (default 5)")
    p.add_argument("--levels-below", type=int, nargs="+", default=[0, 1, 2],
                   help="levels run, counted down from the finest (default 0 1 2)")
    p.add_argument("--sim-time", type=float, default=2.0, help="simulated seconds per run (default 2)")
    p.add_argument("--samples", type=int, default=20, help="sample times up to --sim-time (default 20)")
    p.add_argument("--dt", type=float, nargs="+", default=list(DT_LADDER), help="steps [s] of the integrators without "
                   "a step limit")
    p.add_argument("--fractions", type=float, nargs="+", default=list(BOUND_FRACTIONS),
                   help="the explicit integrators' steps as fractions of their stable step")
    p.add_argument("--ref-dt", type=float, default=1e-4, help="the reference's step [s] (default 1e-4)")
    p.add_argument("--write-presets", action="store_true",
                   help="install the derived presets as the shipped ones (taichi_cloth/data/quality_presets.toml)")
    p.add_argument("--no-progress", action="store_true")
    p.add_argument("--arch", default="cpu", choices=("cpu", "gpu"))
    p.add_argument("--out", default="out/bench/tradeoff", help="folder for the table, plot, recording and presets")


def check(args) -> None:
    """The arguments, before any work: TaichiClothError (one `error:` line on stderr) for an unknown variant, a
    --base, --levels, --samples, --sim-time or --ref-dt out of range, a level or step that cannot be run."""
    for v in args.variants:
        require(v in VARIANTS, f"unknown variant {v!r}; choose from {', '.join(VARIANTS)}")
    require(args.base >= 1 and args.levels >= 1 and args.sim_time > 0 and args.samples >= 1 and args.ref_dt > 0,
            "--base, --levels and --samples must be >= 1; --sim-time and --ref-dt > 0")
    require(all(0 <= b < args.levels for b in args.levels_below),
            f"--levels-below: every value must lie in 0..{args.levels - 1} (levels counted down from the finest)")
    require(all(h > 0 for h in args.dt) and all(f > 0 for f in args.fractions), "--dt and --fractions must be > 0")


def run(args) -> int:
    check(args)
    out = output_folder(args.out)
    runtime.init(args.arch)
    t0 = time.perf_counter()
    study = run_study(args.scenes, args.variants, args.levels_below, args.base, args.levels, args.sim_time,
                      args.samples, args.ref_dt, tuple(args.dt), tuple(args.fractions), cache=out,
                      progress=not args.no_progress)
    presets, text = write_outputs(study, out)
    print(text.split("## Every configuration")[0])
    if args.write_presets:
        write_presets(presets, PRESETS_PATH, study.settings)
        print(f"installed the presets as {PRESETS_PATH}")
    print(f"wrote {out / 'tradeoff.md'}, tradeoff.csv, tradeoff.png, tradeoff.rrd, presets.toml "
          f"({time.perf_counter() - t0:.0f} s)")
    return 0


def write_outputs(study: Study, out: Path) -> tuple[dict, str]:
    """Derive the presets and write tradeoff.md, .csv, .png, .rrd and presets.toml to `out`; returns the
    presets and the markdown report."""
    agg = aggregate(study)
    presets = derive_presets(agg, study.settings["n_levels"])
    text = report(study, agg, presets)
    (out / "tradeoff.md").write_text(text)
    write_csv(study.rows, out / "tradeoff.csv")
    png = plot(study, agg, presets, out / "tradeoff.png")
    write_presets(presets, out / "presets.toml", study.settings)
    record(study, presets, text, png, out / "tradeoff.rrd")
    return presets, text
