"""Taichi start-up and kernel-compile accounting.

`init` starts Taichi once per process (re-initialising frees every field and costs seconds).
`serial_loops(n, default)` says whether the kernels of a cloth of n particles should run their loops in one thread:
on the CPU a parallel loop costs more to dispatch than a small pass costs to run, so below a particle count serial
loops are faster. Where that count lies depends on the integrator: the explicit family runs a frame in a few fused
launches that do real work per particle (PARALLEL_FROM_CPU, 4096), while a solve launches several short loops per
CG iteration, bound by memory, and on the 2-core CPU gained nothing from the second core at any size measured (up
to 66k particles), so a solve runs in one thread by default (PARALLEL_FROM_CPU_SOLVE: never; each integrator names
its own count as `parallel_from_cpu`). `init(...,
parallel_from=n)` or the environment variable TAICHI_CLOTH_PARALLEL_FROM sets one count for every integrator. The
measurements behind both: docs/performance.md, "Why the defaults are what they are". A GPU runs every loop in
parallel.
Taichi writes the kernels it compiled into its offline cache only when its runtime is finalised (ti.reset or a
new ti.init), which a plain interpreter exit does not do: `init` registers that at exit (without it every scene
after a process's first compiled its kernels again in every run).
`CompileCounter` counts kernel compilations so tests can show that a scene compiles only what it
names and that changing a parameter never recompiles.
"""
from __future__ import annotations

import atexit
import os
import subprocess
import sys
import time
from pathlib import Path

import taichi as ti
from taichi.lang import impl
from taichi.lang.misc import is_arch_supported

from clothbase.errors import warn

from . import taichi_frontend

_ARCHS = {"cpu": ti.cpu, "gpu": ti.gpu, "cuda": ti.cuda, "vulkan": ti.vulkan}
_current_arch: str | None = None
_saves_cache_at_exit = False
#: particles from which the CPU runs a cloth's loops in parallel (see the module docstring): the explicit family's
PARALLEL_FROM_CPU = 4096
#: ... and the implicit solves': never (their CG iterations launch many short loops, bound by memory; one thread was
#: as fast at every size measured, and a solve's sums then run in a fixed order: reproducible runs)
PARALLEL_FROM_CPU_SOLVE = 1 << 62
_parallel_from: int | None = None


def init(arch: str = "cpu", parallel_from: int | None = None, **kwargs) -> None:
    """Start Taichi on `arch` ("cpu", "gpu", "cuda" or "vulkan") unless it is already running.

    Taichi runs without fast math (IEEE arithmetic in the order the kernels write it: the same bits on any x86-64
    CPU; TI_FAST_MATH=1 or fast_math=True turns it on). Calling it again with the same arch does nothing; a different arch re-initialises Taichi
    (which frees all fields: do it before building scenes). `parallel_from`: the particle count from which
    the CPU runs a cloth's loops in parallel, for every integrator (default: TAICHI_CLOTH_PARALLEL_FROM, else
    each integrator's own, see serial_loops).
    Extra keyword arguments go to ti.init.
    """
    global _current_arch, _parallel_from
    if arch not in _ARCHS:
        raise ValueError(f"unknown arch {arch!r}: choose one of {', '.join(_ARCHS)}")
    if parallel_from is not None:
        _parallel_from = int(parallel_from)
    if _current_arch == arch and is_initialized():
        return
    global _saves_cache_at_exit
    kwargs.setdefault("offline_cache", True)
    kwargs.setdefault("log_level", ti.WARN)
    if "TI_FAST_MATH" not in os.environ:
        # IEEE arithmetic: fast math lets LLVM reassociate a sum into as many partial sums as the CPU's vectors are
        # wide, so a drape's last bits, and with them a chaotic outcome, followed the CPU model (and it bought no
        # speed: the demo T-shirt ran 0.97x the time without it; docs/performance.md, reproducible runs)
        kwargs.setdefault("fast_math", False)
    taichi_frontend.install()
    if kwargs["offline_cache"]:
        clear_stale_cache_lock(Path(kwargs.get("offline_cache_file_path") or cache_folder()))
    ti.init(arch=gpu_arch() if arch == "gpu" else _ARCHS[arch], **kwargs)
    _current_arch = arch
    if not _saves_cache_at_exit:
        atexit.register(save_kernel_cache)
        _saves_cache_at_exit = True


#: a cache lock older than this [s] was left by a process killed while it wrote the cache (writing takes seconds)
STALE_LOCK_AGE = 600.0


