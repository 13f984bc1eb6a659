"""Runs a batch's unfinished jobs on a backend (the process pool, or a Ray cluster) and keeps every finished row.

Each finished job's row lands in its folder (row.json) the moment it is known, and the results table is rewritten
from every row on disk after each one: Ctrl-C, a killed worker or a killed batch loses only the jobs running then.
A job whose process died without a row (a crash, a kill) is started once more; a second death is an error row.
A job past its [run] timeout is stopped and recorded as "timed out" (not retried: it would time out again).
"""
from __future__ import annotations

import sys
import time
from collections import deque
from pathlib import Path

from ..guards import human_seconds
from .figures import ERROR, OK, TIMED_OUT
from .worker import LOG_FILE, write_row

#: how often [s] the scheduler looks at the clock (timeouts, the progress line) while no job ends
TICK = 1.0
#: how many times a job whose worker died is started in all
ATTEMPTS = 2


def clear_outputs(folder: Path) -> None:
    """Empty a job's folder before an attempt (an earlier attempt's partial files), keeping its log."""
    folder.mkdir(parents=True, exist_ok=True)
    for path in folder.iterdir():
        if path.is_file() and path.name != LOG_FILE:
            path.unlink()


class Progress:
    """The progress line: jobs done / failed / running / waiting and an estimate of the time left (the mean wall
    time of the jobs finished in this run, spread over the workers). One line rewritten in place on a terminal,
    a line per change elsewhere."""

    def __init__(self, total: int, skipped: int, workers: int, stream=None):
        self.total, self.skipped, self.workers = total, skipped, workers
        self.stream = stream or sys.stderr
        self.done = self.failed = self.running = 0
        self.walls: list[float] = []
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.last = ""

    def finished(self, row: dict, wall: float) -> None:
        self.done += 1
        self.failed += row["status"] != OK
        self.walls.append(wall)

    def line(self) -> str:
        waiting = self.total - self.skipped - self.done - self.running
        text = (f"{self.skipped + self.done}/{self.total} done ({self.failed} failed"
                + (f", {self.skipped} from before" if self.skipped else "") + f"), {self.running} running, "
                f"{waiting} waiting")
        if self.walls and (waiting or self.running):
            left = sum(self.walls) / len(self.walls) * (waiting + 0.5 * self.running) / max(self.workers, 1)
            text += f"; about {human_seconds(left)} left"
        return text

    def show(self, event: str = "") -> None:
        text = self.line()
        if self.tty:
            print(f"\r\033[K{text}", end="", file=self.stream, flush=True)
        elif event or text != self.last:
            print(f"{event}{text}" if event else text, file=self.stream, flush=True)
        self.last = text

    def end(self) -> None:
        if self.tty:
            print(file=self.stream, flush=True)


def run_jobs(jobs: list[dict], backend, on_row, progress: Progress) -> None:
    """Run `jobs` (Job.as_dict()) on `backend`; on_row(job, row) after each finished job (it writes the row and
    the table). Raises KeyboardInterrupt on Ctrl-C after stopping the jobs still running."""
    waiting = deque((job, 1) for job in jobs)
    running: dict = {}  # handle -> (job, attempt, start time)
    try:
        while waiting or running:
            while waiting and len(running) < backend.capacity:
                job, attempt = waiting.popleft()
                clear_outputs(Path(job["dir"]))
                running[backend.start(job, attempt)] = (job, attempt, time.perf_counter())
            progress.running = len(running)
            progress.show()
            for handle, row, why in backend.wait(TICK):
                job, attempt, t0 = running.pop(handle)
                if row is None and attempt < ATTEMPTS:
                    waiting.appendleft((job, attempt + 1))
                    progress.show(f"{job['label']}: the worker died ({why}); starting it again\n" if not progress.tty
                                  else "")
                    continue
                if row is None:
                    row = failed_row(job, attempt, ERROR, f"the worker died in both attempts ({why})")
                _finish(job, row, time.perf_counter() - t0, on_row, progress)
            now = time.perf_counter()
            for handle, (job, attempt, t0) in list(running.items()):
                if now - t0 > job["run"]["timeout"]:
                    backend.kill(handle)
                    running.pop(handle)
                    row = failed_row(job, attempt, TIMED_OUT, f"still running after {job['run']['timeout']:g} s "
                                                              "(the [run] timeout); stopped")
                    _finish(job, row, now - t0, on_row, progress)
    except BaseException:
        backend.close()
        raise
    finally:
        progress.running = 0
        progress.end()


def _finish(job: dict, row: dict, wall: float, on_row, progress: Progress) -> None:
    row["process_wall_s"] = wall  # the worker's start and end included
    row.setdefault("wall_s", wall)
    on_row(job, row)
    progress.finished(row, wall)
    progress.running -= 1
    progress.show()


def failed_row(job: dict, attempt: int, status: str, reason: str) -> dict:
    """The row of a job that left none (its worker died, or it ran out of time): names, status, reason."""
    return {"key": job["key"], "label": job["label"], "garment": job["garment"], "body": job["body"],
            "material": job["material"], **{f"{g}_cm": cm for g, cm in job["girths"].items()},
            "attempts": attempt, "status": status, "reason": reason, "outputs": ""}


def record(job: dict, row: dict) -> None:
    """Keep a row in its job's folder (the scheduler's default on_row, before the table is rewritten)."""
    write_row(Path(job["dir"]), row)
