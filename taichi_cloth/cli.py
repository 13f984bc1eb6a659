"""Command line: `python -m taichi_cloth run|body|flatten|bench|info|studio|batch`."""
from __future__ import annotations

import argparse
import importlib
import os
import shutil
import sys
from importlib.metadata import version as package_version
from pathlib import Path

import numpy
import taichi

from clothbase.meshes import load_triangle_mesh

from . import runtime
from .batch import cli as batch_cli
from .body import cli as body_cli
from .errors import BlowUpError, MeshError, PatternError, TaichiClothError
from .flatten import flatten_pieces, format_table, plot_flat, write_flat_dxf
from .garment.pattern import unit_scale
from .guards import MAX_STEPS
from .integrators import INTEGRATORS
from .material import MATERIALS
from .paths import check_output_folder, os_error_text
from .garment.garment import RESOLUTIONS
from .quality import QUALITIES
from .run import run_scene_file as run_and_record
from .studio import cli as studio_cli

EXIT_BAD_INPUT = 2
EXIT_BLOWUP = 3
EXIT_INTERRUPTED = 130  # 128 + SIGINT: what a shell reports for a command stopped by Ctrl-C


def add_run_arguments(p: argparse.ArgumentParser, frames_default=None) -> None:
    p.add_argument("--out", help="output folder (default: the scene's [output] dir, usually out/)")
    p.add_argument("--frames", type=int, default=frames_default, help="frames to run (default: the scene's)")
    p.add_argument("--integrator", help="explicit | verlet | central-difference | approx-implicit | implicit")
    p.add_argument("--dt", type=_step, help='time step [s], or "auto" (chosen from the stable step every frame)')
    p.add_argument("--arch", default="cpu", choices=("cpu", "gpu"), help="Taichi arch (default cpu)")
    p.add_argument("--precision", choices=("f32", "f64"), help="field precision (default: the scene's)")
    p.add_argument("--quality", choices=QUALITIES, help="a measured preset (integrator, step, level) from `bench "
                   "tradeoff`: preview | balanced | accurate; --integrator and --dt still override it")
    p.add_argument("--resolution", choices=tuple(RESOLUTIONS), help="a garment's particle spacing: draft (2 cm), fit "
                   "(1 cm) or fine (5 mm); coarse to fine also its levels (3, 5, 5)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--yes", action="store_true", help="run even when the run has more steps than the guard allows "
                   f"({MAX_STEPS:,}; the count and an estimated time are printed first)")
    p.add_argument("--png", action="store_true", help="also write still pictures beside the recording: NAME.png "
                   "(the final drape, front, back and side framed on the cloth, strain colours) and, for a garment, "
                   "NAME-pattern.png")
    p.add_argument("--until-rest", action="store_true",
                   help="end the run at the first frame at which the cloth is at rest (the scene's [rest] criterion; "
                        "--frames is then the most it runs)")
    p.add_argument("--perturb", type=float, metavar="METRES",
                   help="move every free particle of the start by METRES in a random direction before the run "
                        "(1e-7: float32's round-off on a metre), to tell what a result owes to one trajectory")
    p.add_argument("--seed", type=int, metavar="N", help="the random directions of --perturb (default 0)")


def _step(text: str):
    """--dt: a number of seconds or "auto"."""
    if text == "auto":
        return text
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'must be a number of seconds or "auto", got {text!r}') from None


def run_scene_file(scene_path, args, quiet: bool = False, base_dir=None):
    """`python -m taichi_cloth run` and the scene demos: taichi_cloth.run.run_scene_file (load with the CLI
    overrides in `args`, run, record to OUT/NAME.rrd, export the final mesh beside it), then the line that opens
    the recording. scene_path: a file, or a scene as a dict whose relative paths start at base_dir. Returns
    (summary, loaded scene)."""
    summary, loaded = run_and_record(scene_path, args, quiet, base_dir)
    if loaded.output["record"] and not quiet:
        print(f"open the recording with:  {rerun_command()} {summary.outputs[0]}")
    return summary, loaded


