"""The pattern studio's API (taichi_cloth.studio), driven through Starlette's TestClient: the T-shirt set up from its
DXF through the routes gives the shipped garment file, edits undo, refusals change nothing, paths stay in the
folder, the autosave restores, and a drape job reports its progress and its end (with a quick stand-in command; the
real drape runs in tests/test_studio_browser.py)."""
import io
import os
import shutil
import sys
import time
import tomllib
import warnings
from pathlib import Path

import ezdxf
import numpy as np
import pytest

pytest.importorskip("starlette")
pytest.importorskip("multipart")
with warnings.catch_warnings():  # Starlette 1.10 prefers httpx2 to httpx for its test client
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient

from taichi_cloth.garment.garment import build_garment  # noqa: E402
from taichi_cloth.material import MATERIALS  # noqa: E402
from taichi_cloth.garment.garmentfile import load_garment  # noqa: E402
from taichi_cloth.studio.server import MAX_UPLOAD, create_app  # noqa: E402
from taichi_cloth.studio.session import AUTOSAVE, PREVIOUS  # noqa: E402
from taichi_cloth.studio.tomlfile import garment_text  # noqa: E402
from taichi_cloth.studio.views import mannequin  # noqa: E402

GARMENTS = Path(__file__).resolve().parent.parent / "demos" / "garments"
SHIPPED = tomllib.loads((GARMENTS / "tshirt_dxf.toml").read_text(encoding="utf-8"))


@pytest.fixture
def folder(tmp_path):
    """A start folder with the T-shirt's DXF in it."""
    root = tmp_path / "work"
    root.mkdir()
    shutil.copy(GARMENTS / "tshirt.dxf", root / "tshirt.dxf")
    return root


def client(root, start="tshirt.dxf", **kwargs) -> TestClient:
    return TestClient(create_app(root, start, **kwargs))


def ok(response) -> dict:
    assert response.status_code == 200, response.text
    return response.json()


def set_up_tshirt(c) -> dict:
    """The T-shirt of tshirt_dxf.toml, set up through the routes: its seams, placements, material and spacing."""
    ok(c.post("/api/name", json={"name": SHIPPED["name"]}))
    for seam in SHIPPED["seams"]:
        ok(c.post("/api/seams", json={"a": seam["a"], "b": seam["b"], "name": seam["name"]}))
    for piece in SHIPPED["pieces"]:
        ok(c.put(f"/api/placements/{piece['name']}", json=piece["placement"]))
    ok(c.put("/api/material", json={"preset": SHIPPED["material"], "values": {}}))
    return ok(c.put("/api/spacing", json={"spacing": SHIPPED["spacing"]}))["state"]


def test_the_tshirt_set_up_through_the_api_saves_the_shipped_garment_file(folder):
    c = client(folder)
    state = ok(c.get("/api/state"))
    # the pieces flat, to scale, with their corners, side lengths and grain
    assert [p["name"] for p in state["pieces"]] == ["front", "back", "sleeve_L", "sleeve_R"]
    front = state["pieces"][0]
    assert state["units"] == "cm" and state["spacing"] == 2.0
    assert [c_["name"] for c_ in front["corners"]][:3] == ["hem_R", "hem_L", "arm_L"]
    assert front["sides"][0]["length"] == pytest.approx(52.0, abs=1e-3)  # hem_R to hem_L, 52 cm
    assert front["grain"]["size"] > 0 and len(front["outline"]) > 8
    assert "torso_front" in state["anchors"] and "arm_left" in state["anchors"] and "hips_back" in state["anchors"]
    # a first placement guessed from each piece's name
    assert {k: v["anchor"] for k, v in state["placements"].items()} == {
        "front": "torso_front", "back": "torso_back", "sleeve_L": "arm_left", "sleeve_R": "arm_right"}

    state = set_up_tshirt(c)
    assert len(state["seams"]) == 10 and all(s["pairs"] for s in state["seams"]) and not state["warnings"]
    assert state["seams"][0]["a"]["length"] == pytest.approx(state["seams"][0]["b"]["length"], rel=1e-6)
    assert state["particles"] > 1000
    assert (folder / AUTOSAVE).is_file()
    saved = ok(c.post("/api/save", json={"path": "tshirt_dxf.toml"}))["saved"]
    assert saved == "tshirt_dxf.toml" and not (folder / AUTOSAVE).exists()  # the saved file holds the set-up now
    ours = tomllib.loads((folder / saved).read_text(encoding="utf-8"))
    assert ours == SHIPPED  # same seams with their directions, placements, material, spacing, units and DXF

    body = mannequin()
    a = build_garment(load_garment(folder / saved), body)
    b = build_garment(load_garment(GARMENTS / "tshirt_dxf.toml"), body)
    assert a.data.n_particles == b.data.n_particles == 1464
    np.testing.assert_array_equal(a.seam_pairs, b.seam_pairs)
    np.testing.assert_allclose(a.data.positions, b.data.positions, atol=1e-9)

    # and it opens again as the same set-up
    again = client(folder, saved)
    state2 = ok(again.get("/api/state"))
    assert state2["seams"] == state["seams"] and state2["placements"] == state["placements"]


