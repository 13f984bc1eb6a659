"""The garment's girths against the body's: is a garment too small for its body, and where, in garment terms
("too small: the waistband is 68 cm and the waist 74 cm").

A garment's circumference is measured at rest, from its 2D pattern: the length the sewn garment has round the
body, seam to seam, adding nothing for the seam gaps (the seams will close). Never from the placed 3D shape,
which is stretched by its placement and open at the seams. Two kinds of place:

- **Girth planes** (`kind = "plane"`): the planes the `body` command measures the body's girths on
  (taichi_cloth.body.girth.GirthGauge): horizontal at the chest, the waist and the hips, for the pieces placed on
  the torso; for the pieces placed on an arm (sleeves), the plane through the arm frame's origin perpendicular
  to its axis, where the upper arm is measured. The placed garment's triangles are cut by the plane and each cut
  triangle's segment is measured in the triangle's 2D pattern coordinates. A torso piece is placed with its v
  along the frame's axis (taichi_cloth.garment.placement: s = v - at_v + height), so the cut is one row of the
  pattern, v = const, exactly: the circumference is the sum of the pieces' widths at that row, on the mesh (whose
  outline is the pattern's, resampled: straight sides exactly, curves as chords of about `spacing`). A plane counts
  only where the cut closes round the body: every end of a piece's cut must lie on a seam to another piece of the
  same group (torso, left arm, right arm). Where it ends in an unsewn edge (an armhole, a neckline, the plane above
  the garment's side seams) the garment does not go round the body there and the plane is left out.
- **Openings** (`kind = "opening"`): the loops of unsewn outline (a hem, a skirt's waistband, a neckline, a
  sleeve's hem), chained piece to piece through the seams' end corners; their length is the 2D length of their
  outline edges. An opening counts when, placed, it winds round the torso (or round its arm, for an arm's pieces):
  a sleeveless top's armholes do not. A torso opening is compared with the nearest of the body's neck, chest,
  waist and hips planes (by height): the lowest is "the hem", one nearest the waist "the waistband", one nearest
  the neck "the neckline"; an arm's opening, "the left/right sleeve's hem", with the upper arm.

Too small (`too_small`): a girth where the garment, stretched to the scene's stretch limit, cannot reach round
the body at the distance the cloth keeps from it: garment x (1 + stretch) < body + 2 pi clearance + min_ease.
`stretch` is the stretch limit's max_strain (0.1 by default: no spring of the cloth is longer than 1.1 times its
rest length, so no loop of the garment is either, a knit included: it is the most a fabric is let stretch);
`clearance` is the body collider's thickness (the cloth rests that far off the skin, which adds 2 pi x
thickness round a convex section: 2.5 cm at 4 mm); `min_ease` [m] is ease asked on top (0). It is a bound, not a
prediction: a garment inside it can still fail to close (a stiff fabric), and an opening that is too small for
the girth nearest it may ride up or down to a narrower part of the body; so the batch uses it to say why seams
stayed open, never to skip a run.

Units: metres throughout (the messages in cm).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import MeshError, TaichiClothError
from .garment import FreePlacement
from .seams import route

__all__ = ["Ease", "DEFAULT_STRETCH", "garment_girths", "scene_girths", "too_small", "too_small_message",
           "scene_too_small"]

#: the girths whose horizontal planes a torso piece is measured on
PLANE_GIRTHS = ("chest", "waist", "hips")
#: a torso opening is compared with the nearest of these (by the height of its plane)
OPENING_GIRTHS = ("neck", "chest", "waist", "hips")
#: [m] a girth plane that meets the garment where its cut does not close (an armhole: the T-shirt's 1.25 cm below the
#: mannequin's bust) is moved down by PLANE_STEP until it closes, by PLANE_DROP at most
PLANE_DROP, PLANE_STEP = 0.05, 0.0025
#: the garment's name for its circumference at a girth plane
PLANE_PARTS = {"chest": "chest line", "waist": "waistline", "hips": "hip line", "upper_arm": "sleeve"}
#: the stretch allowed when a scene has no stretch limit (the shipped scenes' max_strain)
DEFAULT_STRETCH = 0.1
_SIDES = {"arm_left": "left", "arm_right": "right"}


@dataclass(frozen=True)
class Ease:
    """One girth of the garment against the body's (a plain record; asdict() for a table).

    part: the garment's name for it ("hem", "waistband", "hip line", "left sleeve"...); girth: the body's girth
    (a GIRTHS name: "hips", "upper_arm"...); kind: "plane" or "opening"; garment: the garment's circumference at
    rest [m]; body: the body's girth [m] (as the `body` command measures it); height: [m] where (a plane's height,
    an opening's mean height as placed; for an arm, along the arm's axis from its frame's origin)."""

    part: str
    girth: str
    kind: str
    garment: float
    body: float
    height: float

    @property
    def ease(self) -> float:
        """[m] garment - body (negative: smaller than the body)."""
        return self.garment - self.body

    def as_dict(self) -> dict:
        return asdict(self)

    def describe(self) -> str:
        """"the hem is 104 cm and the hips 110 cm"."""
        body = self.girth.replace("_", " ")
        return f"the {self.part} is {_cm(self.garment)} and the {body} {_cm(self.body)}"


