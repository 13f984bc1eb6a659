"""ClothBuilder: grids, triangle meshes, mesh files, spring chains and 4-8 hierarchies -> ClothData (numpy, see
taichi_cloth.cloth) -> Model (Taichi fields).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from clothbase.meshes import load_triangle_mesh

from .cloth import PLANES, ClothData, SpringKind, bend_springs, mesh_cloth, spring_arrays
from .guards import check_grid
from .material import Material
from .material import material as as_material
from .multilevel_cloth import MultilevelCloth, multilevel_grid


class ClothBuilder:
    """Builds ClothData from a source. All methods are static; `Model(data)` turns the result into fields."""

    @staticmethod
    def grid(size=(1.0, 1.0), resolution=(32, 32), material: str | Material = "cotton",
             center=(0.0, 0.0, 0.0), plane: str = "xy") -> ClothData:
        """A rectangular sheet of size (W, H) [m] with (nu, nv) particles, centred at `center` [m], lying in
        `plane` ("xy": u along +x, v along +y, i.e. hanging; "xz": horizontal). Particle (i, j) is i + nu*j.

        A grid larger than the machine's memory is refused (SceneError) before anything is allocated
        (taichi_cloth.guards.check_grid).

        Springs: structural on the quad edges, shear on both quad diagonals, bend between particles two
        apart along u and v (the quadratic energy on the triangles when the material's bending is "quadratic").
        Triangles split each quad along alternating diagonals (for normals/rendering).
        """
        mat = as_material(material)
        nu, nv = int(resolution[0]), int(resolution[1])
        W, H = float(size[0]), float(size[1])
        if nu < 2 or nv < 2:
            raise ValueError(f"grid resolution must be at least 2x2 particles, got {nu}x{nv}")
        if W <= 0 or H <= 0:
            raise ValueError(f"grid size must be positive [m], got {W}x{H}")
        if plane not in PLANES:
            raise ValueError(f"grid plane must be one of {', '.join(PLANES)}, got {plane!r}")
        check_grid((nu, nv), "ClothBuilder.grid resolution")  # before numpy allocates any of it
        du, dv = W / (nu - 1), H / (nv - 1)
        iu, jv = np.meshgrid(np.arange(nu), np.arange(nv), indexing="xy")  # (nv, nu)
        idx = (iu + nu * jv).astype(np.int64)
        positions = np.zeros((nu * nv, 3))
        a0, a1 = PLANES[plane]
        positions[:, a0] = (iu.reshape(-1) * du - W / 2)
        positions[:, a1] = (jv.reshape(-1) * dv - H / 2)
        positions += np.asarray(center, dtype=np.float64)

        # area-lumped mass: interior rho*du*dv, halved on edges, quartered at corners
        wu = np.ones(nu)
        wu[[0, -1]] = 0.5
        wv = np.ones(nv)
        wv[[0, -1]] = 0.5
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
        # triangles with alternating diagonals, consistently oriented (normal along +u x +v)
        c00, c10 = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
        c01, c11 = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
        even = ((iu[:-1, :-1] + jv[:-1, :-1]) % 2 == 0).ravel()
        t_even = np.concatenate([np.stack([c00, c10, c11], 1), np.stack([c00, c11, c01], 1)])
        t_odd = np.concatenate([np.stack([c00, c10, c01], 1), np.stack([c10, c11, c01], 1)])
        mask = np.concatenate([even, even])
        triangles = np.where(mask[:, None], t_even, t_odd)
        # bend: skip-one springs along u and v, k = bend / L0^2; or the quadratic energy on the triangles
        if mat.bending == "quadratic":
            b_pairs, k_b, b_kind = bend_springs(triangles, positions, mat)
            bends, bend_ks, bend_kinds = [b_pairs], [k_b], [b_kind]
        else:
            b_u = np.stack([idx[:, :-2].ravel(), idx[:, 2:].ravel()], 1)
            b_v = np.stack([idx[:-2, :].ravel(), idx[2:, :].ravel()], 1)
            bends = [b_u, b_v]
            bend_ks = [np.full(len(b_u), mat.bend / (2 * du) ** 2), np.full(len(b_v), mat.bend / (2 * dv) ** 2)]
            bend_kinds = [SpringKind.BEND, SpringKind.BEND]
        pairs = [h_pairs, v_pairs, d1, d2] + bends
        ks = [k_h, k_v, np.full(len(d1), k_sh), np.full(len(d2), k_sh)] + bend_ks
        kinds = [SpringKind.STRUCTURAL, SpringKind.STRUCTURAL, SpringKind.SHEAR, SpringKind.SHEAR] + bend_kinds
        springs, rest, stiffness, damping, kind = spring_arrays(pairs, ks, kinds, positions, mat.damping)

        return ClothData(positions, mass, springs, rest, stiffness, damping, kind, triangles, (nu, nv),
                         viscosity=mat.viscosity)

    @staticmethod
    def multilevel_grid(size=(1.0, 1.0), base_cells=(4, 4), levels: int = 5, material: str | Material = "cotton",
                        center=(0.0, 0.0, 0.0), plane: str = "xy", start_level: int = 0) -> MultilevelCloth:
        """A W x H [m] rectangle as a multilevel 4-8 hierarchy (a MultilevelCloth: one ClothData per level):
        a base of (nx, ny) cells with alternating diagonals, refined levels-1 times by bisecting every
        triangle across its hypotenuse. A Scene starts it on `start_level` (0-based) and refines as it settles.
        See taichi_cloth.multilevel_cloth."""
        return multilevel_grid(size, base_cells, levels, material, center, plane, start_level)

    @staticmethod
    def triangle_mesh(vertices, triangles, material: str | Material = "cotton", source: str = "mesh",
                      stiffness_rule: str = "edge-area") -> ClothData:
        """A cloth from any manifold triangle mesh (vertices (V,3) [m], triangles (T,3)); see
        taichi_cloth.cloth.mesh_cloth for the springs, masses and the two stiffness rules."""
        return mesh_cloth(vertices, triangles, material, source, stiffness_rule)

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
