"""Placement of 2D pattern pieces around the shipped mannequin (taichi_cloth.garment.placement): the body's
landmarks, parts and frames (taichi_cloth.body.landmarks), and the wrap rule (arc length kept along rows, clearance,
little stretch)."""
import math

import numpy as np
import pytest

from collision.mannequin import load_mannequin
from taichi_cloth.body.landmarks import PARTS, Body, _ray_hits
from taichi_cloth.errors import PatternError
from taichi_cloth.garment.placement import Placement, place

OFFSET = 0.02


@pytest.fixture(scope="module")
def body():
    return Body.from_mannequin()


def grid(width: float, height: float, step: float = 0.01):
    """Points (n,2) [m] of a width x height grid with `step` spacing, row by row (v outer), and its shape."""
    nu, nv = int(round(width / step)) + 1, int(round(height / step)) + 1
    u, v = np.meshgrid(np.linspace(0, width, nu), np.linspace(0, height, nv))
    return np.stack([u.ravel(), v.ravel()], axis=1), nu, nv


def grid_strain(points2d, points3d, nu: int, nv: int) -> float:
    """Largest 3D/2D length ratio - 1 over the grid's row and column edges."""
    idx = np.arange(nu * nv).reshape(nv, nu)
    edges = np.concatenate([np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], axis=1),
                            np.stack([idx[:-1].ravel(), idx[1:].ravel()], axis=1)])
    l2 = np.linalg.norm(points2d[edges[:, 0]] - points2d[edges[:, 1]], axis=1)
    l3 = np.linalg.norm(points3d[edges[:, 0]] - points3d[edges[:, 1]], axis=1)
    return float((l3 / l2 - 1).max())


def sleeve_outline_points(width=0.45, height=0.25, cap=0.13, step=0.01):
    """Grid points (n,2) [m] inside a sleeve: a width-wide strip (underarm seams 0.12 m) under a half-ellipse cap."""
    u, v = np.meshgrid(np.arange(0, width + 1e-9, step), np.arange(0, height + 1e-9, step))
    u, v = u.ravel(), v.ravel()
    base = height - cap
    half = np.where(v <= base, width / 2, width / 2 * np.sqrt(np.clip(1 - ((v - base) / cap) ** 2, 0, 1)))
    keep = np.abs(u - width / 2) <= half + 1e-9
    return np.stack([u[keep], v[keep]], axis=1)


def angular_coverage_deg(phi: np.ndarray) -> float:
    """360 minus the largest gap between the angles phi [rad] around the circle."""
    a = np.sort(np.degrees(phi))
    gaps = np.diff(np.concatenate([a, [a[0] + 360.0]]))
    return 360.0 - float(gaps.max())


# ------------------------------------------------------------------------------------------------ body

def test_landmarks_ordered_and_plausible(body):
    lm = body.landmarks
    order = ["crotch", "hips", "waist", "chest", "armpit", "shoulder", "neck"]
    heights = [lm[k] for k in order]
    assert heights == sorted(heights) and len(set(heights)) == len(heights), lm
    plausible = {"crotch": (0.70, 0.84), "hips": (0.82, 0.95), "waist": (0.98, 1.15), "chest": (1.12, 1.26),
                 "armpit": (1.22, 1.31), "shoulder": (1.32, 1.42), "neck": (1.38, 1.48)}
    for name, (lo, hi) in plausible.items():
        assert lo < lm[name] < hi, (name, lm[name])
    g = body.girths
    for name, (lo, hi) in {"chest": (0.72, 0.95), "waist": (0.60, 0.78), "hips": (0.88, 1.05),
                           "neck": (0.28, 0.38), "upper_arm": (0.20, 0.30)}.items():
        assert lo < g[name] < hi, (name, g[name])
    assert g["waist"] < g["chest"] < g["hips"]


def test_parts_split_arms_from_torso_symmetrically(body):
    v, lab = body.vertices, body.labels
    assert set(np.unique(lab)) == set(PARTS)
    left, right = lab == "arm_left", lab == "arm_right"
    assert left.sum() == right.sum() > 1000
    assert lab[np.argmax(v[:, 0])] == "arm_left" and lab[np.argmin(v[:, 0])] == "arm_right"
    assert np.all(v[left, 0] > 0.1) and np.all(v[right, 0] < -0.1)
    # below the armpit nothing of the arm comes within the torso's half width
    torso_below = (lab == "torso") & (v[:, 1] < body.landmarks["armpit"]) & (v[:, 1] > body.landmarks["waist"])
    assert np.abs(v[torso_below, 0]).max() < 0.17


