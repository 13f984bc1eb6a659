"""`python -m taichi_cloth batch SPEC.toml`: fit garments to bodies in many materials, one job each, on this
machine's cores (the process pool) or on a Ray cluster; a results table, a contact sheet and a summary
(docs/batch.md). Rerunning the same command skips the jobs already finished."""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from ..guards import human_seconds
from ..paths import check_output_folder
from ..run import perturbation
from .figures import OK, STATUSES
from .jobs import make_jobs
from .pool import ProcessPool
from .schedule import Progress, run_jobs
from .sheet import SHEET, write_sheet
from .spec import load_spec
from .table import write_table
from .worker import read_row, write_row

#: `--ray` without an address: a local cluster started on the spot
LOCAL = "local"


def add_parser(sub) -> None:
    p = sub.add_parser("batch", help="fit garments to many bodies in many materials: one job each, a results table "
                       "(Parquet and CSV), a contact sheet; resumable (docs/batch.md)")
    p.add_argument("spec", help="batch spec (.toml): garments, bodies, materials, [run], [output]")
    p.add_argument("--workers", type=int, default=None,
                   help="jobs at once (default: this machine's cores; with --ray: the cluster's CPUs)")
    p.add_argument("--ray", nargs="?", const=LOCAL, metavar="ADDRESS",
                   help="run the jobs on a Ray cluster at ADDRESS (without one: a local cluster started here); "
                        "needs the cluster extra: pip install -e '.[cluster]'")
    p.add_argument("--out", help="output folder (default: the spec's [output] dir)")
    p.add_argument("--retry-failed", action="store_true",
                   help="run again the jobs whose earlier row is not ok (by default every job with a row is done)")
    p.add_argument("--list", action="store_true", help="list the jobs, their keys and whether each is done; run none")
    p.add_argument("--perturb", type=float, metavar="METRES",
                   help="move every job's start by this much in random directions ([run] perturb)")
    p.add_argument("--seeds", type=int, nargs="+", metavar="N",
                   help="with --perturb: run each job once per seed, its label ending _seedN ([run] seeds)")
    p.set_defaults(func=run)


def run(args) -> int:
    spec = load_spec(args.spec, args.out)
    perturb, _ = perturbation(argparse.Namespace(perturb=getattr(args, "perturb", None)))  # one check for both
    if perturb is not None:
        spec.run["perturb"] = perturb
    if getattr(args, "seeds", None):
        spec.run["seeds"] = list(args.seeds)
    jobs = make_jobs(spec)
    check_output_folder(spec.out)
    rows, todo = {}, []
    for job in jobs:
        row = read_row(Path(job.dir))
        if row is not None and row.get("key") == job.key and (row.get("status") == OK or not args.retry_failed):
            rows[job.key] = row
        else:
            todo.append(job)
    if args.list:
        for job in jobs:
            row = rows.get(job.key)
            print(f"{job.label:40s} {job.key}  {row['status'] if row else 'to run'}")
        return 0
    backend = None
    if todo and args.ray is not None:
        try:
            import ray  # noqa: F401  (the cluster extra)
        except ImportError:
            print("error: --ray needs ray, which is not installed: pip install -e '.[cluster]'", file=sys.stderr)
            return 2
        from .cluster import RayCluster

        backend = RayCluster(None if args.ray == LOCAL else args.ray, args.workers)
    elif todo:
        backend = ProcessPool(args.workers or os.cpu_count() or 1)
    spec.out.mkdir(parents=True, exist_ok=True)
    print(f"batch {spec.name}: {len(jobs)} jobs, {len(rows)} done before, {len(todo)} to run"
          + (f" on the {backend.name} ({backend.capacity} at once)" if backend else "") + f"; output {spec.out}",
          flush=True)
    order = [job.key for job in jobs]
    folders = {job.key: job.dir for job in jobs}

    def keep(job: dict, row: dict) -> None:
        write_row(Path(job["dir"]), row)
        rows[job["key"]] = row
        write_table([rows[k] for k in order if k in rows], spec.out)

    progress = Progress(len(jobs), len(rows), backend.capacity if backend else 1)
    try:
        if todo:
            run_jobs([job.as_dict() for job in todo], backend, keep, progress)
    except KeyboardInterrupt as exc:
        exc.output = str(spec.out)  # what taichi_cloth.cli.ends names as kept
        raise
    finally:  # Ctrl-C included: the table and the sheet of every row finished
        done = [rows[k] for k in order if k in rows]
        if done:
            table = write_table(done, spec.out)
            sheet = write_sheet(done, folders, spec.out / SHEET, f"batch {spec.name}: {len(done)} of {len(jobs)} jobs")
    print(summary(spec.name, done, len(jobs), len(todo), progress))
    if done:
        print(f"wrote {table[0]}, {table[1].name} and {sheet.name} beside it")
    return 0


def summary(name: str, rows: list[dict], total: int, ran: int, progress: Progress) -> str:
    """The lines printed at the end: the count of each status, the time, every failed job with its reason."""
    counts = {s: sum(r["status"] == s for r in rows) for s in STATUSES}
    wall = sum(progress.walls)
    lines = [f"batch {name}: {len(rows)} of {total} jobs done: "
             + ", ".join(f"{n} {s}" for s, n in counts.items() if n)
             + f"; {ran} run now ({human_seconds(wall)} of job time"
             + (f", {human_seconds(wall / len(progress.walls))} each" if progress.walls else "") + ")"]
    for r in rows:
        if r["status"] != OK:
            lines.append(f"  {r['label']}: {r['status']}" + (f": {r['reason']}" if r.get("reason") else ""))
    return "\n".join(lines)
