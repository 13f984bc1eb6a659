"""Triangle meshes from files and arrays: topology (edges, the vertex pairs across interior edges, connected
components), validation with one clear message, optional repair, loading.

Used for collision bodies, cloth meshes, 4-8 levels and garments. Vectorised numpy; runs once per mesh.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import MeshError, warn


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
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    half = np.sort(t[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edges, inverse, counts = np.unique(half, axis=0, return_inverse=True, return_counts=True)
    return edges, inverse.reshape(-1, 3), counts


def connected_components(n: int, pairs: np.ndarray) -> np.ndarray:
    """Connected-component labels (n,) int64 (the smallest member index) of a graph on n nodes given as edge
    pairs (k, 2)."""
    label = np.arange(n)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if len(pairs) == 0:
        return label
    a, b = pairs[:, 0], pairs[:, 1]
    while True:
        low = np.minimum(label[a], label[b])
        new = label.copy()
        np.minimum.at(new, a, low)
        np.minimum.at(new, b, low)
        new = new[new]  # pointer jumping: long loops converge in log steps
        if np.array_equal(new, label):
            return label
        label = new


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


def rows_in(rows: np.ndarray, table: np.ndarray) -> np.ndarray:
    """(n,) bool: which rows of the non-negative index pairs `rows` (n, 2) occur in `table` (m, 2) (e.g. which
    springs are edges of a list)."""
    rows, table = np.asarray(rows, dtype=np.int64).reshape(-1, 2), np.asarray(table, dtype=np.int64).reshape(-1, 2)
    if len(table) == 0 or len(rows) == 0:
        return np.zeros(len(rows), dtype=bool)
    base = int(max(rows.max(), table.max())) + 1
    return np.isin(rows[:, 0] * base + rows[:, 1], table[:, 0] * base + table[:, 1])


def edge_face_counts(triangles: np.ndarray) -> np.ndarray:
    """How many triangles share each undirected edge; shape (E,)."""
    return edges_of(triangles)[2]


def mesh_problems(vertices, triangles) -> dict:
    """Counts of each defect: empty, nonfinite (vertices), out_of_range, degenerate (faces), nonmanifold (edges)."""
    v, t = np.asarray(vertices), np.asarray(triangles)
    out = {"empty": int(v.ndim != 2 or len(v) == 0 or t.ndim != 2 or len(t) == 0)}
    if out["empty"]:
        return out
    out["nonfinite"] = int(np.count_nonzero(~np.all(np.isfinite(v), axis=1)))
    out["out_of_range"] = int(np.count_nonzero((t < 0) | (t >= len(v))))
    if out["nonfinite"] or out["out_of_range"]:
        return out
    repeated = (t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 2] == t[:, 0])
    scale = float(np.ptp(v, axis=0).max()) if len(v) > 1 else 1.0
    out["degenerate"] = int(np.count_nonzero(repeated | (triangle_areas(v, t) <= 1e-12 * max(scale, 1e-12) ** 2)))
    out["nonmanifold"] = int(np.count_nonzero(edge_face_counts(t) > 2))
    return out


def open_mesh_warning(triangles, source: str = "mesh") -> None:
    """Warn when a collider mesh is open (edges on one triangle only): it has no inside, so it holds the cloth
    off its surface from one side only."""
    boundary = int(np.count_nonzero(edge_face_counts(triangles) == 1))
    if boundary:
        warn(f"{source}: the collider mesh is open ({boundary} boundary edges, not watertight): it acts as a "
             "one-sided collider; cloth that passes an edge or a hole is not pushed back out, since an open mesh "
             "has no inside")


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(V,3) float64 unit area-weighted vertex normals of a mesh (vertices (V,3) [m], triangles (T,3) int): the sum
    of the area vectors of each vertex's triangles, normalised (zero where a vertex has none or they cancel)."""
    v, t = np.asarray(vertices, np.float64), np.asarray(triangles, np.int64)
    area = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])  # twice the area vector
    n = np.stack([np.bincount(t.ravel(), np.repeat(area[:, c], 3), minlength=len(v)) for c in range(3)],
                 axis=1).astype(np.float64)  # (bincount of no weights is an integer array)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 1e-30)


def validate_triangle_mesh(vertices, triangles, source: str = "mesh") -> None:
    """Raise MeshError naming `source` and the first defect found (see mesh_problems)."""
    v, t = np.asarray(vertices), np.asarray(triangles)
    p = mesh_problems(v, t)
    if p["empty"]:
        what = "vertices" if v.ndim != 2 or len(v) == 0 else "triangles"
        raise MeshError(f"{source}: the mesh has no {what}")
    if p["nonfinite"]:
        raise MeshError(f"{source}: {p['nonfinite']} vertices have NaN or infinite coordinates")
    if p["out_of_range"]:
        raise MeshError(f"{source}: triangle indices out of range 0..{len(v) - 1}")
    if p["degenerate"]:
        raise MeshError(f"{source}: {p['degenerate']} degenerate triangles (zero area or a repeated vertex)")
    if p["nonmanifold"]:
        raise MeshError(f"{source}: non-manifold: {p['nonmanifold']} edges are shared by more than two triangles")


