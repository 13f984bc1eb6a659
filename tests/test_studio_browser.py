"""The pattern studio in a real browser: `python -m taichi_cloth studio tshirt.dxf` served by uvicorn, the page
driven in Debian's Chromium by playwright (no browser download: taichi_cloth.view_check launches it the same way).
The T-shirt's ten seams are made by clicking the sides of its pieces, its four pieces placed, the garment file saved
and compared with the shipped tshirt_dxf.toml, then draped at a coarse spacing until the still picture shows; a
broken DXF shows an error and loses nothing; a file outside the folder is refused.

Marked `browser`: `make studio-check` runs these (`pytest -m browser`); plain pytest leaves them out, and they skip
where playwright, Chromium or the `studio` extra is missing. With STUDIO_SHOTS=DIR the screenshots of each step go
to DIR/studio-*.png (make studio-check: docs/)."""
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import pytest

from taichi_cloth.view_check import CHROMIUM, CHROMIUM_FLAGS

pytestmark = pytest.mark.browser

playwright_api = pytest.importorskip("playwright.sync_api", reason="playwright is missing: pip install -e '.[view]'")
pytest.importorskip("uvicorn", reason="the studio extra is missing: pip install -e '.[studio]'")
pytest.importorskip("starlette", reason="the studio extra is missing: pip install -e '.[studio]'")
if not Path(CHROMIUM).exists():
    pytest.skip(f"{CHROMIUM} is missing (Debian's chromium; make studio-check installs it)", allow_module_level=True)

GARMENTS = Path(__file__).resolve().parent.parent / "demos" / "garments"
SHIPPED = tomllib.loads((GARMENTS / "tshirt_dxf.toml").read_text(encoding="utf-8"))
WINDOW = {"width": 1500, "height": 940}
#: [s] the longest a drape may take here (Taichi compiles the run's kernels first unless its cache has them)
DRAPE_TIMEOUT = 480


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def shots(tmp_path_factory) -> Path:
    folder = Path(os.environ.get("STUDIO_SHOTS") or tmp_path_factory.mktemp("shots"))
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    base = tmp_path_factory.mktemp("studio")
    root = base / "work"
    root.mkdir()
    shutil.copy(GARMENTS / "tshirt.dxf", root / "tshirt.dxf")
    (base / "secret.dxf").write_text("outside the studio's folder\n")
    return root


@pytest.fixture(scope="module")
def studio(folder):
    """The studio's address; the server (its own process group) ends with the module."""
    port = _free_port()
    # as from an activated venv: its `rerun` on the PATH, so the page names the recording's viewer as `rerun`
    env = dict(os.environ, PATH=os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")]))
    proc = subprocess.Popen([sys.executable, "-m", "taichi_cloth", "studio", "tshirt.dxf", "--no-browser",
                             "--port", str(port)], cwd=folder, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True, env=env)
    try:
        said = []
        for line in proc.stdout:  # Taichi's banner first, then the studio's address
            said.append(line)
            m = re.search(r"http://127\.0\.0\.1:\d+/", line)
            if m or len(said) > 20:
                break
        assert m, "the studio did not start: " + "".join(said)
        url = m.group(0)
        end = time.monotonic() + 60
        while time.monotonic() < end:
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.2)
        yield url
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


@pytest.fixture(scope="module")
def page(studio):
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_FLAGS)
        page = browser.new_page(viewport=WINDOW)
        page.on("dialog", lambda d: d.accept())
        page.goto(studio)
        page.wait_for_selector("path.side-hit", state="attached")
        yield page
        browser.close()


SIDE_POINT = """([piece, from, to, along]) => {
  // a point on the side of `piece` between corners `from` and `to`, `along` of the way from `from`, on the screen
  const hits = [...document.querySelectorAll(`path.side-hit[data-piece="${piece}"]`)];
  const h = hits.find((e) => (e.dataset.from === from && e.dataset.to === to) ||
                             (e.dataset.from === to && e.dataset.to === from));
  const L = h.getTotalLength();
  const p = h.getPointAtLength((h.dataset.from === from ? along : 1 - along) * L);
  const m = h.getScreenCTM();
  return [p.x * m.a + p.y * m.c + m.e, p.x * m.b + p.y * m.d + m.f];
}"""


def click_side(page, side: dict) -> None:
    """Click a side near its `from` corner (the studio takes the side as running from the corner nearer the
    click)."""
    x, y = page.evaluate(SIDE_POINT, [side["piece"], side["from"], side["to"], 0.25])
    page.mouse.click(x, y)


