"""Check the demos' recordings as a user sees them: in Rerun's web viewer, in a real browser.

    python -m taichi_cloth.view_check [--out DIR] [--shots DIR] [--demo NAME ...] [--no-run]

For each demo (demos/<name>.py, all of them by default) this runs the demo into DIR (out/view; --no-run: use
the recordings already there), serves its recording with the viewer that rerun-sdk ships (`rerun FILE.rrd
--serve-web`, on 127.0.0.1 and two free ports), opens it in headless Chromium with software WebGL (SwiftShader)
through playwright, waits until the page stops changing, and writes a screenshot to SHOTS/view-<name>.png
(docs/ by default). The 3D panel of the default blueprint (the left ~57 % of the window, above the legend) must
show the cloth: at least MIN_CLOTH_SHARE of its pixels in the cloth's colours (cloth_pixels: the strain map's
white to red, the plain cloth's orange-red; the body is bluish grey, the background dark), and its brightness far
from uniform (standard deviation over MIN_SPREAD of 255). Prints one line per demo; exit 1 if
any check fails, 2 if the browser or the viewer cannot be started.

Needs /usr/bin/chromium (Debian's `chromium`; `make view-check` installs it) and the `view` extra (playwright,
which drives the installed Chromium: no browser download). Not part of `make test`: it takes minutes.
"""
from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
DEMOS = ROOT / "demos"
#: window size [px] of the screenshots
WINDOW = (1600, 1000)
#: the 3D panel of the default blueprint as fractions of the window (x0, y0, x1, y1): left column, above the legend
PANEL_3D = (0.01, 0.07, 0.57, 0.80)
#: the cloth's pixels must be at least this share of the 3D panel, and its brightness spread (std, of 255) this much
MIN_CLOTH_SHARE, MIN_SPREAD = 0.03, 12.0
#: the longest wait [s] for the viewer to load a recording and stop changing
LOAD_TIMEOUT = 120.0
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]


@dataclass
class PanelCheck:
    """What the 3D panel of a screenshot shows: cloth_share (fraction of its pixels in the cloth's colours),
    spread (std of the brightness, 0-255)."""

    cloth_share: float
    spread: float

    @property
    def ok(self) -> bool:
        return self.cloth_share >= MIN_CLOTH_SHARE and self.spread >= MIN_SPREAD

    def describe(self) -> str:
        return f"cloth {100 * self.cloth_share:.1f} % of the 3D panel, brightness spread {self.spread:.0f}/255"


def cloth_pixels(rgb: np.ndarray) -> np.ndarray:
    """(H,W) bool: the pixels of a (H,W,3) uint8 image in the cloth's colours, lit: bright (red 120 or more) and
    red >= green >= blue, as the strain map's white to red and the plain cloth's orange-red are (the body's grey is
    bluish, the 3D view's background dark)."""
    r, g, b = (rgb[..., c].astype(np.int16) for c in range(3))
    return (r >= 120) & (r >= g) & (g >= b)


def check_panel(png: Path) -> PanelCheck:
    """Crop the 3D panel (PANEL_3D) out of a screenshot and measure it."""
    from matplotlib.image import imread  # matplotlib (0.2 s to import): only when a screenshot is checked

    img = imread(png)
    rgb = (img[..., :3] * 255).astype(np.uint8) if img.dtype != np.uint8 else img[..., :3]
    h, w = rgb.shape[:2]
    x0, y0, x1, y1 = PANEL_3D
    panel = rgb[int(y0 * h):int(y1 * h), int(x0 * w):int(x1 * w)]
    return PanelCheck(float(cloth_pixels(panel).mean()), float(panel.astype(np.float64).mean(axis=2).std()))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for(port: int, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return True
        time.sleep(0.2)
    return False


def serve(rrd: Path, log) -> tuple[subprocess.Popen, str]:
    """Start `rerun FILE --serve-web` on 127.0.0.1 (free ports); returns the process and the viewer's address."""
    grpc, web = _free_port(), _free_port()
    rerun = Path(sys.executable).with_name("rerun")
    cmd = [str(rerun) if rerun.exists() else "rerun", str(rrd), "--serve-web", "--bind", "127.0.0.1",
           "--port", str(grpc), "--web-viewer-port", str(web)]
    # a session of its own: the `rerun` script runs the viewer's binary as its child, and stop() ends both
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True,
                            env=dict(os.environ, RERUN_ANALYTICS="0"))
    if not (_wait_for(grpc, 30) and _wait_for(web, 30)):
        stop(proc)
        raise RuntimeError(f"the viewer did not start serving {rrd} (its log: {log.name})")
    url = f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy"
    return proc, url


