"""Triangle-mesh topology of a cloth in numpy: edges and the vertex pairs across interior edges.

These run once when a cloth is built (vectorised numpy); validation, repair and file loading are shared
with the collision bodies and live in collision.meshes.
"""
from __future__ import annotations

import numpy as np

from collision.meshes import edges_of, load_triangle_mesh, triangle_areas, validate_triangle_mesh

__all__ = ["edges_of", "interior_edge_opposites", "load_triangle_mesh", "triangle_areas", "validate_triangle_mesh"]


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
