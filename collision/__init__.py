"""Collision (seed 000 section 2.3, seed 002 section 3.2.3, seed 004 eqs. 5 and 15).

- MeshCollider: a triangle body (the mannequin) binned in a VoxelGrid built by Taichi kernels, with fuzzy
  (mu-ranked) continuous particle-triangle tests, proximity contact and Coulomb friction;
- PrimitiveColliders: spheres (seed 002's push-out), capsules and planes; mannequin_standin(): a sphere and
  capsule body sized like the mannequin, for fast tests;
- meshes: loading, validation and repair of triangle meshes; mannequin: the shipped CC0 body.

Works on plain Taichi fields and numpy arrays and never imports taichi_cloth, so it is testable alone;
taichi_cloth.Scene composes it when a scene names [[colliders]]. Importing it compiles nothing.
"""
from .body import MeshCollider
from .errors import MeshError
from .grid import VoxelGrid
from .meshes import load_triangle_mesh, repair_triangle_mesh, validate_triangle_mesh
from .primitives import PrimitiveColliders, mannequin_standin

__all__ = ["MeshCollider", "MeshError", "PrimitiveColliders", "VoxelGrid", "load_triangle_mesh",
           "mannequin_standin", "repair_triangle_mesh", "validate_triangle_mesh"]
