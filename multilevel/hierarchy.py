"""The 4-8 mesh hierarchy (Hsiao 2006 section 2.2; Velho and Zorin 2001; docs/algorithms.md, multilevel).

A 4-8 mesh is made of right isosceles triangles whose vertices have valence 4 or 8 (inside). One
refinement bisects every triangle across its hypotenuse, inserting the hypotenuse midpoint; the two
triangles sharing a hypotenuse (a "diamond") are split together, so every level is conforming. Two
refinements equal one dyadic refinement; the edge length shrinks by 1/sqrt(2) per level.

Triangles are stored as (hyp_a, hyp_b, apex), counter-clockwise in the 2D rest (pattern) coordinates:
the hypotenuse is the edge hyp_a-hyp_b. Bisecting it at the midpoint m gives the children
(apex, hyp_a, m) and (hyp_b, apex, m), again in that form. Vertices are nested: level L+1 keeps the
vertices of level L at the same indices and appends the midpoints, so a quantity on level L extends to
level L+1 by the prolongation table (parents, weights) alone.

Everything here is numpy; the Taichi kernels that apply the tables live in multilevel.prolong.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clothbase.meshes import edges_of


@dataclass
class Level:
    """One level of a hierarchy (index 0 = the base, Hsiao 2006's level N = 1).

    uv:        (n, 2) float64 [m]  rest (pattern) coordinates
    triangles: (t, 3) int64        (hyp_a, hyp_b, apex), counter-clockwise in uv
    parents:   (n, 3) int64        prolongation from the level above: value[k] = sum_j weights[k, j] *
    weights:   (n, 3) float64        previous[parents[k, j]] over the j with parents[k, j] >= 0 (rows sum to 1);
                                     for the base level, the identity
    diamonds:  (n, 4) int64        for a midpoint vertex: its two parents (the hypotenuse ends) and the two
                                     diamond apexes (-1 where the hypotenuse lies on the boundary); -1 rows for
                                     vertices inherited from the level above
    """

    uv: np.ndarray
    triangles: np.ndarray
    parents: np.ndarray
    weights: np.ndarray
    diamonds: np.ndarray

    @property
    def n_vertices(self) -> int:
        return len(self.uv)

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)

    def prolong(self, values: np.ndarray) -> np.ndarray:
        """Extend per-vertex values of the level above ((n_prev, ...) array) to this level."""
        values = np.asarray(values)
        out = np.zeros((self.n_vertices,) + values.shape[1:], dtype=np.result_type(values, np.float64))
        for j in range(3):
            live = self.parents[:, j] >= 0
            w = self.weights[live, j].reshape((-1,) + (1,) * (values.ndim - 1))
            out[live] += w * values[self.parents[live, j]]
        return out


def identity_tables(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Prolongation tables that copy n values onto themselves."""
    parents = np.full((n, 3), -1, np.int64)
    parents[:, 0] = np.arange(n)
    weights = np.zeros((n, 3))
    weights[:, 0] = 1.0
    return parents, weights


def base_grid(size=(1.0, 1.0), cells=(4, 4)) -> tuple[np.ndarray, np.ndarray]:
    """The base 4-8 triangulation of a W x H rectangle [m] with (nx, ny) square-ish cells, centred at 0:
    each cell split along alternating diagonals, so that inner vertices have valence 4 or 8.

    Returns uv (n, 2) [m] with vertex (i, j) at index i + (nx + 1) j, and triangles (2 nx ny, 3) in
    (hyp_a, hyp_b, apex) form."""
    nx, ny = int(cells[0]), int(cells[1])
    W, H = float(size[0]), float(size[1])
    if nx < 1 or ny < 1:
        raise ValueError(f"a 4-8 base needs at least 1x1 cells, got {nx}x{ny}")
    if not (W > 0 and H > 0):
        raise ValueError(f"a 4-8 base needs a positive size [m], got {W}x{H}")
    i, j = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), indexing="xy")
    uv = np.stack([i.ravel() * W / nx - W / 2, j.ravel() * H / ny - H / 2], 1)
    ci, cj = np.meshgrid(np.arange(nx), np.arange(ny), indexing="xy")
    ci, cj = ci.ravel(), cj.ravel()
    v00 = ci + (nx + 1) * cj
    v10, v01, v11 = v00 + 1, v00 + nx + 1, v00 + nx + 2
    even = (ci + cj) % 2 == 0
    # even cells: diagonal v00-v11; odd cells: diagonal v10-v01 (alternating, so valences are 4 and 8)
    t1 = np.where(even[:, None], np.stack([v11, v00, v10], 1), np.stack([v01, v10, v11], 1))
    t2 = np.where(even[:, None], np.stack([v00, v11, v01], 1), np.stack([v10, v01, v00], 1))
    return uv, np.concatenate([t1, t2]).astype(np.int64)


