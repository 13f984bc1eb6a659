"""The Ray backend (`batch --ray [ADDRESS]`, the `cluster` extra): the same jobs as Ray tasks, on a cluster at
ADDRESS or on a local one started on the spot.

Each task runs in a Ray worker process of its own (max_calls=1: the process exits after its job, so that every
job starts a fresh Taichi runtime that finds its kernels in the node's offline cache, as the process pool's
jobs do), writes its outputs in a temporary folder of its node and returns its row with the files' bytes: the
driver writes them into the job's folder, so a cluster needs no file system shared with this machine. A worker
that dies (WorkerCrashedError and the like) is a job without a row, which the scheduler starts once more.
"""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

from .worker import FAULT_ENV, LOG_FILE, ROW_FILE, execute, save_cache, write_row

INSTALL = "pip install -e '.[cluster]'"


def _task(job: dict, attempt: int) -> tuple[dict, dict]:
    """Inside a Ray worker: the job in a temporary folder; (row, {file name: bytes}) of what it wrote."""
    with tempfile.TemporaryDirectory(prefix="taichi-cloth-batch-") as tmp:
        job = dict(job, dir=tmp, scene=dict(job["scene"], output=dict(job["scene"]["output"], dir=tmp)))
        log = open(Path(tmp) / LOG_FILE, "a", encoding="utf-8")  # noqa: SIM115 (this process's output until it exits)
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
        row = execute(job, attempt)
        save_cache()  # a Ray worker may end without its exit handlers too
        log.flush()
        files = {p.name: p.read_bytes() for p in Path(tmp).iterdir() if p.is_file()}
    return row, files


class RayCluster:
    """The scheduler's backend on Ray (taichi_cloth.batch.pool.ProcessPool's interface). capacity: the cluster's
    CPUs (a job takes one), or `workers` when given."""

    name = "Ray"

    def __init__(self, address: str | None, workers: int | None = None):
        import ray  # the `cluster` extra

        self.ray = ray
        env = {k: os.environ[k] for k in ("TI_OFFLINE_CACHE_FILE_PATH", "TI_ADVANCED_OPTIMIZATION", FAULT_ENV)
               if k in os.environ}
        if address is None:
            ray.init(num_cpus=workers or None, include_dashboard=False, log_to_driver=False,
                     runtime_env={"env_vars": env})
        else:
            ray.init(address=address, log_to_driver=False, runtime_env={"env_vars": env})
        cpus = int(ray.cluster_resources().get("CPU", 1))
        self.capacity = max(1, min(cpus, workers) if workers else cpus)
        self.remote = ray.remote(num_cpus=1, max_calls=1, max_retries=0)(_task)
        self.running: dict = {}  # ObjectRef -> job

    def start(self, job: dict, attempt: int):
        ref = self.remote.remote(job, attempt)
        self.running[ref] = job
        return ref

    def wait(self, timeout: float) -> list:
        if not self.running:
            return []
        ready, _ = self.ray.wait(list(self.running), num_returns=len(self.running), timeout=timeout)
        out = []
        for ref in ready:
            job = self.running.pop(ref)
            try:
                row, files = self.ray.get(ref)
            except self.ray.exceptions.RayError as exc:  # the worker died, or the task could not run
                out.append((ref, None, " ".join(str(exc).split())[:200]))
                continue
            folder = Path(job["dir"])
            folder.mkdir(parents=True, exist_ok=True)
            for name, data in files.items():
                if name == LOG_FILE:
                    with open(folder / LOG_FILE, "ab") as log:
                        log.write(data)
                elif name != ROW_FILE:
                    (folder / name).write_bytes(data)
            write_row(folder, row)
            out.append((ref, row, None))
        return out

    def kill(self, handle) -> None:
        self.running.pop(handle, None)
        self.ray.cancel(handle, force=True)

    def close(self) -> None:
        for ref in list(self.running):
            self.kill(ref)
        self.ray.shutdown()
