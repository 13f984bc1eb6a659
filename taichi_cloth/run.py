"""Running a scene file: the one routine behind `python -m taichi_cloth run` and the demo scripts.

`load_scene_file` loads a scene file (path or dict) with the command line's overrides and checks the run's length;
`run_scene_file` does that, runs it, records it to OUT/NAME.rrd, exports the final mesh beside it and prints the
summary (taichi_cloth.cli.run_scene_file, which the demos call, adds the line that opens the recording). Both read
their overrides from an argparse.Namespace made by `taichi_cloth.cli.add_run_arguments` (out, frames, integrator,
dt, arch, precision, quality, resolution, no_progress, yes, png, until_rest, perturb, seed); an attribute it lacks
counts as not given.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

from . import runtime
from .control import ModelChange
from .errors import BlowUpError, SceneError
from .garment.ease import scene_too_small_message
from .garment.metrics import garment_quality
from .guards import check_run_length
from .paths import free_stem
from .pattern_view import log_scene_pattern
from .perturb import perturb_start
from .scenefile import LoadedScene, load_scene, parse_scene
from .still import write_pictures
from .summary import RunSummary


def load_scene_file(source: str | Path | dict, args: argparse.Namespace,
                    base_dir: str | Path | None = None) -> LoadedScene:
    """Load `source` (a TOML path, or a scene dict whose relative paths are read from `base_dir`) with the
    overrides in `args`; --until-rest makes the scene's runs end at rest; --perturb moves its start
    (taichi_cloth.perturb.perturb_start, with --seed), an event of the run. Starts Taichi on args.arch (default
    "cpu") once the file has parsed, so a bad file fails before Taichi starts. Raises SceneError for bad input
    and for a run longer than the step guard allows without --yes."""
    parse_scene(source, Path(base_dir) if base_dir is not None else None)
    perturb, seed = perturbation(args)
    runtime.init(getattr(args, "arch", None) or "cpu")
    loaded = load_scene(source, frames=getattr(args, "frames", None), integrator=getattr(args, "integrator", None),
                        dt=getattr(args, "dt", None), precision=getattr(args, "precision", None),
                        out=getattr(args, "out", None), quality=getattr(args, "quality", None),
                        resolution=getattr(args, "resolution", None), base_dir=base_dir)
    if getattr(args, "until_rest", False):
        loaded.scene.stop_at_rest = True
    check_run_length(loaded.scene, loaded.frames, confirmed=getattr(args, "yes", False),
                     label=str(loaded.config["_label"]))
    if perturb is not None:
        perturb_start(loaded.scene, perturb, seed)
        loaded.scene.apply(ModelChange(event=f"start moved by {perturb:g} m (seed {seed})"))  # in the summary
    return loaded


def perturbation(args: argparse.Namespace) -> tuple[float | None, int]:
    """(--perturb [m] or None, --seed); SceneError for a distance that is negative or not finite, or a seed
    without a perturbation (it would be ignored)."""
    perturb, seed = getattr(args, "perturb", None), getattr(args, "seed", None)
    if perturb is None:
        if seed is not None:
            raise SceneError(f"--seed {seed}: nothing to seed without --perturb METRES")
        return None, 0
    if not math.isfinite(perturb) or perturb < 0:
        raise SceneError(f"--perturb must be a distance >= 0 m, got {perturb}")
    return float(perturb), 0 if seed is None else int(seed)


def run_scene_file(source: str | Path | dict, args: argparse.Namespace, quiet: bool = False,
                   base_dir: str | Path | None = None) -> tuple[RunSummary, LoadedScene]:
    """Load `source` as `load_scene_file` does, run its frames, record them to OUT/NAME.rrd when its [output]
    record is on (a garment's pattern included) and export the final mesh beside it when [output] mesh is
    on (NAME-2, NAME-3... when an earlier run's files are there: nothing is overwritten); --png adds the still
    pictures. A garment whose sewing gave up and that is too small for its body says so among the summary's warnings
    (taichi_cloth.garment.ease: "too small: the hem is 104 cm and the hips 110 cm"). Prints the summary (and a
    garment's quality table) unless `quiet`; the recording is the first of
    the summary's outputs.

    Returns (summary, loaded scene). Raises SceneError/MeshError for bad input and BlowUpError (with .summary)
    when the run goes unstable; the recording made so far is kept, with the mesh of the last good state. Any other
    exception (KeyboardInterrupt, OSError) propagates with the recording closed, its path as `.output`."""
    loaded = load_scene_file(source, args, base_dir)
    scene, out = loaded.scene, Path(loaded.output["dir"])
    png = getattr(args, "png", False)
    if loaded.config.get("_quality") is not None and not quiet:
        print(loaded.config["_quality"].describe())
    suffixes = ([".rrd"] if loaded.output["record"] else []) + ([".obj", ".ply"] if loaded.output["mesh"] else []) \
        + ([".png", "-pattern.png"] if png else [])
    stem = free_stem(out, loaded.name, suffixes)
    rec = None
    if loaded.output["record"]:
        from .recorder import Recorder  # imports rerun: only when something records

        rec = Recorder(out / f"{stem}.rrd", recording_name=loaded.name, overwrite=True)
        log_scene_pattern(rec, scene)
    summary = None
    try:
        summary = scene.run(loaded.frames, recorder=rec, progress=not getattr(args, "no_progress", False),
                            record_every=loaded.output["record_every"])
    except BlowUpError as err:
        summary = getattr(err, "summary", None)
        raise
    except BaseException as err:  # Ctrl-C, a full disk...: the recording made so far is kept (closed below)
        if rec is not None and getattr(err, "output", None) is None:
            err.output = str(rec.path)  # what the command line names as kept (taichi_cloth.cli.ends)
        raise
    finally:
        if rec is not None:
            rec.close()
        if summary is not None:
            if rec is not None:
                summary.outputs.append(str(rec.path))
            if loaded.output["mesh"]:
                out.mkdir(parents=True, exist_ok=True)
                for suffix in (".obj", ".ply"):
                    summary.outputs.append(str(scene.export_mesh(out / f"{stem}{suffix}")))
            if png:
                summary.outputs += [str(p) for p in write_pictures(scene, out / stem)]
    sewing = scene.controller("sewing")
    if sewing is not None and sewing.gave_up:
        small = scene_too_small_message(scene)
        if small:
            summary.warnings.append(f"{small} (the garment at its stretch limit, the cloth at the body's collision "
                                    "thickness: taichi_cloth.garment.ease)")
    if not quiet:
        print(summary.format())
        if scene.controller("sewing") is not None:
            print(garment_quality(scene).format())  # per piece: area, boundary and strain; seam gap, penetrations
    return summary, loaded
