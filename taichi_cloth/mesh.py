"""Triangle-mesh topology in numpy: edges, edge-adjacent triangles, validation and file loading.

These run once when a cloth is built (vectorised numpy, no per-element Python loops); the
per-step work on meshes is done by Taichi kernels elsewhere.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import MeshError


def triangle_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Areas [m^2] of triangles (T,3) int over vertices (V,3) float; shape (T,)."""
    if len(triangles) == 0:
        return np.zeros(0)
    p = vertices[triangles]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


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


def validate_triangle_mesh(vertices: np.ndarray, triangles: np.ndarray, source: str = "mesh") -> None:
    """Raise MeshError naming `source` if the mesh is empty, has non-finite vertices, indices out of
    range, degenerate (zero-area or repeated-index) faces, or edges shared by more than two faces."""
    v = np.asarray(vertices)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise MeshError(f"{source}: the mesh has no vertices")
    if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0:
        raise MeshError(f"{source}: the mesh has no triangles")
    if not np.all(np.isfinite(v)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(v), axis=1)))
        raise MeshError(f"{source}: {bad} vertices have NaN or infinite coordinates")
    if t.min() < 0 or t.max() >= len(v):
        raise MeshError(f"{source}: triangle indices out of range 0..{len(v) - 1}")
    repeated = (t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 2] == t[:, 0])
    area = triangle_areas(v, t)
    scale = np.ptp(v, axis=0).max() if len(v) > 1 else 1.0
    degenerate = repeated | (area <= 1e-12 * max(scale, 1e-12) ** 2)
    if degenerate.any():
        raise MeshError(
            f"{source}: {int(degenerate.sum())} degenerate triangles (zero area or a repeated vertex), "
            f"first at face {int(np.argmax(degenerate))}"
        )
    _, _, counts = edges_of(t)
    if counts.max() > 2:
        raise MeshError(
            f"{source}: non-manifold: {int((counts > 2).sum())} edges are shared by more than two triangles"
        )


def load_triangle_mesh(path: str | Path, scale: float = 1.0, translate=(0.0, 0.0, 0.0)):
    """Read a triangle mesh (OBJ, STL, PLY, GLB, OFF...) with trimesh; returns (vertices (V,3) float64 [m],
    triangles (T,3) int32). Duplicate vertices are merged; the result is validated (MeshError if unusable)."""
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise MeshError(f"{path}: no such mesh file")
    try:
        mesh = trimesh.load(path, force="mesh", process=True)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise MeshError(f"{path}: cannot read the mesh ({exc})") from None
    vertices = np.asarray(mesh.vertices, dtype=np.float64) * float(scale) + np.asarray(translate, dtype=np.float64)
    triangles = np.asarray(mesh.faces, dtype=np.int32)
    validate_triangle_mesh(vertices, triangles, str(path))
    return vertices, triangles
