"""A cloth on a multilevel 4-8 hierarchy (Hsiao 2006 section 2.2): one ClothData per level.

Every level is built from the 2D rest (pattern) coordinates, never from a deformed shape:
- springs: structural on the triangle legs, shear on the hypotenuses (the diamond diagonals), bend across
  every interior edge; spring constants by the isotropic rule of taichi_cloth.cloth.mesh_cloth, so the odd
  (45-degree) and even levels are the same material (Young's modulus material.sheet_modulus, Poisson 1/3);
- masses: area-lumped, density * sum of adjacent areas / 3, rescaled so that every level carries exactly
  the same total mass (for a rectangle the areas already agree; a resampled outline differs slightly).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clothbase.meshes import rows_in
from multilevel.hierarchy import Hierarchy48, signed_areas

from .cloth import ClothData, SpringKind, in_plane, mesh_cloth
from .guards import check_multilevel_grid
from .material import Material
from .material import material as as_material


@dataclass
class MultilevelCloth:
    """hierarchy: the multilevel.Hierarchy48 (levels of uv, triangles and prolongation tables);
    levels: ClothData per level (levels[0] coarsest); start_level: the level a scene starts on;
    material, center, plane: how the levels were built (a local refinement builds its meshes the same way)."""

    hierarchy: object
    levels: list[ClothData]
    start_level: int = 0
    material: Material | None = None
    center: tuple = (0.0, 0.0, 0.0)
    plane: str = "xy"

    def build(self, level) -> ClothData:
        """ClothData of another mesh of this cloth (a locally refined level), with the same total mass."""
        return level_cloth(level, self.material, self.center, self.plane, float(self.levels[-1].mass.sum()))

    def __post_init__(self):
        if not 0 <= self.start_level < len(self.levels):
            raise ValueError(f"start_level must lie in 0..{len(self.levels) - 1}, got {self.start_level}")

    @property
    def capacity(self) -> tuple[int, int, int]:
        """(particles, springs, triangles): the largest of each over the levels (the finest, for 4-8)."""
        return (max(d.n_particles for d in self.levels), max(d.n_springs for d in self.levels),
                max(len(d.triangles) for d in self.levels))

    @property
    def n_levels(self) -> int:
        return len(self.levels)


def level_cloth(level, material: str | Material, center=(0.0, 0.0, 0.0), plane: str = "xy",
                total_mass: float | None = None) -> ClothData:
    """ClothData of one hierarchy level: uv [m] placed in `plane` around `center` [m]; masses rescaled
    to `total_mass` [kg] when given."""
    positions = in_plane(level.uv, plane, center)
    data = mesh_cloth(positions, level.triangles, material, source="4-8 level", stiffness_rule="isotropic")
    if total_mass is not None:
        data.mass *= total_mass / data.mass.sum()
    # the hypotenuses of the regular triangles are the diamond diagonals: the "shear" springs of the level
    regular = getattr(level, "regular", None)
    tri = level.triangles if regular is None else level.triangles[regular]
    hyp = np.sort(tri[:, :2], axis=1)
    pairs = np.sort(data.springs, axis=1)
    structural = data.kind == SpringKind.STRUCTURAL
    is_hyp = rows_in(pairs, hyp) & structural
    data.kind[is_hyp] = SpringKind.SHEAR
    return data


def multilevel_cloth(hierarchy, material: str | Material = "cotton", center=(0.0, 0.0, 0.0), plane: str = "xy",
                     start_level: int = 0) -> MultilevelCloth:
    """ClothData for every level of `hierarchy`, all with the finest level's total mass."""
    mat = as_material(material)
    finest = hierarchy.levels[-1]
    total = mat.density * float(signed_areas(finest.uv, finest.triangles).sum())
    levels = [level_cloth(L, mat, center, plane, total) for L in hierarchy.levels]
    return MultilevelCloth(hierarchy, levels, start_level, mat, tuple(center), plane)


def _whole(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def multilevel_grid(size=(1.0, 1.0), base_cells=(4, 4), levels: int = 5, material: str | Material = "cotton",
                    center=(0.0, 0.0, 0.0), plane: str = "xy", start_level: int = 0) -> MultilevelCloth:
    """A W x H [m] rectangle as a 4-8 hierarchy: base grid of (nx, ny) cells with alternating diagonals,
    refined levels-1 times by bisection. Level L (0-based) has spacing (W/nx) / 2^(L/2). A hierarchy larger than
    the machine's memory is refused (SceneError) before anything is allocated (taichi_cloth.guards)."""
    if _whole(levels) and len(base_cells) == 2 and all(_whole(c) and c >= 1 for c in base_cells) and levels >= 1:
        check_multilevel_grid(base_cells, levels, "ClothBuilder.multilevel_grid")  # the hierarchy checks the rest
    return multilevel_cloth(Hierarchy48.rectangle(size, base_cells, levels), material, center, plane, start_level)
