"""Strain of a cloth per vertex, and its colour map (white at rest, through yellow, to red at full scale).

Used for the strain map a garment's recording shows (StrainMap, a controller that only records), and by the
flattening error maps.
"""
from __future__ import annotations

import numpy as np

from .cloth import SpringKind
from .control import Controller


def vertex_strain(data, x: np.ndarray) -> np.ndarray:
    """(P,) largest |strain| of the structural springs at each particle (x: (P,3) [m]); 0 where none."""
    x = np.asarray(x, dtype=np.float64)[: data.n_particles]
    s = data.kind == int(SpringKind.STRUCTURAL)
    a, b = data.springs[s, 0], data.springs[s, 1]
    L0 = data.rest_length[s]
    strain = np.abs(np.linalg.norm(x[b] - x[a], axis=1) / np.maximum(L0, 1e-12) - 1.0)
    out = np.zeros(data.n_particles)
    np.maximum.at(out, a, strain)
    np.maximum.at(out, b, strain)
    return out


def strain_colors(strain: np.ndarray, full_scale: float = 0.1) -> np.ndarray:
    """(P,4) uint8 RGBA strain map: white at 0, through yellow to red at `full_scale` (10 %) and above."""
    s = np.clip(np.asarray(strain) / full_scale, 0.0, 1.0)
    rgba = np.empty((len(s), 4), np.uint8)
    rgba[:, 0] = 255
    rgba[:, 1] = (255 * (1.0 - 0.75 * s)).astype(np.uint8)
    rgba[:, 2] = (255 * np.clip(1.0 - 2.0 * s, 0.0, 1.0)).astype(np.uint8)
    rgba[:, 3] = 255
    return rgba


class StrainMap(Controller):
    """Colours every recorded frame's vertices by their largest structural strain (strain_colors, full red at
    `full_scale`). model: the scene's Model (its current ClothData is read at each frame)."""

    name = "strain_map"

    def __init__(self, model, full_scale: float = 0.1):
        self.model, self.full_scale = model, float(full_scale)

    def record(self, frame) -> None:
        frame.colors = strain_colors(vertex_strain(self.model.data, frame.positions), self.full_scale)
