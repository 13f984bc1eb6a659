"""ClothBuilder: grids, triangle meshes and spring chains -> ClothData (numpy) -> Model (Taichi fields).

Rest lengths always come from the rest (pattern or initial) positions, never from a deformed shape.
Masses are lumped from area, so the total mass is exactly density * area.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from pathlib import Path

import numpy as np

from .material import Material, material as as_material
from .mesh import edges_of, interior_edge_opposites, load_triangle_mesh, triangle_areas, validate_triangle_mesh


class SpringKind(IntEnum):
    """What a spring models. Stored as int32 in Model.spring_kind."""

    STRUCTURAL = 0
    SHEAR = 1
    BEND = 2
    SEAM = 3


@dataclass
class ClothData:
    """A cloth before it lives in Taichi fields (all numpy, SI units).

    positions:   (P,3) float64 [m]  initial positions (also the rest shape unless rest_positions is set)
    mass:        (P,)  float64 [kg]
    springs:     (S,2) int64        particle indices (a, b)
    rest_length: (S,)  float64 [m]
    stiffness:   (S,)  float64 [N/m]
    damping:     (S,)  float64 [N*s/m]
    kind:        (S,)  int64        SpringKind
    triangles:   (T,3) int64        for rendering, normals and wind (may be empty for a chain)
    grid_shape:  (nu, nv) for grids (particle i + nu*j), else None
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

    @property
    def n_particles(self) -> int:
        return len(self.positions)

    @property
    def n_springs(self) -> int:
        return len(self.springs)

    def count(self, kind: SpringKind) -> int:
        return int(np.count_nonzero(self.kind == kind))


def _spring_arrays(pairs: list[np.ndarray], ks: list[np.ndarray], kinds: list[int], positions, damping_ratio):
    springs = np.concatenate(pairs).astype(np.int64)
    stiffness = np.concatenate(ks).astype(np.float64)
    kind = np.concatenate([np.full(len(p), kd, np.int64) for p, kd in zip(pairs, kinds)])
    rest = np.linalg.norm(positions[springs[:, 1]] - positions[springs[:, 0]], axis=1)
    return springs, rest, stiffness, damping_ratio * stiffness, kind


_PLANES = {"xy": (0, 1), "xz": (0, 2), "yz": (1, 2), "zy": (2, 1)}