def test_a_garment_file_with_inline_outlines_round_trips(folder):
    shutil.copy(GARMENTS / "tshirt.toml", folder / "tshirt.toml")
    c = client(folder, "tshirt.toml")
    state = ok(c.get("/api/state"))
    assert len(state["seams"]) == 10 and state["target"] == "tshirt.toml"
    ok(c.post("/api/save", json={"path": "sub/copy.toml"}))  # a folder below: written there
    body = mannequin()
    a = build_garment(load_garment(folder / "sub" / "copy.toml"), body)
    b = build_garment(load_garment(GARMENTS / "tshirt.toml"), body)
    np.testing.assert_array_equal(a.seam_pairs, b.seam_pairs)
    np.testing.assert_allclose(a.data.positions, b.data.positions, atol=1e-9)
    # a DXF garment saved one folder down names its DXF from there
    c2 = client(folder)
    ok(c2.post("/api/save", json={"path": "sub/t.toml"}))
    assert tomllib.loads((folder / "sub" / "t.toml").read_text())["dxf"] == "../tshirt.dxf"
    assert len(load_garment(folder / "sub" / "t.toml").pieces) == 4


def test_seams_undo_redo_delete_flip_and_rename(folder):
    c = client(folder)
    side = {"piece": "front", "from": "hem_L", "to": "arm_L"}
    partner = {"piece": "back", "from": "hem_L", "to": "arm_L"}
    r = ok(c.post("/api/seams", json={"a": side, "b": partner}))
    assert r["index"] == 0 and r["state"]["seams"][0]["name"] == "seam 1"
    v = r["state"]["version"]
    flipped = ok(c.post("/api/seams/0/flip", json={"side": "b"}))["state"]["seams"][0]
    assert (flipped["b"]["from"], flipped["b"]["to"]) == ("arm_L", "hem_L")
    assert flipped["b"]["points"][0] == r["state"]["seams"][0]["b"]["points"][-1]  # drawn the other way
    assert ok(c.patch("/api/seams/0", json={"name": "left side"}))["state"]["seams"][0]["name"] == "left side"
    assert ok(c.delete("/api/seams/0"))["state"]["seams"] == []
    state = ok(c.post("/api/undo"))["state"]
    assert state["seams"][0]["name"] == "left side"
    state = ok(c.post("/api/undo"))["state"]
    assert state["seams"][0]["name"] == "seam 1" and state["seams"][0]["b"]["from"] == "arm_L"
    state = ok(c.post("/api/undo"))["state"]
    assert state["seams"][0]["b"]["from"] == "hem_L" and state["version"] > v
    assert ok(c.post("/api/redo"))["state"]["seams"][0]["b"]["from"] == "arm_L"
    ok(c.post("/api/undo"))
    assert ok(c.post("/api/undo"))["state"]["seams"] == []
    assert c.post("/api/undo").status_code == 409  # back at the opened DXF: nothing before it
    assert c.delete("/api/seams/7").status_code == 404