def seams_shown(page) -> int:
    return page.locator("#seam-list li").count()


def wait_seams(page, n: int) -> None:
    """Until the seam list shows n seams (the page redraws once the answer is read)."""
    page.wait_for_function(f"document.querySelectorAll('#seam-list li').length === {n}")


def wait_text(page, selector: str, words: str) -> None:
    page.wait_for_function("([s, w]) => (document.querySelector(s) || {textContent: ''}).textContent.includes(w)",
                           arg=[selector, words])


def test_seams_by_clicking_placement_and_save_give_the_shipped_set_up(page, folder, shots):
    page.screenshot(path=str(shots / "studio-setup.png"))
    names = page.eval_on_selector_all("g.piece", "gs => gs.map((g) => g.dataset.piece)")
    assert names == ["front", "back", "sleeve_L", "sleeve_R"]
    assert page.locator("circle.corner").count() == 8 + 8 + 5 + 5

    # a span picked by its two corners, two segments long here, on each piece; then taken back
    for piece, start, end in (("front", "hem_L", "shoulder_L"), ("back", "hem_L", "shoulder_L")):
        for corner in (start, end):
            page.click(f'circle.corner[data-piece="{piece}"][data-corner="{corner}"]')
    wait_seams(page, 1)
    assert "front hem_L → shoulder_L (48.7 cm)" in page.inner_text("#seam-list li")
    assert page.evaluate("state.seams[0].a.points.length") > 10  # along both segments, the armhole curve included
    page.click("#undo-btn")
    wait_seams(page, 0)
    # sides too different in length: kept, shown red with both lengths, until its tolerance takes them
    click_side(page, {"piece": "front", "from": "hem_R", "to": "hem_L"})
    click_side(page, {"piece": "sleeve_L", "from": "hem_F", "to": "hem_B"})
    page.wait_for_selector("#seam-list li.mismatch")
    assert "lengths 52.0 and 30.0 cm: 42.3 % apart (tolerance 10 %)" in page.inner_text("#seam-list li.mismatch")
    assert "52.0 cm" in page.inner_text("#warnings") and "30.0 cm" in page.inner_text("#warnings")
    page.fill("#seam-list .seam-tol", "50")
    page.press("#seam-list .seam-tol", "Enter")
    page.wait_for_function("state.seams.length === 1 && state.seams[0].pairs")
    assert page.locator("#seam-list li.mismatch").count() == 0
    page.click("#undo-btn")
    page.wait_for_function("state.seams.length === 1 && !state.seams[0].pairs")
    page.click("#undo-btn")
    wait_seams(page, 0)

    for k, seam in enumerate(SHIPPED["seams"]):
        click_side(page, seam["a"])
        assert "Now click the partner side" in page.inner_text("#pick-help")
        with page.expect_response(lambda r: r.url.endswith("/api/seams") and r.request.method == "POST") as made:
            click_side(page, seam["b"])
        assert made.value.ok, made.value.text()
        wait_seams(page, k + 1)
        name = page.locator("#seam-list li").nth(k).locator(".seam-name")
        with page.expect_response(lambda r: "/api/seams/" in r.url and r.request.method == "PATCH"):
            name.fill(seam["name"])
            name.press("Enter")
    assert seams_shown(page) == 10
    assert page.locator("path.seam-side").count() == 20 and page.locator("#seam-list li.mismatch").count() == 0
    page.locator("#seam-list li").nth(6).locator(".sides").first.click()  # selected: drawn thicker, its row marked
    page.screenshot(path=str(shots / "studio-seams.png"))

    # a wrong pick is flipped back with the button, and undo takes an edit back
    with page.expect_response("**/api/seams/0/flip"):
        page.locator("#seam-list li").nth(0).locator(".flip-b").click()
    wait_text(page, "#seam-list li", "arm_L → hem_L")
    with page.expect_response("**/api/seams/0/flip"):
        page.locator("#seam-list li").nth(0).locator(".flip-b").click()
    wait_text(page, "#seam-list li", "hem_L → arm_L")
    page.locator("#seam-list li").nth(9).locator(".delete").click()
    wait_seams(page, 9)
    page.click("#undo-btn")
    wait_seams(page, 10)

    page.fill("#garment-name", SHIPPED["name"])
    with page.expect_response("**/api/name"):
        page.press("#garment-name", "Enter")

    page.click("nav.tabs button[data-tab=placement]")
    for piece in SHIPPED["pieces"]:
        pl = piece["placement"]
        page.select_option("#pl-piece", piece["name"])
        page.select_option("#pl-anchor", pl["anchor"])
        page.fill("#pl-at-u", str(pl["at"][0]))
        page.fill("#pl-at-v", str(pl["at"][1]))
        page.fill("#pl-offset", str(pl["offset"]))
        with page.expect_response(lambda r: "/api/placements/" in r.url) as placed:
            page.click("#pl-apply")
        assert placed.value.ok, placed.value.text()
        page.wait_for_function("([name, pl]) => JSON.stringify(state.placements[name]) === JSON.stringify(pl)",
                               arg=[piece["name"], pl])
    page.wait_for_function("document.getElementById('placement-img').dataset.version === String(state.version)",
                           timeout=60_000)
    assert page.evaluate("document.getElementById('placement-img').naturalWidth") > 400
    page.screenshot(path=str(shots / "studio-placement.png"))

    page.click("nav.tabs button[data-tab=material]")
    page.select_option("#mat-preset", SHIPPED["material"])
    with page.expect_response("**/api/material"):
        page.click("#mat-apply")
    page.fill("#spacing", str(SHIPPED["spacing"]))
    with page.expect_response("**/api/spacing"):
        page.click("#spacing-apply")
    assert "particles" in page.inner_text("#particles")

    page.fill("#save-path", "tshirt_studio.toml")
    with page.expect_response("**/api/save") as saved:
        page.click("#save-btn")
    assert saved.value.ok, saved.value.text()
    wait_text(page, "#message", "saved tshirt_studio.toml")
    ours = tomllib.loads((folder / "tshirt_studio.toml").read_text(encoding="utf-8"))
    assert [s for s in ours["seams"] if s not in SHIPPED["seams"]] == []
    assert ours == SHIPPED


