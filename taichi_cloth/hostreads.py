"""Counting the host's reads of device data: every value the Python side takes back from Taichi.

A read is a scalar field's element read in Python scope (`field[i]`, `field[None]`), one entry of a vector or
matrix field's element (Taichi reads them one by one: a vec3 element is three reads), a field's `to_numpy`, or a
kernel's returned value. Writes (`field[None] = ...`, `from_numpy`) are not reads: they do not wait for the
device. On a GPU each read waits for every launch queued before it, so a read inside a step stalls the step; on
the CPU it costs little, but the count is the same on every arch, so the CPU's test holds the GPU's budget: at most
one read per frame in steady state (the frame's measurement), none inside the steps.

    with HostReads() as reads:
        scene.run(10)
    reads.total, reads.by_site  # {"Diagnostics.measure": 10, ...}

The counter patches Taichi's read entry points for the duration of the block (nested blocks count into every
open one) and names each read by the engine function that made it (the first caller outside Taichi).
"""
from __future__ import annotations

import sys
from collections import Counter

from taichi.lang import kernel_impl, matrix
from taichi.lang.field import ScalarField
from taichi.lang.matrix import MatrixField
from taichi.lang.struct import StructField

_open: list["HostReads"] = []
_depth = 0  # a read that makes other reads inside Taichi (a struct field's to_numpy) counts once
_originals: dict = {}


def _site() -> str:
    frame = sys._getframe(2)
    while frame is not None and frame.f_globals.get("__name__", "").startswith(("taichi.", "taichi_cloth.hostreads")):
        frame = frame.f_back
    if frame is None:
        return "?"
    code = frame.f_code
    owner = frame.f_locals.get("self")
    where = type(owner).__name__ if owner is not None else frame.f_globals["__name__"]
    return f"{where}.{code.co_name}"


def _counting(original, returns_only: bool = False):
    def read(*args, **kwargs):
        global _depth
        if _depth or (returns_only and not args[0].return_type):
            return original(*args, **kwargs)
        _depth += 1
        try:
            return original(*args, **kwargs)
        finally:
            _depth -= 1
            site = _site()
            for counter in _open:
                counter.by_site[site] += 1
    return read


_PATCHES = [(ScalarField, "__getitem__"), (matrix, "_read_host_access"), (ScalarField, "to_numpy"),
            (MatrixField, "to_numpy"), (StructField, "to_numpy")]


def _install() -> None:
    for cls, name in _PATCHES:
        _originals[(cls, name)] = getattr(cls, name)
        setattr(cls, name, _counting(getattr(cls, name)))
    _originals[(kernel_impl.Kernel, "__call__")] = kernel_impl.Kernel.__call__
    kernel_impl.Kernel.__call__ = _counting(kernel_impl.Kernel.__call__, returns_only=True)


def _uninstall() -> None:
    for (cls, name), original in _originals.items():
        setattr(cls, name, original)
    _originals.clear()


class HostReads:
    """The host reads made inside a `with` block: `total`, and `by_site` (a Counter keyed by the engine function,
    "Class.method" or "module.function", that read)."""

    def __init__(self) -> None:
        self.by_site: Counter = Counter()

    @property
    def total(self) -> int:
        return sum(self.by_site.values())

    def __enter__(self) -> "HostReads":
        if not _open:
            _install()
        _open.append(self)
        return self

    def __exit__(self, *exc) -> None:
        _open.remove(self)
        if not _open:
            _uninstall()
