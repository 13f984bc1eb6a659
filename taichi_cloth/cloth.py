"""ClothData: a cloth before it lives in Taichi fields (numpy, SI units), and the rules that make springs.

A cloth is particles with masses and springs of four kinds. Rest lengths always come from the rest (pattern or
initial) positions, never from a deformed shape; masses are lumped from area, so the total mass is exactly
density x area. `mesh_cloth` is the spring rule of an arbitrary triangle mesh (used by ClothBuilder, the 4-8 levels
and the garments); the grid has its own (taichi_cloth.builder).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from clothbase.meshes import edges_of, interior_edge_opposites, triangle_areas, validate_triangle_mesh

from .bending import quadratic_bending
from .material import Material
from .material import material as as_material

#: plane name -> the coordinate axes (u, v) of a flat cloth laid in it ("xy": hanging, "xz": horizontal)
PLANES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2), "zy": (2, 1)}


class SpringKind(IntEnum):
    """What a spring models. Stored as int32 in Model.spring_kind."""

    STRUCTURAL = 0
    SHEAR = 1
    BEND = 2
    SEAM = 3
    #: a pair term of the quadratic bending energy (taichi_cloth.bending): rest length 0, a constant of either sign
    QUADRATIC_BEND = 4


@dataclass
class ClothData:
    """A cloth before it lives in Taichi fields (all numpy, SI units).

    positions:   (P,3) float64 [m]  initial positions (also the rest shape unless rest_positions is set)
    mass:        (P,)  float64 [kg]
    springs:     (S,2) int64        particle indices (a, b)
    rest_length: (S,)  float64 [m]
    stiffness:   (S,)  float64 [N/m]
    damping:     (S,)  float64 [N*s/m]  stiffness-proportional: along the spring, isotropic on a QUADRATIC_BEND
                                      pair (axial_damping, viscous_damping)
    kind:        (S,)  int64        SpringKind
    triangles:   (T,3) int64        for rendering, normals and wind (may be empty for a chain)
    grid_shape:  (nu, nv) for grids (particle i + nu*j), else None
    viscosity:   [m^2/s] the material's internal (membrane) viscosity: see viscous_damping
    """

    positions: np.ndarray
    mass: np.ndarray
    springs: np.ndarray
    rest_length: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    kind: np.ndarray
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    grid_shape: tuple[int, int] | None = None
    viscosity: float = 0.0

    @property
    def n_particles(self) -> int:
        return len(self.positions)

    @property
    def n_springs(self) -> int:
        return len(self.springs)

    def count(self, kind: SpringKind) -> int:
        return int(np.count_nonzero(self.kind == kind))

    def axial_damping(self) -> np.ndarray:
        """(S,) float64 [N*s/m]: each spring's damping along its direction: `damping`, 0 on a QUADRATIC_BEND pair
        (whose direction is not a deformation's: its damping is the isotropic damping x K of viscous_damping)."""
        return np.where(self.kind == SpringKind.QUADRATIC_BEND, 0.0, self.damping)

    def viscous_damping(self) -> np.ndarray:
        """(S,) float64 [N*s/m]: the isotropic dashpot c_s = viscosity * mu_s / L_s^2 of every mesh edge (structural
        and shear springs; mu_s = m_a m_b / (m_a + m_b), L_s its rest length), 0 on bend and seam springs; on a
        QUADRATIC_BEND pair its `damping` (ratio x k: the bending energy's Hessian times the ratio, Rayleigh
        damping of the bending modes, 0 on a rigid motion). It pulls
        the velocities of neighbouring particles together (force c_s (v_b - v_a) on a), so a velocity difference
        between neighbours decays at the rate viscosity / L_s^2 whatever the spacing: a velocity pattern of wavelength
        lambda decays at about viscosity (2 pi / lambda)^2 (docs/algorithms.md, damping)."""
        bending = np.where(self.kind == SpringKind.QUADRATIC_BEND, self.damping, 0.0)
        if self.viscosity == 0.0 or self.n_springs == 0:
            return bending
        ma, mb = self.mass[self.springs[:, 0]], self.mass[self.springs[:, 1]]
        mesh_edge = (self.kind == SpringKind.STRUCTURAL) | (self.kind == SpringKind.SHEAR)
        return bending + np.where(mesh_edge, self.viscosity * ma * mb / (ma + mb)
                                  / np.maximum(self.rest_length, 1e-12) ** 2, 0.0)


def in_plane(uv: np.ndarray, plane: str, center=(0.0, 0.0, 0.0)) -> np.ndarray:
    """(n,3) float64 [m]: 2D points uv (n,2) [m] laid in `plane` (a PLANES name) around `center` [m]."""
    if plane not in PLANES:
        raise ValueError(f"plane must be one of {', '.join(PLANES)}, got {plane!r}")
    a0, a1 = PLANES[plane]
    uv = np.asarray(uv, dtype=np.float64)
    positions = np.zeros((len(uv), 3))
    positions[:, a0], positions[:, a1] = uv[:, 0], uv[:, 1]
    return positions + np.asarray(center, dtype=np.float64)


def spring_arrays(pairs: list[np.ndarray], ks: list[np.ndarray], kinds: list[int], positions, damping_ratio):
    """(springs (S,2), rest (S,) [m], stiffness (S,) [N/m], damping (S,) [N s/m], kind (S,)) of spring groups:
    index pairs, their constants [N/m] and kinds; rest lengths from `positions` [m] (0 for QUADRATIC_BEND pairs),
    damping = ratio [s] x k."""
    springs = np.concatenate(pairs).astype(np.int64).reshape(-1, 2)
    stiffness = np.concatenate(ks).astype(np.float64)
    kind = np.concatenate([np.full(len(p), kd, np.int64) for p, kd in zip(pairs, kinds)])
    rest = np.linalg.norm(positions[springs[:, 1]] - positions[springs[:, 0]], axis=1)
    rest[kind == SpringKind.QUADRATIC_BEND] = 0.0
    return springs, rest, stiffness, damping_ratio * stiffness, kind


def orthotropic_edges(uv: np.ndarray, triangles: np.ndarray, n_edges: int, face_edge: np.ndarray,
                      mat: Material) -> np.ndarray:
    """(E,) float64 [N/m]: edge constants that give every triangle the square grid's sheet along the uv axes (the
    warp and weft of a woven fabric): C11 = C22 = stretch + shear, C66 = C12 = shear, so a pull along an axis meets
    `stretch` and a shear (a pull on the bias) only `shear`. A central spring of constant k, length L and direction
    (c, s) adds k L^2 / A (c^4, s^4, c^2 s^2) to a triangle's (C11, C22, C66); each triangle's three constants solve
    those three equations (by non-negative least squares on relative errors where no constants >= 0 solve them
    exactly: the pattern mesher's boundary band, the 45-degree-rotated 4-8 levels), and an edge's constant is the
    sum of its triangles', at least `shear`. On the 4-8 lattice it is exact: the axis edges get `stretch` and the
    diagonals 2 x `shear`, the square grid's springs (tests/test_membrane.py). The isotropic rule
    instead ties the shear to the stretch (G = 3 E / 8), which a fabric's bias does not (silk: 22 N/m against
    9807), and which holds a draped fabric in too few folds.
    face_edge: (T,3) the edge id of each triangle's edge k (from corner k to k + 1)."""
    uv = np.asarray(uv, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    d = np.stack([uv[t[:, (k + 1) % 3]] - uv[t[:, k]] for k in range(3)], axis=1)  # (T,3,2)
    L2 = np.einsum("tkc,tkc->tk", d, d)
    area = 0.5 * np.abs(d[:, 0, 0] * d[:, 1, 1] - d[:, 0, 1] * d[:, 1, 0])
    c2, s2 = d[..., 0] ** 2 / L2, d[..., 1] ** 2 / L2
    w = L2 / area[:, None]
    M = np.stack([w * c2 * c2, w * s2 * s2, w * c2 * s2], axis=1)  # (T, component, edge)
    target = np.array([mat.stretch + mat.shear, mat.stretch + mat.shear, mat.shear])
    # relative residuals: where no constants >= 0 fit, a triangle misses each modulus by a like fraction, rather
    # than missing the small shear by multiples to fit the large stretch
    Mr = M / target[None, :, None]
    # non-negative least squares of three unknowns: the best of the solutions on each subset of the edges that has
    # no negative constant
    k = np.zeros((len(t), 3))
    best = np.full(len(t), np.inf)
    for subset in ([0, 1, 2], [0, 1], [1, 2], [0, 2], [0], [1], [2]):
        sol = np.einsum("tij,j->ti", np.linalg.pinv(Mr[:, :, subset], rcond=1e-9), np.ones(3))
        resid = np.linalg.norm(np.einsum("tij,tj->ti", Mr[:, :, subset], sol) - 1.0, axis=1)
        better = np.all(sol >= 0.0, axis=1) & (resid < best - 1e-12)
        best = np.where(better, resid, best)
        k[better] = 0.0
        k[np.ix_(np.nonzero(better)[0], subset)] = sol[better]
    # an edge no triangle gave a constant would be a mechanism: it keeps the bias's own stiffness
    return np.maximum(np.bincount(face_edge.reshape(-1), k.reshape(-1), minlength=n_edges), mat.shear)


def bend_springs(triangles: np.ndarray, positions: np.ndarray, mat: Material):
    """The bending springs of a triangle mesh at rest `positions` (P,3) [m] for the material's bending model:
    (pairs (K,2) int64, constants (K,) [N/m], kind). "springs": one across every interior edge between its two
    apexes, k = bend / L0^2; "quadratic": the pair terms of taichi_cloth.bending with B = bend."""
    t = np.asarray(triangles, dtype=np.int64)
    if mat.bending == "quadratic":
        pairs, k = quadratic_bending(t, positions[t], mat.bend)
        return pairs, k, SpringKind.QUADRATIC_BEND
    pairs = interior_edge_opposites(t)
    L = np.linalg.norm(positions[pairs[:, 1]] - positions[pairs[:, 0]], axis=1) if len(pairs) else np.zeros(0)
    return pairs, mat.bend / np.maximum(L, 1e-12) ** 2, SpringKind.BEND


def mesh_cloth(vertices, triangles, material: str | Material = "cotton", source: str = "mesh",
                  stiffness_rule: str = "edge-area", uv: np.ndarray | None = None) -> ClothData:
    """A cloth from any manifold triangle mesh (vertices (V,3) [m], triangles (T,3)).

    Structural springs on every edge; bending springs by the material's model (bend_springs: across every interior
    edge between its two opposite vertices with k = bend / L0^2, or the quadratic energy's pairs); masses density *
    (adjacent area) / 3. No shear springs: the triangle edges already resist shear. The structural constant follows
    `stiffness_rule`:
      "edge-area": k = stretch * A_e / L0^2 (A_e = area of the triangles sharing the edge; Van Gelder);
      "isotropic": k = sum over the edge's triangles t of 3 E A_t / (sum of t's squared edge lengths),
                   E = material.sheet_modulus. Every edge of a right isosceles (4-8) or an equilateral
                   lattice then gets the same constant, which makes the lattice isotropic with Young's
                   modulus exactly E and Poisson's ratio 1/3 (the Cauchy relation of central springs),
                   so the 45-degree-rotated odd 4-8 levels are the same material as the even ones.
                   For a material whose membrane is "orthotropic", the square grid's sheet along the axes of
                   `uv` ((V,2) [m], the pattern's; default: the vertices' first two coordinates) instead:
                   orthotropic_edges.
    """
    mat = as_material(material)
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    validate_triangle_mesh(v, t, source)
    area = triangle_areas(v, t)
    mass = np.zeros(len(v))
    np.add.at(mass, t.reshape(-1), np.repeat(area / 3.0, 3))
    if np.any(mass == 0):
        raise ValueError(f"{source}: {int(np.sum(mass == 0))} vertices belong to no triangle")
    mass *= mat.density
    edges, face_edge, _ = edges_of(t)
    L = np.linalg.norm(v[edges[:, 1]] - v[edges[:, 0]], axis=1)
    if stiffness_rule == "isotropic" and mat.membrane == "orthotropic":
        grain = v[:, :2] if uv is None else np.asarray(uv, dtype=np.float64)
        k_edge = orthotropic_edges(grain, t, len(edges), face_edge, mat)
    elif stiffness_rule == "edge-area":
        edge_area = np.zeros(len(edges))
        np.add.at(edge_area, face_edge.reshape(-1), np.repeat(area, 3))
        k_edge = mat.stretch * edge_area / L**2
    elif stiffness_rule == "isotropic":
        per_triangle = 3.0 * mat.sheet_modulus * area / (L[face_edge] ** 2).sum(axis=1)
        k_edge = np.zeros(len(edges))
        np.add.at(k_edge, face_edge.reshape(-1), np.repeat(per_triangle, 3))
    else:
        raise ValueError(f"stiffness_rule must be 'edge-area' or 'isotropic', got {stiffness_rule!r}")
    bend_pairs, k_bend, bend_kind = bend_springs(t, v, mat)
    springs, rest, stiffness, damping, kind = spring_arrays(
        [edges, bend_pairs], [k_edge, k_bend], [SpringKind.STRUCTURAL, bend_kind], v, mat.damping)
    return ClothData(v, mass, springs, rest, stiffness, damping, kind, t, viscosity=mat.viscosity)