def test_a_length_mismatch_is_shown_with_both_lengths(folder):
    c = client(folder)
    r = ok(c.post("/api/seams", json={"a": {"piece": "front", "from": "hem_R", "to": "hem_L"},
                                      "b": {"piece": "sleeve_L", "from": "hem_F", "to": "hem_B"}, "name": "odd"}))
    seam = r["state"]["seams"][0]
    assert not seam["pairs"] and seam["a"]["length"] == pytest.approx(52.0) and seam["b"]["length"] == pytest.approx(30)
    (warning,) = r["state"]["warnings"]
    assert "52.0 cm" in warning and "30.0 cm" in warning and "42.3 %" in warning and "tolerance 10 %" in warning
    # a tolerance that takes it
    assert ok(c.patch("/api/seams/0", json={"tolerance": 0.5}))["state"]["seams"][0]["pairs"]


@pytest.mark.parametrize("a, b, words", [
    ({"piece": "front", "from": "hem_L", "to": "hem_L"}, {"piece": "back", "from": "hem_L", "to": "arm_L"},
     "starts and ends at the same corner"),
    ({"piece": "front", "from": "hem_L", "to": "elbow"}, {"piece": "back", "from": "hem_L", "to": "arm_L"},
     "no corner 'elbow'"),
    ({"piece": "collar", "from": "a", "to": "b"}, {"piece": "back", "from": "hem_L", "to": "arm_L"},
     "unknown piece 'collar'"),
    ({"piece": "front", "from": "hem_L"}, {"piece": "back", "from": "hem_L", "to": "arm_L"}, "must give piece"),
])
def test_a_seam_that_cannot_be_sewn_is_refused_and_changes_nothing(folder, a, b, words):
    c = client(folder)
    before = ok(c.get("/api/state"))
    r = c.post("/api/seams", json={"a": a, "b": b})
    assert r.status_code == 400 and words in r.json()["error"], r.text
    assert "\n" not in r.json()["error"]
    assert ok(c.get("/api/state"))["version"] == before["version"]


def test_an_outline_stretch_sewn_twice_names_the_seam(folder):
    c = client(folder)
    ok(c.post("/api/seams", json={"a": {"piece": "front", "from": "hem_L", "to": "arm_L"},
                                  "b": {"piece": "back", "from": "hem_L", "to": "arm_L"}, "name": "left side"}))
    r = c.post("/api/seams", json={"a": {"piece": "front", "from": "arm_L", "to": "hem_L"},
                                   "b": {"piece": "back", "from": "hem_R", "to": "arm_R"}})
    assert r.status_code == 400 and "already sewn by seam 'left side'" in r.json()["error"]


def test_placement_material_and_spacing(folder):
    c = client(folder)
    state = ok(c.put("/api/placements/front", json={"anchor": "hips_front", "at": [0, 10], "offset": 3, "height": 0,
                                                     "wrap": True}))["state"]
    assert state["placements"]["front"] == {"anchor": "hips_front", "at": [0, 10], "offset": 3}  # defaults left out
    r = c.put("/api/placements/front", json={"anchor": "knee"})
    assert r.status_code == 400 and "unknown anchor 'knee'" in r.json()["error"] and "torso_front" in r.json()["error"]
    assert c.put("/api/placements/front", json={"anchor": "torso_front", "offset": -1}).status_code == 400
    assert c.put("/api/placements/collar", json={"anchor": "torso_front"}).status_code == 404
    png = c.get("/api/views/placement.png")
    assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"

    denim = MATERIALS["denim"].stretch  # a value equal to the preset's is no override
    state = ok(c.put("/api/material", json={"preset": "denim", "values": {"density": 0.5, "stretch": denim}}))["state"]
    assert state["material"]["preset"] == "denim" and state["material"]["overrides"] == {"density": 0.5}
    assert state["material"]["values"]["stretch"] == denim
    assert c.put("/api/material", json={"preset": "tweed"}).status_code == 400
    assert c.put("/api/material", json={"preset": "silk", "values": {"density": -1}}).status_code == 400

    coarse = ok(c.put("/api/spacing", json={"spacing": 4.0}))["state"]["particles"]
    fine = ok(c.put("/api/spacing", json={"spacing": 2.0}))["state"]["particles"]
    assert 3.0 < fine / coarse < 4.0  # nearly four times the particles at half the spacing (the outlines add less)
    r = c.put("/api/spacing", json={"spacing": 1e-6})
    assert r.status_code == 400 and "particles need about" in r.json()["error"]  # the memory guard's message
    assert ok(c.get("/api/state"))["spacing"] == 2.0


