"""Sums that come out the same whatever order a parallel loop adds their terms in.

A float addition is not associative, so a scatter that adds float terms into a field with atomics (a Jacobi pass
that accumulates several contacts' pushes on one particle) gives a result that depends on the order the threads
arrive in, and two runs of one scene differ. Integer addition is exact: each term is rounded to a multiple of
1/SCALE and added as a 64-bit integer, and the sum is the same in any order.

SCALE = 2^40 per unit: a resolution of 9.1e-13 (metres, or metres per second), far below float32's round-off on
positions of a metre (6e-8), with room for sums up to 8.4e6 units; a term beyond LIMIT units is clamped there.
"""
import taichi as ti

SCALE = float(2 ** 40)
LIMIT = 1.0e6


@ti.func
def to_fixed(v):
    """A float vector as 64-bit fixed point (round to nearest multiple of 1 / SCALE, clamped at +-LIMIT)."""
    return ti.cast(ti.round(ti.math.clamp(ti.cast(v, ti.f64), -LIMIT, LIMIT) * SCALE), ti.i64)


@ti.func
def from_fixed(v, dtype: ti.template()):
    """A 64-bit fixed-point vector back as a float vector of `dtype`."""
    return ti.cast(ti.cast(v, ti.f64) / SCALE, dtype)
