"""Exact count of a mesh's intersecting triangle pairs (the measure of self-collision: a cloth at rest should have
none). Plain numpy on the host: it runs once per measurement, not per step.

Two triangles that share no vertex intersect iff one of the six edges pierces the other triangle (their
intersection, when not coplanar, is a segment whose ends lie on edges of one or the other). The candidates are the
pairs whose centroids lie within the sum of their largest centroid-to-corner distances (a k-d tree query), so no
intersecting pair is missed. Pairs that share a vertex (neighbours around a vertex or an edge) always touch and are
not counted; coplanar overlaps (measure zero in a simulated cloth) are not counted either.
"""
import numpy as np
from scipy.spatial import cKDTree


def intersecting_pairs(positions, triangles) -> np.ndarray:
    """(K,2) int64 index pairs (i < j) of the triangles of `triangles` (T,3) int over `positions` (P,3) [m] that
    intersect and share no vertex."""
    x = np.asarray(positions, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    if len(t) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    corners = x[t]  # (T,3,3)
    centroid = corners.mean(1)
    radius = np.linalg.norm(corners - centroid[:, None], axis=2).max(1)
    pairs = cKDTree(centroid).query_pairs(2.0 * float(radius.max()), output_type="ndarray").astype(np.int64)
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    a, b = pairs[:, 0], pairs[:, 1]
    near = np.linalg.norm(centroid[a] - centroid[b], axis=1) <= radius[a] + radius[b]
    shared = (t[a][:, :, None] == t[b][:, None, :]).any(axis=(1, 2))
    pairs = pairs[near & ~shared]
    a, b = pairs[:, 0], pairs[:, 1]
    hit = np.zeros(len(pairs), dtype=bool)
    for first, second in ((a, b), (b, a)):
        for k in range(3):
            p, q = corners[first, k], corners[first, (k + 1) % 3]
            hit |= _segment_pierces(p, q, corners[second])
    return np.sort(pairs[hit], axis=1)


def count_intersecting_pairs(positions, triangles) -> int:
    """How many pairs of triangles (sharing no vertex) intersect."""
    return len(intersecting_pairs(positions, triangles))


def _segment_pierces(p: np.ndarray, q: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """(N,) bool: segment p-q (N,3) crosses triangle tri (N,3,3), Moller-Trumbore with the segment's parameter in
    [0, 1] (a segment in the triangle's plane does not count)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    d = q - p
    e1, e2 = b - a, c - a
    h = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, h)
    scale = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1) * np.linalg.norm(d, axis=1)
    ok = np.abs(det) > 1e-12 * np.maximum(scale, 1e-300)
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = p - a
    u = inv * np.einsum("ij,ij->i", s, h)
    qv = np.cross(s, e1)
    v = inv * np.einsum("ij,ij->i", d, qv)
    w = inv * np.einsum("ij,ij->i", e2, qv)
    return ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (w >= 0) & (w <= 1)
