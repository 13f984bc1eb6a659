"""Quadratic bending (Bergou, Wardetzky, Harmon, Zorin and Grinspun, "A quadratic bending model for inextensible
surfaces", SGP 2006) written as zero-rest-length pair springs.

For an interior edge (x0, x1) with apexes x2 and x3 of its two triangles, and the cotangents of the rest triangles'
angles at the edge's ends (alpha_0, beta_0 in the first triangle at x0, x1; alpha_1, beta_1 in the second),

    K = [cot b0 + cot b1,  cot a0 + cot a1,  -(cot a0 + cot b0),  -(cot a1 + cot b1)]   (a = alpha, b = beta),
    Q = K K^T / (A_0 + A_1),        E = B / 2 * sum over edges of x^T Q x     (Q acting on each coordinate),

B the bending rigidity [N m]. K x is 0 on any flat placement of the rest triangles and |e| * 2 sin(theta / 2) at a
dihedral bend theta, so each hinge holds B / 2 * |e|^2 theta^2 / (A_0 + A_1) (Bergou's Q is 3 x ours: with this
scale an isometric cylindrical bend of curvature kappa holds the continuum B / 2 * kappa^2 * area on a lattice of
equilateral triangles, in every direction, and on the right-triangle grids of the pattern mesher along the grid's
axes; along its diagonals 1.5 x that, a hinge energy's known anisotropy; tests/test_bending.py). Because every row
of Q sums to zero,

    x^T Q x = - sum over pairs a < b of Q_ab |x_a - x_b|^2,

so the energy is exactly that of springs of rest length 0 and constant k_ab = -B Q_ab between the stencil's pairs
(summed over the stencils that share a pair; some constants are negative, the sum of the blocks is positive
semi-definite). The force is linear in the positions and its Jacobian constant: unlike the bend springs across the
hinge (a force of order theta^2 at a small bend), a small bend is resisted to first order, with the fabric's
measured rigidity and no calibration. The pairs are all mesh edges and the hinges' apex pairs, so the system's
sparsity is that of the bend springs.

Only intrinsic rest geometry enters (the rest triangles' side lengths), so pieces sewn along a seam get stencils
across it from the two pattern triangles unfolded flat.
"""
from __future__ import annotations

import numpy as np

from clothbase.meshes import edges_of


def side_lengths(corners: np.ndarray) -> np.ndarray:
    """(T,3) float64 [m]: the length of each triangle's side opposite corner k, from its corners (T,3,D) [m]."""
    c = np.asarray(corners, dtype=np.float64)
    return np.stack([np.linalg.norm(c[:, (k + 2) % 3] - c[:, (k + 1) % 3], axis=1) for k in range(3)], axis=1)


def _cotangents_and_areas(lengths: np.ndarray):
    """(T,3) cotangent of each corner's angle and (T,) area [m^2] of triangles with side lengths (T,3) [m]
    (side k opposite corner k)."""
    a2 = lengths**2
    s = 0.5 * lengths.sum(axis=1)
    area = np.sqrt(np.maximum(s * (s - lengths[:, 0]) * (s - lengths[:, 1]) * (s - lengths[:, 2]), 0.0))
    cot = np.stack([(a2[:, (k + 1) % 3] + a2[:, (k + 2) % 3] - a2[:, k]) for k in range(3)], axis=1)
    return cot / np.maximum(4.0 * area, 1e-300)[:, None], area


def quadratic_bending(triangles: np.ndarray, corners: np.ndarray, rigidity: float):
    """The pair springs of the quadratic bending energy (module docstring) of a triangle mesh.

    triangles: (T,3) int64 particle indices; corners: (T,3,D) float64 [m], each triangle's rest corners (pattern
    (u, v) or flat 3D; only their side lengths are used); rigidity: B [N m].
    Returns pairs (K,2) int64 (a < b, unique) and k (K,) float64 [N/m], the springs' constants (rest length 0).
    Triangles with a repeated particle (collapsed by a seam merge) and edges not shared by exactly two triangles
    contribute nothing.
    """
    t = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
    corners = np.asarray(corners, dtype=np.float64)
    ok = (t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 2] != t[:, 0])
    t, corners = t[ok], corners[ok]
    if len(t) == 0 or rigidity == 0.0:
        return np.zeros((0, 2), np.int64), np.zeros(0)
    cot, area = _cotangents_and_areas(side_lengths(corners))
    _, face_edge, counts = edges_of(t)
    flat = face_edge.reshape(-1)
    entry = np.argsort(flat, kind="stable")  # (triangle, corner k) entries grouped by edge; edge k runs k -> k+1
    first = np.searchsorted(flat[entry], np.nonzero(counts == 2)[0])
    e1, e2 = entry[first], entry[first + 1]
    t1, k1 = e1 // 3, e1 % 3
    t2, k2 = e2 // 3, e2 % 3
    p, q, apex1 = t[t1, k1], t[t1, (k1 + 1) % 3], t[t1, (k1 + 2) % 3]
    apex2 = t[t2, (k2 + 2) % 3]
    cot_p1, cot_q1 = cot[t1, k1], cot[t1, (k1 + 1) % 3]
    same = t[t2, k2] == p  # the second triangle runs the edge p -> q too (a flipped neighbour) or q -> p
    cot_p2 = np.where(same, cot[t2, k2], cot[t2, (k2 + 1) % 3])
    cot_q2 = np.where(same, cot[t2, (k2 + 1) % 3], cot[t2, k2])
    K = np.stack([cot_q1 + cot_q2, cot_p1 + cot_p2, -(cot_p1 + cot_q1), -(cot_p2 + cot_q2)], axis=1)
    scale = 1.0 / (area[t1] + area[t2])
    ids = np.stack([p, q, apex1, apex2], axis=1)
    a_idx, b_idx = np.triu_indices(4, 1)
    a, b = ids[:, a_idx].reshape(-1), ids[:, b_idx].reshape(-1)
    k = (-rigidity * scale[:, None] * K[:, a_idx] * K[:, b_idx]).reshape(-1)
    pairs = np.sort(np.stack([a, b], axis=1), axis=1)
    keep = pairs[:, 0] != pairs[:, 1]
    pairs, k = pairs[keep], k[keep]
    unique, inverse = np.unique(pairs, axis=0, return_inverse=True)
    return unique, np.bincount(inverse.reshape(-1), k, minlength=len(unique))


def bending_energy(positions: np.ndarray, pairs: np.ndarray, k: np.ndarray) -> float:
    """The quadratic bending energy [J] at positions (P,3) [m]: sum of k_ab / 2 |x_a - x_b|^2 over the pairs."""
    d = positions[pairs[:, 1]] - positions[pairs[:, 0]]
    return float(0.5 * np.sum(k * np.einsum("ij,ij->i", d, d)))
