"""A garment on its 4-8 levels (Hsiao 2006 section 2.2): sewn on a coarse level, refined as the drape settles.

The pieces are meshed once as outline hierarchies (garment.outline), so every level pairs its seams (the sides
of a seam have equal counts on every level). Per level there is a GarmentCloth (the pieces apart, with that level's
seam springs: what the sewing works on, on the start level) and the same cloth with its seams merged (what the
refiner switches between once the seams are joined). The merge is the sewing's own (sewing.merge_seams), applied to
every level, and the prolongation tables of the pieces are carried over to the merged numbering: the parents of a
merged vertex are the merged parents of any of its members. That is consistent because the outline tables keep
seam partners paired: a boundary sample of level k+1 copies, or halves between, samples of level k along its
segment, and so does its partner along the partner's segment, whose samples are merged with them on level k. So a
closed seam stays closed through a switch, and the levels stay nested (the prolongation of level k reproduces
level k's positions at the vertices level k+1 inherits); build_levels checks both.

The merged levels form one MultilevelCloth (taichi_cloth.multilevel_cloth): the Refiner and the integrators that
take 4-8 levels see the same hierarchy as for a sheet.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clothbase.meshes import edges_of
from multilevel.hierarchy import Hierarchy48, Level, identity_tables

from ..body.landmarks import Body
from ..cloth import ClothData
from ..errors import PatternError
from ..multilevel_cloth import MultilevelCloth
from .garment import GarmentCloth, GarmentLevelPlan, GarmentSpec, plan_garment_levels
from .mesh import level_mesh
from .sewing import merge_seams


@dataclass
class GarmentLevel:
    """One level of a MultilevelGarment.

    garment:    GarmentCloth: the pieces of this level apart, with their seam springs
    merged:     ClothData: the same cloth with every seam pair merged into one particle (at the placed positions)
    current_of: (P_k,) int64 the merged particle of every particle of `garment`
    """

    garment: GarmentCloth
    merged: ClothData
    current_of: np.ndarray


@dataclass
class MultilevelGarment:
    """A garment meshed on several 4-8 levels, run coarse to fine.

    levels:      GarmentLevel per level (levels[0] the coarsest)
    cloth:       MultilevelCloth of the merged levels (its hierarchy: their prolongation tables)
    start_level: the level (0-based) the pieces are placed and sewn on
    plan:        the GarmentLevelPlan the levels were assembled from (a local refinement assembles more)
    """

    levels: list
    cloth: MultilevelCloth
    start_level: int
    plan: GarmentLevelPlan | None = None

    @property
    def spec(self) -> GarmentSpec:
        return self.garment.spec

    @property
    def garment(self) -> GarmentCloth:
        """The GarmentCloth that is sewn: the start level's."""
        return self.levels[self.start_level].garment

    @property
    def n_levels(self) -> int:
        return len(self.levels)

    @property
    def capacity(self) -> tuple[int, int, int]:
        """(particles, springs, triangles) the model's fields need: the pieces apart on the start level, or a merged
        level, whichever is largest."""
        d = self.garment.data
        return tuple(max(a, b) for a, b in zip((d.n_particles, d.n_springs, len(d.triangles)), self.cloth.capacity))

    @property
    def local_capacity(self) -> tuple[int, int, int]:
        """The capacity for local refinement (taichi_cloth.garment.local): a locally refined mesh has at most the
        finest level's particles and triangles, so at most its edges (the same surface: Euler), but its Delaunay
        triangles may give more bend springs than the finest level's: one structural and at most one bend spring
        per edge."""
        edges = len(edges_of(self.cloth.levels[-1].triangles)[0])
        p, s, t = self.capacity
        return p, max(s, 2 * edges), t


def multilevel_garment(spec: GarmentSpec, body: Body | None = None, seam_stiffness: float | None = None,
                       start_level: int = 0) -> MultilevelGarment:
    """Mesh `spec` on its `levels` 4-8 levels (spec.levels >= 2), place and pair every level, merge every level's
    seams and carry the prolongation tables over (see the module docstring). start_level: 0-based, the level the
    pieces are sewn on. PatternError when spec.levels < 2 or start_level is out of range."""
    if spec.levels < 2:
        raise PatternError(f"garment {spec.name!r}: coarse-to-fine needs levels >= 2 in the garment, got "
                           f"{spec.levels}")
    if not 0 <= start_level < spec.levels:
        raise PatternError(f"garment {spec.name!r}: start level {start_level + 1} must lie in 1..{spec.levels}")
    plan = plan_garment_levels(spec, body, seam_stiffness)
    garments = [plan.assemble([level_mesh(m, k) for m in plan.finest]) for k in range(spec.levels)]
    levels, tables = [], []
    for k, g in enumerate(garments):
        zero = np.zeros_like(g.data.positions)
        merged, _, _, current_of = merge_seams(g.data, g, g.data.positions, zero)
        levels.append(GarmentLevel(g, merged, current_of))
        tables.append(_merged_level(g, merged, current_of, levels[k - 1] if k else None))
    cloth = MultilevelCloth(Hierarchy48(tables), [lev.merged for lev in levels], start_level, garments[-1].material)
    return MultilevelGarment(levels, cloth, start_level, plan)


def _merged_level(g: GarmentCloth, merged: ClothData, current_of: np.ndarray, coarser: GarmentLevel | None) -> Level:
    """The hierarchy Level of a merged garment level: its triangles, and the prolongation tables from the merged
    level above (identity on the coarsest). uv: each merged particle's pattern point in one of its pieces (a merged
    seam particle has one in each; the tables, not uv, place the particles of a switch)."""
    n = merged.n_particles
    first = np.full(n, -1, np.int64)
    first[current_of[::-1]] = np.arange(len(current_of))[::-1]  # a member of every merged particle: the first
    uv = g.rest_uv()[first]
    diamonds = np.full((n, 4), -1, np.int64)
    if coarser is None:
        parents, weights = identity_tables(n)
        return Level(uv, merged.triangles, parents, weights, diamonds)
    # the pieces' own tables, in the original numbering of both levels
    piece_parents, piece_weights = [], []
    for m, off in zip(g.meshes, coarser.garment.offsets):
        lev = m.hierarchy.levels[m.level]
        piece_parents.append(np.where(lev.parents >= 0, lev.parents + off, -1))
        piece_weights.append(lev.weights)
    P, W = np.concatenate(piece_parents), np.concatenate(piece_weights)
    P = np.where(P >= 0, coarser.current_of[np.maximum(P, 0)], -1)  # parents in the coarser merged numbering
    parents, weights = P[first], W[first]
    # every member of a merged particle must be placed where its representative is: the seams stay closed
    probe = np.random.default_rng(0).standard_normal(coarser.merged.n_particles)
    of_members = (np.where(P >= 0, probe[np.maximum(P, 0)], 0.0) * W).sum(1)
    of_merged = (np.where(parents >= 0, probe[np.maximum(parents, 0)], 0.0) * weights).sum(1)
    if np.abs(of_members - of_merged[current_of]).max() > 1e-9:
        raise PatternError(f"garment {g.spec.name!r}: the seams of level {g.meshes[0].level + 1} do not prolong "
                           "from the level above (a seam's partners have different tables)")
    return Level(uv, merged.triangles, parents, weights, diamonds)