def rerun_command() -> str:
    """How to start the Rerun viewer from here: plain `rerun` when it is on PATH, else the one installed beside
    this Python (e.g. .venv/bin/rerun when the venv is not activated)."""
    beside = Path(sys.executable).parent / "rerun"
    on_path = shutil.which("rerun")
    if not beside.is_file() or (on_path and Path(on_path).resolve() == beside.resolve()):
        return "rerun"
    try:
        return str(beside.relative_to(Path.cwd()))
    except ValueError:
        return str(beside)


def ends(call, out=None) -> int:
    """Run `call()` (a command, or a demo's main) and return its exit code; what a user can cause ends it with one
    line on stderr and an exit code instead, never a traceback, and nothing already written is deleted:

    - bad input (TaichiClothError, MeshError): `error: <message>`, EXIT_BAD_INPUT;
    - a file or folder that cannot be read or written (OSError: a read-only folder, a full disk):
      `error: <path>: <reason>`, EXIT_BAD_INPUT;
    - a run that blew up (BlowUpError): its summary on stdout, then `error: <message>; what was recorded is kept`,
      EXIT_BLOWUP;
    - Ctrl-C (KeyboardInterrupt): `interrupted: ... kept what was written to <path>`, EXIT_INTERRUPTED.

    The path named is the exception's own (OSError.filename), else its `.output` (the recording a run was writing:
    taichi_cloth.run.run_scene_file, Recorder), else `out` (the command's output folder or file, when it exists)."""
    try:
        return call()
    except BlowUpError as exc:
        summary = getattr(exc, "summary", None)
        if summary is not None:
            print(summary.format())
        return _say(f"error: {exc}; what was recorded is kept", EXIT_BLOWUP)
    except (TaichiClothError, MeshError) as exc:
        return _say(f"error: {exc}", EXIT_BAD_INPUT)
    except BrokenPipeError:  # the reader went away (`... | head`): nothing left to say to it
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (so that the exit flush does not fail again)
        return 0
    except OSError as exc:
        return _say(f"error: {os_error_text(exc, _written(exc, out))}", EXIT_BAD_INPUT)
    except KeyboardInterrupt as exc:
        kept = _written(exc, out)
        return _say("interrupted: stopped by Ctrl-C" + (f"; kept what was written to {kept}" if kept else ""),
                    EXIT_INTERRUPTED)


def _written(exc: BaseException, out) -> str | None:
    """The path to name for what a failed or interrupted command kept: the exception's `.output`, else `out` when it
    exists."""
    output = getattr(exc, "output", None)
    if output is not None:
        return str(output)
    return str(out) if out is not None and Path(out).exists() else None


def _say(line: str, code: int) -> int:
    print(line, file=sys.stderr)
    return code


def _cmd_run(args) -> int:
    run_scene_file(args.scene, args)
    return 0


