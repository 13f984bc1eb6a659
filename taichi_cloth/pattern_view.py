"""The seam set-up view of a garment's pattern (as pattern CAD shows it): the pieces flat and side by side, their
corners named, every seam drawn as a numbered pair of sides with the direction each side was picked in.

`pattern_view(spec)` extracts the plain geometry (numpy, metres); `plot_pattern(view, path)` draws it to a PNG with
matplotlib's Agg backend (no display needed); `log_pattern(recorder, view)` logs it into a recording under
`pattern/` as static 2D data (Recorder.log_pattern).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .garment.seams import route

#: [m] space between two pieces laid side by side
GAP = 0.12


@dataclass
class PieceView:
    """name; outline: (n, 2) [m] closed (first point repeated at the end); corners: (k, 2) [m]; corner_names."""

    name: str
    outline: np.ndarray
    corners: np.ndarray
    corner_names: list


@dataclass
class SeamSideView:
    """number: the seam's number (1-based, the pair's label); seam: its name; piece: the piece of this side;
    points: (m, 2) [m] the side from its start corner to its end corner, in pick order."""

    number: int
    seam: str
    piece: str
    points: np.ndarray


@dataclass
class PatternView:
    """A garment's pattern laid out flat: pieces in order, then the two sides of every seam (a, b, a, b...)."""

    name: str
    pieces: list = field(default_factory=list)
    sides: list = field(default_factory=list)


def pattern_view(spec, gap: float = GAP, tolerance: float = 1e-3) -> PatternView:
    """The PatternView of a GarmentSpec (taichi_cloth.garment.garment): pieces shifted to lie side by side along
    x, `gap` [m] apart, bottoms on y = 0; outlines sampled within `tolerance` [m]."""
    shift, x0, view = {}, 0.0, PatternView(spec.name)
    for piece in spec.pieces:
        outline = piece.outline(tolerance)
        lo, hi = outline.min(axis=0), outline.max(axis=0)
        shift[piece.name] = np.array([x0 - lo[0], -lo[1]])
        x0 += float(hi[0] - lo[0]) + gap
        view.pieces.append(PieceView(piece.name, np.vstack([outline, outline[:1]]) + shift[piece.name],
                                     piece.corners + shift[piece.name], list(piece.corner_names)))
    pieces = {p.name: p for p in spec.pieces}
    for number, seam in enumerate(spec.seams, start=1):
        for side in (seam.a, seam.b):
            piece = pieces[side.piece]
            lines = piece.polylines(tolerance)
            r = route(piece, seam, side, np.array([s.length() for s in piece.segments]))
            pts = np.vstack([lines[r.segments[0]]] + [lines[s][1:] for s in r.segments[1:]])
            view.sides.append(SeamSideView(number, seam.name, side.piece,
                                           (pts if r.forward else pts[::-1]) + shift[side.piece]))
    return view


def seam_color(number: int) -> tuple:
    """RGB in 0..1 of seam `number` (matplotlib's tab10 cycle), the same in the PNG and the recording."""
    from matplotlib import colormaps  # matplotlib (0.2 s to import): only for a garment's pattern view

    return tuple(colormaps["tab10"]((number - 1) % 10)[:3])


def _midpoint(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(point half-way along a polyline, unit tangent there)."""
    d = np.linalg.norm(np.diff(points, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(d)])
    k = int(np.clip(np.searchsorted(s, 0.5 * s[-1]), 1, len(points) - 1))
    t = points[k] - points[k - 1]
    return 0.5 * (points[k] + points[k - 1]), t / max(float(np.linalg.norm(t)), 1e-12)


def plot_pattern(view: PatternView, path, title: str | None = None) -> Path:
    """Write the seam set-up view to a PNG at `path` (cm axes): pieces filled light, corners as dots with their
    names, each seam side in its seam's colour with an arrow along the pick direction and the seam's number;
    the seams are listed by number below. Returns the path."""
    import matplotlib  # 0.5 s with pyplot: only when a picture is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cm = 100.0
    pts = np.vstack([p.outline for p in view.pieces])
    width, height = np.ptp(pts, axis=0) + 0.1
    fig, ax = plt.subplots(figsize=(13, min(13, 13 * height / width + 1.6)), dpi=110)
    for p in view.pieces:
        ax.fill(*(p.outline * cm).T, facecolor=(0.93, 0.93, 0.9), edgecolor=(0.3, 0.3, 0.3), linewidth=0.8)
        c = p.outline[:-1].mean(axis=0) * cm
        ax.text(*c, p.name, ha="center", va="center", fontsize=11, color=(0.35, 0.35, 0.35), style="italic")
        ax.plot(*(p.corners * cm).T, "o", color="black", markersize=3)
        centre = p.outline[:-1].mean(axis=0)
        for name, q in zip(p.corner_names, p.corners):
            away = q - centre
            away = away / max(float(np.linalg.norm(away)), 1e-12)
            ax.annotate(name, q * cm, xytext=away * 10, textcoords="offset points", fontsize=7,
                        ha="center", va="center", color=(0.15, 0.15, 0.15))
    for s in view.sides:
        color = seam_color(s.number)
        ax.plot(*(s.points * cm).T, color=color, linewidth=2.6, solid_capstyle="round")
        mid, tangent = _midpoint(s.points)
        ax.annotate("", xy=(mid + 0.02 * tangent) * cm, xytext=(mid - 0.02 * tangent) * cm,
                    arrowprops=dict(arrowstyle="-|>", color=color, lw=2, mutation_scale=14))
        normal = np.array([-tangent[1], tangent[0]])
        ax.annotate(str(s.number), mid * cm, xytext=normal * 11, textcoords="offset points", fontsize=9,
                    fontweight="bold", ha="center", va="center", color=color)
    names = list(dict.fromkeys((s.number, s.seam) for s in view.sides))
    legend = "   ".join(f"{n} {seam}" for n, seam in names)
    ax.set_title(title or f"{view.name}: pattern pieces and seams (numbered pairs, arrows: pick direction)")
    if legend:
        fig.text(0.5, 0.02, "seams: " + legend, ha="center", fontsize=8, wrap=True)
    ax.set_aspect("equal")
    ax.set_xlabel("cm")
    ax.set_ylabel("cm")
    ax.grid(True, color=(0.9, 0.9, 0.9), linewidth=0.5)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    fig.savefig(path)
    plt.close(fig)
    return path


def log_pattern(recorder, view: PatternView) -> None:
    """Log the view into a recording (Recorder.log_pattern: static 2D data under `pattern/`)."""
    recorder.log_pattern({p.name: p.outline for p in view.pieces},
                         np.vstack([p.corners for p in view.pieces]),
                         [n for p in view.pieces for n in p.corner_names],
                         [s.points for s in view.sides], [str(s.number) for s in view.sides],
                         [tuple(int(255 * c) for c in seam_color(s.number)) for s in view.sides])


def garment_spec(scene):
    """The GarmentSpec of a scene's garment, or None when the scene sews none."""
    sewing = scene.controller("sewing")
    return None if sewing is None else sewing.garment.spec


def log_scene_pattern(recorder, scene) -> None:
    """Log the pattern of the scene's garment into the recording (nothing for a scene without one)."""
    spec = garment_spec(scene)
    if spec is not None:
        log_pattern(recorder, pattern_view(spec))
