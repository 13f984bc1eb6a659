"""3D -> 2D flattening (Fan et al. 1998 section 3.2): developable pieces exactly, doubly curved ones with finite errors
that grow with the curvature, flat pieces unchanged, and clear errors for meshes that are not discs."""
import numpy as np
import pytest

from taichi_cloth.errors import MeshError
from taichi_cloth.flatten import disc_boundary, flatten, flatten_pieces, plot_flat, unfold, write_flat_dxf
from taichi_cloth.garment.dxf import read_dxf
from taichi_cloth.garment.mesh import mesh_piece
from taichi_cloth.garment.pattern import PatternPiece


def grid(n: int, m: int):
    """(s, w) in [0, 1]^2 on an n x m vertex grid and its counter-clockwise triangles (T, 3)."""
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    idx = i * m + j
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    tri = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return i.ravel() / (n - 1), j.ravel() / (m - 1), tri


@pytest.fixture(scope="module")
def disc():
    """A round pattern piece (radius 0.2 m) meshed by the garment mesher: (uv (V,2), triangles, outline)."""
    piece = PatternPiece.from_polygon("disc", 0.2 * np.c_[np.cos(np.linspace(0, 2 * np.pi, 48, endpoint=False)),
                                                         np.sin(np.linspace(0, 2 * np.pi, 48, endpoint=False))])
    m = mesh_piece(piece, 0.025)
    return m.uv, m.triangles, m.boundary_loop


def sphere_cap(uv, angle: float, radius: float = 0.3):
    """The disc mapped onto a sphere of `radius` [m]: the rim at polar angle `angle` [rad], arc length kept
    proportional to the disc radius (the cap is seen from outside, so the winding stays outward)."""
    rho = np.linalg.norm(uv, axis=1)
    phi = np.arctan2(uv[:, 1], uv[:, 0])
    theta = rho / rho.max() * angle
    return radius * np.c_[np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]


def test_cylinder_patch_is_developable_and_flattens_exactly():
    s, w, tri = grid(25, 13)
    theta = 0.75 * np.pi * s  # 135 degrees of a 0.3 m cylinder, 0.4 m high
    v = np.c_[0.3 * np.cos(theta), 0.4 * w, 0.3 * np.sin(theta)]
    piece = flatten(v, tri, "cylinder")
    assert piece.area_error < 1e-3 and piece.boundary_error < 1e-3  # the bound: 0.1 %
    assert piece.area_error < 1e-12 and piece.boundary_error < 1e-12  # measured: exact (unfolding is exact)
    assert np.abs(piece.edge_error).max() < 1e-12
    assert piece.flipped == 0
    # the unrolled rectangle: width = arc length, height = 0.4
    ext = np.ptp(piece.aligned_to(np.c_[0.3 * theta, 0.4 * w]), axis=0)
    np.testing.assert_allclose(sorted(ext), sorted([0.4, 24 * 0.6 * np.sin(np.pi / 64)]), rtol=1e-12)  # 24 chords


def test_flat_piece_round_trips(disc):
    uv, tri, loop = disc
    rot = np.linalg.qr(np.array([[0.3, -0.8, 0.5], [0.9, 0.1, -0.4], [0.2, 0.6, 0.7]]))[0]
    v = np.c_[uv, np.zeros(len(uv))] @ rot.T + [0.1, 1.2, -0.3]  # the same sheet, tilted and moved in 3D
    piece = flatten(v, tri, "flat")
    assert piece.iterations == 0  # nothing to relax
    np.testing.assert_allclose(piece.aligned_to(uv), uv, atol=1e-12)
    assert piece.area_error < 1e-12 and piece.boundary_error < 1e-12
    np.testing.assert_array_equal(np.sort(piece.boundary), np.sort(loop))