def repair_triangle_mesh(vertices, triangles, source: str = "mesh"):
    """Drop what can be dropped safely: faces touching non-finite vertices, degenerate faces, unused vertices.
    Warns saying what was done; returns (vertices, triangles). Non-manifold edges are not repairable here."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    if len(v) == 0 or len(t) == 0:
        raise MeshError(f"{source}: the mesh is empty")
    done = []
    finite = np.all(np.isfinite(v), axis=1)
    bad = ~np.all(finite[t], axis=1)
    if bad.any():
        done.append(f"dropped {int(bad.sum())} faces on NaN/inf vertices")
        t = t[~bad]
    scale = float(np.ptp(v[finite], axis=0).max()) if finite.sum() > 1 else 1.0
    repeated = (t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 2] == t[:, 0])
    degenerate = repeated | (triangle_areas(v, t) <= 1e-12 * max(scale, 1e-12) ** 2)
    if degenerate.any():
        done.append(f"dropped {int(degenerate.sum())} degenerate faces")
        t = t[~degenerate]
    used = np.unique(t)
    if len(used) < len(v):
        done.append(f"dropped {len(v) - len(used)} unused vertices")
        remap = np.full(len(v), -1, np.int64)
        remap[used] = np.arange(len(used))
        v, t = v[used], remap[t]
    if done:
        warn(f"{source}: repaired: " + "; ".join(done))
    validate_triangle_mesh(v, t, source)
    return v, t


def write_triangle_mesh(path: str | Path, vertices: np.ndarray, triangles: np.ndarray) -> Path:
    """Write vertices (V,3) [m] and triangles (T,3) with meshio, the format by suffix (.obj, .ply, .vtk...); without
    triangles, the vertices as a point cloud. Returns the path."""
    import meshio  # 0.2 s to import: only when a mesh is written

    path = Path(path)
    cells = ([("triangle", np.asarray(triangles, dtype=np.int32))] if len(triangles)
             else [("vertex", np.arange(len(vertices), dtype=np.int32)[:, None])])
    meshio.write(path, meshio.Mesh(vertices, cells))
    return path


def read_mesh_arrays(path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V,3) float64, triangles (T,3) int64) of a mesh file as written (trimesh, nothing merged or
    checked); MeshError naming the file when trimesh cannot read it."""
    import trimesh  # 0.7 s to import: only when a mesh file is read

    try:
        mesh = trimesh.load(path, force="mesh", process=False)
        v = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
        t = np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise MeshError(f"{path}: unreadable as a mesh ({type(exc).__name__}: {exc})") from None
    return v, t


def load_triangle_mesh(path: str | Path, scale: float = 1.0, translate=(0.0, 0.0, 0.0), repair: bool = False):
    """Read a triangle mesh (OBJ, STL, PLY, GLB, OFF...) with trimesh; returns (vertices (V,3) float64 [m],
    triangles (T,3) int64). `scale` multiplies the file's coordinates into metres, then `translate` [m] is
    added. Duplicate vertices are merged. Defects raise MeshError, or are repaired with a warning if `repair`."""
    import trimesh  # 0.7 s to import: only when a mesh file is read

    path = Path(path)
    if path.is_dir():
        raise MeshError(f"{path}: is a folder, not a mesh file")
    if not path.is_file():
        raise MeshError(f"{path}: no such mesh file")
    if path.suffix.lower() == ".dxf":
        raise MeshError(f"{path}: unreadable as a mesh: a DXF file holds 2D pattern outlines, not triangles (a "
                        "garment file reads them: dxf = \"pattern.dxf\")")
    v, t = read_mesh_arrays(path)
    if len(v) == 0 or len(t) == 0:
        raise MeshError(f"{path}: unreadable as a mesh: no {'vertices' if len(v) == 0 else 'triangles'} found in "
                        "it (is it a mesh file? OBJ, STL, PLY, OFF, GLB)")
    if len(v) and len(t) and np.all(np.isfinite(v)):
        merged = trimesh.Trimesh(v, t, process=True, validate=False)  # merge duplicate vertices (OBJ uv seams)
        v, t = np.asarray(merged.vertices, dtype=np.float64), np.asarray(merged.faces, dtype=np.int64)
    v = v * float(scale) + np.asarray(translate, dtype=np.float64)
    if repair:
        return repair_triangle_mesh(v, t, str(path))
    validate_triangle_mesh(v, t, str(path))
    return v, t
