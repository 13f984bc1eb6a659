"""The garment matrix: does every shipped garment sew and come to rest on every body it is cut for, in every fabric?

Runs the batch demos/batch/garment_matrix.toml (6 garments: three garment files and three GarmentCode
specifications, x the mannequin and four bodies in each garment's size range x silk, jersey, shirting, denim and
wool, at 2 cm) and, with --fit, its mannequin row at 1 cm
(garment_matrix_fit.toml), then reads their results tables and writes one table: a row per garment and body, a
column per fabric, each cell "ok" with its rest time or the job's status and reason.

A job is **ok** when its batch status is ok (sewn, at rest by the run's cap, no particle inside the body) and it
came to rest within REST_WITHIN seconds of simulated time (the cap is 5 s already). A job whose garment is smaller
than the body ("too small", taichi_cloth.garment.ease) does not count against the matrix: its reason says so in
garment terms. The share of ok jobs is over the others. (Self-crossing of the cloth is not checked here.)

    python -m benchmarks.garment_matrix [--fit] [--starts 3] [--workers 2] [--out out/bench/garment_matrix]

With --starts N every job also runs from N starts moved by MOVE = 1e-7 m (seeds 1..N, the batch's --perturb): an ok
cell then gives the rest times over all its starts, and "moved: k of N" where only k of them were ok too (a rest by
a margin, not by the round-off of one trajectory).

Writes OUT/garment_matrix.md (the table), OUT/results-draft.csv and, with --fit, OUT/results-fit.csv (the batches'
rows), and leaves each batch's contact sheet in its own output folder (printed). A rerun skips finished jobs (the
batch's own resume).
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from taichi_cloth.batch.table import read_table
from taichi_cloth.cli import main as cli

ROOT = Path(__file__).resolve().parents[1]
SPECS = {"draft": ROOT / "demos" / "batch" / "garment_matrix.toml",
         "fit": ROOT / "demos" / "batch" / "garment_matrix_fit.toml"}
#: [s] of simulated time a job must be at rest by
REST_WITHIN = 5.0
#: [m] how far --starts moves every particle's start
MOVE = 1e-7
FABRICS = ("silk", "jersey", "shirting", "denim", "wool")


def verdict(row: dict) -> tuple[str, bool | None]:
    """(cell text, ok): ok None where the garment is too small for the body (not counted)."""
    status = row.get("status")
    rest = row.get("rest_time_s")
    if status == "ok" and rest is not None and rest <= REST_WITHIN:
        return f"ok {rest:.2f} s", True
    if status == "too small":
        return f"too small: {row.get('reason', '').split(';')[0].removeprefix('too small: ')}", None
    if status == "ok":
        return f"at rest at {rest:.2f} s", False
    reason = (row.get("reason") or "").replace("|", "/")
    return f"{status}: {reason[:90]}", False


def table(rows: list[dict], resolution: str, moved: list[dict] | None = None) -> tuple[str, int, int, int]:
    """The Markdown table of one batch's rows, and (ok jobs, counted jobs, ok jobs ok from every moved start);
    moved: the rows of the same jobs from moved starts (None: not run)."""
    starts: dict = {}
    for r in moved or []:
        starts.setdefault((r["garment"], r["body"], r["material"]), []).append(r)
    fabrics = [f for f in FABRICS if any(r["material"] == f for r in rows)]
    keys = []
    for r in rows:
        if (r["garment"], r["body"]) not in keys:
            keys.append((r["garment"], r["body"]))
    by = {(r["garment"], r["body"], r["material"]): r for r in rows}
    lines = [f"| garment | body ({resolution}) | " + " | ".join(fabrics) + " |",
             "|---|---|" + "---|" * len(fabrics)]
    ok = counted = steady = 0
    for g, b in keys:
        cells = []
        for f in fabrics:
            row = by.get((g, b, f))
            if row is None:
                cells.append("")
                continue
            text, good = verdict(row)
            if good and moved is not None:
                others = starts.get((g, b, f), [])
                fine = [r["rest_time_s"] for r in others if verdict(r)[1]]
                times = [row["rest_time_s"], *fine]
                text = f"ok {min(times):.2f}-{max(times):.2f} s"
                if len(fine) < len(others) or not others:
                    text += f" (moved: {len(fine)} of {len(others)})"
                else:
                    steady += 1
            cells.append(text)
            if good is not None:
                counted += 1
                ok += int(good)
        girths = ", ".join(f"{k[:-3]} {row[k]:g}" for k in ("chest_cm", "waist_cm", "hips_cm")
                           if row is not None and row.get(k) is not None)
        lines.append(f"| {g} | {b}{f' ({girths})' if girths else ''} | " + " | ".join(cells) + " |")
    return "\n".join(lines), ok, counted, steady


def run_batch(resolution: str, folder: Path, csv: Path, workers: int | None, extra=()) -> list[dict] | None:
    """Run the matrix's batch of one resolution into `folder` (extra: more `batch` arguments), copy its CSV to `csv`
    and return its rows (None when the batch could not run)."""
    command = ["batch", str(SPECS[resolution]), "--out", str(folder), *extra]
    if workers:
        command += ["--workers", str(workers)]
    if cli(command) not in (0, 1):
        return None
    shutil.copyfile(folder / "results.csv", csv)
    return read_table(folder / "results.parquet")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fit", action="store_true", help="also the mannequin row at 1 cm (15 jobs more)")
    ap.add_argument("--workers", type=int, default=None, help="jobs at once (default: this machine's cores)")
    ap.add_argument("--starts", type=int, default=0,
                    help=f"also run every job from this many starts moved by {MOVE:g} m (seeds 1..N)")
    ap.add_argument("--out", default="out/bench/garment_matrix", help="where the table goes")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    parts = []
    total_ok = total = 0
    for resolution in ("draft", "fit") if args.fit else ("draft",):
        folder = out / f"batch-{resolution}"
        rows = run_batch(resolution, folder, out / f"results-{resolution}.csv", args.workers)
        if rows is None:
            return 2
        moved = None
        if args.starts > 0:
            moved = run_batch(resolution, out / f"batch-{resolution}-moved", out / f"results-{resolution}-moved.csv",
                              args.workers, ["--perturb", str(MOVE), "--seeds",
                                             *[str(k) for k in range(1, args.starts + 1)]])
            if moved is None:
                return 2
        text, ok, counted, steady = table(rows, "2 cm" if resolution == "draft" else "1 cm", moved)
        total_ok, total = total_ok + ok, total + counted
        line = (f"{text}\n\n{ok} of {counted} jobs ok at {'2' if resolution == 'draft' else '1'} cm "
                f"({100 * ok / max(counted, 1):.0f} %)")
        if moved is not None:
            line += f"; {steady} of them ok from all {args.starts} starts moved by {MOVE:g} m as well"
        parts.append(f"{line}; contact sheet: {folder / 'contact_sheet.png'}")
    report = "\n\n".join(parts) + f"\n\nIn all: {total_ok} of {total} ok ({100 * total_ok / max(total, 1):.0f} %)\n"
    (out / "garment_matrix.md").write_text(report, encoding="utf-8")
    print(report)
    print(f"wrote {out / 'garment_matrix.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
