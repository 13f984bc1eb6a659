"""The `body` subcommand: morph the shipped mannequin to measured girths and write the mesh.

    python -m taichi_cloth body --chest 96 --waist 74 --hips 100 --out out/body.obj
    python -m taichi_cloth body --ranges

Girths on the command line are in CENTIMETRES (a tailor's tape), converted to metres for the Python API
(taichi_cloth.body.fit_body). The core is plain functions (`make_body`, `write_body`, `format_ranges`) that
tests call without a subprocess; `add_parser(subparsers)` registers the subcommand and `run(args)` executes it:
0 on success, 2 with one line `error: ...` on stderr for bad input (a girth out of reach, no girth given, an
output suffix other than .obj/.ply/.stl).
"""
import argparse
import sys
from pathlib import Path

from ..errors import BodyError, MeshError
from .fit import GirthOutOfRange, default_body, fit_body, girth_ranges
from .girth import GIRTHS

__all__ = ["EXIT_BAD_INPUT", "SUFFIXES", "add_parser", "format_ranges", "make_body", "run", "write_body"]

EXIT_BAD_INPUT = 2
SUFFIXES = (".obj", ".ply", ".stl")
DEFAULT_OUT = "out/body.obj"


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Register `body` on an argparse subparsers object; sets func=run. Returns the subparser."""
    p = subparsers.add_parser(
        "body", help="morph the mannequin to measured girths (cm) and write the body mesh",
        description="Morph the shipped mannequin's blend shapes so that its girths match the ones given, "
                    "measured like a tape around the body. Girths are in CENTIMETRES. Give at least one "
                    "girth, or --ranges to see what this body can reach.")
    for name in GIRTHS:
        flag = "--" + name.replace("_", "-")
        p.add_argument(flag, dest=name, type=float, metavar="CM", help=f"{name.replace('_', ' ')} girth [cm]")
    p.add_argument("--tolerance", type=float, default=0.1, metavar="CM",
                   help="largest allowed difference between a measured and an asked girth [cm] (default 0.1)")
    p.add_argument("--out", default=DEFAULT_OUT,
                   help=f"output mesh, .obj/.ply/.stl, metres, Y up (default {DEFAULT_OUT}; the folder is created)")
    p.add_argument("--ranges", action="store_true", help="print the reachable range of each girth [cm] and exit")
    p.set_defaults(func=run)
    return p


def format_ranges(ranges: dict, base: dict | None = None) -> str:
    """A table of reachable ranges {girth: (lo, hi) m} in cm, with the base body's girths if given."""
    rows = [f"{'girth':<10} {'min cm':>7} {'base cm':>8} {'max cm':>7}"]
    for n, (lo, hi) in ranges.items():
        b = f"{100 * base[n]:8.1f}" if base and n in base else f"{'':8}"
        rows.append(f"{n:<10} {100 * lo:7.1f} {b} {100 * hi:7.1f}")
    return "\n".join(rows)


def _check_suffix(out) -> Path:
    path = Path(out)
    if path.suffix.lower() not in SUFFIXES:
        raise BodyError(f"--out {path}: unsupported suffix {path.suffix or '(none)'!r}; use one of "
                        f"{', '.join(SUFFIXES)}")
    return path


def write_body(path, vertices, triangles) -> Path:
    """Write a body mesh (vertices (V,3) [m], triangles (T,3)) as .obj/.ply/.stl (by suffix), creating the
    folder. Vertex order is kept (OBJ/PLY), so the file reloads as a morph of the same body. Returns the path."""
    import trimesh  # 0.7 s to import: only when a body is written

    path = _check_suffix(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh = trimesh.Trimesh(vertices, triangles, process=False)
    if path.suffix.lower() == ".obj":
        # 9 digits: 1e-9 m, far below the mesh's precision; no normals, no texture: positions and faces only
        mesh.export(path, include_normals=False, include_texture=False, digits=9)
    else:
        mesh.export(path)
    return path


def make_body(girths_cm: dict, out=DEFAULT_OUT, tolerance_cm: float = 0.1):
    """Fit the mannequin to girths {name: cm} within tolerance_cm and write it to `out`. Returns (BodyFit, Path).

    Raises GirthOutOfRange / BodyError (messages in cm for out-of-range targets) before writing anything."""
    path = _check_suffix(out)
    targets = {n: float(v) / 100.0 for n, v in girths_cm.items()}
    try:
        fit = fit_body(targets, tolerance=float(tolerance_cm) / 100.0)
    except GirthOutOfRange as err:   # the same message in the units the user typed
        raise GirthOutOfRange(err.name, err.target, err.lo, err.hi, unit="cm") from None
    return fit, write_body(path, fit.vertices, fit.triangles)


def run(args) -> int:
    """Execute `body` with parsed args (add_parser's options). Returns 0, or 2 after one `error:` line."""
    try:
        if getattr(args, "ranges", False):
            blend, gauge = default_body()
            print(format_ranges(girth_ranges(blend, gauge), gauge.measure(blend.base)))
            return 0
        girths = {n: getattr(args, n, None) for n in GIRTHS}
        girths = {n: v for n, v in girths.items() if v is not None}
        if not girths:
            raise BodyError("no girth given: use e.g. --chest 96 --waist 74 --hips 100 (cm), or --ranges")
        for name, cm in girths.items():  # checked here, in the unit typed (fit_body speaks in metres)
            if not cm > 0 or cm == float("inf"):
                raise BodyError(f"--{name.replace('_', '-')} must be a positive girth in cm, got {cm:g}")
        tolerance = getattr(args, "tolerance", 0.1)
        if not 0 < tolerance < float("inf"):
            raise BodyError(f"--tolerance must be a positive length in cm, got {tolerance:g}")
        fit, path = make_body(girths, getattr(args, "out", DEFAULT_OUT), tolerance)
    except (BodyError, MeshError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(fit.format())
    print(f"wrote {path}")
    return 0