def test_frames_are_orthonormal_and_the_arms_mirror(body):
    expected = {"torso_front", "torso_back", "waist_front", "waist_back", "hips_front", "hips_back",
                "arm_left", "arm_right"}
    assert expected <= set(body.frames)
    for f in body.frames.values():
        assert abs(np.linalg.norm(f.axis) - 1) < 1e-12 and abs(np.linalg.norm(f.front) - 1) < 1e-12
        assert abs(f.axis @ f.front) < 1e-12
        assert f.part in PARTS
    tf, tb = body.frames["torso_front"], body.frames["torso_back"]
    assert tf.front @ [0, 0, 1] > 0.999 and tb.front @ [0, 0, -1] > 0.999
    assert tf.side @ [1, 0, 0] > 0.999 and tb.side @ [-1, 0, 0] > 0.999
    assert abs(tf.origin[1] - body.landmarks["chest"]) < 1e-9
    mirror = np.array([-1.0, 1.0, 1.0])
    al, ar = body.frames["arm_left"], body.frames["arm_right"]
    for attr in ("origin", "axis", "front"):
        assert np.allclose(getattr(al, attr) * mirror, getattr(ar, attr), atol=2e-3), attr
    assert al.axis[1] > 0.5 and al.axis[0] < 0          # up the arm, toward the shoulder
    assert al.front[0] > 0.5                            # the arm's outer side
    assert al.part == "arm_left" and ar.part == "arm_right"


def test_radial_extent_is_never_below_the_surface(body):
    frame = body.frames["torso_front"]
    rng = np.random.default_rng(1)
    s = rng.uniform(-0.3, 0.3, 10_000)
    a = rng.uniform(-math.pi, math.pi, 10_000)
    ext = body.radial_extent(frame, s, a)
    tri = body.vertices[body.triangles[body._triangle_labels() == "torso"]]
    for k in range(60):
        direction = math.cos(a[k]) * frame.front + math.sin(a[k]) * frame.side
        hits = _ray_hits(frame.origin + s[k] * frame.axis, direction, tri)
        exact = hits.max() if len(hits) else 0.0
        assert exact - 1e-9 <= ext[k] <= exact + 0.25       # binned: conservative, never inside the body
    assert body.radial_extent("torso_front", s[:1], a[:1])[0] == ext[0]      # a frame name works too


def test_surface_point_and_signed_distance(body):
    front = body.surface_point("torso_front")
    assert abs(front[1] - body.landmarks["chest"]) < 1e-9 and 0.12 < front[2] < 0.18
    assert np.allclose(body.surface_point("torso_front", 0.05), front + [0, 0, 0.05])
    d = body.signed_distance([body.frames["torso_front"].origin, front + [0, 0, 0.03], [0, 1.0, 1.0]])
    assert d[0] == pytest.approx(-0.05) and d[1] == pytest.approx(0.03, abs=0.005) and d[2] == 0.05


def test_from_mesh_follows_a_wider_body(body):
    m = load_mannequin()
    wider = m.vertices * [1.06, 1.0, 1.06]
    other = Body.from_mesh(wider, m.triangles)
    for name in ("waist", "hips", "armpit", "neck"):
        assert abs(other.landmarks[name] - body.landmarks[name]) < 0.03, name
    for name in ("waist", "hips", "neck"):
        assert other.girths[name] == pytest.approx(1.06 * body.girths[name], rel=0.03), name


# ------------------------------------------------------------------------------------------- placement

