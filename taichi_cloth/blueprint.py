"""The default layout (Rerun blueprint) of a recording: what a user sees on opening it.

The 3D view large, looking at the cloth from the front (+z) at a distance that frames it as the still pictures'
front view does (fit_distance), the pattern's 2D view (origin /pattern) as a tab for garments, the strain colours'
legend under it, and the plots grouped beside it (energy, strain, seam gap, speed, level, events). The recorder
(taichi_cloth.recorder) keeps a Shown per cloth entity and sends default_blueprint when the box it frames changes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import rerun.blueprint as rrb

from .still import FRAME_MARGIN

#: the entity of the strain colours' legend (a colour bar image)
LEGEND = "legend/strain"
#: the plots of the default blueprint: (the first part of a series path under metrics/<entity>/, the view's name)
PLOTS = (("energy", "energy [J]"), ("strain", "max strain [-]"), ("seam_gap", "seam gap [mm]"),
         ("speed", "max speed [m/s]"), ("level", "level"))
#: the viewer's vertical field of view [deg] and the 3D view's width / height in the default blueprint
CAMERA_FOV_Y, VIEW_ASPECT = 55.0, 1.1


@dataclass
class Shown:
    """What the blueprint shows of one cloth entity: its SceneLayout, and its box [m] at its last frame logged (the
    translation applied), (3,) lo and hi, None before; points: that frame's (P,3) positions [m] (no translation)."""

    layout: object
    translation: np.ndarray
    lo: np.ndarray | None = None
    hi: np.ndarray | None = None
    points: np.ndarray | None = None


def camera(center: np.ndarray, elevation: float, distance: float) -> tuple[np.ndarray, np.ndarray]:
    """(eye (3,) [m], basis (3,3): rows right, up, forward) of the default 3D view's camera: `distance` [m] in
    front (+z) of `center`, `elevation` [m] above it, looking at it, y up."""
    eye = center + np.array([0.0, elevation, distance])
    forward = (center - eye) / np.linalg.norm(center - eye)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    return eye, np.stack([right, np.cross(right, forward), forward])


def fit_distance(points: np.ndarray, center: np.ndarray, elevation: float, pad: float) -> float:
    """The least distance [m] in front (+z) of `center` (3,) [m] at which the default 3D view's camera (_camera;
    CAMERA_FOV_Y high, VIEW_ASPECT wide) sees every one of `points` (N,3) [m] with `pad` [m] to spare around it at
    its depth, as the still pictures' orthographic views frame the cloth (taichi_cloth.still.FRAME_MARGIN). Fitting
    the points rather than the box's front face lets a garment fill the view: its widest part (the sleeves) lies
    behind the front face, a quarter smaller there in perspective. Bisection: the fit holds from that distance on."""
    tan_y = np.tan(np.radians(CAMERA_FOV_Y) / 2)
    tan = np.array([tan_y * VIEW_ASPECT, tan_y])
    x = np.asarray(points, np.float64).reshape(-1, 3)
    x = x[np.isfinite(x).all(axis=1)]
    if not len(x) or not np.isfinite(center).all():
        return 1.0  # a cloth that blew up: any distance (the run says why)

    def fits(distance: float) -> bool:
        eye, basis = camera(center, elevation, distance)
        d = (x - eye) @ basis.T
        return bool((d[:, 2] > 0).all() and ((np.abs(d[:, :2]) + pad) <= d[:, 2:] * tan).all())

    near, far = 0.0, 1.0 + float(np.abs(x - center).max(initial=0.0)) / tan_y
    for _ in range(60):
        if fits(far):
            break
        far *= 2.0
    for _ in range(40):  # to within 1e-12 of the far bound's first guess
        mid = 0.5 * (near + far)
        near, far = (near, mid) if fits(mid) else (mid, far)
    return far


def default_blueprint(shown: dict, lo: np.ndarray, hi: np.ndarray, points: np.ndarray) -> rrb.Blueprint:
    """The default layout of the cloths `shown`: the 3D view (a camera in front (+z) of the box lo..hi [m] of
    every cloth's last frame, looking at its centre, as near as it can be while it sees all of those frames'
    `points` (N,3) [m] with the still pictures' margin: fit_distance; the viewer opens a recording at its end)
    with the pattern as a tab for garments and the strain legend below, the grouped plots and the events beside
    it."""
    center, size = 0.5 * (lo + hi), np.maximum(hi - lo, 0.05)
    # a little from above; the margin of taichi_cloth.still: FRAME_MARGIN of the box's largest extent
    elevation, pad = 0.1 * size[1], FRAME_MARGIN * float(size.max())
    distance = fit_distance(points, center, elevation, pad)
    eye = rrb.EyeControls3D(position=(center + [0.0, elevation, distance]).tolist(),
                            look_target=center.tolist(), eye_up=[0.0, 1.0, 0.0])
    scene = rrb.Spatial3DView(name="scene", origin="/", eye_controls=eye,
                              background=rrb.BackgroundKind.GradientDark,  # the white of no strain stands out
                              contents=["+ /**", "- /metrics/**", f"- /{LEGEND}/**", "- /pattern/**"])
    if any(s.layout.garment for s in shown.values()):
        scene = rrb.Tabs(scene, rrb.Spatial2DView(name="pattern", origin="/pattern"), active_tab=0)
    left, shares = [scene], [1.0]
    if any(s.layout.strain_scale is not None for s in shown.values()):
        left.append(rrb.Spatial2DView(name="strain colours", origin=f"/{LEGEND}"))
        shares = [7.0, 1.0]
    plots = []
    for group, name in PLOTS:
        contents = [f"/metrics/{e}/{group}/**" for e, s in shown.items()
                    if any(path.split("/")[0] == group for path in s.layout.series)]
        if contents:
            plots.append(rrb.TimeSeriesView(name=name, origin="/metrics", contents=contents,
                                            plot_legend=rrb.Corner2D.RightTop))
    events = rrb.TextLogView(name="events", origin="/", contents=[f"/{e}/events" for e in shown])
    speed = [f"/metrics/{e}/perf/**" for e, s in shown.items() if "perf/steps_per_s" in s.layout.series]
    if speed:
        events = rrb.Tabs(events, rrb.TimeSeriesView(name="steps per second", origin="/metrics", contents=speed,
                                                     plot_legend=rrb.Corner2D.RightTop))
    plots.append(events)
    return rrb.Blueprint(
        rrb.Horizontal(rrb.Vertical(*left, row_shares=shares), rrb.Vertical(*plots), column_shares=[3, 2]),
        rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed"))