class ClothBuilder:
    """Builds ClothData from a source. All methods are static; `Model(data)` turns the result into fields."""

    @staticmethod
    def grid(size=(1.0, 1.0), resolution=(32, 32), material: str | Material = "cotton",
             center=(0.0, 0.0, 0.0), plane: str = "xy") -> ClothData:
        """A rectangular sheet of size (W, H) [m] with (nu, nv) particles, centred at `center` [m], lying in
        `plane` ("xy": u along +x, v along +y, i.e. hanging; "xz": horizontal). Particle (i, j) is i + nu*j.

        Springs: structural on the quad edges, shear on both quad diagonals, bend between particles two
        apart along u and v. Triangles split each quad along alternating diagonals (for normals/rendering).
        """
        mat = as_material(material)
        nu, nv = int(resolution[0]), int(resolution[1])
        W, H = float(size[0]), float(size[1])
        if nu < 2 or nv < 2:
            raise ValueError(f"grid resolution must be at least 2x2 particles, got {nu}x{nv}")
        if W <= 0 or H <= 0:
            raise ValueError(f"grid size must be positive [m], got {W}x{H}")
        if plane not in _PLANES:
            raise ValueError(f"grid plane must be one of {', '.join(_PLANES)}, got {plane!r}")
        du, dv = W / (nu - 1), H / (nv - 1)
        iu, jv = np.meshgrid(np.arange(nu), np.arange(nv), indexing="xy")  # (nv, nu)
        idx = (iu + nu * jv).astype(np.int64)
        positions = np.zeros((nu * nv, 3))
        a0, a1 = _PLANES[plane]
        positions[:, a0] = (iu.reshape(-1) * du - W / 2)
        positions[:, a1] = (jv.reshape(-1) * dv - H / 2)
        positions += np.asarray(center, dtype=np.float64)

        # area-lumped mass: interior rho*du*dv, halved on edges, quartered at corners
        wu = np.ones(nu); wu[[0, -1]] = 0.5
        wv = np.ones(nv); wv[[0, -1]] = 0.5
        mass = (mat.density * du * dv * np.outer(wv, wu)).reshape(-1)

        # structural: k = stretch * (strip width) / length; boundary strips are half as wide
        h_pairs = np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1)
        h_width = np.repeat(wv, nu - 1) * dv
        v_pairs = np.stack([idx[:-1, :].ravel(), idx[1:, :].ravel()], 1)
        v_width = np.tile(wu, nv - 1) * du
        k_h = mat.stretch * h_width / du
        k_v = mat.stretch * v_width / dv
        # shear: both diagonals of every cell, k = shear * 2 * cell area / diagonal^2 (= shear on squares)
        d1 = np.stack([idx[:-1, :-1].ravel(), idx[1:, 1:].ravel()], 1)
        d2 = np.stack([idx[:-1, 1:].ravel(), idx[1:, :-1].ravel()], 1)
        k_sh = mat.shear * 2 * du * dv / (du * du + dv * dv)
        # bend: skip-one springs along u and v, k = bend / L0^2
        b_u = np.stack([idx[:, :-2].ravel(), idx[:, 2:].ravel()], 1)
        b_v = np.stack([idx[:-2, :].ravel(), idx[2:, :].ravel()], 1)
        pairs = [h_pairs, v_pairs, d1, d2, b_u, b_v]
        ks = [k_h, k_v, np.full(len(d1), k_sh), np.full(len(d2), k_sh),
              np.full(len(b_u), mat.bend / (2 * du) ** 2), np.full(len(b_v), mat.bend / (2 * dv) ** 2)]
        kinds = [SpringKind.STRUCTURAL, SpringKind.STRUCTURAL, SpringKind.SHEAR, SpringKind.SHEAR,
                 SpringKind.BEND, SpringKind.BEND]
        springs, rest, stiffness, damping, kind = _spring_arrays(pairs, ks, kinds, positions, mat.damping)

        # triangles with alternating diagonals, consistently oriented (normal along +u x +v)
        c00, c10 = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
        c01, c11 = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
        even = ((iu[:-1, :-1] + jv[:-1, :-1]) % 2 == 0).ravel()
        t_even = np.concatenate([np.stack([c00, c10, c11], 1), np.stack([c00, c11, c01], 1)])
        t_odd = np.concatenate([np.stack([c00, c10, c01], 1), np.stack([c10, c11, c01], 1)])
        mask = np.concatenate([even, even])
        triangles = np.where(mask[:, None], t_even, t_odd)
        return ClothData(positions, mass, springs, rest, stiffness, damping, kind, triangles, (nu, nv))

    @staticmethod
    def multilevel_grid(size=(1.0, 1.0), base_cells=(4, 4), levels: int = 5, material: str | Material = "cotton",
                        center=(0.0, 0.0, 0.0), plane: str = "xy", start_level: int = 0):
        """A W x H [m] rectangle as a multilevel 4-8 hierarchy (a MultilevelCloth: one ClothData per level):
        a base of (nx, ny) cells with alternating diagonals, refined levels-1 times by bisecting every
        triangle across its hypotenuse. A Scene starts it on `start_level` (0-based) and refines as it settles.
        See taichi_cloth.multilevel_cloth."""
        from .multilevel_cloth import multilevel_grid

        return multilevel_grid(size, base_cells, levels, material, center, plane, start_level)

    @staticmethod
    def triangle_mesh(vertices, triangles, material: str | Material = "cotton", source: str = "mesh",
                      stiffness_rule: str = "edge-area") -> ClothData:
        """A cloth from any manifold triangle mesh (vertices (V,3) [m], triangles (T,3)).

        Structural springs on every edge; bend springs across every interior edge between its two opposite
        vertices with k = bend / L0^2; masses density * (adjacent area) / 3. No shear springs: the triangle
        edges already resist shear. The structural constant follows `stiffness_rule`:
          "edge-area": k = stretch * A_e / L0^2 (A_e = area of the triangles sharing the edge; Van Gelder);
          "isotropic": k = sum over the edge's triangles t of 3 E A_t / (sum of t's squared edge lengths),
                       E = material.sheet_modulus. Every edge of a right isosceles (4-8) or an equilateral
                       lattice then gets the same constant, which makes the lattice isotropic with Young's
                       modulus exactly E and Poisson's ratio 1/3 (the Cauchy relation of central springs),
                       so the 45-degree-rotated odd 4-8 levels are the same material as the even ones.
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
        if stiffness_rule == "edge-area":
            edge_area = np.zeros(len(edges))
            np.add.at(edge_area, face_edge.reshape(-1), np.repeat(area, 3))
            k_edge = mat.stretch * edge_area / L**2
        elif stiffness_rule == "isotropic":
            per_triangle = 3.0 * mat.sheet_modulus * area / (L[face_edge] ** 2).sum(axis=1)
            k_edge = np.zeros(len(edges))
            np.add.at(k_edge, face_edge.reshape(-1), np.repeat(per_triangle, 3))
        else:
            raise ValueError(f"stiffness_rule must be 'edge-area' or 'isotropic', got {stiffness_rule!r}")
        bend_pairs = interior_edge_opposites(t)
        Lb = np.linalg.norm(v[bend_pairs[:, 1]] - v[bend_pairs[:, 0]], axis=1) if len(bend_pairs) else np.zeros(0)
        springs, rest, stiffness, damping, kind = _spring_arrays(
            [edges, bend_pairs], [k_edge, mat.bend / np.maximum(Lb, 1e-12) ** 2],
            [SpringKind.STRUCTURAL, SpringKind.BEND], v, mat.damping)
        return ClothData(v, mass, springs, rest, stiffness, damping, kind, t)

    @staticmethod
    def mesh_file(path: str | Path, material: str | Material = "cotton", scale: float = 1.0,
                  translate=(0.0, 0.0, 0.0)) -> ClothData:
        """A cloth from a mesh file (OBJ, PLY, STL, ...) read with trimesh; `scale` multiplies the file's
        coordinates into metres, then `translate` [m] is added."""
        vertices, triangles = load_triangle_mesh(path, scale, translate)
        return ClothBuilder.triangle_mesh(vertices, triangles, material, source=str(path))

    @staticmethod
    def chain(n: int, length: float, mass: float, stiffness: float, damping: float = 0.0,
              top=(0.0, 0.0, 0.0), direction=(0.0, -1.0, 0.0)) -> ClothData:
        """A chain of `n` particles of `mass` [kg] each, joined by n-1 structural springs of constant
        `stiffness` [N/m] and damping coefficient `damping` [N*s/m], total rest `length` [m], laid from
        `top` along `direction`."""
        if n < 2:
            raise ValueError("a chain needs at least 2 particles")
        d = np.asarray(direction, dtype=np.float64)
        d /= np.linalg.norm(d)
        positions = np.asarray(top, dtype=np.float64) + np.outer(np.linspace(0.0, length, n), d)
        springs = np.stack([np.arange(n - 1), np.arange(1, n)], 1).astype(np.int64)
        S = n - 1
        return ClothData(positions, np.full(n, float(mass)), springs, np.full(S, length / (n - 1)),
                         np.full(S, float(stiffness)), np.full(S, float(damping)),
                         np.full(S, int(SpringKind.STRUCTURAL), np.int64))
