"""Sums in a fixed order (clothbase.ordered_sum): what CG's dot products and the line search's energies use where a
cloth's loops run in parallel, so that a loaded machine, or one with another number of cores, gives the same bits."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import taichi as ti

from clothbase.ordered_sum import WIDTH, OrderedSums

#: terms whose magnitudes span 8 decades, so that adding them in another order changes the last bits
N = 100_000

RUN = """
import sys
import numpy as np
import taichi as ti
from taichi_cloth import runtime
runtime.init("cpu", cpu_max_num_threads=int(sys.argv[1]), offline_cache=False)
from clothbase.ordered_sum import OrderedSums
n = {n}
rng = np.random.default_rng(0)
terms = ti.field(ti.f64, n)
terms.from_numpy(rng.normal(size=n) * np.logspace(0, 8, n))
live = ti.field(ti.i32, ())
live[None] = n
sums = OrderedSums(1, n)

@ti.kernel
def both() -> ti.types.vector(2, ti.f64):
    plain = ti.cast(0.0, ti.f64)
    for i in range(live[None]):
        plain += terms[i]
        sums.put(i, ti.Vector([terms[i]], ti.f64))
    return ti.Vector([sums.total(live[None])[0], plain])

print(*(float(s).hex() for s in both()))
"""


def sums_on(script: Path, threads: int) -> tuple[str, str]:
    """(the ordered sum, the plain accumulator's sum) of the N terms, as hex floats, in a process whose parallel loops
    run on `threads` threads (`script`: RUN in a file, where Taichi finds the kernel's source)."""
    done = subprocess.run([sys.executable, str(script), str(threads)], capture_output=True, text=True,
                          timeout=300, cwd=Path(__file__).resolve().parents[1], env=dict(os.environ))
    assert done.returncode == 0, done.stderr[-2000:]
    ordered, plain = done.stdout.split()[-2:]
    return ordered, plain


def test_the_ordered_sum_is_the_same_bits_on_one_two_or_three_threads(tmp_path):
    """The plain accumulator of a parallel loop (Taichi adds the threads' partial sums) gives other bits on another
    number of threads: the premise; the ordered sum gives the same bits on each."""
    script = tmp_path / "sums.py"
    script.write_text(RUN.format(n=N))
    runs = [sums_on(script, k) for k in (1, 2, 3)]
    assert len({ordered for ordered, _ in runs}) == 1, runs
    assert len({plain for _, plain in runs}) > 1, runs  # the threads' order shows in a plain sum of these terms


def tree_sum(values: np.ndarray) -> float:
    """The ordered sum's tree in Python: blocks of WIDTH terms added in index order, level after level."""
    level = [float(v) for v in values]
    while len(level) > 1:
        sums = []
        for start in range(0, len(level), WIDTH):
            acc = 0.0
            for v in level[start:start + WIDTH]:
                acc += v
            sums.append(acc)
        level = sums
    return level[0] if level else 0.0


@pytest.fixture(scope="module")
def summed():
    """(values (C,2) float64, a function n -> the ordered sums (2,) of the first n) for a capacity C of 5,000."""
    capacity = 5000
    values = np.random.default_rng(1).normal(size=(capacity, 2)) * np.logspace(0, 6, capacity)[:, None]
    field = ti.Vector.field(2, ti.f64, capacity)
    field.from_numpy(values)
    sums = OrderedSums(2, capacity)

    @ti.kernel
    def total(n: ti.i32) -> ti.types.vector(2, ti.f64):
        for i in range(n):
            sums.put(i, field[i])
        return sums.total(n)

    return values, lambda n: total(n).to_numpy()


@pytest.mark.parametrize("n", [0, 1, WIDTH - 1, WIDTH, WIDTH + 1, WIDTH * WIDTH + 1, 5000])
def test_the_ordered_sum_adds_in_a_tree_fixed_by_the_index(summed, n):
    """Every level's blocks, across their edges and with a partial last block: the same bits as the tree added in
    Python (the compiled kernel keeps the order: no reassociation), and within round-off of the exact sum."""
    values, total = summed
    got = total(n)
    for k in range(2):
        assert got[k] == tree_sum(values[:n, k])
        assert abs(got[k] - float(np.sum(values[:n, k], dtype=np.longdouble))) <= 1e-12 * np.abs(values[:n, k]).sum()