def _cm(metres: float) -> str:
    """A length in cm to 0.1 cm, without a trailing .0: 68 cm, 95.5 cm."""
    text = f"{100 * metres:.1f}"
    return (text[:-2] if text.endswith(".0") else text) + " cm"


# ------------------------------------------------------------------------------------------- measuring

def _groups(garment) -> list:
    """Per piece, the body part its placement wraps it round ("torso", "arm_left", "arm_right"), or None (laid
    flat without a body)."""
    out = []
    for m in garment.meshes:
        p = garment.spec.placements[m.piece.name]
        out.append(None if isinstance(p, FreePlacement) or garment.body is None else garment.body.frame(p.anchor).part)
    return out


def _anchors(garment) -> dict:
    """{group: a frame name of that group used by the garment}."""
    out = {}
    for m, g in zip(garment.meshes, _groups(garment)):
        if g is not None:
            out.setdefault(g, garment.spec.placements[m.piece.name].anchor)
    return out


def _routes(garment) -> list:
    """[(seam, SideRoute a, SideRoute b)] of every seam (recomputed from the pattern, as the build did)."""
    pieces = {m.piece.name: m.piece for m in garment.meshes}
    tol = garment.spec.spacing / 2000.0
    lengths = {n: np.array([s.length(tol) for s in p.segments]) for n, p in pieces.items()}
    return [(s, route(pieces[s.a.piece], s, s.a, lengths[s.a.piece]), route(pieces[s.b.piece], s, s.b,
                                                                              lengths[s.b.piece]))
            for s in garment.spec.seams]


def _sewn_within_group(garment, groups) -> np.ndarray:
    """(P,) bool: particles in a seam pair whose two particles' pieces are in the same group."""
    piece = garment.piece_of_particle()
    pairs = garment.seam_pairs
    g = np.array([groups[k] if groups[k] is not None else f"free{k}" for k in range(len(groups))], dtype=object)
    same = g[piece[pairs[:, 0]]] == g[piece[pairs[:, 1]]]
    out = np.zeros(garment.offsets[-1], bool)
    out[pairs[same].ravel()] = True
    return out


def _cut(garment, keep_tri: np.ndarray, distance: np.ndarray, sewn: np.ndarray):
    """(the 2D length [m] of the cut of the kept triangles by the plane where `distance` (P,) changes sign, whether
    the cut closes: no end of it on an outline edge that is not sewn within the group); (None, False) when the
    plane cuts none of them."""
    tri = garment.data.triangles[keep_tri]
    uv = garment.rest_uv()
    above = distance[tri] >= 0.0
    n_above = above.sum(1)
    cut = tri[(n_above == 1) | (n_above == 2)]
    if not len(cut):
        return None, False
    ab = above[(n_above == 1) | (n_above == 2)]
    pairs = ((0, 1), (1, 2), (2, 0))
    points, crossed = [], []
    for e0, e1 in pairs:
        i, j = cut[:, e0], cut[:, e1]
        c = ab[:, e0] != ab[:, e1]
        t = distance[i] / np.where(c, distance[i] - distance[j], 1.0)
        points.append(uv[i] + t[:, None] * (uv[j] - uv[i]))
        crossed.append(c)
    c = np.stack(crossed, 1)                        # (n, 3): every cut triangle has two crossed edges
    ends = np.stack(points, 1)[c].reshape(-1, 2, 2)
    length = float(np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1).sum())
    # the cut's ends: crossed edges of one triangle only (outline edges); each must be sewn
    edges = np.concatenate([np.sort(cut[:, [a, b]], 1)[c[:, k]] for k, (a, b) in enumerate(pairs)])
    all_edges = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), 1)
    uniq, count = np.unique(all_edges, axis=0, return_counts=True)
    outline = {tuple(e) for e in uniq[count == 1]}
    for a, b in edges:
        if (a, b) in outline and not (sewn[a] and sewn[b]):
            return length, False
    return length, True


