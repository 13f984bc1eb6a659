"""Write the shipped GarmentCode garments: sewing patterns in the `specification.json` format of GarmentCode's
pygarment library (Korosteleva and Sorkine-Hornung, "GarmentCode: Programming Parametric Sewing Patterns",
SIGGRAPH Asia 2023), drawn here for the shipped mannequin, so that the GarmentCode reader has garments to sew:

    python demos/garments/make_garmentcode.py    # writes trousers.json, dress.json and flared_skirt.json here

Each panel is drawn in centimetres as seen from the front (x to the body's left, y up, the floor at 0) and laid
flat in a plane in front of or behind the body (its `translation`; the dress's side panels are turned by 90 degrees
to face the body's sides): front panels wind counter-clockwise, back panels clockwise, so that each faces out of
the body. Seams join the panels' edges
(`stitches`); which ends meet is read from where the panels lie. Measures of the mannequin used (cm): waist
66.9 at 108.3, hips 95.5 at 87.7, crotch at 77.2, neck base at 142.7, armpit at 126.5.
"""
import json
import math
from pathlib import Path

HERE = Path(__file__).resolve().parent


def control(start, end, point):
    """pygarment's relative coordinates [t, k] of the control point `point` of the curve start -> end: point =
    start + t e + k perp(e), e = end - start, perp(e) = (-e_y, e_x)."""
    ex, ey = end[0] - start[0], end[1] - start[1]
    dx, dy = point[0] - start[0], point[1] - start[1]
    n = ex * ex + ey * ey
    return [round((dx * ex + dy * ey) / n, 6), round((dx * -ey + dy * ex) / n, 6)]


def reverse(outline):
    """The same loop run the other way round: [(point, curve to the next point)] with each edge's curve turned
    (a cubic's control points swapped, a circle's side flipped)."""
    n = len(outline)
    out = []
    for k in range(n):
        point = outline[(n - k) % n][0]
        curve = outline[(n - k - 1) % n][1]  # the edge that now runs from `point` to the next
        if curve is not None:
            kind, *params = curve
            if kind == "cubic":
                params = params[::-1]
            elif kind == "circle":
                params = [params[0], params[1], 1 - params[2]]
            curve = (kind, *params)
        out.append((point, curve))
    return out


def mirror(outline):
    """The loop's mirror image across the body's mid-plane (x -> -x), reversed so that it winds as before."""
    def flip(p):
        return (-p[0], p[1])

    out = []
    for point, curve in outline:
        if curve is not None:
            kind, *params = curve
            curve = ((kind, params[0], params[1], 1 - params[2]) if kind == "circle"
                     else (kind, *[flip(q) for q in params]))
        out.append((flip(point), curve))
    return reverse(out)


def panel(outline, z, x=0.0, turn=0.0):
    """The specification's panel of `outline` [(point (x, y) cm, curve to the next point: None, ("quadratic",
    control), ("cubic", control1, control2) or ("circle", radius, large_arc, right))] laid flat at depth z [cm],
    its origin at x [cm], turned by `turn` [deg] about the vertical (90: the panel's x runs backward, it faces
    the body's left)."""
    n = len(outline)
    edges = []
    for k, (a, curve) in enumerate(outline):
        edge = {"endpoints": [k, (k + 1) % n]}
        if curve is not None:
            kind, *params = curve
            b = outline[(k + 1) % n][0]
            edge["curvature"] = ({"type": "circle", "params": [params[0], int(params[1]), int(params[2])]}
                                 if kind == "circle" else
                                 {"type": kind, "params": [control(a, b, q) for q in params]})
        edges.append(edge)
    return {"translation": [x, 0.0, z], "rotation": [0.0, turn, 0.0],
            "vertices": [[round(p[0], 4), round(p[1], 4)] for p, _ in outline], "edges": edges}


def specification(panels, stitches):
    return {"pattern": {"panels": panels, "stitches": stitches, "panel_order": list(panels)},
            "parameters": {}, "parameter_order": [],
            "properties": {"curvature_coords": "relative", "normalize_panel_translation": False,
                           "normalized_edge_loops": True, "units_in_meter": 100}}


def edge(outline, a, b):
    """The index of the edge of `outline` (as a panel writes it) that joins points a and b, either way round."""
    points = [p for p, _ in outline]
    n = len(points)
    for k in range(n):
        if {points[k], points[(k + 1) % n]} == {a, b}:
            return k
    raise KeyError((a, b))


