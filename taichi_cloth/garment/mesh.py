"""Meshing of pattern pieces: particles and triangles inside the outline, boundary sampled at a chosen spacing.

A piece is meshed by the multilevel outline mesher (garment.outline): a 4-8 interior lattice plus a
Delaunay band along the boundary, with every outline segment resampled at uniform arc length to an exact
number of intervals. Exact counts are what let a seam pair its two sides point for point; the 4-8 interior is
what makes the piece a level of a multilevel hierarchy when a scene asks for levels (`levels` > 1).

The mesh-quality check refuses inverted triangles and slivers with one message naming the piece.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from multilevel.hierarchy import signed_areas

from ..errors import PatternError
from .outline import OutlineHierarchy, outline_hierarchy
from .pattern import PatternPiece

MIN_ANGLE_DEG = 10.0  # below this a triangle is a sliver: its springs are nearly collinear and stiff in one direction


@dataclass
class MeshQuality:
    """min_angle [deg], max_aspect (longest edge / shortest altitude), inverted (count of triangles with
    non-positive signed area in uv), slivers (count with an angle below the threshold), n_triangles."""

    min_angle: float
    max_aspect: float
    inverted: int
    slivers: int
    n_triangles: int


@dataclass
class PieceMesh:
    """One meshed pattern piece.

    piece:             the PatternPiece
    uv:                (n, 2) float64 [m] rest (pattern) coordinates of the particles
    triangles:         (t, 3) int64, counter-clockwise in uv (seen from the outside of the garment)
    boundary_segments: list, per outline segment, of int64 vertex indices along it (corners included), in the
                       segment's direction
    boundary_loop:     (m,) int64 the boundary vertices in loop order
    quality:           MeshQuality
    hierarchy:         the OutlineHierarchy it is a level of, and `level` (0-based) which one
    """

    piece: PatternPiece
    uv: np.ndarray
    triangles: np.ndarray
    boundary_segments: list
    boundary_loop: np.ndarray
    quality: MeshQuality
    hierarchy: OutlineHierarchy
    level: int

    @property
    def n_vertices(self) -> int:
        return len(self.uv)

    @property
    def area(self) -> float:
        """Area of the triangles [m^2] (the sampled outline's area)."""
        return float(signed_areas(self.uv, self.triangles).sum())


def mesh_quality(uv: np.ndarray, triangles: np.ndarray, min_angle: float = MIN_ANGLE_DEG) -> MeshQuality:
    """Angles, aspect ratios and orientation of 2D triangles (uv (n,2) [m], triangles (t,3))."""
    p = uv[triangles]
    e = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 1], p[:, 0] - p[:, 2]], 1)  # (t,3,2) edges
    length = np.linalg.norm(e, axis=2)
    area = signed_areas(uv, triangles)
    # the angle at corner k lies between edge k and the reversed edge k-1
    a, b = e, -np.roll(e, 1, axis=1)
    cos = (a * b).sum(2) / np.maximum(length * np.roll(length, 1, axis=1), 1e-300)
    angles = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    altitude = 2 * np.abs(area) / np.maximum(length.max(1), 1e-300)
    aspect = length.max(1) / np.maximum(altitude, 1e-300)
    return MeshQuality(min_angle=float(angles.min()) if len(triangles) else 0.0,
                       max_aspect=float(aspect.max()) if len(triangles) else 0.0,
                       inverted=int(np.count_nonzero(area <= 0)),
                       slivers=int(np.count_nonzero(angles.min(1) < min_angle)),
                       n_triangles=len(triangles))


def check_quality(name: str, quality: MeshQuality, min_angle: float = MIN_ANGLE_DEG) -> None:
    """PatternError naming the piece if its mesh has inverted triangles or slivers."""
    if quality.inverted:
        raise PatternError(f"piece {name!r}: the mesh has {quality.inverted} inverted triangles")
    if quality.slivers:
        raise PatternError(f"piece {name!r}: the mesh has {quality.slivers} sliver triangles (smallest angle "
                           f"{quality.min_angle:.1f} deg < {min_angle:g} deg); use a smaller spacing or smooth the "
                           "outline's sharp corners")


def mesh_piece(piece: PatternPiece, spacing: float, segment_counts=None, levels: int = 1, level: int | None = None,
               min_angle: float = MIN_ANGLE_DEG, tolerance: float | None = None) -> PieceMesh:
    """Mesh `piece` with boundary spacing `spacing` [m] on the finest of `levels` 4-8 levels (or on `level`).

    segment_counts: intervals per outline segment on level 0 (seam partners need equal counts; see
                    seams.plan_counts); default round(length / spacing). The finest level has
                    count * 2**((levels-1)//2) intervals per segment, so `spacing` is level 0's spacing.
    tolerance:      chord tolerance [m] for sampling curved segments (default spacing / 200)
    """
    if not (isinstance(spacing, (int, float)) and np.isfinite(spacing) and spacing > 0):
        raise PatternError(f"piece {piece.name!r}: spacing must be a positive length [m], got {spacing!r}")
    piece.validate()
    polylines = piece.polylines(tolerance if tolerance is not None else spacing / 200.0)
    try:
        hierarchy = outline_hierarchy(polylines, levels, spacing, segment_counts)
    except ValueError as err:
        raise PatternError(f"piece {piece.name!r}: {err}") from None
    k = levels - 1 if level is None else level
    lev = hierarchy.levels[k]
    quality = mesh_quality(lev.uv, lev.triangles, min_angle)
    check_quality(piece.name, quality, min_angle)
    return PieceMesh(piece, lev.uv, lev.triangles.astype(np.int64), lev.boundary_segments,
                     lev.boundary_loop, quality, hierarchy, k)


def level_mesh(mesh: PieceMesh, level: int, min_angle: float = MIN_ANGLE_DEG) -> PieceMesh:
    """The PieceMesh of another level (0-based) of `mesh`'s hierarchy (the same outline and seam counts), checked
    for inverted triangles and slivers like the level it was meshed on."""
    if level == mesh.level:
        return mesh
    lev = mesh.hierarchy.levels[level]
    quality = mesh_quality(lev.uv, lev.triangles, min_angle)
    check_quality(f"{mesh.piece.name} (level {level + 1})", quality, min_angle)
    return PieceMesh(mesh.piece, lev.uv, lev.triangles.astype(np.int64), lev.boundary_segments,
                     lev.boundary_loop, quality, mesh.hierarchy, level)