def _cmd_flatten(args) -> int:
    """`flatten piece.obj [...] --out pieces.dxf`: flatten 3D pieces, print the error table, write DXF + PNG."""
    out = Path(args.out or Path("out") / (Path(args.meshes[0]).stem + ".dxf"))
    if out.suffix.lower() != ".dxf":
        print(f"error: --out must name a .dxf file, got {out}", file=sys.stderr)
        return EXIT_BAD_INPUT
    check_output_folder(out.parent)  # before the flattening: an OSError naming the folder when it cannot be one
    try:
        scale = unit_scale(args.units)
        pieces = [(Path(m).stem, *load_triangle_mesh(m, scale=scale), None) for m in args.meshes]
        runtime.init(args.arch)
        flat = flatten_pieces(pieces, tolerance=args.tolerance)
    except (MeshError, PatternError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    out.parent.mkdir(parents=True, exist_ok=True)
    print(format_table(flat))
    print(f"wrote {write_flat_dxf(flat, out)} and {plot_flat(flat, out.with_suffix('.png'))}")
    return 0


def _cmd_info(args) -> int:
    version = ".".join(map(str, taichi.__version__)) if isinstance(taichi.__version__, tuple) else taichi.__version__
    print(f"taichi {version}, numpy {numpy.__version__}, rerun-sdk {package_version('rerun-sdk')}")
    print("integrators:")
    for name, cls in INTEGRATORS.items():
        kind = "no step limit" if cls.unconditionally_stable else "explicit, step limited (docs/algorithms.md, step limits)"
        print(f"  {name:20s} {kind}")
        for opt_name, opt in cls.OPTIONS.items():
            print(f"      {opt_name} = {opt.default!r}: {opt.doc}")
    print("materials (density kg/m^2, stretch N/m, shear N/m, bend N m, damping s, viscosity m^2/s):")
    for name, m in MATERIALS.items():
        print(f"  {name:8s} {m.density:6.3g} {m.stretch:8.4g} {m.shear:8.4g} {m.bend:8.2g} {m.damping:8.2g} "
              f"{m.viscosity:8.2g}")
    return 0


#: `bench SUITE`: modules of the top-level benchmarks package, each with add_arguments(parser) and run(args) -> exit
#: code (benchmarks imports the engine, never the other way: the suites are found by name)
SUITES = {"integrators": "integrators", "collision": "collision_cost", "tradeoff": "tradeoff", "stability": "stability",
          "peers": "peers"}  # suite -> module (collision_cost: a script in benchmarks/ must not shadow `collision`)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m taichi_cloth", description="taichi-cloth: mass-spring cloth on Taichi")
    sub = parser.add_subparsers(dest="command", required=True)
    p_run = sub.add_parser("run", help="run a scene file, write OUT/NAME.rrd and the final mesh")
    p_run.add_argument("scene", help="scene file (.toml)")
    add_run_arguments(p_run)
    p_run.set_defaults(func=_cmd_run)
    body_cli.add_parser(sub)
    p_flat = sub.add_parser("flatten", help="flatten 3D pieces (disc meshes) to 2D: error table, DXF and PNG")
    p_flat.add_argument("meshes", nargs="+", help="3D piece meshes (OBJ, PLY, STL...), one disc each")
    p_flat.add_argument("--out", help="DXF to write (default out/<first mesh>.dxf); the error map goes beside it as .png")
    p_flat.add_argument("--units", default="m", help="length unit of the mesh files: m, cm, mm or in (default m)")
    p_flat.add_argument("--tolerance", type=float, default=1e-6, help="relative energy change to stop at (default 1e-6)")
    p_flat.add_argument("--arch", default="cpu", choices=("cpu", "gpu"), help="Taichi arch (default cpu)")
    p_flat.set_defaults(func=_cmd_flatten)
    p_info = sub.add_parser("info", help="versions, integrators and their options, materials")
    p_info.set_defaults(func=_cmd_info)
    studio_cli.add_parser(sub)
    batch_cli.add_parser(sub)
    p_bench = sub.add_parser("bench", help="benchmarks: `bench [integrators]`, `bench " + "`, `bench ".join(list(SUITES)[1:]) + "`")
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["bench"]:  # a suite imports what it measures: only a bench command loads them
        suites = p_bench.add_subparsers(dest="suite", required=True)
        for name, module_name in SUITES.items():
            module = importlib.import_module(f"benchmarks.{module_name}")
            p_suite = suites.add_parser(name, help=module.__doc__.strip().splitlines()[0], description=module.__doc__,
                                        formatter_class=argparse.RawDescriptionHelpFormatter)
            module.add_arguments(p_suite)
            p_suite.set_defaults(func=module.run)
        if len(argv) == 1 or argv[1] not in (*SUITES, "-h", "--help"):
            argv.insert(1, "integrators")  # `bench` alone is the integrator benchmark
    args = parser.parse_args(argv)
    return ends(lambda: args.func(args), getattr(args, "out", None))
