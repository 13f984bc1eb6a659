"""A still picture of a scene's current state, for a report, a README or a machine without a display: the cloth
shaded in its strain colours (taichi_cloth.strain), the body light grey, front and side views side by side.

Drawn with matplotlib's Agg backend as flat-shaded triangles in painter's order (farthest first) under an
orthographic camera, so it needs neither a display nor OpenGL. A body mesh above MAX_BODY_TRIANGLES triangles is
drawn from a subsample of its triangles (they are small beside the cloth's, so the gaps do not show at this size)
to keep a picture to a few seconds.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .pattern_view import garment_spec, pattern_view, plot_pattern
from .strain import strain_colormap, vertex_strain

#: body triangles drawn at most (a regular subsample of the mesh's beyond this)
MAX_BODY_TRIANGLES = 60000
BODY_RGB = (0.70, 0.72, 0.76)
#: the views: (title, screen-right axis, depth axis toward the viewer), y up in both
VIEWS = (("front", np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])),
         ("side", np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0])))
LIGHT = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])


def body_meshes(scene) -> list:
    """(vertices (V,3) [m], triangles (T,3)) of every mesh collider of the scene (the body, as it is now) and of
    every sphere collider (an icosphere)."""
    import trimesh  # 0.7 s to import: only to draw a sphere collider

    colliders = scene.controller("colliders")
    if colliders is None:
        return []
    out = [(np.asarray(m.vertices_np, np.float64), np.asarray(m.triangles_np, np.int64)) for m in colliders.bodies]
    for obj in colliders.objects:
        for center, radius in getattr(obj, "spheres_np", []):
            ball = trimesh.creation.icosphere(subdivisions=3, radius=radius)
            out.append((np.asarray(ball.vertices) + center, np.asarray(ball.faces, np.int64)))
    return out


def subsample(triangles: np.ndarray, at_most: int) -> np.ndarray:
    """Every k-th triangle so that at most `at_most` remain."""
    step = int(np.ceil(len(triangles) / at_most)) if len(triangles) > at_most else 1
    return triangles[::step]


def _shade(points: np.ndarray, rgb: np.ndarray, right: np.ndarray, toward: np.ndarray, closed: bool,
           lift: float = 0.0):
    """(screen polygons (T,3,2), face colours (T,3), depth (T,)) of triangles given as corner points (T,3,3).
    closed: a body (outward normals): its faces turned away are dropped; else a two-sided sheet, lit on the side
    the viewer sees. lift [m]: added to the depth, so that a cloth lying on a body is drawn over it although its
    triangles are larger than the body's (painter's order compares centroids)."""
    up = np.cross(toward, right)
    n = np.cross(points[:, 1] - points[:, 0], points[:, 2] - points[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
    facing = n @ toward
    if closed:
        keep = facing > 0
        points, rgb, n = points[keep], rgb[keep], n[keep]
    else:
        n *= np.where(facing < 0, -1.0, 1.0)[:, None]
    light = LIGHT[0] * right + LIGHT[1] * up + LIGHT[2] * toward
    lit = 0.35 + 0.65 * np.clip(n @ light, 0.0, 1.0)
    screen = np.stack([points @ right, points @ up], axis=-1)
    return screen, np.clip(rgb * lit[:, None], 0.0, 1.0), (points @ toward).mean(axis=1) + lift


def render_still(scene, path, title: str | None = None, full_scale: float = 0.1) -> Path:
    """Write a PNG at `path` of the scene's cloth as it is now (strain colours, red at `full_scale` strain) and its
    mesh bodies (light grey), front and side views. Returns the path."""
    import matplotlib  # 0.5 s with pyplot: only when a picture is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = scene.model.data
    x = np.asarray(scene.positions(), np.float64)[: data.n_particles]
    strain = vertex_strain(data, x)
    colormap = strain_colormap(full_scale)  # the recording's legend and vertex colours use the same map
    cloth_rgb = colormap.colors(strain)[:, :3] / 255.0
    tris = np.asarray(data.triangles, np.int64)
    edge = float(np.median(np.linalg.norm(x[tris[:, 1]] - x[tris[:, 0]], axis=1))) if len(tris) else 0.0
    parts = [(x[tris], cloth_rgb[tris].mean(axis=1), False, edge)]
    for v, t in body_meshes(scene):
        t = subsample(t, MAX_BODY_TRIANGLES)
        parts.append((v[t], np.tile(BODY_RGB, (len(t), 1)), True, 0.0))
    extent = np.vstack([p[0].reshape(-1, 3) for p in parts])
    lo, hi = extent.min(axis=0), extent.max(axis=0)
    fig, axes = plt.subplots(1, 2, figsize=(10, 6.2), dpi=110)
    for ax, (name, right, toward) in zip(axes, VIEWS):
        shaded = [_shade(p, rgb, right, toward, closed, lift) for p, rgb, closed, lift in parts]
        screen = np.concatenate([s for s, _, _ in shaded])
        colors = np.concatenate([c for _, c, _ in shaded])
        order = np.argsort(np.concatenate([d for _, _, d in shaded]))  # farthest first
        ax.add_collection(PolyCollection(screen[order], facecolors=colors[order], edgecolors=colors[order],
                                         linewidths=0.2, antialiased=False))
        corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1]) for c in (lo[2], hi[2])])
        u, w = corners @ right, corners @ np.cross(toward, right)
        pad = 0.04 * max(np.ptp(u), np.ptp(w))
        ax.set_xlim(u.min() - pad, u.max() + pad)
        ax.set_ylim(w.min() - pad, w.max() + pad)
        ax.set_aspect("equal")
        ax.set_axis_off()
        ax.set_title(name)
    peak = float(strain.max()) if len(strain) else 0.0
    fig.suptitle(title or f"{scene.name}: t = {scene.state.t:.2f} s, max strain {100 * peak:.1f} %", fontsize=10)
    fig.tight_layout(rect=(0.0, 0.12, 1.0, 1.0))
    bar = fig.add_axes((0.3, 0.09, 0.4, 0.025))
    low, high = colormap.range_percent
    fig.colorbar(matplotlib.cm.ScalarMappable(matplotlib.colors.Normalize(low, high), colormap.matplotlib()),
                 cax=bar, orientation="horizontal", label="strain [%] (the top colour: that and above)")
    fig.savefig(path)
    plt.close(fig)
    return path


def write_pictures(scene, base, name: str | None = None) -> list[Path]:
    """The still pictures of a run beside its recording: `base`.png (render_still) and, when the scene sews a
    garment, `base`-pattern.png (taichi_cloth.pattern_view.plot_pattern). base: a path without suffix."""
    base = Path(base)
    out = [render_still(scene, base.with_name(base.name + ".png"))]
    spec = garment_spec(scene)
    if spec is not None:
        out.append(plot_pattern(pattern_view(spec), base.with_name(base.name + "-pattern.png")))
    return out
