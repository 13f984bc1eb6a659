"""Float sums of a parallel loop, added in an order fixed by the items' indices: the same bits on 1 thread or 16, on a
quiet machine or a loaded one, on the CPU or a GPU.

A kernel-local accumulator in a parallel loop (`acc += term`) is reduced by Taichi per thread and the threads'
partial sums are then added in the order the threads finish; which items a thread takes depends on timing (on the
CPU, from about 4,000 items the sum of one loop differs in its last bits between 1, 2 and 3 threads). A solve whose
dot products change the state (CG's alpha and beta, a line search's energies) then follows the machine's load.

OrderedSums instead keeps each item's K terms, then adds them in a tree of fixed shape: blocks of WIDTH consecutive
terms, each added in index order by one thread, the block sums again in blocks of WIDTH, and so on to one. Every
level is a parallel loop (WIDTH-fold fewer items each: 3 levels up to 262,144 items); the shape depends only on the
item count. Used where a cloth's loops run in parallel; where they run in one thread a plain accumulator is already
in a fixed order.
"""
import taichi as ti

from .fields import FieldBlock

#: terms added by one thread in index order per block (a level has WIDTH-fold fewer items than the one before)
WIDTH = 64


def _levels(capacity: int) -> list[int]:
    """The sizes of the tree's levels for `capacity` items: capacity, ceil(capacity / WIDTH), ... down to 1."""
    sizes = [max(int(capacity), 1)]
    while sizes[-1] > 1:
        sizes.append(-(-sizes[-1] // WIDTH))
    return sizes if len(sizes) > 1 else sizes + [1]


@ti.data_oriented
class OrderedSums:
    """K float64 sums over up to `capacity` items.

    In a kernel: `put(i, terms)` in the item loop (terms: a K-vector, float64), then at the kernel's top level (not
    inside a loop) `total(n)` returns the K sums (a K-vector, float64) of items 0..n-1, every item below n having
    been put. buf: (capacity + the tree's upper levels,) K-vectors of float64: the terms, then each level's block
    sums.
    """

    def __init__(self, k: int, capacity: int):
        self.k = int(k)
        self.sizes = _levels(capacity)
        self.offsets = [sum(self.sizes[:j]) for j in range(len(self.sizes))]
        blk = FieldBlock()
        self.buf = blk.vector(self.k, ti.f64, sum(self.sizes))
        blk.finalize(self)

    @ti.func
    def put(self, i, terms):
        """Item i's K terms (a K-vector)."""
        self.buf[i] = ti.cast(terms, ti.f64)

    @ti.func
    def total(self, n):
        """The K sums of items 0..n-1 (a K-vector of float64; zero for n <= 0), each level one parallel loop."""
        for level in ti.static(range(len(self.sizes) - 1)):
            src, dst = ti.static(self.offsets[level], self.offsets[level + 1])
            stride = ti.static(WIDTH ** level)  # items of level 0 behind one item of this level
            items = (n + stride - 1) // stride  # this level's live items
            for b in range((items + WIDTH - 1) // WIDTH):
                acc = ti.Vector.zero(ti.f64, self.k)
                for j in range(b * WIDTH, ti.min(b * WIDTH + WIDTH, items)):
                    acc += self.buf[src + j]
                self.buf[dst + b] = acc
        out = ti.Vector.zero(ti.f64, self.k)
        if n > 0:
            out = self.buf[ti.static(self.offsets[-1])]
        return out
