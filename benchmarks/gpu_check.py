"""The whole GPU measurement in one command, for the few minutes a GPU is lent: every integrator at 64, 128 and
256 (with the implicit step's multigrid rows) and the T-shirt, ms per step, beside the same rows on the reference
CPU, in one table.

    python -m benchmarks.gpu_check [--cpu out/bench/bench.csv] [--minutes 7] [--out out/gpu_check]

--cpu is a bench.csv that `python -m taichi_cloth bench integrators --sizes 64 128 256` wrote on the reference CPU
(the 2-core machine of docs/performance.md): carry it to the GPU machine with the working tree. Each size, and then
the garment, is timed in a subprocess of its own (`bench integrators --arch gpu`), smallest first, each with the time
that is left of --minutes: a size that does not finish in time costs that time and no more, and the sizes before it
are kept. The table goes to stdout and to OUT/table.md (its rows to OUT/rows.csv), with the date and the device
(nvidia-smi); keep the latest in
docs/performance.md, "On a GPU". --arch cpu runs the same on this machine's CPU (a rehearsal without a GPU).

The GPU machines lent here have Python 3.12 and numpy, scipy and rich, but not taichi, trimesh, meshio or dill, and
no network. Fetch their wheels here (in the repo's root; 57 MB, and the working tree's 9 MB travel with them):

    echo /.whl/ >> .git/info/exclude
    python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
        -d .whl taichi==1.7.4 trimesh==5.2.0 meshio==5.3.5 dill

and run there, carrying .whl and out/bench (the CPU's bench.csv):

    python3 -m pip install -q --no-index --no-deps --target /tmp/site .whl/*.whl && export PYTHONPATH=/tmp/site &&
    PYTHONUNBUFFERED=1 python3 -m benchmarks.gpu_check --cpu out/bench/bench.csv --out $OUT

Without rerun-sdk the recorder's column is empty (NaN); the timings do not need it.
"""
from __future__ import annotations

import argparse
import csv
import datetime
import shutil
import subprocess
import sys
import time
from pathlib import Path

from benchmarks import write_csv

ROOT = Path(__file__).resolve().parents[1]
#: the garment's subprocess times it with a tiny grid beside it (`bench integrators` needs one size); that row is
#: left out of the table
GARMENT_GRID = 8


def device_name(arch: str) -> str:
    """The GPU's name, memory and driver from nvidia-smi, or a plain word where there is none."""
    if arch == "gpu" and shutil.which("nvidia-smi"):
        done = subprocess.run(["nvidia-smi", "--query-gpu=name,memory.total,driver_version", "--format=csv,noheader"],
                              capture_output=True, text=True)
        if done.returncode == 0 and done.stdout.strip():
            return done.stdout.strip().splitlines()[0]
    return "GPU (no nvidia-smi)" if arch == "gpu" else "this machine's CPU"


def bench(arch: str, sizes: list[int], garment: bool, steps: int, out: Path, seconds: float) -> tuple[list[dict], str]:
    """Run `bench integrators` on `arch` in a subprocess for at most `seconds` [s]; returns its rows (bench.csv) and
    a note ("" when it finished)."""
    cmd = [sys.executable, "-m", "taichi_cloth", "bench", "integrators", "--arch", arch, "--steps", str(steps),
           "--out", str(out), "--sizes", *map(str, sizes)]
    if garment:
        cmd += ["--integrators", "implicit", "--no-multigrid", "--garment", str(ROOT / "demos/scenes/sew_tshirt.toml")]
    else:
        cmd += ["--garment", "none"]
    if seconds <= 0:
        return [], "no time left"
    try:
        done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=seconds)
    except subprocess.TimeoutExpired:
        return [], f"did not finish in the {seconds:.0f} s left"
    if done.returncode != 0:
        return [], "failed: " + (done.stderr.strip().splitlines() or ["no message"])[-1]
    with open(out / "bench.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    if garment:
        rows = [r for r in rows if r["integrator"].startswith("garment")]
        if not rows:
            return [], "no garment rows"
    return rows, ""


def read_cpu(path: Path | None) -> dict:
    """(integrator, n) -> ms per step of a bench.csv from the reference CPU (empty without one)."""
    if path is None or not path.exists():
        return {}
    with open(path, newline="") as fh:
        return {(r["integrator"], r["n"]): float(r["ms_per_step"]) for r in csv.DictReader(fh)}


def table(rows: list[dict], cpu: dict) -> list[str]:
    """The markdown table: n, integrator, ms/step here, on the reference CPU, their ratio, CG iterations."""
    lines = ["| n x n | integrator | ms/step here | ms/step on the reference CPU | CPU / here | CG iterations/step |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        ms = float(r["ms_per_step"])
        ref = cpu.get((r["integrator"], r["n"]))
        its = f"{float(r['cg_iterations']):.1f}" if r.get("cg_iterations") else "-"
        lines.append(f"| {r['n']} | {r['integrator']} | {ms:.3f} | {f'{ref:.3f}' if ref else '-'} | "
                     f"{f'{ref / ms:.2f}' if ref else '-'} | {its} |")
    return lines


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cpu", type=Path, default=None, help="bench.csv of the reference CPU (default: none)")
    p.add_argument("--sizes", type=int, nargs="+", default=[64, 128, 256])
    p.add_argument("--steps", type=int, default=10, help="steps per timed block (bench integrators: 5 blocks)")
    p.add_argument("--minutes", type=float, default=7.0, help="the time all the runs may take together")
    p.add_argument("--arch", choices=("gpu", "cpu"), default="gpu")
    p.add_argument("--no-garment", action="store_true")
    p.add_argument("--out", type=Path, default=Path("out/gpu_check"), help="table.md and rows.csv go here")
    p.add_argument("--runs", type=Path, default=Path("out/gpu_check_runs"),
                   help="each run's own bench files (kept apart: a device machine returns only a few files)")
    args = p.parse_args(argv)
    deadline = time.monotonic() + 60.0 * args.minutes
    rows, notes = [], []
    runs = [(f"n = {n}", [n], False) for n in args.sizes]
    if not args.no_garment:
        runs.append(("the T-shirt", [GARMENT_GRID], True))
    for label, sizes, garment in runs:
        t0 = time.monotonic()
        got, note = bench(args.arch, sizes, garment, args.steps, args.runs / label.replace(" ", "").replace("=", "_"),
                          deadline - time.monotonic())
        rows += got
        line = f"{label}: {len(got)} rows in {time.monotonic() - t0:.0f} s" + (f" ({note})" if note else "")
        notes.append(line)
        print(line, flush=True)
    head = [f"{datetime.date.today().isoformat()}, {device_name(args.arch)}, `python -m benchmarks.gpu_check"
            f"{' --arch cpu' if args.arch == 'cpu' else ''} --sizes {' '.join(map(str, args.sizes))}`", ""]
    text = "\n".join(head + table(rows, read_cpu(args.cpu)) + [""] + [f"- {n}" for n in notes]) + "\n"
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "table.md").write_text(text)
    if rows:
        write_csv(rows, args.out / "rows.csv")
    print("\n" + text)
    return 0 if rows else 1


if __name__ == "__main__":
    sys.exit(main())
