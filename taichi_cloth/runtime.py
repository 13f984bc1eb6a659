"""Taichi start-up and kernel-compile accounting.

`init` starts Taichi once per process (re-initialising frees every field and costs seconds).
`CompileCounter` counts kernel compilations so tests can show that a scene compiles only what it
names and that changing a parameter never recompiles.
"""
from __future__ import annotations

import taichi as ti
from taichi.lang import impl

_ARCHS = {"cpu": ti.cpu, "gpu": ti.gpu, "cuda": ti.cuda, "vulkan": ti.vulkan}
_current_arch: str | None = None


def init(arch: str = "cpu", **kwargs) -> None:
    """Start Taichi on `arch` ("cpu", "gpu", "cuda" or "vulkan") unless it is already running.

    Calling it again with the same arch does nothing; a different arch re-initialises Taichi
    (which frees all fields: do it before building scenes). Extra keyword arguments go to ti.init.
    """
    global _current_arch
    if arch not in _ARCHS:
        raise ValueError(f"unknown arch {arch!r}: choose one of {', '.join(_ARCHS)}")
    if _current_arch == arch and is_initialized():
        return
    kwargs.setdefault("offline_cache", True)
    kwargs.setdefault("log_level", ti.WARN)
    ti.init(arch=_ARCHS[arch], **kwargs)
    _current_arch = arch


def is_initialized() -> bool:
    """True once ti.init has run in this process (by us or by the caller)."""
    return impl.get_runtime().prog is not None


def ensure_initialized() -> None:
    """Start Taichi on the CPU if nobody has started it yet."""
    if not is_initialized():
        init("cpu")


def _compiled_instances() -> dict[str, int]:
    counts: dict[str, int] = {}
    for kernel in impl.get_runtime().kernels:
        n = len(kernel.compiled_kernels)
        if n:
            name = kernel.func.__qualname__
            counts[name] = counts.get(name, 0) + n
    return counts


class CompileCounter:
    """Counts Taichi kernel compilations made inside a `with` block.

    Each (kernel, template instance) pair compiled counts once; a kernel loaded from the offline
    cache still counts, since it is still materialised. `compiled` maps a kernel's qualified name
    (e.g. "Wind.compute_normals") to how many instances were compiled in the block.
    """

    def __enter__(self) -> "CompileCounter":
        self._before = _compiled_instances()
        self.compiled: dict[str, int] = {}
        return self

    def __exit__(self, *exc) -> None:
        after = _compiled_instances()
        self.compiled = {k: n - self._before.get(k, 0) for k, n in after.items() if n > self._before.get(k, 0)}

    @property
    def total(self) -> int:
        return sum(self.compiled.values())

    def names(self) -> list[str]:
        return sorted(self.compiled)
