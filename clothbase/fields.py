"""Taichi fields allocated in one releasable SNode tree per component (every package of the engine uses it).

Taichi puts fields created between two kernel launches into a new SNode tree and never frees it; after
about 500 trees the CPU runtime crashes (seen: a segfault in from_numpy). A process that builds many scenes
(a test session, a parameter sweep) must release what it no longer uses. But destroying a tree makes Taichi
drop every compiled kernel, so trees are not destroyed when their owner dies: they are queued, and the
queue is flushed only when a new block is allocated while more than LIVE_TREE_LIMIT trees exist. A running
scene therefore never recompiles because some other object was collected; building a new scene after
hundreds of dead ones costs one round of recompiles.
"""
import weakref

import taichi as ti

LIVE_TREE_LIMIT = 256

_live = 0
_retired: list = []


class FieldBlock:
    """Collects fields, then `finalize(owner)` builds their tree and retires it when `owner` is collected.

    shape: () for a 0-d field, an int or a tuple of ints for a dense field. Fields of a block may only be
    used after `finalize`. Whoever uses them must keep the owner alive."""

    _AXES = {1: ti.i, 2: ti.ij, 3: ti.ijk}

    def __init__(self):
        if _live > LIVE_TREE_LIMIT and _retired:
            flush_retired()
        self.builder = ti.FieldsBuilder()
        self.tree = None

    def _place(self, f, shape):
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        if shape:
            self.builder.dense(self._AXES[len(shape)], shape).place(f)
        else:
            self.builder.place(f)
        return f

    def scalar(self, dtype, shape):
        return self._place(ti.field(dtype), shape)

    def vector(self, n: int, dtype, shape):
        return self._place(ti.Vector.field(n, dtype), shape)

    def matrix(self, n: int, m: int, dtype, shape):
        return self._place(ti.Matrix.field(n, m, dtype), shape)

    def finalize(self, owner) -> None:
        global _live
        self.tree = self.builder.finalize()
        _live += 1
        weakref.finalize(owner, _retired.append, self.tree)


def live_trees() -> int:
    """How many field trees exist (live and retired but not yet destroyed)."""
    return _live


def flush_retired() -> int:
    """Destroy the trees of collected owners (every compiled kernel is dropped once). Returns how many."""
    global _live
    done = 0
    while _retired:
        tree = _retired.pop()
        try:
            tree.destroy()
        except Exception:  # a runtime reset (ti.init) already freed it
            pass
        _live -= 1
        done += 1
    return done


def fill_prefix(f, values) -> None:
    """Write `values` into the first len(values) entries of field `f` (fields are capacity-sized)."""
    n = len(values)
    if n == 0:
        return
    if n == f.shape[0]:
        f.from_numpy(values)
    else:
        buf = f.to_numpy()
        buf[:n] = values
        f.from_numpy(buf)
