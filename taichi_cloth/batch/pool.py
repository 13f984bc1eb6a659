"""The process pool: each job in a process of its own, at most `workers` at once, on this machine.

A process per job rather than a long-lived worker per core, measured on the skirt (docs/batch.md, overhead): a
Taichi runtime that builds a second scene compiles that scene's kernels again (new fields, new kernel
instances: 4.5 s of first frame), while a fresh process finds them in the offline kernel cache that every job
shares (1.2 s). The processes are forked from a server that has imported the engine once (multiprocessing's
forkserver, with the worker module preloaded), so a job starts in a fraction of a second, Taichi not yet started:
each job starts its own runtime. A job that crashes its process (a segmentation fault, the OOM killer, kill -9)
takes nothing else with it: the scheduler sees the process gone without a row and retries the job once.
"""
from __future__ import annotations

import multiprocessing
import os
import signal
from multiprocessing.connection import wait as wait_for
from pathlib import Path

from .worker import FAULT_ENV, job_process, read_row


class ProcessPool:
    """The backend of taichi_cloth.batch.schedule on this machine (the interface RayCluster has too): start(job,
    attempt) -> handle; wait(timeout) -> [(handle, row or None, why)]; kill(handle); close()."""

    name = "process pool"

    def __init__(self, workers: int):
        self.capacity = max(1, int(workers))
        self.context = multiprocessing.get_context("forkserver")
        self.context.set_forkserver_preload(["taichi_cloth.batch.worker"])
        self.running: dict = {}  # sentinel -> (process, job)

    def start(self, job: dict, attempt: int):
        process = self.context.Process(target=job_process, args=(job, attempt, os.environ.get(FAULT_ENV, "")),
                                       name=f"batch {job['label']}", daemon=True)
        process.start()
        self.running[process.sentinel] = (process, job)
        return process.sentinel

    def wait(self, timeout: float) -> list:
        """The jobs whose processes ended within `timeout` seconds: (handle, row, None) for a row written, (handle,
        None, why) for a process that died without one."""
        out = []
        for sentinel in wait_for(list(self.running), timeout=timeout):
            process, job = self.running.pop(sentinel)
            process.join()
            row = read_row(Path(job["dir"]))
            if process.exitcode == 0 and row is not None and row.get("key") == job["key"]:
                out.append((sentinel, row, None))
            else:
                out.append((sentinel, None, exit_text(process.exitcode)))
        return out

    def kill(self, handle) -> None:
        process, _ = self.running.pop(handle)
        process.kill()
        process.join()

    def close(self) -> None:
        """Stop every job still running (Ctrl-C): SIGTERM, then SIGKILL for one that lingers."""
        for process, _ in self.running.values():
            process.terminate()
        for process, _ in self.running.values():
            process.join(5.0)
            if process.is_alive():
                process.kill()
                process.join()
        self.running.clear()


def exit_text(code: int | None) -> str:
    """How a process ended, in words: `exit code 70`, `killed by SIGKILL`."""
    if code is None:
        return "still running"
    if code < 0:
        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    return f"exit code {code}"
