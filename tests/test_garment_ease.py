"""The garment's girths against the body's (taichi_cloth.garment.ease): the shipped skirt's and T-shirt's
circumferences at rest against their patterns, the too-small check on the mannequin and on a body whose waist is
larger than the skirt's waistband, and the message's words."""
from pathlib import Path

import numpy as np
import pytest

from taichi_cloth.garment.ease import Ease, garment_girths, too_small, too_small_message
from taichi_cloth.garment.garment import build_garment
from taichi_cloth.garment.garmentfile import load_garment

GARMENTS = Path(__file__).resolve().parents[1] / "demos" / "garments"


@pytest.fixture(scope="module")
def skirt():
    return build_garment(load_garment(GARMENTS / "skirt.toml"))


@pytest.fixture(scope="module")
def tshirt():
    return build_garment(load_garment(GARMENTS / "tshirt.toml"))


def by_part(eases):
    return {e.part: e for e in eases}


def pattern_width(piece, v):
    """[m] the outline's width at height v, from the pattern's own curves (sampled to 0.1 um)."""
    p = piece.outline(tolerance=1e-7)
    q = np.roll(p, -1, axis=0)
    cross = (p[:, 1] - v) * (q[:, 1] - v) < 0
    t = (v - p[cross, 1]) / (q[cross, 1] - p[cross, 1])
    x = p[cross, 0] + t * (q[cross, 0] - p[cross, 0])
    assert len(x) == 2
    return float(x.max() - x.min())


def row_of(garment, k, height):
    """The pattern row v of piece k that lies at `height` [m] as placed (a torso piece's v runs up the body)."""
    m, o = garment.meshes[k], garment.offsets[k]
    shift = garment.data.positions[o:o + m.n_vertices, 1] - m.uv[:, 1]
    assert np.ptp(shift) < 1e-9
    return height - shift[0]


def test_the_skirts_waistband_hips_and_hem_are_its_patterns_widths(skirt):
    eases = by_part(garment_girths(skirt))
    assert set(eases) == {"waistband", "hip line", "hem"}    # the waist plane is above the skirt: no waistline
    assert eases["waistband"].garment == pytest.approx(0.68, abs=1e-9)   # straight sides: exact
    assert eases["hem"].garment == pytest.approx(1.24, abs=1e-9)
    assert (eases["waistband"].girth, eases["hem"].girth, eases["hip line"].girth) == ("waist", "hips", "hips")
    hips = eases["hip line"]
    analytic = sum(pattern_width(m.piece, row_of(skirt, k, hips.height)) for k, m in enumerate(skirt.meshes))
    # the mesh's outline is the pattern's B-spline sides as chords 2 cm apart: within 1 mm in all
    assert hips.garment == pytest.approx(analytic, abs=1e-3)
    assert 1.04 < hips.garment < 1.06


def test_the_tshirts_hem_is_104_cm_its_chest_96_at_the_armholes(tshirt):
    eases = by_part(garment_girths(tshirt))
    assert eases["hem"].garment == pytest.approx(1.04, abs=1e-9) and eases["hem"].girth == "hips"
    chest = eases["chest line"]   # the bust plane meets the armholes: measured at the highest row that closes
    analytic = sum(pattern_width(tshirt.meshes[k].piece, row_of(tshirt, k, chest.height)) for k in (0, 1))
    assert chest.garment == pytest.approx(analytic, abs=1e-3) and 0.96 <= chest.garment < 0.97
    assert eases["left sleeve's hem"].garment == pytest.approx(0.30, abs=1e-9)
    assert eases["left sleeve's hem"].girth == "upper_arm"
    assert "neckline" in eases and not too_small(eases.values())


def test_the_message_says_what_is_too_small_in_garment_terms():
    hem = Ease("hem", "hips", "opening", 1.04, 1.10, 0.9)
    band = Ease("waistband", "waist", "opening", 0.68, 0.74, 1.06)
    assert too_small_message([hem]) == "too small: the hem is 104 cm and the hips 110 cm"
    assert too_small_message([band, hem]) == ("too small: the waistband is 68 cm and the waist 74 cm; "
                                              "the hem is 104 cm and the hips 110 cm")
    assert too_small_message([Ease("left sleeve", "upper_arm", "plane", 0.2, 0.255, 0.0)]) == \
        "too small: the left sleeve is 20 cm and the upper arm 25.5 cm"
    assert too_small_message([]) == ""


def test_too_small_allows_the_stretch_limit_and_the_clearance():
    band = Ease("waistband", "waist", "opening", 0.68, 0.74, 1.06)
    assert too_small([band], stretch=0.0) == [band]
    assert too_small([band], stretch=0.1) == []                  # 74.8 cm at the stretch limit reaches 74
    assert too_small([band], stretch=0.1, clearance=0.004) == [band]   # not with the cloth 4 mm off the skin
    assert too_small([band], stretch=0.1, min_ease=0.01) == [band]


def test_the_skirt_is_too_small_on_a_waist_of_74_cm_not_on_the_mannequin(skirt):
    from taichi_cloth.body import fit_body
    from taichi_cloth.body.landmarks import Body

    assert too_small(garment_girths(skirt), 0.1, 0.004) == []
    fit = fit_body({"waist": 0.74}, tolerance=1e-3)
    body = Body.from_mesh(fit.vertices, fit.triangles)
    big = build_garment(load_garment(GARMENTS / "skirt.toml"), body)
    small = too_small(garment_girths(big), 0.1, 0.004)
    assert [e.part for e in small] == ["waistband"]
    assert small[0].body == pytest.approx(0.74, abs=1.5e-3) and small[0].garment == pytest.approx(0.68, abs=1e-9)
    assert too_small_message(small).startswith("too small: the waistband is 68 cm and the waist 7")


def test_a_batch_job_with_open_seams_on_a_body_too_large_is_too_small_with_the_reason(skirt):
    """figures.seams_open_status on a stand-in of a finished scene: the skirt on the mannequin stays "seams open",
    on a body of waist 74 cm it is "too small", the reason in garment terms first."""
    from types import SimpleNamespace

    from taichi_cloth.batch.figures import SEAMS_OPEN, STATUSES, TOO_SMALL, seams_open_status
    from taichi_cloth.body import fit_body

    def scene(vertices):
        parts = {"sewing": SimpleNamespace(garment=skirt), "stretch_limit": SimpleNamespace(max_strain=0.1),
                 "colliders": SimpleNamespace(bodies=[SimpleNamespace(vertices_np=vertices, thickness=0.004)])}
        return SimpleNamespace(controller=parts.get)

    assert STATUSES.index(TOO_SMALL) == STATUSES.index(SEAMS_OPEN) - 1
    assert seams_open_status(scene(skirt.body.vertices), "sewing gave up") == (SEAMS_OPEN, "sewing gave up")
    fit = fit_body({"waist": 0.74}, tolerance=1e-3)
    status, reason = seams_open_status(scene(fit.vertices), "sewing gave up; left side 12.0 mm")
    assert status == TOO_SMALL
    assert reason.startswith("too small: the waistband is 68 cm and the waist 7")
    assert reason.endswith("; sewing gave up; left side 12.0 mm")