def clear_stale_cache_lock(folder: Path) -> None:
    """Remove the offline cache's lock file when a killed process left it behind: Taichi then refuses to write the
    cache in every later run, and every run compiles every kernel again. Says so in one warning."""
    lock = folder / "ticache.lock"
    try:
        age = time.time() - lock.stat().st_mtime
    except OSError:  # no lock: nothing to clear
        return
    if age > STALE_LOCK_AGE:
        lock.unlink(missing_ok=True)
        warn(f"removed the stale kernel-cache lock {lock} ({age / 60:.0f} min old, left by a killed process)")


def cache_folder() -> Path:
    """The offline kernel cache's folder when init is not given one: TI_OFFLINE_CACHE_FILE_PATH, else Taichi's
    default."""
    return Path(os.environ.get("TI_OFFLINE_CACHE_FILE_PATH") or Path.home() / ".cache" / "taichi" / "ticache")


def save_kernel_cache() -> None:
    """Finalise the Taichi runtime, which writes the kernels compiled in this process to the offline cache (see the
    module docstring): at exit, or by a process that ends without running its exit handlers (a multiprocessing
    child ends in os._exit: taichi_cloth.batch.worker calls it before)."""
    if is_initialized():
        try:
            ti.reset()
        except Exception:  # a runtime already torn down has nothing left to write
            pass


#: the GPU backends tried for arch "gpu", in Taichi's order less OpenGL: probing OpenGL on a machine without a
#: display or GPU driver crashes the process (a segmentation fault inside ti.init(arch=ti.gpu), Taichi 1.7.4),
#: and every GPU that OpenGL could reach has a Vulkan driver too
GPU_ARCHS = ("cuda", "vulkan", "metal")

#: the Vulkan probe, run in a child process: Taichi starts on Vulkan and runs one kernel, or the child fails (an
#: exception, or a crash of the driver, which must not take the caller with it)
_VULKAN_PROBE = """
import sys
import taichi as ti
from taichi.lang import impl
ti.init(arch=ti.vulkan, offline_cache=False, log_level=ti.ERROR)
if impl.current_cfg().arch != ti.vulkan:
    sys.exit(3)
x = ti.field(ti.i32, 4)
@ti.kernel
def fill():
    for i in x:
        x[i] = i + 1
fill()
sys.exit(0 if x.to_numpy().sum() == 10 else 4)
"""
#: [s] the probe's limit (Taichi's start on a GPU takes a few seconds)
VULKAN_PROBE_SECONDS = 120.0
_vulkan_usable: bool | None = None


def vulkan_device_usable() -> bool:
    """Whether Taichi can run on a Vulkan device here. Taichi's is_arch_supported(ti.vulkan) only finds the Vulkan
    loader (libvulkan): on a machine with the loader and no device (no GPU, or no driver for it) it says yes, and
    ti.init(arch=ti.vulkan) then fails. So a child process starts Taichi on Vulkan and runs one kernel (once per
    process; a few seconds, only for --arch gpu where the loader is there)."""
    global _vulkan_usable
    if _vulkan_usable is None:
        try:
            done = subprocess.run([sys.executable, "-c", _VULKAN_PROBE], capture_output=True,
                                  timeout=VULKAN_PROBE_SECONDS)
            _vulkan_usable = done.returncode == 0
        except (OSError, subprocess.SubprocessError):
            _vulkan_usable = False
    return _vulkan_usable


def gpu_arch():
    """The first GPU backend of GPU_ARCHS this machine can run on, or ti.cpu with one warning line when none is. A
    Vulkan loader without a usable device (vulkan_device_usable) is no GPU."""
    loader_only = False
    for name in GPU_ARCHS:
        if not is_arch_supported(getattr(ti, name)):
            continue
        if name == "vulkan" and not vulkan_device_usable():
            loader_only = True
            continue
        return getattr(ti, name)
    why = "; the Vulkan loader is installed but finds no usable device" if loader_only else ""
    warn(f"no GPU found (no CUDA, Vulkan or Metal device{why}): running on the CPU")
    return ti.cpu


def one_thread_loops() -> bool:
    """Whether any loop may run in one thread on this arch: on the CPU only. A GPU thread alone is slow, so there
    every loop runs in parallel, and what is sequential by nature (a dense factor, a fixed-order reduction) takes
    launches instead (linear.dense). TAICHI_CLOTH_GPU_LOOPS=1 makes the CPU follow the GPU's policy, so that its
    paths run, and are tested, here (at their cost on the CPU)."""
    return impl.current_cfg().arch == ti.cpu and os.environ.get("TAICHI_CLOTH_GPU_LOOPS", "0") in ("", "0")