def trousers():
    """Wide-legged trousers: a front and a back panel a leg, crotch seams front and back, inseams and outseams;
    waist 75 cm at 106-106.5 cm, hips 104 cm, rise 74.5 cm front waist to back waist (the crotch 5 cm below the
    body's), hems 43 cm round at 8 cm. The panels lie 6 cm off the centre line so that the crotch extensions of
    the two legs do not overlap. The crotch curves meet the inseams at right angles or less (four panels meet
    there: more than 360 degrees of cloth round the point folds through itself), and the centre back leans out by
    3 cm at the waist (a straight one stood off the small of the back in a fold that crossed itself)."""
    q = "quadratic"
    front = [((6.5, 106.0), None), ((6.5, 84.0), (q, (6.5, 72.0))), ((0.5, 72.0), None), ((15.0, 8.0), None),
             ((36.0, 8.0), None), ((32.0, 87.7), (q, (30.5, 100.0))), ((26.0, 106.0), None)]
    back = [((9.5, 106.5), None), ((6.5, 84.0), (q, (6.5, 72.0))), ((0.5, 72.0), None), ((15.0, 8.0), None),
            ((37.0, 8.0), None), ((33.0, 87.7), (q, (31.5, 100.0))), ((27.5, 106.0), None)]
    outlines = {"front_left": (front, 20.0), "front_right": (mirror(front), 20.0),
                "back_left": (reverse(back), -16.0), "back_right": (mirror(reverse(back)), -16.0)}
    panels = {name: panel(o, z) for name, (o, z) in outlines.items()}

    def at(name, a, b):
        o = outlines[name][0]
        if name.endswith("right"):
            a, b = (-a[0], a[1]), (-b[0], b[1])
        return {"panel": name, "edge": edge(o, a, b)}

    stitches = []
    for side in ("left", "right"):
        f, b = f"front_{side}", f"back_{side}"
        stitches += [[at(f, (36.0, 8.0), (32.0, 87.7)), at(b, (37.0, 8.0), (33.0, 87.7))],    # outseam, lower
                     [at(f, (32.0, 87.7), (26.0, 106.0)), at(b, (33.0, 87.7), (27.5, 106.0))],  # outseam, hip
                     [at(f, (0.5, 72.0), (15.0, 8.0)), at(b, (0.5, 72.0), (15.0, 8.0))]]       # inseam
    for f in ("front", "back"):
        top = (6.5, 106.0) if f == "front" else (9.5, 106.5)
        stitches += [[at(f"{f}_left", top, (6.5, 84.0)), at(f"{f}_right", top, (6.5, 84.0))],          # centre
                     [at(f"{f}_left", (6.5, 84.0), (0.5, 72.0)), at(f"{f}_right", (6.5, 84.0), (0.5, 72.0))]]  # crotch
    return specification(panels, stitches)


def dress():
    """A sleeveless A-line dress: a front, a back and a side panel under each arm (the arms hang too close to
    the torso for front and back alone to reach round the chest), shoulder seams, side seams; chest 92 cm at
    118 cm, hips 103 cm, hem 127 cm round at 62 cm; neckline 8.5 cm deep in front, 2 cm at the back."""
    q = "quadratic"

    def outline(neck):  # front or back as seen from the front, counter-clockwise from the left hem
        return [((27.0, 62.0), None), ((21.5, 87.7), None), ((19.5, 118.0), (q, (14.5, 124.0))),
                ((15.0, 141.0), None), ((7.0, 145.0), (q, (0.0, neck))), ((-7.0, 145.0), None),
                ((-15.0, 141.0), (q, (-14.5, 124.0))), ((-19.5, 118.0), None), ((-21.5, 87.7), None),
                ((-27.0, 62.0), None)]

    front, back = outline(128.0), reverse(outline(141.0))
    side = [((-9.5, 62.0), None), ((9.5, 62.0), None), ((4.0, 87.7), None), ((3.5, 118.0), None),
            ((-3.5, 118.0), None), ((-4.0, 87.7), None)]
    panels = {"front": panel(front, 21.0), "back": panel(back, -16.0),
              "side_left": panel(side, 2.5, x=21.5, turn=90.0), "side_right": panel(side, 2.5, x=-21.5, turn=-90.0)}
    stitches = []
    for sign, name in ((1.0, "left"), (-1.0, "right")):
        def at(panel_name, a, b, o):
            return {"panel": panel_name, "edge": edge(o, (sign * a[0], a[1]), (sign * b[0], b[1]))}

        stitches.append([at("front", (15.0, 141.0), (7.0, 145.0), front),  # the shoulder
                         at("back", (15.0, 141.0), (7.0, 145.0), back)])
        # the side panel's u runs backward on the left, forward on the right: its edge toward the front at u < 0
        # on the left
        for main, o, u in (("front", front, -sign), ("back", back, sign)):
            stitches += [[at(main, (19.5, 118.0), (21.5, 87.7), o),
                          {"panel": f"side_{name}", "edge": edge(side, (3.5 * u, 118.0), (4.0 * u, 87.7))}],
                         [at(main, (21.5, 87.7), (27.0, 62.0), o),
                          {"panel": f"side_{name}", "edge": edge(side, (4.0 * u, 87.7), (9.5 * u, 62.0))}]]
    return specification(panels, stitches)


def flared_skirt():
    """A third-circle skirt: a front and a back panel, each a sixth of an annulus (circle-arc waist and hem, the
    edges GarmentCode writes as "circle" curvature), sewn at the sides; waist 69 cm (1.5 cm of ease: a looser
    waist creeps down the body), 45 cm long, hem 163 cm round. The sides' waist ends lie at 110.5 cm."""
    waist, length, turn = 69.0, 45.0, math.pi / 3  # [cm], [cm], each panel's angle [rad]
    r0 = 0.5 * waist / turn
    r1 = r0 + length
    c, s = math.cos(0.5 * turn), math.sin(0.5 * turn)
    apex = 110.5 + r0 * c

    def at(r, side):
        return (round(side * r * s, 4), round(apex - r * c, 4))

    # counter-clockwise from the waist's right end: the hem sags below its chord (to the right of -> +x), the
    # waist too (to the left of its direction, -x)
    front = [(at(r0, -1), None), (at(r1, -1), ("circle", r1, 0, 1)), (at(r1, 1), None),
             (at(r0, 1), ("circle", r0, 0, 0))]
    back = reverse(front)
    panels = {"front": panel(front, 20.0), "back": panel(back, -15.0)}
    stitches = [[{"panel": "front", "edge": edge(front, at(r0, side), at(r1, side))},
                 {"panel": "back", "edge": edge(back, at(r0, side), at(r1, side))}] for side in (-1, 1)]
    return specification(panels, stitches)


GARMENTS = {"trousers": trousers, "dress": dress, "flared_skirt": flared_skirt}

if __name__ == "__main__":
    for name, make in GARMENTS.items():
        path = HERE / f"{name}.json"
        path.write_text(json.dumps(make(), indent=1) + "\n", encoding="utf-8")
        print("wrote", path)