def test_front_piece_wraps_with_rows_kept_and_clears_the_body(body):
    p2, nu, nv = grid(0.5, 0.6)
    x = place(p2, Placement("torso_front", offset=OFFSET), body)
    assert x.shape == p2.shape[:1] + (3,) and x.dtype == np.float64
    frame = body.frames["torso_front"]
    s, r, phi = frame.to_local(x)
    rows_r, rows_phi, rows_s = r.reshape(nv, nu), np.unwrap(phi.reshape(nv, nu), axis=1), s.reshape(nv, nu)
    assert np.ptp(rows_r, axis=1).max() < 1e-12                        # each row on one circle
    assert np.ptp(rows_s, axis=1).max() < 1e-12                        # at one axial position
    arc = rows_r[:, :1] * np.diff(rows_phi, axis=1)
    assert np.abs(arc - np.diff(p2[:, 0].reshape(nv, nu), axis=1)).max() < 1e-9
    clearance = body.signed_distance(x, max_distance=0.05)
    assert clearance.min() >= OFFSET / 2, clearance.min()
    centre = x[(nv // 2) * nu + nu // 2]
    assert abs(centre[1] - body.landmarks["chest"]) < 1e-9
    assert centre[2] > body.surface_point("torso_front")[2] + OFFSET - 1e-9
    assert abs(centre[0]) < 1e-9
    assert grid_strain(p2, x, nu, nv) < 0.06


def test_back_piece_lands_behind_and_runs_toward_minus_x(body):
    p2, nu, nv = grid(0.5, 0.6)
    x = place(p2, Placement("torso_back"), body)
    centre = x[(nv // 2) * nu + nu // 2]
    assert centre[2] < body.surface_point("torso_back")[2] - OFFSET
    row = x.reshape(nv, nu, 3)[nv // 2]
    assert np.all(np.diff(row[:, 0]) < 0)                               # +u runs toward -x
    assert body.signed_distance(x).min() >= OFFSET / 2
    assert grid_strain(p2, x, nu, nv) < 0.06


def test_sleeve_wraps_the_arm_and_clears_arm_and_torso(body):
    p2 = sleeve_outline_points()
    x = place(p2, Placement("arm_left"), body)
    frame = body.frames["arm_left"]
    _, _, phi = frame.to_local(x)
    assert angular_coverage_deg(phi) > 300
    assert body.signed_distance(x).min() >= OFFSET / 2
    # the right sleeve is the mirror image (the same drawing, seen from outside the other arm)
    xr = place(p2, Placement("arm_right"), body)
    assert np.allclose(np.sort(xr[:, 0]), np.sort(-x[:, 0]), atol=0.01)


def test_rectangle_sleeve_stays_clear(body):
    p2, nu, nv = grid(0.45, 0.25)
    x = place(p2, Placement("arm_left", at=(0.225, 0.25)), body)      # hangs from the middle of the upper arm
    assert body.signed_distance(x).min() >= OFFSET / 2
    assert grid_strain(p2, x, nu, nv) < 0.06


def test_turned_and_flat_placements(body):
    p2, nu, nv = grid(0.3, 0.4)
    side = place(p2, Placement("waist_front", angle=90.0), body)
    centre = side[(nv // 2) * nu + nu // 2]
    assert centre[0] > 0.12 and abs(centre[2] - body.frames["waist_front"].origin[2]) < 1e-9
    flat = place(p2, Placement("hips_back", wrap=False, offset=0.03), body)
    assert np.ptp(flat[:, 2]) < 1e-12                                   # a plane facing -z
    assert np.all(np.diff(flat.reshape(nv, nu, 3)[0, :, 0]) < 0)
    assert body.signed_distance(flat).min() >= 0.015


def test_placement_errors_name_the_problem(body):
    p2, _, _ = grid(0.1, 0.1)
    with pytest.raises(PatternError, match=r"'sleeve_left'.*arm_left, arm_right, hips_back"):
        place(p2, Placement("sleeve_left"), body)
    with pytest.raises(PatternError, match="offset must be >= 0"):
        Placement("torso_front", offset=-0.01)
    with pytest.raises(PatternError, match="height must be finite"):
        Placement("torso_front", height=float("nan"))
    with pytest.raises(PatternError, match="at must be two finite numbers"):
        Placement("torso_front", at=(0.1,))
    with pytest.raises(PatternError, match=r"shape \(n, 2\)"):
        place(np.zeros((4, 3)), Placement("torso_front"), body)


@pytest.mark.parametrize("key", ["u_axis", "v_axis"])
def test_a_free_placement_with_a_zero_axis_is_refused_naming_the_key(key):
    """A zero axis has no direction: the piece was placed at NaN. Refused when the placement is made, in Python and
    in a garment file, naming the key and its value."""
    from taichi_cloth.garment.garment import FreePlacement

    with pytest.raises(PatternError, match=rf"^free placement {key} must be a non-zero direction, got \(0, 0, 0\)$"):
        FreePlacement((0.0, 1.0, 0.0), **{key: (0, 0, 0)})
    with pytest.raises(PatternError, match=r"u_axis \(1, 0, 0\) and v_axis \(2, 0, 0\) are parallel"):
        FreePlacement((0.0, 1.0, 0.0), u_axis=(1, 0, 0), v_axis=(2, 0, 0))
    with pytest.raises(PatternError, match=r"free placement origin must be 3 finite numbers, got \(0.0, nan, 0.0\)"):
        FreePlacement((0.0, float("nan"), 0.0))


@pytest.mark.parametrize("placement, words", [
    ("{origin = [0, 100, 0], u_axis = [0, 0, 0]}",
     r"\[\[pieces\]\] #1 placement u_axis: must be non-zero \(a direction\), got \[0, 0, 0\]"),
    ("{origin = [0, 100, 0], v_axis = [0.0, 0.0, 0.0]}",
     r"\[\[pieces\]\] #1 placement v_axis: must be non-zero \(a direction\), got \[0.0, 0.0, 0.0\]"),
    ("{origin = [0, 100, 0], u_axis = [0, 1, 0]}",
     r"\[\[pieces\]\] #1 \('front'\) placement: u_axis \(0, 1, 0\) and v_axis \(0.0, 1.0, 0.0\) are parallel"),
])
def test_a_garment_file_refuses_a_zero_or_parallel_axis(tmp_path, placement, words):
    from taichi_cloth.garment.garmentfile import load_garment

    path = tmp_path / "flat.toml"
    path.write_text(f"""name = "flat"
units = "cm"
spacing = 5
[[pieces]]
name = "front"
outline = [{{at = [0, 0]}}, {{at = [20, 0]}}, {{at = [20, 20]}}, {{at = [0, 20]}}]
placement = {placement}
""")
    with pytest.raises(PatternError, match=rf"^{tmp_path / 'flat.toml'}: {words}$"):
        load_garment(path)