def _winds(points2d: np.ndarray, centre: np.ndarray) -> bool:
    """Whether the closed polygon (n, 2) winds round `centre` (2,)."""
    d = points2d - centre
    ang = np.arctan2(d[:, 1], d[:, 0])
    turn = np.diff(np.concatenate([ang, ang[:1]]))
    turn = (turn + np.pi) % (2 * np.pi) - np.pi
    return abs(turn.sum()) > np.pi


def _openings(garment, groups) -> list:
    """[(group, vertex loop (original particles, in order, the seam gaps between runs jumped), 2D length [m])]
    of every loop of unsewn outline chained through the seams' end corners."""
    sewn = {}
    for seam, ra, rb in _routes(garment):
        for side, r in ((seam.a, ra), (seam.b, rb)):
            sewn.update({(side.piece, s): True for s in r.segments})
    uv = garment.rest_uv()
    runs = []   # (piece index, vertices in loop order)
    for k, m in enumerate(garment.meshes):
        n = len(m.piece.segments)
        free = [not sewn.get((m.piece.name, s), False) for s in range(n)]
        if all(free):
            continue   # a piece with no seam is an opening of its own only if it wraps: not a garment's opening
        start = next(s for s in range(n) if not free[s])   # begin after a sewn segment
        run = []
        for step in range(1, n + 1):
            s = (start + step) % n
            if free[s]:
                run.append(s)
            elif run:
                runs.append((k, run))
                run = []
        if run:
            runs.append((k, run))
    verts = []
    for k, segs in runs:
        bs = garment.meshes[k].boundary_segments
        v = np.concatenate([np.asarray(bs[segs[0]])] + [np.asarray(bs[s])[1:] for s in segs[1:]])
        verts.append(v + garment.offsets[k])
    # an end corner joins the run whose end is its seam partner
    partner = {}
    for a, b in garment.seam_pairs:
        partner.setdefault(int(a), []).append(int(b))
        partner.setdefault(int(b), []).append(int(a))
    end_of = {}
    for r, v in enumerate(verts):
        end_of.setdefault(int(v[0]), []).append((r, 0))
        end_of.setdefault(int(v[-1]), []).append((r, 1))

    def joined(r, e):
        """The (run, end) that end e of run r is sewn to, or None."""
        for q in partner.get(int(verts[r][-e]), []):   # -0: the start; -1: the end
            for other in end_of.get(q, []):
                if other != (r, e):
                    return other
        return None

    out, used = [], set()
    for r0 in range(len(verts)):
        if r0 in used:
            continue
        loop, r, e_in, closed = [], r0, 0, False
        while True:
            used.add(r)
            v = verts[r] if e_in == 0 else verts[r][::-1]
            loop.append(v)
            nxt = joined(r, 1 - e_in)
            if nxt is None:
                break
            r, e_in = nxt
            if r == r0:
                closed = True
                break
            if r in used:
                break
        if not closed:
            continue
        length = sum(float(np.linalg.norm(np.diff(uv[v], axis=0), axis=1).sum()) for v in loop)
        out.append((groups[runs[r0][0]], np.concatenate(loop), length))
    return out


def _body_girths(vertices, triangles):
    """(GirthGauge, {girth: m}) of a body: the shipped mannequin's gauge for its morphs, else one built on it."""
    from ..body.fit import default_body   # scipy: only here
    from ..body.girth import GirthGauge

    vertices = np.asarray(vertices, np.float64)
    gauge = default_body()[1]
    if vertices.shape != gauge.base.shape:
        gauge = GirthGauge.from_body(vertices, triangles)
    return gauge, gauge.measure(vertices)


