"""Errors of the collision package (kept here so that collision never imports taichi_cloth)."""


class MeshError(ValueError):
    """A mesh is unusable (missing file, empty, non-manifold, NaN vertices, degenerate faces): the message
    names the file and what is wrong. taichi_cloth re-exports this class as taichi_cloth.MeshError."""
