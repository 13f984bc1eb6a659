"""Collision (Hsiao 2006 section 2.3, Zhang et al. 2017 section 3.2.3, Fan et al. 1998 eqs. 5 and 15).

- MeshCollider: a triangle body (the mannequin) binned in a VoxelGrid built by Taichi kernels, with fuzzy
  (mu-ranked) continuous particle-triangle tests, proximity contact and Coulomb friction;
- PrimitiveColliders: spheres (Zhang et al. 2017's push-out), capsules and planes; mannequin_standin(): a sphere and
  capsule body sized like the mannequin, for fast tests;
- mannequin: the shipped CC0 body (mesh loading, validation and repair live in clothbase.meshes).

Works on plain Taichi fields and numpy arrays and never imports taichi_cloth, so it is testable alone;
taichi_cloth.Scene composes it when a scene names [[colliders]]. Importing it compiles nothing.
"""
from .body import MeshCollider
from .grid import VoxelGrid
from .primitives import PrimitiveColliders, mannequin_standin

__all__ = ["MeshCollider", "PrimitiveColliders", "VoxelGrid", "mannequin_standin"]