def test_a_broken_dxf_or_garment_file_is_refused_and_changes_nothing(folder):
    c = client(folder)
    ok(c.post("/api/seams", json={"a": {"piece": "front", "from": "hem_L", "to": "arm_L"},
                                  "b": {"piece": "back", "from": "hem_L", "to": "arm_L"}}))
    before = ok(c.get("/api/state"))
    (folder / "broken.dxf").write_text("0\nSECTION\n2\nENTITIES\n0\nLINE\n8\nA\n10\n0\n20\n0\n11\n1\n21\n0\n0\nEOF\n")
    (folder / "broken.toml").write_text('name = "x"\nspacing = [\n')
    (folder / "wrong.toml").write_text('name = "x"\nspacing = 2\n[[pieces]]\nname = "a"\n'
                                       'placement = { anchor = "torso_front" }\n')
    for path, words in (("broken.dxf", "broken.dxf"), ("broken.toml", "not valid TOML"),
                        ("wrong.toml", "needs an outline")):
        r = c.post("/api/open", json={"path": path})
        assert r.status_code == 400 and words in r.json()["error"], r.text
    for name, data in (("bad.dxf", b"this is not a DXF file"), ("bad.toml", b"spacing = = 2")):
        r = c.post("/api/upload", files={"file": (name, data)})
        assert r.status_code == 400 and name in r.json()["error"], r.text
        assert not (folder / name).exists() and not list(folder.glob(".studio-upload*"))
    after = ok(c.get("/api/state"))
    assert after["version"] == before["version"] and after["seams"] == before["seams"]
    assert c.post("/api/upload", files={"file": ("notes.txt", b"hello")}).status_code == 400
    assert c.post("/api/open", json={"path": "missing.dxf"}).status_code == 404
    assert c.post("/api/open", content=b"{not json", headers={"content-type": "application/json"}).status_code == 400


def test_an_upload_is_kept_in_the_folder_without_overwriting(folder):
    c = client(folder, None)
    assert ok(c.get("/api/state"))["open"] is False
    data = (GARMENTS / "tshirt.dxf").read_bytes()
    r = ok(c.post("/api/upload", files={"file": ("tshirt.dxf", data)}))
    assert r["kept"] == "tshirt-2.dxf" and (folder / "tshirt-2.dxf").read_bytes() == data
    assert r["state"]["name"] == "tshirt" and r["state"]["dxf"] == "tshirt-2.dxf"
    r = ok(c.post("/api/upload", files={"file": ("../../evil.dxf", data)}))  # only the name is kept
    assert r["kept"] == "evil.dxf" and (folder / "evil.dxf").is_file()


def test_an_oversize_upload_is_refused_with_413(folder):
    c = client(folder)
    r = c.post("/api/upload", files={"file": ("big.dxf", b"0" * (MAX_UPLOAD + 200_000))})
    assert r.status_code == 413 and "5 MB" in r.json()["error"]
    assert not (folder / "big.dxf").exists()
    r = c.post("/api/seams", content=b"{" + b" " * (2 * 1024 * 1024) + b"}",
               headers={"content-type": "application/json"})
    assert r.status_code == 413  # an edit too large to be one


