"""Triangle-mesh topology of a cloth in numpy: edges and the vertex pairs across interior edges.

These run once when a cloth is built (vectorised numpy); validation, repair and file loading are shared
with the collision bodies and live in collision.meshes.
"""
from __future__ import annotations

import numpy as np

from collision.meshes import load_triangle_mesh, triangle_areas, validate_triangle_mesh

__all__ = ["edges_of", "interior_edge_opposites", "load_triangle_mesh", "triangle_areas", "validate_triangle_mesh"]


def edges_of(triangles: np.ndarray):
    """Unique undirected edges of a triangle list.

    Returns edges (E,2) int64 with edges[:,0] < edges[:,1]; face_edge (T,3), the id of the edge
    from corner k to corner k+1 of each triangle; counts (E,), how many triangles share each edge.
    """
    t = np.asarray(triangles, dtype=np.int64)
    half = np.stack([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]], axis=1).reshape(-1, 2)
    half.sort(axis=1)
    edges, inverse, counts = np.unique(half, axis=0, return_inverse=True, return_counts=True)
    return edges, inverse.reshape(-1, 3), counts


def interior_edge_opposites(triangles: np.ndarray) -> np.ndarray:
    """For every edge shared by exactly two triangles, the two vertices opposite it; shape (K,2).

    These pairs are the bend springs of an arbitrary triangle mesh.
    """
    t = np.asarray(triangles, dtype=np.int64)
    edges, face_edge, counts = edges_of(t)
    # the vertex opposite the edge (k, k+1) of a triangle is its corner k+2
    opposite = t[:, [2, 0, 1]].reshape(-1)
    edge_id = face_edge.reshape(-1)
    order = np.argsort(edge_id, kind="stable")
    edge_sorted = edge_id[order]
    opp_sorted = opposite[order]
    interior = counts == 2
    # positions of the first of the two entries of each interior edge in the sorted list
    first = np.searchsorted(edge_sorted, np.nonzero(interior)[0])
    pairs = np.stack([opp_sorted[first], opp_sorted[first + 1]], axis=1)
    pairs.sort(axis=1)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    return np.unique(pairs, axis=0)