def garment_girths(garment, vertices=None, triangles=None) -> list[Ease]:
    """The Ease of every girth the garment (a GarmentCloth, placed on its body) covers: its circumference at rest
    at the body's girth planes and at its openings, against the body's girths (module docstring). vertices,
    triangles: the body to measure (default: the body the garment was placed on; a morph of it, e.g. where the
    run morphed the body, must keep the garment's heights). [] for a garment placed without a body."""
    if garment.body is None:
        return []
    if vertices is None:
        vertices, triangles = garment.body.vertices, garment.body.triangles
    gauge, girths = _body_girths(vertices, triangles if triangles is not None else garment.body.triangles)
    vertices = np.asarray(vertices, np.float64)
    groups = _groups(garment)
    anchors = _anchors(garment)
    sewn = _sewn_within_group(garment, groups)
    x = garment.data.positions
    tri_group = np.array([groups[k] for k in garment.triangle_pieces()], dtype=object)
    out = []
    planes = {g: gauge.definitions[g].point(vertices)[1] for g in OPENING_GIRTHS if g in gauge.definitions}
    if "torso" in anchors:
        keep = tri_group == "torso"
        for g in PLANE_GIRTHS:
            if g not in planes:
                continue
            h = planes[g]
            length, closed = _cut(garment, keep, x[:, 1] - h, sewn)
            if length is None:
                continue   # the garment is not there
            while not closed and h > planes[g] - PLANE_DROP + 1e-9:   # an armhole, a neckline: a lower row
                h -= PLANE_STEP
                length, closed = _cut(garment, keep, x[:, 1] - h, sewn)
            if closed:
                out.append(Ease(PLANE_PARTS[g], g, "plane", length, girths[g], float(h)))
    for arm in ("arm_left", "arm_right"):
        if arm in anchors and "upper_arm" in girths:
            frame = garment.body.frame(arm)
            length, closed = _cut(garment, tri_group == arm, (x - frame.origin) @ frame.axis, sewn)
            if closed:
                out.append(Ease(f"{_SIDES[arm]} sleeve", "upper_arm", "plane", length, girths["upper_arm"], 0.0))
    torso_openings = []
    for group, loop, length in _openings(garment, groups):
        p = x[loop]
        if group == "torso":
            h = float(p[:, 1].mean())
            near = (garment.body.labels == "torso") & (np.abs(garment.body.vertices[:, 1] - h) < 0.01)
            centre = (garment.body.vertices[near][:, [0, 2]].mean(0) if near.any()
                      else garment.body.frame(anchors["torso"]).origin[[0, 2]])
            if _winds(p[:, [0, 2]], centre) and planes:
                g = min(planes, key=lambda n: abs(planes[n] - h))
                torso_openings.append((h, g, length))
        elif group in _SIDES and "upper_arm" in girths:
            frame = garment.body.frame(group)
            d = p - frame.origin
            if _winds(np.stack([d @ frame.front, d @ frame.side], 1), np.zeros(2)):
                out.append(Ease(f"{_SIDES[group]} sleeve's hem", "upper_arm", "opening", length, girths["upper_arm"],
                                float((d @ frame.axis).mean())))
    lowest = min((h for h, _, _ in torso_openings), default=None)
    for h, g, length in torso_openings:
        part = ("hem" if h == lowest else "waistband" if g == "waist" else "neckline" if g == "neck"
                else f"opening at the {g}")
        out.append(Ease(part, g, "opening", length, girths[g], h))
    return out


def too_small(eases, stretch: float = DEFAULT_STRETCH, clearance: float = 0.0, min_ease: float = 0.0) -> list[Ease]:
    """The girths of `eases` (garment_girths) where the garment is too small for the body: garment x (1 + stretch)
    < body + 2 pi clearance + min_ease (module docstring; stretch: the stretch limit's max_strain; clearance [m]:
    the body collider's thickness; min_ease [m]: ease asked on top)."""
    return [e for e in eases if e.garment * (1.0 + stretch) < e.body + 2 * math.pi * clearance + min_ease]


def too_small_message(items) -> str:
    """One line in garment terms: "too small: the hem is 104 cm and the hips 110 cm" (several joined by "; ");
    "" for none."""
    return "too small: " + "; ".join(e.describe() for e in items) if items else ""


def scene_girths(scene) -> tuple[list[Ease], float, float]:
    """(garment_girths of a garment scene's garment against its body collider as it is now, the stretch limit's
    max_strain (DEFAULT_STRETCH without one), the body collider's thickness [m] (0 without one))."""
    sewing = scene.controller("sewing")
    if sewing is None:
        return [], DEFAULT_STRETCH, 0.0
    limit = scene.controller("stretch_limit")
    stretch = float(limit.max_strain) if limit is not None else DEFAULT_STRETCH
    colliders = scene.controller("colliders")
    bodies = colliders.bodies if colliders is not None else []
    if not bodies:
        return garment_girths(sewing.garment), stretch, 0.0
    body = bodies[0]
    return garment_girths(sewing.garment, body.vertices_np, None), stretch, float(body.thickness)


def scene_too_small(scene, min_ease: float = 0.0) -> list[Ease]:
    """too_small of a garment scene (scene_girths: its stretch limit and its body's thickness)."""
    eases, stretch, clearance = scene_girths(scene)
    return too_small(eases, stretch, clearance, min_ease)


def scene_too_small_message(scene) -> str:
    """too_small_message of a garment scene: "" where the garment is not too small or its body cannot be measured
    (not a morph of the mannequin, and no girths found on it)."""
    try:
        return too_small_message(scene_too_small(scene))
    except (TaichiClothError, MeshError):
        return ""