def test_paths_outside_the_folder_are_refused(folder, tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    shutil.copy(GARMENTS / "tshirt.dxf", outside / "secret.dxf")
    (outside / "secret.png").write_bytes(b"\x89PNG")
    os.symlink(outside / "secret.dxf", folder / "link.dxf")
    os.symlink(outside, folder / "linked")
    c = client(folder)
    before = ok(c.get("/api/state"))["version"]
    for path, status in (("../outside/secret.dxf", 403), (str(outside / "secret.dxf"), 400), ("link.dxf", 403),
                         ("linked/secret.dxf", 403)):
        r = c.post("/api/open", json={"path": path})
        assert r.status_code == status and "refused" in r.json()["error"], (path, r.text)
    for path in ("../x.toml", "linked/x.toml", "/tmp/x.toml"):
        r = c.post("/api/save", json={"path": path})
        assert r.status_code in (400, 403) and "refused" in r.json()["error"]
    assert not (outside / "x.toml").exists()
    assert c.get("/files/..%2Foutside%2Fsecret.png").status_code == 403
    assert c.get("/files/linked/secret.png").status_code == 403
    assert c.get("/files/%2Fetc%2Fpasswd").status_code == 400
    assert c.get("/files/tshirt.dxf").status_code == 400  # pictures only
    # a garment file whose dxf leads outside the folder
    (folder / "sneaky.toml").write_text(f'dxf = "{outside / "secret.dxf"}"\nspacing = 2\n')
    r = c.post("/api/open", json={"path": "sneaky.toml"})
    assert r.status_code == 403 and "outside" in r.json()["error"]
    assert ok(c.get("/api/state"))["version"] == before
    assert "link.dxf" not in ok(c.get("/api/files"))["files"]


def test_an_existing_file_is_overwritten_only_when_asked(folder):
    (folder / "other.toml").write_text("# someone's file\n")
    c = client(folder)
    r = c.post("/api/save", json={"path": "other.toml"})
    assert r.status_code == 409 and "exists" in r.json()["error"]
    assert (folder / "other.toml").read_text() == "# someone's file\n"
    ok(c.post("/api/save", json={"path": "other.toml", "overwrite": True}))
    ok(c.post("/api/save", json={}))  # Save again: to the file it saved last, no question
    assert load_garment(folder / "other.toml").name == "tshirt"


def test_the_autosave_follows_every_change_and_is_offered_at_the_next_start(folder):
    c = client(folder)
    assert not (folder / AUTOSAVE).exists()  # opening a file is not a change of its own
    ok(c.post("/api/seams", json={"a": {"piece": "front", "from": "hem_L", "to": "arm_L"},
                                  "b": {"piece": "back", "from": "hem_L", "to": "arm_L"}, "name": "left side"}))
    auto = tomllib.loads((folder / AUTOSAVE).read_text())
    assert [s["name"] for s in auto["seams"]] == ["left side"]
    ok(c.put("/api/placements/front", json={"anchor": "torso_front", "at": [0, 31], "offset": 2}))
    auto = tomllib.loads((folder / AUTOSAVE).read_text())
    assert auto["pieces"][0]["placement"] == {"anchor": "torso_front", "at": [0, 31], "offset": 2}
    assert load_garment(folder / AUTOSAVE).name == "tshirt"  # the autosave is a garment file
    last = ok(c.get("/api/state"))

    # the tab closed, the studio stopped: the next start offers it, and restoring it brings the set-up back
    c2 = client(folder)
    state = ok(c2.get("/api/state"))
    assert state["restore"]["file"] == PREVIOUS and state["seams"] == []
    assert not (folder / AUTOSAVE).exists() and (folder / PREVIOUS).is_file()
    state = ok(c2.post("/api/restore"))["state"]
    assert state["seams"] == last["seams"] and state["placements"] == last["placements"] and state["restore"] is None
    assert (folder / AUTOSAVE).is_file() and not (folder / PREVIOUS).exists()
    assert ok(c2.post("/api/undo"))["state"]["seams"] == []  # a restore is an edit like any other
    assert c2.post("/api/restore").status_code == 409


def test_dismissing_the_autosave_keeps_it_as_a_file(folder):
    c = client(folder)
    ok(c.post("/api/name", json={"name": "mine"}))
    c2 = client(folder)
    assert ok(c2.get("/api/state"))["restore"] is not None
    assert ok(c2.post("/api/restore/dismiss"))["state"]["restore"] is None
    assert load_garment(folder / PREVIOUS).name == "mine"


FAKE_RUN = r"""
import sys, time, pathlib
out, frames = pathlib.Path(sys.argv[1]), int(sys.argv[2])
if sys.argv[3] == "fail":
    print("error: garment 'x': the run fell over", file=sys.stderr)
    sys.exit(2)
if sys.argv[3] == "open":  # a run that ends with its seams still open: exit 0, the quality table's note says so
    print("note: seams still open: left side (12.0 mm)")
    sys.exit(0)
for i in range(frames + 1):
    sys.stderr.write(f"\rx:  {100 * i // frames}%|##| {i}/{frames} [00:00<00:00, 5.0frame/s]")
    sys.stderr.flush()
    time.sleep(0.01)
out.mkdir(parents=True, exist_ok=True)
from PIL import Image
Image.new("RGB", (8, 8), (200, 30, 30)).save(out / "x.png")
print("| piece | area 2D [cm^2] |")
print("|---|---|")
print("| front | 2248 |")
print("seam gap: max 0.50 mm, mean 0.20 mm")
print(f"open the recording with:  rerun {out / 'x.rrd'}")
"""


def fake_drape(mode):
    return lambda scene, out, frames: [sys.executable, "-c", FAKE_RUN, str(out), str(frames), mode]


def wait_for_drape(c, timeout=30.0) -> dict:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        status = ok(c.get("/api/drape"))
        if status["state"] != "running":
            return status
        time.sleep(0.05)
    raise AssertionError("the drape did not end")


def test_a_drape_reports_progress_pictures_and_its_end(folder):
    from taichi_cloth.scenefile import parse_scene

    c = client(folder, drape_command=fake_drape("ok"))
    set_up_tshirt(c)
    assert ok(c.get("/api/drape"))["state"] == "idle"
    started = ok(c.post("/api/drape", json={"frames": 20, "quick": True}))["state"]["drape"]
    assert started["state"] == "running" and started["note"] == "quick, spacing 4 cm"
    assert c.post("/api/drape", json={"frames": 20}).status_code == 409  # one at a time
    status = wait_for_drape(c)
    assert status["state"] == "done" and status["progress"] == 1.0 and status["reason"] is None
    assert status["quality"][:3] == ["| piece | area 2D [cm^2] |", "|---|---|", "| front | 2248 |"]
    (picture,) = status["pictures"]
    assert picture.startswith("studio-drape/tshirt_dxf-out/") and c.get(f"/files/{picture}").status_code == 200
    assert status["open_command"] == "rerun studio-drape/tshirt_dxf-out/x.rrd"
    # what a real drape runs: a scene that sews the set-up, at the quick spacing
    scene = folder / "studio-drape" / "tshirt_dxf-scene.toml"
    cfg = parse_scene(scene)
    assert cfg["frames"] == 20 and cfg["cloth"]["garment"] == "tshirt_dxf.toml"
    spec = load_garment(folder / "studio-drape" / "tshirt_dxf.toml")
    assert spec.spacing == pytest.approx(0.04) and len(spec.seams) == 10
    # the next drape writes to a fresh folder
    ok(c.post("/api/drape", json={"frames": 5, "quick": False}))
    status = wait_for_drape(c)
    assert status["pictures"][0].startswith("studio-drape/tshirt_dxf-out-2/") and status["note"] == "spacing 2 cm"
    assert c.post("/api/drape", json={"frames": 0}).status_code == 400


def test_a_failed_drape_shows_its_one_line_reason(folder):
    c = client(folder, drape_command=fake_drape("fail"))
    ok(c.post("/api/drape", json={"frames": 5}))
    status = wait_for_drape(c)
    assert status["state"] == "failed" and status["reason"] == "garment 'x': the run fell over"
    c = client(folder, drape_command=fake_drape("open"))
    ok(c.post("/api/drape", json={"frames": 5}))
    status = wait_for_drape(c)
    assert status["state"] == "failed"
    assert status["reason"] == "seams still open: left side (12.0 mm) when the run ended: drape more frames"


def test_the_garment_text_reads_back_as_written():
    doc = {"name": 'a "quoted"\\ name', "units": "cm", "material": {"preset": "silk", "bend": 1e-05},
           "spacing": 2.5, "levels": 2, "pieces": [{"name": "p q", "outline": [{"at": [0, 0], "name": "x"},
                                                                             {"at": [1.5, 0], "bspline": [[1, 1]]},
                                                                             {"at": [0, 1]}],
                                                   "placement": {"anchor": "torso_front", "wrap": False}}],
           "seams": [{"name": "s", "a": {"piece": "p q", "from": "x", "to": 1}, "b": {"piece": "p q", "from": 2,
                                                                                 "to": "x"}}]}
    assert tomllib.loads(garment_text(doc, ["a comment"])) == doc


def test_the_studio_command_without_its_extra_says_how_to_install_it(monkeypatch, capsys):
    from taichi_cloth.cli import main

    monkeypatch.setitem(sys.modules, "uvicorn", None)
    assert main(["studio", "--no-browser"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "pip install -e '.[studio]'" in err[0]


def test_the_studio_command_refuses_a_file_outside_its_folder(folder, monkeypatch, capsys):
    pytest.importorskip("uvicorn")
    from taichi_cloth.cli import main

    monkeypatch.chdir(folder)
    assert main(["studio", "../elsewhere.dxf", "--no-browser"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "refused" in err and "\n" not in err
    assert main(["studio", "missing.dxf", "--no-browser"]) == 2
    assert "no such file" in capsys.readouterr().err


def test_the_page_is_served_offline(folder):
    c = client(folder)
    page = c.get("/")
    assert page.status_code == 200 and "/static/studio.js" in page.text
    for name in ("studio.js", "studio.css"):
        r = c.get(f"/static/{name}")
        assert r.status_code == 200
        assert "http://" not in r.text.replace("http://www.w3.org/2000/svg", "") and "https://" not in r.text
    assert "https://" not in page.text


def test_placement_picture_shows_the_pieces_in_their_colours(folder):
    from PIL import Image

    c = client(folder)
    set_up_tshirt(c)
    img = np.asarray(Image.open(io.BytesIO(c.get("/api/views/placement.png").content)).convert("RGB"))
    # the front piece's colour (#7fa7d9), shaded: many pixels near its hue
    r, g, b = (img[..., k].astype(int) for k in range(3))
    assert ((b > r + 40) & (b > g + 10)).mean() > 0.02


def test_a_dxf_without_units_opens_in_the_unit_the_page_gives_and_saves_it(folder):
    doc = ezdxf.new("R12")  # pattern CAD's layout: the piece a block on layer 1, no $INSUNITS, inches
    block = doc.blocks.new("FRONT")
    block.add_polyline2d([(0, 0), (10, 0), (10, 17), (7.5, 23), (3, 24.5), (0, 22)], close=True,
                         dxfattribs={"layer": "1"})
    doc.modelspace().add_blockref("FRONT", (0, 0))
    doc.saveas(folder / "front.dxf")
    c = client(folder)
    before = ok(c.get("/api/state"))
    r = c.post("/api/open", json={"path": "front.dxf"})
    assert r.status_code == 400 and "no unit" in r.json()["error"] and "dxf_units" in r.json()["error"], r.text
    assert "\n" not in r.json()["error"] and ok(c.get("/api/state"))["version"] == before["version"]
    assert c.post("/api/open", json={"path": "front.dxf", "units": "inch"}).status_code == 400
    state = ok(c.post("/api/open", json={"path": "front.dxf", "units": "in"}))["state"]
    assert state["units"] == "in" and [p["name"] for p in state["pieces"]] == ["FRONT"]
    assert state["pieces"][0]["sides"][0]["length"] == pytest.approx(10.0, abs=1e-3)  # the hem: 10 in
    ok(c.post("/api/save", json={"path": "front.toml"}))
    saved = tomllib.loads((folder / "front.toml").read_text(encoding="utf-8"))
    assert saved["dxf"] == "front.dxf" and saved["dxf_units"] == "in" and saved["units"] == "in"
    assert ok(c.post("/api/open", json={"path": "front.toml"}))["state"]["pieces"][0]["sides"][0]["length"] == \
        pytest.approx(10.0, abs=1e-3)
    data = (folder / "front.dxf").read_bytes()
    assert c.post("/api/upload", files={"file": ("up.dxf", data)}).status_code == 400
    r = ok(c.post("/api/upload", files={"file": ("up.dxf", data)}, data={"units": "in"}))
    assert r["kept"] == "up.dxf" and r["state"]["units"] == "in"


def test_a_dxf_piece_s_pattern_options_and_the_dxf_s_options_are_set_saved_and_undone(folder):
    doc = ezdxf.new("R12")  # a half front on its side, on a fold, graded S and M, inches
    for size, grade in (("S", 0.95), ("M", 1.0)):
        block = doc.blocks.new(f"FRONT_{size}")
        half = np.array([[0, 0], [0, -10], [17, -10], [23, -7.5], [24.5, -3], [22, 0]]) * grade
        block.add_polyline2d([tuple(p) for p in half], close=True, dxfattribs={"layer": "1"})
        block.add_line((0, 0), (22 * grade, 0), dxfattribs={"layer": "6"})  # the fold: centre front
        block.add_line((5, -5), (15, -5), dxfattribs={"layer": "7"})  # the grain: up is +x
        block.add_text(f"Size: {size}", dxfattribs={"layer": "1", "insert": (8, -4)})
        doc.modelspace().add_blockref(f"FRONT_{size}", (0, 0))
    doc.modelspace().add_text("Units: ENGLISH", dxfattribs={"insert": (-30, 0)})
    doc.modelspace().add_text("Sample Size: M", dxfattribs={"insert": (-30, -5)})
    doc.saveas(folder / "graded.dxf")
    c = client(folder, "graded.dxf")
    state = ok(c.get("/api/state"))
    assert state["units"] == "in" and state["pattern_options"] == {"FRONT": {}} and state["dxf_options"] == {}
    hem = state["pieces"][0]["sides"][0]["length"]
    assert hem == pytest.approx(10.0, abs=1e-3)  # upright and unfolded: the hem runs from centre front to the side
    state = ok(c.put("/api/dxf", json={"dxf_size": "S", "seam_allowance": 0.5}))["state"]
    assert state["dxf_options"] == {"dxf_size": "S", "seam_allowance": 0.5}
    assert state["pieces"][0]["sides"][0]["length"] == pytest.approx(9.5 - 0.5, abs=1e-3)  # S, less the allowance
    state = ok(c.put("/api/pieces/FRONT/pattern", json={"unfold": False, "rotate": 0}))["state"]
    assert state["pattern_options"] == {"FRONT": {"unfold": False, "rotate": 0}}
    r = c.put("/api/pieces/FRONT/pattern", json={"turn": 90})
    assert r.status_code == 400 and "unknown keys turn" in r.json()["error"]
    assert c.put("/api/pieces/BACK/pattern", json={}).status_code == 404
    r = c.put("/api/dxf", json={"dxf_size": "XL"})
    assert r.status_code == 400 and "no size 'XL'" in r.json()["error"] and "\n" not in r.json()["error"]
    ok(c.post("/api/save", json={"path": "graded.toml"}))
    saved = tomllib.loads((folder / "graded.toml").read_text(encoding="utf-8"))
    assert saved["dxf_size"] == "S" and saved["seam_allowance"] == 0.5
    assert saved["pieces"][0]["unfold"] is False and saved["pieces"][0]["rotate"] == 0
    ok(c.post("/api/undo"))
    assert ok(c.get("/api/state"))["pattern_options"] == {"FRONT": {}}


def test_a_garmentcode_specification_opens_and_saves_as_the_garment_file_it_reads_as(folder):
    shutil.copy(GARMENTS / "trousers.json", folder / "trousers.json")
    c = client(folder)
    assert "trousers.json" in ok(c.get("/api/files"))["files"]
    state = ok(c.post("/api/open", json={"path": "trousers.json"}))["state"]
    assert state["units"] == "cm" and [p["name"] for p in state["pieces"]] == [
        "front_left", "front_right", "back_left", "back_right"]
    assert len(state["seams"]) == 10
    ok(c.post("/api/save", json={"path": "trousers.toml"}))
    saved, read = load_garment(folder / "trousers.toml"), load_garment(folder / "trousers.json")
    assert saved.seams == read.seams and saved.placements == read.placements
    for a, b in zip(saved.pieces, read.pieces):
        assert a.corner_names == b.corner_names and a.area() == pytest.approx(b.area(), rel=1e-9)
    r = ok(c.post("/api/upload", files={"file": ("pants.json", (folder / "trousers.json").read_bytes())}))
    assert r["kept"] == "pants.json" and r["state"]["name"] == "pants" and len(r["state"]["pieces"]) == 4
    r = c.post("/api/upload", files={"file": ("broken.json", b"{not json")})
    assert r.status_code == 400 and "broken.json: not a readable GarmentCode specification" in r.json()["error"]
    assert not (folder / "broken.json").exists()