def next_plan(plan: int, largest: int, short: int, chunk: int, cap: int) -> int:
    """The iterations (or passes) to launch per solve from the next frame on, where no loop runs in one thread and
    the host reads nothing inside a step: twice the `largest` solve since the last frame and a `chunk` more (a
    drape's solves grow from frame to frame as it falls and lands), or twice the `plan` when it stopped `short`
    solves before their end; at most `cap`. An unchanged plan when nothing was solved since (largest = short = 0)."""
    if largest == 0 and short == 0:
        return plan
    return min(cap, 2 * plan if short else 2 * largest + chunk)


def serial_loops(n_particles: int, default: int = PARALLEL_FROM_CPU) -> bool:
    """Whether a cloth of n_particles should run its kernels' loops in one thread: where one_thread_loops() allows
    it (the CPU), below `default` particles (the integrator's parallel_from_cpu), or below the count
    init(parallel_from=...) or TAICHI_CLOTH_PARALLEL_FROM set for every integrator."""
    if not one_thread_loops():
        return False
    threshold = _parallel_from
    if threshold is None:
        threshold = int(os.environ.get("TAICHI_CLOTH_PARALLEL_FROM", default))
    return n_particles < threshold


def is_initialized() -> bool:
    """True once ti.init has run in this process (by us or by the caller)."""
    return impl.get_runtime().prog is not None


def ensure_initialized() -> None:
    """Start Taichi on the CPU if nobody has started it yet."""
    if not is_initialized():
        init("cpu")


def _compiled_keys() -> dict:
    """{kernel: set of the template instances compiled so far} (a flush of retired field trees clears them all)."""
    return {kernel: set(kernel.compiled_kernels) for kernel in impl.get_runtime().kernels if kernel.compiled_kernels}


class CompileCounter:
    """Counts Taichi kernel compilations made inside a `with` block.

    Each (kernel, template instance) pair compiled counts once; a kernel loaded from the offline
    cache still counts, since it is still materialised. `compiled` maps a kernel's qualified name
    (e.g. "Wind.compute_normals") to how many instances were compiled in the block. Taichi's own utility kernels
    (a field's fill and copy_from, its numpy transfers: module taichi._kernels) are kept apart in `taichi_own`:
    Taichi instantiates them per field layout on first use, and once, in one run of the whole suite out of six,
    their instances for a level switch's fill and copy appeared inside a block of switches that compiled none of
    the engine's kernels.
    """

    def __enter__(self) -> "CompileCounter":
        self._before = _compiled_keys()
        self.compiled: dict[str, int] = {}
        self.taichi_own: dict[str, int] = {}
        return self

    def __exit__(self, *exc) -> None:
        # instances present now that were not before: a count difference would miss the ones compiled after a
        # flush of retired field trees inside the block (the flush drops every compiled kernel)
        self.compiled, self.taichi_own = {}, {}
        for kernel, keys in _compiled_keys().items():
            new = len(keys - self._before.get(kernel, set()))
            if new:
                name = kernel.func.__qualname__
                into = self.taichi_own if kernel.func.__module__.startswith("taichi.") else self.compiled
                into[name] = into.get(name, 0) + new

    @property
    def total(self) -> int:
        return sum(self.compiled.values())

    def names(self) -> list[str]:
        return sorted(self.compiled)


def _compiling_function() -> str:
    """The qualified name of the kernel or Taichi function being compiled (from Taichi's AST builder's context)."""
    frame = sys._getframe(2)
    while frame is not None:
        ctx = frame.f_locals.get("ctx")
        if ctx is not None and getattr(ctx, "func", None) is not None and hasattr(ctx.func, "func"):
            return ctx.func.func.__qualname__
        frame = frame.f_back
    return "?"


class OneThreadLoops:
    """The functions whose loops were compiled to run in one thread (ti.loop_config(serialize=True)) inside a `with`
    block: `sites`, a set of qualified names ("PCG._solve_in_thread"). Tests use it to hold the loop policy
    (one_thread_loops): on a GPU, none."""

    def __enter__(self) -> "OneThreadLoops":
        self.sites: set[str] = set()
        self._original = ti.loop_config

        def loop_config(*args, **kwargs):
            if kwargs.get("serialize") or kwargs.get("parallelize") == 1:
                self.sites.add(_compiling_function())
            return self._original(*args, **kwargs)

        loop_config.__module__ = self._original.__module__  # Taichi's own: its AST builder calls it as such
        ti.loop_config = loop_config
        return self

    def __exit__(self, *exc) -> None:
        ti.loop_config = self._original