@pytest.mark.slow
def test_sphere_caps_have_finite_errors_that_grow_with_the_cap_angle(disc):
    uv, tri, _ = disc
    angles = [0.25, 0.5, 0.75, 1.0]  # polar angle of the rim [rad]
    pieces = flatten_pieces([(f"cap{a}", sphere_cap(uv, a), tri, None) for a in angles])
    area = [p.area_error for p in pieces]
    bound = [p.boundary_error for p in pieces]
    for p in pieces:
        assert p.flipped == 0
        assert np.isfinite(p.uv).all() and 0 < p.area_error < 0.05 and 0 < p.boundary_error < 0.2
        assert p.energy[-1] < p.energy[0]  # the relaxation lowered the elastic energy
        assert abs(p.energy[-2] - p.energy[-1]) <= 1e-6 * p.energy[-2]  # and stopped on the energy criterion
    assert np.all(np.diff(area) > 0) and np.all(np.diff(bound) > 0)
    # a sphere cap's rim is shorter than a flat disc of the same area: the layout cannot keep both, and the
    # 2D outline comes out longer than the 3D one
    assert all(p.boundary_2d > p.boundary_3d for p in pieces)
    # relaxing improves on the raw unfolding
    assert all(p.boundary_error < p.initial_boundary_error for p in pieces)
    # the springs settle near the equal-area layout (area error 0.03-0.6 %): a disc of the cap's area
    # 2 pi R^2 (1 - cos a) has a rim 1 / cos(a / 2) times the cap's, the boundary error we measure within 3 %
    for p, a in zip(pieces, angles):
        assert p.boundary_error == pytest.approx(1 / np.cos(a / 2) - 1, rel=0.03), p.name


def test_flattened_piece_exports_dxf_with_its_corners_and_a_plot(disc, tmp_path):
    uv, tri, loop = disc
    corners = {"a": int(loop[0]), "b": int(loop[len(loop) // 2])}
    piece = flatten(sphere_cap(uv, 0.5), tri, "cap", corners=corners)
    path = write_flat_dxf([piece], tmp_path / "cap.dxf")
    (back,) = read_dxf(path)
    assert back.name == "cap" and sorted(back.corner_names) == ["a", "b"]
    assert back.area() == pytest.approx(piece.area_2d, rel=1e-6)  # mm in the file
    png = plot_flat([piece], tmp_path / "cap.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_unfolding_keeps_every_triangle_of_a_disc_counter_clockwise(disc):
    uv, tri, _ = disc
    flat = unfold(sphere_cap(uv, 0.8), tri)
    p = flat[tri]
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    assert (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0] > 0).all()


@pytest.mark.parametrize("case, message", [
    ("tube", "2 boundary loops"),
    ("closed", "closed surface"),
    ("two", "2 separate pieces"),
    ("flipped", "not consistently wound"),
    ("empty", "no vertices"),
])
def test_meshes_that_are_not_discs_are_refused(case, message):
    s, w, tri = grid(9, 5)
    v = np.c_[np.cos(2 * np.pi * s), w, np.sin(2 * np.pi * s)]
    if case == "tube":  # weld the seam of the unrolled cylinder
        n, m = 9, 5
        seam = (np.arange(len(s)) // m == n - 1)
        idx = np.arange(len(s))
        idx[seam] -= (n - 1) * m
        tri = idx[tri]
        keep = np.unique(tri)
        v, tri = v[keep], np.searchsorted(keep, tri)
    elif case == "closed":
        import trimesh

        ico = trimesh.creation.icosphere(1)
        v, tri = ico.vertices, ico.faces
    elif case == "two":
        tri = np.concatenate([tri, tri + len(v)])
        v = np.concatenate([v, v + 5.0])
    elif case == "flipped":
        tri = tri.copy()
        tri[0] = tri[0, ::-1]
    elif case == "empty":
        v, tri = np.zeros((0, 3)), np.zeros((0, 3), int)
    with pytest.raises(MeshError, match=message):
        disc_boundary(v, tri, "piece.obj")


def test_flatten_cli_writes_dxf_and_png(disc, tmp_path, capsys):
    import trimesh

    from taichi_cloth.cli import main

    uv, tri, _ = disc
    obj = tmp_path / "cap.obj"
    trimesh.Trimesh(sphere_cap(uv, 0.5), tri, process=False).export(obj)
    assert main(["flatten", str(obj), "--out", str(tmp_path / "cap.dxf")]) == 0
    out = capsys.readouterr().out
    assert "| cap |" in out and (tmp_path / "cap.dxf").is_file() and (tmp_path / "cap.png").is_file()
    bad = tmp_path / "ico.obj"
    trimesh.creation.icosphere(1).export(bad)
    assert main(["flatten", str(bad), "--out", str(tmp_path / "ico.dxf")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "closed surface" in err[0] and not (tmp_path / "ico.dxf").exists()
