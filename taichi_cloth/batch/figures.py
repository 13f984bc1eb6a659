"""A finished job's status and figures: the garment quality row (taichi_cloth.garment.metrics) and the gap between
the garment and the body at the chest, waist and hips.

Status, first that holds: "too small" (seams open, as below, and the garment too small for the body at one of its
girths: taichi_cloth.garment.ease, the reason in garment terms, "too small: the waistband is 68 cm and the waist
74 cm", then the open seams), "seams open" (a seam pair still wider than the sewing's epsilon at the end: sewing gave
up, or was still closing at the frame cap), "inside the body" (more particles inside the body than [run]
max_inside), "not at rest by the cap" (with until_rest: the cap came first), else "ok". The too-small check is made only
once the seams stayed open, never before the run: it is a bound at the stretch limit, and an opening can ride to a
narrower part of the body (taichi_cloth.garment.ease). A run that blew up, ran out of time or failed never gets here (the worker and the scheduler name those).

The gap at a girth: the median distance [m] to the body's surface of the cloth particles within GAP_BAND of the
girth's plane (the horizontal plane the `body` command measures that girth on, on this body); None where no
cloth is there (a skirt at the chest).
"""
from __future__ import annotations

import numpy as np

from ..garment.ease import scene_too_small_message
from ..garment.metrics import garment_quality

#: the girths whose gap to the garment a row reports
GAP_GIRTHS = ("chest", "waist", "hips")
#: [m] half the height of the band of cloth particles the gap at a girth is taken over
GAP_BAND = 0.015

OK, SEAMS_OPEN, INSIDE, NOT_AT_REST = "ok", "seams open", "inside the body", "not at rest by the cap"
BLEW_UP, TIMED_OUT, ERROR = "blew up", "timed out", "error"
#: seams open because the garment is smaller than the body (the reason says where, in garment terms)
TOO_SMALL = "too small"
#: every status a row can have, the good one first
STATUSES = (OK, BLEW_UP, TOO_SMALL, SEAMS_OPEN, NOT_AT_REST, INSIDE, TIMED_OUT, ERROR)


def body_gaps(scene) -> dict:
    """{girth: median gap [m] or None} for GAP_GIRTHS, on the scene's first mesh collider (the body)."""
    from ..body import default_body  # scipy: the girth gauge

    colliders = scene.controller("colliders")
    bodies = colliders.bodies if colliders is not None else []
    if not bodies:
        return {g: None for g in GAP_GIRTHS}
    body = bodies[0]
    gauge = default_body()[1]
    if body.vertices_np.shape != gauge.base.shape:  # not a morph of the shipped mannequin: no girth planes
        return {g: None for g in GAP_GIRTHS}
    x = np.asarray(scene.positions(), np.float64)[: scene.model.data.n_particles]
    distance = body.signed_distance(x)
    out = {}
    for g in GAP_GIRTHS:
        y = gauge.definitions[g].point(body.vertices_np)[1]
        near = np.abs(x[:, 1] - y) < GAP_BAND
        out[g] = float(np.median(distance[near])) if near.any() else None
    return out


def seams_open_status(scene, reason: str) -> tuple[str, str]:
    """(status, reason) of a job whose seams stayed open: TOO_SMALL with the garment's too-small girths in words
    before `reason` (the open seams) where the garment is too small for the body (ease.scene_too_small), else
    SEAMS_OPEN with `reason`. A check that cannot measure this body (not a morph of the mannequin, and no girths
    found on it) leaves SEAMS_OPEN."""
    small = scene_too_small_message(scene)
    if not small:
        return SEAMS_OPEN, reason
    return TOO_SMALL, "; ".join(x for x in (small, reason) if x)


def finished_row(scene, summary, run: dict) -> dict:
    """The status, its reason and the figures of a job whose run ended (at rest or at the cap)."""
    quality = garment_quality(scene)
    sewing = scene.controller("sewing")
    opened = sewing.open_seams(sewing.gaps()) if sewing is not None else {}
    rest = scene.rest.status
    row = {"frames": summary.frames, "steps": summary.steps, "sim_time_s": summary.sim_time,
           "first_frame_s": summary.first_frame_wall, "particles": summary.n_particles,
           "rest_time_s": rest.since if rest is not None and rest.at_rest else None,
           "max_strain": max((p.max_strain for p in quality.pieces), default=None),
           "mean_strain": (float(np.mean([p.mean_strain for p in quality.pieces])) if quality.pieces else None),
           "area_error_max": max((p.area_error for p in quality.pieces), default=None),
           "seam_gap_max_mm": 1e3 * quality.seam_gap_max, "inside": quality.penetrations,
           "max_speed_mm_s": 1e3 * quality.max_speed}
    for p in quality.pieces:
        row[f"area_error_{p.name}"] = p.area_error
    for g, gap in body_gaps(scene).items():
        row[f"gap_{g}_mm"] = None if gap is None else 1e3 * gap
    inside = quality.penetrations or 0
    if opened or (sewing is not None and (sewing.active or sewing.gave_up)):
        why = "sewing gave up" if sewing.gave_up else ("still sewing at the frame cap" if sewing.active else "")
        seams = ", ".join(f"{k} {1e3 * v:.1f} mm" for k, v in opened.items())
        status, reason = seams_open_status(scene, "; ".join(x for x in (why, seams) if x))
    elif inside > run["max_inside"]:
        status, reason = INSIDE, f"{inside} particles inside the body (max_inside {run['max_inside']})"
    elif run["until_rest"] and not summary.stopped_at_rest:
        status = NOT_AT_REST
        reason = (rest.describe(scene.rest.criterion) if rest is not None else "no frame ran") + \
            f" at frame {summary.frames}"
    else:
        status, reason = OK, ""
    return dict(row, status=status, reason=reason)
