"""Quality of a draped garment (Fan et al. 1998 table 1 and section 4): per piece, the area and boundary-length errors
between the 2D pattern and its 3D form, the strain of its edges; for the garment, the seam gap, how many
particles ended inside the body and whether the drape reached static equilibrium.

Errors are relative to the 2D pattern here (the pattern is the reference when a garment is draped, 2D -> 3D):
area error = |S3D - S2D| / S2D, boundary error = |L3D - L2D| / L2D, each over a piece's own triangles and
outline (a merged seam particle belongs to both of its pieces). Strain is l / L0 - 1 per triangle edge, with
L0 from the pattern.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class PieceQuality:
    """One piece: areas [m^2], boundary lengths [m], relative errors, edge strain (max |strain|, mean |strain|)."""

    name: str
    area_2d: float
    area_3d: float
    boundary_2d: float
    boundary_3d: float
    max_strain: float
    mean_strain: float

    @property
    def area_error(self) -> float:
        return abs(self.area_3d - self.area_2d) / self.area_2d

    @property
    def boundary_error(self) -> float:
        return abs(self.boundary_3d - self.boundary_2d) / self.boundary_2d


@dataclass
class GarmentQuality:
    """pieces: PieceQuality list; seam_gap_max / seam_gap_mean [m]; penetrations: particles inside the body
    (None without a body collider); max_speed [m/s]; static: the drape is at rest by the scene's rest criterion
    (taichi_cloth.rest); notes: what the table cannot show (open seams...)."""

    pieces: list
    seam_gap_max: float
    seam_gap_mean: float
    penetrations: int | None
    max_speed: float
    static: bool
    notes: list = field(default_factory=list)

    def format(self) -> str:
        lines = ["| piece | area 2D [cm^2] | area 3D [cm^2] | area error | boundary 2D [cm] | boundary 3D [cm] | "
                 "boundary error | max strain | mean strain |",
                 "|---|---|---|---|---|---|---|---|---|"]
        for p in self.pieces:
            lines.append(f"| {p.name} | {1e4 * p.area_2d:.0f} | {1e4 * p.area_3d:.0f} | {100 * p.area_error:.2f} % | "
                         f"{100 * p.boundary_2d:.1f} | {100 * p.boundary_3d:.1f} | {100 * p.boundary_error:.2f} % | "
                         f"{100 * p.max_strain:.1f} % | {100 * p.mean_strain:.2f} % |")
        lines.append(f"seam gap: max {1e3 * self.seam_gap_max:.2f} mm, mean {1e3 * self.seam_gap_mean:.2f} mm; "
                     f"particles inside the body: {'n/a' if self.penetrations is None else self.penetrations}; "
                     f"static equilibrium: {'yes' if self.static else 'no'} (max speed {1e3 * self.max_speed:.1f} mm/s)")
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


def piece_quality(garment, current_of: np.ndarray, x: np.ndarray) -> list[PieceQuality]:
    """PieceQuality of every piece of `garment` (a GarmentCloth) for current positions x ((P,3) [m]) in the
    current numbering; current_of maps the garment's original particles to current ones."""
    uv = garment.rest_uv()
    tri0 = garment.data.triangles
    tri_piece = garment.triangle_pieces()
    X = np.asarray(x, dtype=np.float64)[current_of]  # positions in the original numbering
    out = []
    for k, mesh in enumerate(garment.meshes):
        t = tri0[tri_piece == k]
        d1, d2 = uv[t[:, 1]] - uv[t[:, 0]], uv[t[:, 2]] - uv[t[:, 0]]
        a2 = 0.5 * np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
        a3 = 0.5 * np.linalg.norm(np.cross(X[t[:, 1]] - X[t[:, 0]], X[t[:, 2]] - X[t[:, 0]]), axis=1)
        e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
        e = np.unique(np.sort(e, axis=1), axis=0)
        L0 = np.linalg.norm(uv[e[:, 1]] - uv[e[:, 0]], axis=1)
        strain = np.abs(np.linalg.norm(X[e[:, 1]] - X[e[:, 0]], axis=1) / L0 - 1.0)
        b = garment.boundary_edges(k)
        out.append(PieceQuality(mesh.piece.name, float(a2.sum()), float(a3.sum()),
                                float(np.linalg.norm(uv[b[:, 1]] - uv[b[:, 0]], axis=1).sum()),
                                float(np.linalg.norm(X[b[:, 1]] - X[b[:, 0]], axis=1).sum()),
                                float(strain.max()), float(strain.mean())))
    return out


def garment_quality(scene) -> GarmentQuality:
    """The GarmentQuality of a garment scene now. Penetrations count particles whose signed distance to a mesh
    collider (the body) is negative; static: the scene's rest criterion held at its last frame (taichi_cloth.rest:
    the same test as `run --until-rest`); when it did not, the notes say why."""
    sewing = scene.controller("sewing")
    if sewing is None:
        raise ValueError("garment_quality needs a garment scene (its cloth a GarmentCloth)")
    x = scene.positions()
    gaps = sewing.gaps(x)
    pieces = piece_quality(sewing.garment, sewing.current_of, x)
    colliders = scene.controller("colliders")
    bodies = colliders.bodies if colliders is not None else []
    penetrations = int(sum(np.count_nonzero(b.signed_distance(x) < 0.0) for b in bodies)) if bodies else None
    m = scene.measure()
    notes = []
    if sewing.active or sewing.gave_up:
        opened = sewing.open_seams(gaps)
        notes.append("seams still open: " + (", ".join(f"{k} ({1e3 * v:.1f} mm)" for k, v in opened.items()) or "none"))
    status = scene.rest.status
    static = status is not None and status.at_rest
    if status is not None and not static:
        notes.append(status.describe(scene.rest.criterion))
    return GarmentQuality(pieces, float(gaps.max()) if len(gaps) else 0.0, float(gaps.mean()) if len(gaps) else 0.0,
                          penetrations, m.max_speed, static, notes)


def draped_pieces(scene) -> list:
    """Every piece of a garment scene as it is draped now, ready for taichi_cloth.flatten.flatten_pieces: a list
    of (name, vertices (n,3) float64 [m], triangles (t,3) int64, corners {corner name: vertex}) in the piece's own
    numbering (its PieceMesh's: triangles counter-clockwise in the pattern, seen from outside). A particle merged
    at a seam appears in both of its pieces."""
    sewing = scene.controller("sewing")
    garment = sewing.garment
    x = scene.positions()[sewing.current_of]  # the original numbering
    out = []
    for k, mesh in enumerate(garment.meshes):
        corners = {name: int(seg[0]) for name, seg in zip(mesh.piece.corner_names, mesh.boundary_segments)}
        out.append((mesh.piece.name, x[garment.offsets[k]: garment.offsets[k + 1]].copy(), mesh.triangles.copy(),
                    corners))
    return out