def bisect(uv: np.ndarray, triangles: np.ndarray) -> Level:
    """Bisect every triangle across its hypotenuse (one 4-8 refinement). The midpoints of the distinct
    hypotenuses are appended to uv in order of first appearance."""
    n = len(uv)
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    key = np.sort(np.stack([a, b], 1), axis=1)
    hyp, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")  # number the midpoints in order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    mid = n + rank[inverse.reshape(-1)]
    hyp = hyp[order]
    new_uv = np.concatenate([uv, 0.5 * (uv[hyp[:, 0]] + uv[hyp[:, 1]])])
    children = np.concatenate([np.stack([c, a, mid], 1), np.stack([b, c, mid], 1)])
    # children of triangle t at rows t and T + t: interleave so that siblings stay neighbours in memory
    T = len(triangles)
    children = children.reshape(2, T, 3).transpose(1, 0, 2).reshape(2 * T, 3)

    m = len(hyp)
    parents, weights = identity_tables(n + m)
    parents[n:, 0], parents[n:, 1] = hyp[:, 0], hyp[:, 1]
    weights[n:, 0] = weights[n:, 1] = 0.5
    diamonds = np.full((n + m, 4), -1, np.int64)
    diamonds[n:, :2] = hyp
    apex_slot = np.zeros(m, np.int64)
    for t in range(T):  # at most two triangles share a hypotenuse
        k = rank[inverse[t]]
        diamonds[n + k, 2 + apex_slot[k]] = c[t]
        apex_slot[k] += 1
    if np.any(apex_slot > 2):
        raise ValueError("not a 4-8 mesh: a hypotenuse is shared by more than two triangles")
    return Level(new_uv, children.astype(np.int64), parents, weights, diamonds)


class Hierarchy48:
    """A nested sequence of 4-8 meshes, levels[0] the coarsest. Build one with `rectangle`."""

    def __init__(self, levels: list[Level]):
        if not levels:
            raise ValueError("a hierarchy needs at least one level")
        self.levels = levels

    def __len__(self) -> int:
        return len(self.levels)

    def __getitem__(self, k: int) -> Level:
        return self.levels[k]

    @property
    def finest(self) -> Level:
        return self.levels[-1]

    @classmethod
    def from_base(cls, uv: np.ndarray, triangles: np.ndarray, levels: int) -> "Hierarchy48":
        """Refine a base 4-8 triangulation (hypotenuse-first triangles) levels-1 times."""
        if not 1 <= levels <= 12:
            raise ValueError(f"levels must lie in 1..12, got {levels}")
        n = len(uv)
        parents, weights = identity_tables(n)
        out = [Level(np.asarray(uv, np.float64), np.asarray(triangles, np.int64), parents, weights,
                     np.full((n, 4), -1, np.int64))]
        for _ in range(levels - 1):
            out.append(bisect(out[-1].uv, out[-1].triangles))
        return cls(out)

    @classmethod
    def rectangle(cls, size=(1.0, 1.0), base_cells=(4, 4), levels: int = 5) -> "Hierarchy48":
        """A W x H [m] rectangle: base grid of (nx, ny) cells with alternating diagonals, then levels-1
        bisections. Level L (0-based) has spacing base/2^(L/2); even levels are axis-aligned grids."""
        return cls.from_base(*base_grid(size, base_cells), levels)


# ---------------------------------------------------------------------- checks (used by tests and builders)
def edge_use(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct undirected edges (E, 2) and how many triangles use each (E,)."""
    edges, _, count = edges_of(triangles)
    return edges, count


def valences(triangles: np.ndarray, n: int) -> np.ndarray:
    """(n,) number of distinct edge neighbours of each vertex."""
    edges, _ = edge_use(triangles)
    return np.bincount(edges.reshape(-1), minlength=n)


def boundary_vertices(triangles: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: the vertex lies on an edge used by one triangle only."""
    edges, count = edge_use(triangles)
    out = np.zeros(n, dtype=bool)
    out[edges[count == 1].reshape(-1)] = True
    return out


def hanging_vertices(uv: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Indices of vertices that lie strictly inside an edge of some triangle (a non-conforming mesh has
    them: a refined side meets an unrefined one). Empty for a conforming mesh."""
    edges, _ = edge_use(triangles)
    p, q = uv[edges[:, 0]], uv[edges[:, 1]]
    # only midpoints can hang in a 4-8 hierarchy; look each edge midpoint up among the vertices
    mids = np.round(0.5 * (p + q) / _tolerance(uv)).astype(np.int64)
    keys = np.round(uv / _tolerance(uv)).astype(np.int64)
    lookup = {tuple(k): i for i, k in enumerate(keys)}
    return np.array(sorted({lookup[tuple(m)] for m in mids if tuple(m) in lookup}), dtype=np.int64)


def signed_areas(uv: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(t,) signed areas [m^2] of 2D triangles (positive when counter-clockwise)."""
    p = uv[triangles]
    a, b = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return 0.5 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])