def test_a_quick_drape_shows_its_still_picture(page, shots):
    page.click("nav.tabs button[data-tab=drape]")
    page.fill("#drape-frames", "90")
    page.check("#drape-quick")
    page.fill("#drape-spacing", "4")
    with page.expect_response(lambda r: r.url.endswith("/api/drape") and r.request.method == "POST") as started:
        page.click("#drape-btn")
    assert started.value.ok, started.value.text()
    page.wait_for_selector("#drape-result img.drape-still", timeout=DRAPE_TIMEOUT * 1000)
    page.wait_for_function("[...document.querySelectorAll('#drape-result img')].every((i) => i.complete && "
                           "i.naturalWidth > 0)")
    status = page.inner_text("#drape-status")
    assert status.startswith("done: 90 frames, quick, spacing 4 cm"), status
    assert page.evaluate("document.getElementById('drape-progress').value") == 1
    assert page.locator("#drape-result table tr").count() == 5  # the quality table: a header and four pieces
    assert page.inner_text("#drape-result code") == "rerun studio-drape/tshirt_dxf-out/tshirt_dxf.rrd"
    page.locator("#drape-result img.drape-still").scroll_into_view_if_needed()
    page.screenshot(path=str(shots / "studio-drape.png"))


def test_a_broken_dxf_shows_an_error_and_loses_nothing(page, folder, shots):
    before = page.evaluate("state.version")
    page.set_input_files("#upload-input", files=[{"name": "broken.dxf", "mimeType": "application/octet-stream",
                                                   "buffer": b"0\nSECTION\n2\nENTITIES\n0\nLINE\n8\nA\n0\nEOF\n"}])
    wait_text(page, "#message.error", "broken.dxf")
    assert page.evaluate("state.version") == before and seams_shown(page) == 10
    assert not (folder / "broken.dxf").exists()
    page.click("nav.tabs button[data-tab=seams]")  # the seams are all still there
    page.screenshot(path=str(shots / "studio-error.png"))
    # the page goes on working
    with page.expect_response("**/api/seams/0"):
        page.locator("#seam-list li").nth(0).locator(".seam-name").fill("left side seam")
        page.locator("#seam-list li").nth(0).locator(".seam-name").press("Enter")
    page.wait_for_function("state.seams[0].name === 'left side seam'")
    page.click("#undo-btn")
    page.wait_for_function("state.seams[0].name === 'left side'")
    assert page.locator("#seam-list li .seam-name").first.input_value() == "left side"


def test_a_file_outside_the_folder_is_refused(page):
    page.fill("#open-path", "../secret.dxf")
    with page.expect_response("**/api/open") as refused:
        page.click("#open-btn")
    assert refused.value.status == 403
    wait_text(page, "#message.error", "refused")
    status = page.evaluate("fetch('/files/..%2Fsecret.png').then((r) => r.status)")
    assert status == 403
    assert seams_shown(page) == 10