def stop(proc: subprocess.Popen) -> None:
    """End a server started by serve(), its child processes too."""
    try:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(10)
    except ProcessLookupError:
        pass
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def screenshot(browser, url: str, png: Path) -> PanelCheck:
    """Open `url` in a new page, wait until the 3D panel shows the cloth and the page stops changing (two
    screenshots 3 s apart alike; at most LOAD_TIMEOUT), write the last screenshot to `png` and measure it."""
    page = browser.new_page(viewport={"width": WINDOW[0], "height": WINDOW[1]})
    try:
        page.goto(url)
        end = time.monotonic() + LOAD_TIMEOUT
        before = None
        while True:
            time.sleep(3.0)
            page.screenshot(path=str(png))
            now = png.read_bytes()
            check = check_panel(png)
            if (check.ok and now == before) or time.monotonic() > end:
                return check
            before = now
    finally:
        page.close()


def run_demo(name: str, out: Path) -> Path:
    """Run demos/<name>.py into `out` (its recording overwritten); returns the recording's path."""
    rrd = out / f"{name}.rrd"
    for old in [p for suffix in (".rrd", ".obj", ".ply") for p in out.glob(f"{name}*{suffix}")]:
        old.unlink()  # the run numbers its files past any recording or mesh of an earlier run
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    done = subprocess.run([sys.executable, str(DEMOS / f"{name}.py"), "--out", str(out), "--no-progress"],
                          capture_output=True, text=True, env=env)
    if done.returncode != 0 or not rrd.exists():
        tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
        raise RuntimeError(f"demos/{name}.py exited {done.returncode}: {tail[0]}")
    return rrd


def demo_names() -> list[str]:
    return sorted(p.stem for p in DEMOS.glob("*.py") if not p.stem.startswith("_"))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/view"), help="where the demos write their recordings")
    parser.add_argument("--shots", type=Path, default=ROOT / "docs", help="where the screenshots go")
    parser.add_argument("--demo", action="append", choices=demo_names(), help="check only this demo (repeatable)")
    parser.add_argument("--no-run", action="store_true", help="check the recordings already in --out")
    args = parser.parse_args(argv)
    if not Path(CHROMIUM).exists():
        print(f"error: {CHROMIUM} not found: install Debian's chromium (`make view-check` does)", file=sys.stderr)
        return 2
    try:
        from playwright.sync_api import sync_playwright  # an optional extra ('.[view]')
    except ImportError:
        print("error: playwright is missing: pip install -e '.[view]'", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    args.shots.mkdir(parents=True, exist_ok=True)
    failed = 0
    with sync_playwright() as p:  # playwright gives the browser a fresh profile of its own
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True,
                                    args=CHROMIUM_FLAGS)
        for name in args.demo or demo_names():
            png = args.shots / f"view-{name}.png"
            try:
                rrd = args.out / f"{name}.rrd" if args.no_run else run_demo(name, args.out)
                if not rrd.exists():
                    raise RuntimeError(f"no recording {rrd} (run without --no-run)")
                with open(args.out / f"{name}.viewer.log", "w") as log:
                    proc, url = serve(rrd, log)
                    try:
                        check = screenshot(browser, url, png)
                    finally:
                        stop(proc)
            except RuntimeError as err:
                print(f"{name}: FAILED: {err}")
                failed += 1
                continue
            print(f"{name}: {'ok' if check.ok else 'FAILED'}: {check.describe()}; screenshot {png}")
            failed += not check.ok
        browser.close()
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