def _tolerance(uv: np.ndarray) -> float:
    span = float(np.ptp(uv, axis=0).max()) if len(uv) else 1.0
    return 1e-9 * max(span, 1e-12)


def refine_local(uv: np.ndarray, triangles: np.ndarray, marked: np.ndarray, depth: np.ndarray | None = None,
                 max_depth: int | None = None) -> tuple[Level, np.ndarray]:
    """Bisect the `marked` triangles ((t,) bool) across their hypotenuses, keeping the mesh conforming:
    a triangle whose hypotenuse neighbour does not share that hypotenuse first has the neighbour split (the
    4-8 forced split, recursively), then both halves of the diamond are split together.

    depth: (t,) int, how many bisections made each triangle (default 0); a triangle at max_depth is not
    split (marks on it are dropped), so a locally refined mesh never outgrows the global level max_depth.
    Returns the refined Level (vertices nested: old ones first, midpoints appended; prolongation tables
    from the input) and the new triangles' depths."""
    tris = [tuple(int(v) for v in t) for t in np.asarray(triangles, np.int64)]
    depths = list(np.zeros(len(tris), np.int64) if depth is None else np.asarray(depth, np.int64))
    alive = [True] * len(tris)
    by_edge: dict[tuple[int, int], list[int]] = {}
    for k, (a, b, c) in enumerate(tris):
        for e in ((a, b), (b, c), (c, a)):
            by_edge.setdefault((min(e), max(e)), []).append(k)
    n0 = len(uv)
    points = [tuple(p) for p in np.asarray(uv, np.float64)]
    mids: dict[tuple[int, int], int] = {}
    parents: list[tuple[int, int]] = []

    def neighbour(k: int, edge: tuple[int, int]) -> int:
        for j in by_edge[edge]:
            if j != k and alive[j]:
                return j
        return -1

    def bisect_one(k: int, m: int) -> None:
        a, b, c = tris[k]
        alive[k] = False
        for e in ((a, b), (b, c), (c, a)):
            by_edge[(min(e), max(e))].remove(k)
        for child in ((c, a, m), (b, c, m)):
            tris.append(child)
            depths.append(depths[k] + 1)
            alive.append(True)
            j = len(tris) - 1
            x, y, z = child
            for e in ((x, y), (y, z), (z, x)):
                by_edge.setdefault((min(e), max(e)), []).append(j)

    def split(k: int) -> None:
        a, b, _ = tris[k]
        edge = (min(a, b), max(a, b))
        n = neighbour(k, edge)
        if n >= 0 and (min(tris[n][:2]), max(tris[n][:2])) != edge:
            split(n)  # the neighbour is coarser: split it first; its child on this edge has it as hypotenuse
            n = neighbour(k, edge)
        m = mids.get(edge)
        if m is None:
            m = n0 + len(parents)
            mids[edge] = m
            parents.append(edge)
            pa, pb = points[a], points[b]
            points.append((0.5 * (pa[0] + pb[0]), 0.5 * (pa[1] + pb[1])))
        bisect_one(k, m)
        if n >= 0:
            bisect_one(n, m)

    limit = np.inf if max_depth is None else max_depth
    for k in np.nonzero(np.asarray(marked, bool))[0]:
        if alive[k] and depths[k] < limit:
            split(int(k))
    keep = np.nonzero(alive)[0]
    n = n0 + len(parents)
    par, w = identity_tables(n)
    diamonds = np.full((n, 4), -1, np.int64)
    if parents:
        pe = np.asarray(parents, np.int64)
        par[n0:, 0], par[n0:, 1] = pe[:, 0], pe[:, 1]
        w[n0:, 0] = w[n0:, 1] = 0.5
        diamonds[n0:, :2] = pe
    level = Level(np.asarray(points, np.float64), np.asarray([tris[k] for k in keep], np.int64).reshape(-1, 3),
                  par, w, diamonds)
    return level, np.asarray(depths, np.int64)[keep]
