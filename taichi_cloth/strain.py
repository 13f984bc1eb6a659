"""Strain of a cloth per vertex, and its colour map (white at rest, through yellow, to red at full scale).

Used for the strain map a garment's recording shows (StrainMap, a controller that only records), its legend, the
still images (strain_colormap: one colour map for all of them), and by the flattening error maps.
"""
from __future__ import annotations

import io
from dataclasses import dataclass

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


#: the strain colour map's stops: (fraction of the full scale, RGB 0-255): white at rest, orange at half, red at
#: full scale (the green channel falls linearly, the blue one is gone at half)
STRAIN_STOPS = ((0.0, (255.0, 255.0, 255.0)), (0.5, (255.0, 159.375, 0.0)), (1.0, (255.0, 63.75, 0.0)))
#: the default full scale of the strain map (10 %): as the stretch limit's usual max_strain
STRAIN_FULL_SCALE = 0.1


@dataclass(frozen=True)
class StrainColorMap:
    """The strain colour map as a recording's legend and a still image show it.

    name:        "strain"; stops: STRAIN_STOPS ((fraction of full_scale, (r, g, b) 0-255), ...)
    full_scale:  strain [-] at and above which the colour is full red (0.1: 10 %)
    """

    name: str
    stops: tuple
    full_scale: float

    @property
    def range_percent(self) -> tuple[float, float]:
        """(0, full scale) [%]: the range the colours span."""
        return 0.0, 100.0 * self.full_scale

    def colors(self, strain) -> np.ndarray:
        """(P,4) uint8 RGBA of (P,) strains [-]: piecewise linear between the stops, clamped at full scale."""
        s = np.clip(np.asarray(strain, dtype=np.float64) / self.full_scale, 0.0, 1.0)
        at = [f for f, _ in self.stops]
        rgba = np.full((len(s), 4), 255, np.uint8)
        for c in range(3):
            rgba[:, c] = np.interp(s, at, [rgb[c] for _, rgb in self.stops]).astype(np.uint8)
        return rgba

    def matplotlib(self):
        """The same map as a matplotlib colormap over [0, 1] (normalise strains by full_scale, or per cent by
        range_percent[1]); matplotlib is imported on call."""
        from matplotlib.colors import LinearSegmentedColormap  # matplotlib (0.2 s to import): only for a plot

        return LinearSegmentedColormap.from_list(self.name, [(f, np.asarray(rgb) / 255.0) for f, rgb in self.stops])

    def legend_png(self, width_px: int = 900, height_px: int = 110) -> bytes:
        """A horizontal colour bar, ticked in per cent over range_percent, as PNG bytes (matplotlib, Agg)."""
        from matplotlib.colorbar import ColorbarBase  # matplotlib (0.2 s to import): only for a legend
        from matplotlib.colors import Normalize
        from matplotlib.figure import Figure

        dpi = 100
        fig = Figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi)
        ax = fig.add_axes((0.03, 0.52, 0.94, 0.3))
        bar = ColorbarBase(ax, cmap=self.matplotlib(), norm=Normalize(*self.range_percent), orientation="horizontal")
        bar.set_label(f"{self.name} [%] (red: {self.range_percent[1]:g} % and above)", fontsize=12)
        ax.tick_params(labelsize=12)
        out = io.BytesIO()
        fig.savefig(out, format="png", dpi=dpi)
        return out.getvalue()


def strain_colormap(full_scale: float = STRAIN_FULL_SCALE) -> StrainColorMap:
    """The strain colour map with its range, for the recordings, their legend and the still images alike."""
    return StrainColorMap("strain", STRAIN_STOPS, float(full_scale))


def strain_colors(strain: np.ndarray, full_scale: float = STRAIN_FULL_SCALE) -> np.ndarray:
    """(P,4) uint8 RGBA strain map (strain_colormap): white at 0, through orange to red at `full_scale` (10 %)."""
    return strain_colormap(full_scale).colors(strain)


class StrainMap(Controller):
    """Colours every recorded frame's vertices by their largest structural strain (strain_colors, full red at
    `full_scale`). model: the scene's Model (its current ClothData is read at each frame)."""

    name = "strain_map"

    def __init__(self, model, full_scale: float = STRAIN_FULL_SCALE):
        self.model, self.full_scale = model, float(full_scale)

    def layout(self, layout) -> None:
        layout.strain_scale = self.full_scale

    def record(self, frame) -> None:
        frame.colors = strain_colors(vertex_strain(self.model.data, frame.positions), self.full_scale)
