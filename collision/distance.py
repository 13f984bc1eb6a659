"""Exact point-to-triangle-mesh distances in numpy, with a uniform-grid broad phase (no Taichi).

Used where a distance is needed once, on the host: garment placement (clearance from the body) and the
speed/accuracy study (how far a simulated cloth surface lies from the reference's).
"""
from __future__ import annotations

import numpy as np


def pairs_by_cell(lo: np.ndarray, hi: np.ndarray, cell: float):
    """(item ids, cell keys) of every integer cell each box [lo, hi] (k,D) touches; keys as int64."""
    a = np.floor(lo / cell).astype(np.int64)
    b = np.floor(hi / cell).astype(np.int64)
    n = b - a + 1
    count = np.prod(n, axis=1)
    item = np.repeat(np.arange(len(lo)), count)
    local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    key = np.zeros(len(item), dtype=np.int64)
    for dim in range(lo.shape[1]):
        nd = n[item, dim]
        idx = a[item, dim] + local % nd
        local = local // nd
        key = key * 1_000_003 + idx
    return item, key


def candidates(point_keys: np.ndarray, item: np.ndarray, key: np.ndarray):
    """(point index, item id) pairs where the point's cell key matches the item's."""
    order = np.argsort(key, kind="stable")
    key, item = key[order], item[order]
    start = np.searchsorted(key, point_keys, side="left")
    stop = np.searchsorted(key, point_keys, side="right")
    count = stop - start
    pi = np.repeat(np.arange(len(point_keys)), count)
    offs = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    return pi, item[np.repeat(start, count) + offs]


def point_key(p: np.ndarray, cell: float) -> np.ndarray:
    idx = np.floor(p / cell).astype(np.int64)
    key = np.zeros(len(p), dtype=np.int64)
    for dim in range(p.shape[1]):
        key = key * 1_000_003 + idx[:, dim]
    return key


def _segment_distance(p, a, b):
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-30), 0, 1)
    return np.linalg.norm(p - a - t[:, None] * ab, axis=1)


def _point_triangle_distance(p, a, b, c):
    """Distances (k,) between points p (k,3) and triangles (a, b, c) (k,3) each."""
    n = np.cross(b - a, c - a)
    nn = np.maximum(np.einsum("ij,ij->i", n, n), 1e-30)
    h = np.einsum("ij,ij->i", p - a, n) / nn
    q = p - h[:, None] * n
    inside = np.ones(len(p), dtype=bool)
    for u, w in ((a, b), (b, c), (c, a)):
        inside &= np.einsum("ij,ij->i", np.cross(w - u, q - u), n) >= 0
    d = np.where(inside, np.abs(h) * np.sqrt(nn), np.inf)
    for u, w in ((a, b), (b, c), (c, a)):
        d = np.minimum(d, _segment_distance(p, u, w))
    return d


def unsigned_distance(p: np.ndarray, tri: np.ndarray, cutoff: float) -> np.ndarray:
    """(n,) float64 [m]: distance from each point of p (n,3) to the nearest of the triangles tri (k,3,3),
    exact up to `cutoff` [m] and clipped to it beyond."""
    cell = max(cutoff, 0.005)
    item, key = pairs_by_cell(tri.min(axis=1) - cutoff, tri.max(axis=1) + cutoff, cell)
    out = np.full(len(p), cutoff)
    for start in range(0, len(p), 500):
        chunk = p[start:start + 500]
        pi, ti = candidates(point_key(chunk, cell), item, key)
        if len(pi) == 0:
            continue
        d = _point_triangle_distance(chunk[pi], tri[ti, 0], tri[ti, 1], tri[ti, 2])
        np.minimum.at(out[start:start + 500], pi, d)
    return out
