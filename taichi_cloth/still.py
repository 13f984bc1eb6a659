"""A still picture of a scene's current state, for a report, a README or a machine without a display: the cloth in
its strain colours (taichi_cloth.strain), the body light grey, seen from the front, the back and the side.

Each view is framed on the cloth's bounding box (FRAME_MARGIN around it; the body is drawn only where it falls in
that frame), under an orthographic camera, at a scale common to the three views (PANEL_PX tall for a garment).
The views are drawn by a small z-buffered software rasterizer in numpy (rasterize: every pixel centre inside a
triangle is a fragment, the nearest fragment per pixel wins) and smooth-shaded per pixel: the area-weighted vertex
normals and the vertex colours are interpolated at each pixel and lit there, so folds and wrinkles read. It needs
neither a display, nor OpenGL, nor Taichi, and it is deterministic (ties in depth: the lower triangle index wins).
matplotlib (Agg) only lays the views out and adds the title and the strain legend.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clothbase.meshes import vertex_normals

from .pattern_view import garment_spec, pattern_view, plot_pattern
from .strain import strain_colormap, vertex_strain

BODY_RGB = (0.70, 0.72, 0.76)
#: the views: (title, screen-right axis, depth axis toward the viewer), y up in all
VIEWS = (("front", np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])),
         ("back", np.array([-1.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0])),
         ("side", np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0])))
#: the margin around the cloth's box in a view, as a fraction of the box's larger screen extent, on each side (the
#: recording's default camera frames the same box with the same margin: taichi_cloth.recorder)
FRAME_MARGIN = 0.05
#: a panel's height [px] (the views share one scale; a wide cloth is drawn smaller: MAX_PANEL_WIDTH_PX)
PANEL_PX = 800
MAX_PANEL_WIDTH_PX = 1000
#: the smallest framed extent across (along) a view, as a fraction of the extent along (across): a flat sheet seen
#: edge-on still gets a panel to lie in
MIN_ASPECT = 0.35
#: lights in view coordinates (right, up, toward the viewer): a key light from the upper right, a weaker fill from
#: the left, an ambient term and a little specular (Blinn-Phong, the viewer along +toward: orthographic)
KEY = np.array([0.35, 0.55, 1.0]) / np.linalg.norm([0.35, 0.55, 1.0])
FILL = np.array([-0.7, -0.1, 0.7]) / np.linalg.norm([-0.7, -0.1, 0.7])
AMBIENT, KEY_WEIGHT, FILL_WEIGHT = 0.22, 0.68, 0.18
SPECULAR, SHININESS = (0.06, 0.12), 24.0  # (cloth, body): a matte cloth, a slightly glossier body
#: the panels' background, top and bottom of a vertical gradient (dark: the white of no strain stands out)
BACKGROUND = ((0.33, 0.35, 0.39), (0.14, 0.15, 0.17))
#: the picture's layout [px]: between two panels, left and right of them, above them (the title and the panels'
#: names) and below them (the strain legend)
GAP_PX, SIDE_PX, TOP_PX, BOTTOM_PX = 16, 16, 64, 110
#: candidate pixels [count] a rasterizer pass handles at once (its memory: about 100 bytes each)
CHUNK = 1 << 20
#: the bounding-box sizes [px] triangles are grouped by in rasterize (a box is rounded up to the next)
BOX_SIZES = np.array([1, 2, 3, 4, 5, 6, 8, 10, 12, 14, 16, 20, 24, 28, 32, 40, 48, 56, 64, 80, 96, 112, 128, 160,
                      192, 224, 256, 320, 384, 448, 512])


@dataclass
class Panel:
    """One view drawn: name ("front", ...); rgb (H,W,3) float64 in 0..1; cloth (H,W) bool, the pixels where the
    cloth is the nearest surface; body (H,W) bool, the same for a body; scale [px/m]."""

    name: str
    rgb: np.ndarray
    cloth: np.ndarray
    body: np.ndarray
    scale: float


def body_meshes(scene) -> list:
    """(vertices (V,3) [m], triangles (T,3)) of every mesh collider of the scene (the body, as it is now) and of
    every sphere collider (an icosphere)."""
    colliders = scene.controller("colliders")
    if colliders is None:
        return []
    out = [(np.asarray(m.vertices_np, np.float64), np.asarray(m.triangles_np, np.int64)) for m in colliders.bodies]
    for obj in colliders.objects:
        for center, radius in getattr(obj, "spheres_np", []):
            import trimesh  # 0.7 s to import: only to draw a sphere collider

            ball = trimesh.creation.icosphere(subdivisions=3, radius=radius)
            out.append((np.asarray(ball.vertices) + center, np.asarray(ball.faces, np.int64)))
    return out


def rasterize(screen: np.ndarray, depth: np.ndarray, shape: tuple[int, int]):
    """Z-buffer triangles: (tri (H*W,) int64, the index of the nearest triangle at each pixel, -1 where none;
    bary (H*W,3) float64, that pixel centre's barycentric coordinates in it; z (H*W,) float64, its depth, -inf
    where none). Pixels row-major, row 0 at the top.

    screen: (T,3,2) float64 corner positions [px] (x right, y down; pixel (i, j)'s centre is at (j + 0.5, i + 0.5));
    depth: (T,3) corner depths (larger: nearer the viewer), linear across a triangle (an orthographic camera);
    shape: (H, W). A pixel centre on a shared edge belongs to both triangles (the depth test picks one), so no
    cracks; among fragments at equal depth the one of the lower triangle index wins (deterministic)."""
    H, W = shape
    tri_at = np.full(H * W, -1, np.int64)
    bary = np.zeros((H * W, 3))
    zbuf = np.full(H * W, -np.inf)
    s = np.asarray(screen, np.float64)
    e1, e2 = s[:, 1] - s[:, 0], s[:, 2] - s[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    lo = np.ceil(s.min(axis=1) - 0.5).astype(np.int64)  # the first and last pixel whose centre may be inside
    hi = np.floor(s.max(axis=1) - 0.5).astype(np.int64)
    keep = (np.abs(det) > 1e-12) & (hi[:, 0] >= 0) & (hi[:, 1] >= 0) & (lo[:, 0] < W) & (lo[:, 1] < H)
    keep &= (hi >= lo).all(axis=1)
    ids = np.flatnonzero(keep)
    if not len(ids):
        return tri_at, bary, zbuf
    lo, hi = np.maximum(lo[ids], 0), np.minimum(hi[ids], [W - 1, H - 1])
    ext = hi - lo + 1  # (width, height) [px] of each bounding box in the image
    # the barycentric coordinates l1, l2 and the depth as affine functions of the pixel position: a*x + b*y + c
    inv = 1.0 / det[ids]
    p0, e1, e2, d = s[ids, 0], e1[ids], e2[ids], np.asarray(depth, np.float64)[ids]
    a1, b1 = e2[:, 1] * inv, -e2[:, 0] * inv
    a2, b2 = -e1[:, 1] * inv, e1[:, 0] * inv
    c1, c2 = -(a1 * p0[:, 0] + b1 * p0[:, 1]), -(a2 * p0[:, 0] + b2 * p0[:, 1])
    dz1, dz2 = d[:, 1] - d[:, 0], d[:, 2] - d[:, 0]
    coef = np.stack([a1, b1, c1, a2, b2, c2, a1 * dz1 + a2 * dz2, b1 * dz1 + b2 * dz2,
                     d[:, 0] + c1 * dz1 + c2 * dz2], axis=1)
    # triangles grouped by the size of their bounding box, rounded up to one of BOX_SIZES (about 50 groups a view),
    # so that a group's candidate pixels are an (n, h, w) array: no per-candidate gathers (twice as fast)
    sizes = BOX_SIZES[: np.searchsorted(BOX_SIZES, ext.max()) + 1]
    if ext.max() > sizes[-1]:
        sizes = np.r_[sizes, ext.max()]
    bw, bh = sizes[np.searchsorted(sizes, ext[:, 0])], sizes[np.searchsorted(sizes, ext[:, 1])]
    order = np.lexsort((bh, bw))  # stable: by triangle index within a group
    keys = bw[order] * (int(sizes[-1]) + 1) + bh[order]
    bounds = np.r_[np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]]), len(order)]
    for g0, g1 in zip(bounds[:-1], bounds[1:]):
        w, h = int(bw[order[g0]]), int(bh[order[g0]])
        per = max(CHUNK // (w * h), 1)
        for c0 in range(g0, g1, per):
            m = order[c0:min(c0 + per, g1)]
            cf = coef[m][:, :, None, None]
            px = lo[m, 0][:, None, None] + np.arange(w)[None, None, :]
            py = lo[m, 1][:, None, None] + np.arange(h)[None, :, None]
            x, y = px + 0.5, py + 0.5
            l1 = cf[:, 0] * x + cf[:, 1] * y + cf[:, 2]
            l2 = cf[:, 3] * x + cf[:, 4] * y + cf[:, 5]
            inside = (l1 >= -1e-9) & (l2 >= -1e-9) & (l1 + l2 <= 1.0 + 1e-9) & (px < W) & (py < H)
            if not inside.any():
                continue
            z = (cf[:, 6] * x + cf[:, 7] * y + cf[:, 8])[inside]
            pix = np.broadcast_to(py * W + px, inside.shape)[inside]
            tri = np.broadcast_to(ids[m][:, None, None], inside.shape)[inside]
            l1, l2 = l1[inside], l2[inside]
            # the nearest fragment of each pixel in this chunk (the lower triangle index at a tie) ...
            nearest = np.lexsort((tri, -z, pix))
            sorted_pix = pix[nearest]
            first = nearest[np.r_[True, sorted_pix[1:] != sorted_pix[:-1]]]
            # ... replaces the z-buffer's where it is nearer (or as near, of a lower triangle index)
            pix = pix[first]
            nearer = (z[first] > zbuf[pix]) | ((z[first] == zbuf[pix]) & (tri[first] < tri_at[pix]))
            pix, first = pix[nearer], first[nearer]
            zbuf[pix], tri_at[pix] = z[first], tri[first]
            bary[pix] = np.stack([1.0 - l1[first] - l2[first], l1[first], l2[first]], axis=1)
    return tri_at, bary, zbuf


def frame(points: np.ndarray, views=VIEWS, panel_px: int = PANEL_PX, max_width_px: int = MAX_PANEL_WIDTH_PX):
    """The framing of each view on `points` (N,3) [m] (the cloth): (scale [px/m], [(u0, v1, W, H) per view]): the
    screen position [m] (right, up) of a panel's top-left corner and its size [px]. The views share one scale: the
    tallest framed extent is `panel_px` tall, unless the widest would then be wider than `max_width_px`."""
    spans = []
    for _, right, toward in views:
        u, v = points @ right, points @ np.cross(toward, right)
        spans.append((u.min(), u.max(), v.min(), v.max()))
    # one margin for all views (the largest extent's FRAME_MARGIN), so that they share their height as y is up in all
    pad = FRAME_MARGIN * max(max(u1 - u0, v1 - v0) for u0, u1, v0, v1 in spans + [(0.0, 1e-3, 0.0, 0.0)])
    boxes = []
    for u0, u1, v0, v1 in spans:
        du, dv = u1 - u0 + 2 * pad, v1 - v0 + 2 * pad
        du, dv = max(du, MIN_ASPECT * dv), max(dv, MIN_ASPECT * du)
        boxes.append((0.5 * (u0 + u1), 0.5 * (v0 + v1), du, dv))
    scale = min(panel_px / max(b[3] for b in boxes), max_width_px / max(b[2] for b in boxes))
    out = []
    for uc, vc, du, dv in boxes:
        W, H = max(int(round(du * scale)), 1), max(int(round(dv * scale)), 1)
        out.append((uc - 0.5 * W / scale, vc + 0.5 * H / scale, W, H))
    return scale, out


def render_views(cloth_x: np.ndarray, cloth_triangles: np.ndarray, cloth_rgb: np.ndarray, bodies=(), views=VIEWS,
                 panel_px: int = PANEL_PX, max_width_px: int = MAX_PANEL_WIDTH_PX, frame_on=None) -> list[Panel]:
    """The views of a cloth and bodies, framed on the cloth (frame), z-buffered (rasterize), smooth-shaded.

    cloth_x: (P,3) [m]; cloth_triangles: (T,3) int; cloth_rgb: (P,3) float in 0..1, the vertex colours; bodies:
    [(vertices (V,3) [m], triangles (B,3) int)], closed and wound outward (their faces turned away are culled),
    drawn BODY_RGB. The cloth is two-sided: lit on the side facing the viewer. frame_on: (N,3) [m] points the views
    are framed on instead of the cloth (the pattern studio frames pieces being placed on the whole body)."""
    x = np.asarray(cloth_x, np.float64)
    tris = np.asarray(cloth_triangles, np.int64).reshape(-1, 3)
    rgb = np.asarray(cloth_rgb, np.float64)
    pts = x[np.unique(tris)] if len(tris) else x
    if frame_on is not None:
        pts = np.asarray(frame_on, np.float64).reshape(-1, 3)
    pts = pts if len(pts) else np.zeros((1, 3))  # no cloth: an empty frame round the origin
    scale, framing = frame(pts, views, panel_px, max_width_px)
    edge = float(np.median(np.linalg.norm(x[tris[:, 1]] - x[tris[:, 0]], axis=1))) if len(tris) else 0.0
    # the cloth lies a collision thickness (a few mm) off the body, but its flat triangles can cut the body's
    # tessellation where both curve: half an edge (at most 1 cm) toward the viewer keeps it in front there
    lift = min(0.5 * edge, 0.01)
    # every mesh as corner arrays: points (N,3,3) [m], unit normals (N,3,3), albedo (N,3,3) in 0..1, is a body
    cloth_n = vertex_normals(x, tris)
    meshes = [(x[tris], cloth_n[tris], rgb[tris], False)]
    for v, t in bodies:
        v, t = np.asarray(v, np.float64), np.asarray(t, np.int64)
        meshes.append((v[t], vertex_normals(v, t)[t], np.broadcast_to(BODY_RGB, (len(t), 3, 3)), True))
    panels = []
    for (name, right, toward), (u0, v1, W, H) in zip(views, framing):
        up = np.cross(toward, right)
        screens, depths, normals, albedo, closed = [], [], [], [], []
        for points, n, colour, is_body in meshes:
            if is_body:  # a closed body: its faces turned away from the viewer are hidden anyway
                face = np.cross(points[:, 1] - points[:, 0], points[:, 2] - points[:, 0]) @ toward
                points, n, colour = points[face > 0], n[face > 0], colour[face > 0]
            screens.append(np.stack([(points @ right - u0) * scale, (v1 - points @ up) * scale], axis=-1))
            depths.append(points @ toward + (0.0 if is_body else lift))
            normals.append(n)
            albedo.append(colour)
            closed.append(np.full(len(points), is_body))
        tri_at, bary, _ = rasterize(np.concatenate(screens), np.concatenate(depths), (H, W))
        hit = np.flatnonzero(tri_at >= 0)
        t, b = tri_at[hit], bary[hit][:, :, None]
        n = (np.concatenate(normals)[t] * b).sum(axis=1)
        colour = (np.concatenate(albedo)[t] * b).sum(axis=1)
        is_body = np.concatenate(closed)[t]
        view = np.stack([n @ right, n @ up, n @ toward], axis=1)  # the normal in view coordinates
        view /= np.maximum(np.linalg.norm(view, axis=1, keepdims=True), 1e-12)
        # the cloth is lit on the side the viewer sees; a body's normal turned away (at its outline) faces sideways
        view[~is_body] *= np.where(view[~is_body, 2] < 0, -1.0, 1.0)[:, None]
        view[is_body, 2] = np.maximum(view[is_body, 2], 0.0)
        half = (KEY + [0.0, 0.0, 1.0]) / np.linalg.norm(KEY + [0.0, 0.0, 1.0])
        lit = (AMBIENT + KEY_WEIGHT * np.clip(view @ KEY, 0.0, 1.0) + FILL_WEIGHT * np.clip(view @ FILL, 0.0, 1.0))
        gloss = np.where(is_body, SPECULAR[1], SPECULAR[0]) * np.clip(view @ half, 0.0, 1.0) ** SHININESS
        image = np.empty((H * W, 3))
        image[:] = np.repeat(np.linspace(*np.asarray(BACKGROUND), H), W, axis=0)
        image[hit] = np.clip(colour * lit[:, None] + gloss[:, None], 0.0, 1.0)
        cloth_px, body_px = np.zeros(H * W, bool), np.zeros(H * W, bool)
        cloth_px[hit[~is_body]], body_px[hit[is_body]] = True, True
        panels.append(Panel(name, image.reshape(H, W, 3), cloth_px.reshape(H, W), body_px.reshape(H, W), scale))
    return panels


def render_still(scene, path, title: str | None = None, full_scale: float = 0.1, panel_px: int = PANEL_PX) -> Path:
    """Write a PNG at `path` of the scene's cloth as it is now (strain colours, red at `full_scale` strain) and its
    bodies (light grey): front, back and side views framed on the cloth (render_views), a title line (the scene,
    t, the largest strain) and the strain legend; panel_px: the panels' height [px] (frame). Returns the path."""
    data = scene.model.data
    x = np.asarray(scene.positions(), np.float64)[: data.n_particles]
    strain = vertex_strain(data, x)
    colormap = strain_colormap(full_scale)  # the recording's legend and vertex colours use the same map
    panels = render_views(x, np.asarray(data.triangles, np.int64), colormap.colors(strain)[:, :3] / 255.0,
                          body_meshes(scene), panel_px=panel_px)
    peak = float(strain.max()) if len(strain) else 0.0
    title = title or f"{scene.name}: t = {scene.state.t:.2f} s, max strain {100 * peak:.1f} %"
    return compose(panels, path, title, colormap)


def compose(panels: list[Panel], path, title: str, colormap) -> Path:
    """Lay the panels out side by side at one pixel per pixel (no resampling), each named above, the title line
    on top and the colour map's legend below, and write an RGB PNG at `path`. Returns the path."""
    import matplotlib.cm  # matplotlib (0.5 s to import): only when a picture is drawn
    import matplotlib.colors
    from matplotlib.figure import Figure

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    gap, side, top, bottom, dpi = GAP_PX, SIDE_PX, TOP_PX, BOTTOM_PX, 100
    H = max(p.rgb.shape[0] for p in panels)
    width = sum(p.rgb.shape[1] for p in panels) + gap * (len(panels) - 1) + 2 * side
    height = H + top + bottom
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi)
    x0 = side
    for p in panels:
        h, w = p.rgb.shape[:2]
        fig.figimage(p.rgb, xo=x0, yo=bottom + (H - h), origin="upper")
        fig.text((x0 + 0.5 * w) / width, (bottom + H + 6) / height, p.name, ha="center", va="bottom", fontsize=13)
        x0 += w + gap
    fig.text(0.5, 1.0 - 12 / height, title, ha="center", va="top", fontsize=13)
    bar_w = min(600, width - 2 * side)
    bar = fig.add_axes(((width - bar_w) / 2 / width, 62 / height, bar_w / width, 18 / height))
    low, high = colormap.range_percent
    fig.colorbar(matplotlib.cm.ScalarMappable(matplotlib.colors.Normalize(low, high), colormap.matplotlib()),
                 cax=bar, orientation="horizontal", label="strain [%] (the top colour: that and above)")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from PIL import Image  # matplotlib's own PNG writer: here without the alpha channel (a sixth smaller)

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    Image.fromarray(np.asarray(canvas.buffer_rgba())[..., :3]).save(path, format="png")
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
