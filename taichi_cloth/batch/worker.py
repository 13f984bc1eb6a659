"""One job, run in the process that calls it: the garment placed on its body, sewn and draped
(taichi_cloth.run.run_scene_file, as `run --until-rest --png` does), then its row.

`execute(job)` returns the row, whatever happened: a run that blew up, bad input (a girth out of the body's reach,
a broken garment) or any other exception is a row with its status and one-line reason, never an exception (but
Ctrl-C, which stops the batch). `job_process(job, attempt)` is a worker process's whole life (taichi_cloth.batch.pool):
its output goes to the job's log.txt, it writes the row to the job's row.json (atomically) and exits.

A test hook, TAICHI_CLOTH_BATCH_FAULT="LABEL=KIND[,LABEL=KIND...]", makes the named jobs fail on purpose: "exit"
(the process dies midway, as a crash or a kill would), "exit-once" (only the first attempt dies), "raise" (an
exception inside the job).
"""
from __future__ import annotations

import argparse
import fcntl
import json
import os
import socket
import sys
import time
import traceback
from pathlib import Path

from .. import runtime
from ..errors import BlowUpError, MeshError, TaichiClothError
from ..run import run_scene_file
from .figures import BLEW_UP, ERROR, finished_row

ROW_FILE = "row.json"
LOG_FILE = "log.txt"
FAULT_ENV = "TAICHI_CLOTH_BATCH_FAULT"
#: the file in the kernel cache's folder that the jobs take turns on to write the cache
CACHE_LOCK = "batch-writer.lock"
#: the exit code of a job that its fault hook kills
FAULT_EXIT = 70


def fault(label: str) -> str | None:
    """The fault TAICHI_CLOTH_BATCH_FAULT asks of job `label`, or None."""
    for item in os.environ.get(FAULT_ENV, "").split(","):
        name, _, kind = item.partition("=")
        if name.strip() == label:
            return kind.strip()
    return None


def _inject(job: dict, attempt: int) -> None:
    kind = fault(job["label"])
    if kind == "exit" or (kind == "exit-once" and attempt == 1):
        sys.stdout.flush()
        os._exit(FAULT_EXIT)
    if kind == "raise":
        raise RuntimeError(f"fault injected by {FAULT_ENV}")


def execute(job: dict, attempt: int = 1) -> dict:
    """Run `job` (Job.as_dict()) here and return its row: the job's names and girths, attempt, status, reason,
    wall_s, the figures (figures.finished_row) and the outputs (paths relative to the job's folder)."""
    start = time.perf_counter()
    row = {"key": job["key"], "label": job["label"], "garment": job["garment"], "body": job["body"],
           "material": job["material"], **{f"{g}_cm": cm for g, cm in job["girths"].items()},
           "attempts": attempt, "worker": f"{socket.gethostname()}:{os.getpid()}",
           "started": time.strftime("%Y-%m-%dT%H:%M:%S")}
    run = job["run"]
    args = argparse.Namespace(out=None, until_rest=run["until_rest"], png=run["png"], no_progress=True, yes=True,
                              perturb=run.get("perturb"), seed=run.get("seed"))
    summary = None
    try:
        _inject(job, attempt)
        t0 = time.perf_counter()
        runtime.init("cpu")  # here, to time it apart (run_scene_file finds it started)
        row["init_s"] = time.perf_counter() - t0
        summary, loaded = run_scene_file(job["scene"], args, quiet=True, base_dir=job["base_dir"])
        row.update(finished_row(loaded.scene, summary, run), step_s=summary.wall_step)
    except BlowUpError as exc:
        summary = getattr(exc, "summary", None)
        row.update(status=BLEW_UP, reason=_line(exc))
        if summary is not None:
            row.update(frames=summary.frames, steps=summary.steps, sim_time_s=summary.sim_time,
                       first_frame_s=summary.first_frame_wall, particles=summary.n_particles)
    except (TaichiClothError, MeshError, OSError) as exc:
        row.update(status=ERROR, reason=_line(exc))
    except Exception as exc:  # a bug, not bad input: the reason names it, the log keeps the traceback
        traceback.print_exc()
        row.update(status=ERROR, reason=f"{type(exc).__name__}: {_line(exc)}")
    folder = Path(job["dir"])
    outputs = summary.outputs if summary is not None else []
    row["outputs"] = " ".join(sorted(Path(p).name for p in outputs if Path(p).parent.resolve() == folder.resolve()))
    row["wall_s"] = time.perf_counter() - start
    return row


def _line(exc: BaseException) -> str:
    """An exception's message as one line."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text


def write_row(folder: Path, row: dict) -> Path:
    """Write `row` to folder/row.json atomically: a reader finds the whole row or none."""
    path = folder / ROW_FILE
    tmp = folder / f".{ROW_FILE}.{os.getpid()}"
    tmp.write_text(json.dumps(row, indent=1, default=float), encoding="utf-8")
    os.replace(tmp, path)
    return path


def read_row(folder: Path) -> dict | None:
    """The row a job's folder holds, or None (no row yet, or an unreadable one)."""
    try:
        return json.loads((Path(folder) / ROW_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def job_process(job: dict, attempt: int, faults: str = "") -> None:
    """A worker process's life: output to the job's log, the job, its row written. Exits with 0 when the row is
    written, 130 on Ctrl-C (no row: the job is not finished). `faults`: the batch's TAICHI_CLOTH_BATCH_FAULT (the
    process is forked from a server started earlier, whose environment may be older than the batch's)."""
    os.environ[FAULT_ENV] = faults
    folder = Path(job["dir"])
    folder.mkdir(parents=True, exist_ok=True)
    log = open(folder / LOG_FILE, "a", encoding="utf-8")  # noqa: SIM115 (the process's stdout until it exits)
    os.dup2(log.fileno(), 1)
    os.dup2(log.fileno(), 2)
    sys.stdout = sys.stderr = log
    print(f"--- attempt {attempt}, pid {os.getpid()}, {time.strftime('%Y-%m-%d %H:%M:%S')}", flush=True)
    try:
        row = execute(job, attempt)
    except KeyboardInterrupt:
        os._exit(130)
    write_row(folder, row)
    save_cache()
    log.flush()


def save_cache() -> None:
    """Write the kernels this job compiled into the offline cache every job shares (a multiprocessing child ends
    in os._exit, which skips the exit handler that would), one process at a time: two processes writing the cache
    at once fight over its lock, and the loser writes nothing."""
    if not runtime.is_initialized():
        return
    folder = runtime.cache_folder()
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / CACHE_LOCK, "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            runtime.save_kernel_cache()
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
