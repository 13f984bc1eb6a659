"""A drape from the studio: the set-up sewn and draped on the mannequin by `python -m taichi_cloth run` in a child
process, so that the page stays responsive and a crash of the run cannot take the studio down.

`write_drape` writes the set-up as a garment file and a scene that sews it (the settings of
demos/scenes/sew_tshirt.toml) into DRAPE_FOLDER of the start folder; a quick drape writes the garment at a coarser
spacing. `DrapeJob` runs the command (`--png`: the still pictures), reads the frame count off its progress bar, and
when it ends says how it went: done, or failed with one line (the run's `error:` line, sewing that gave up or
seams still open at the end), the pictures, the quality table and the command that opens the recording.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
from pathlib import Path

from ..garment.pattern import unit_scale
from ..paths import free_stem
from .tomlfile import garment_text

#: the drape's files, in the start folder
DRAPE_FOLDER = "studio-drape"
#: [m] the spacing of a quick drape (a fast look, not a fitting: docs/garments.md, resolution)
QUICK_SPACING = 0.04
#: frames of a drape by default (60 per simulated second: the shipped T-shirt sews in 0.7 s)
DEFAULT_FRAMES = 120
MAX_FRAMES = 3600

SCENE = """# Written by the pattern studio: the garment {garment} sewn and draped on the mannequin (the settings of
# demos/scenes/sew_tshirt.toml).
name = "{name}"
frames = {frames}
fps = 60.0
air_damping = 1.0

[cloth]
garment = "{garment}"

[integrator]
name = "implicit"
dt = 0.008333333
cg_tolerance = 1e-3

[sewing]
close_speed = 0.5
epsilon = 0.002
energy_tolerance = 0.05
gravity = false

[[colliders]]
type = "mesh"
path = "mannequin"
thickness = 0.004
friction = 0.4

[stretch_limit]
max_strain = 0.1
iterations = 20
"""


def stem_of(name: str) -> str:
    """A file stem from a garment's name (letters, digits, - and _)."""
    return re.sub(r"[^A-Za-z0-9_-]+", "_", name).strip("_") or "garment"


def write_drape(session, frames: int, spacing: float | None = None) -> tuple[Path, Path]:
    """Write the session's set-up (at `spacing` [m], when given) and a scene that drapes it for `frames` frames into
    DRAPE_FOLDER; returns (scene file, a fresh output folder beside it)."""
    folder = session.folder.root / DRAPE_FOLDER
    folder.mkdir(exist_ok=True)
    stem = stem_of(session.spec.name)
    garment = folder / f"{stem}.toml"
    doc = session.doc_for(garment)
    if spacing is not None:
        doc["spacing"] = round(spacing / unit_scale(doc.get("units", "m")), 9)
        doc.pop("resolution", None)
    garment.write_text(garment_text(doc, ["Written by the pattern studio for a drape: the set-up as it was then."]),
                       encoding="utf-8")
    scene = folder / f"{stem}-scene.toml"
    scene.write_text(SCENE.format(name=stem, frames=int(frames), garment=garment.name), encoding="utf-8")
    out = folder / free_stem(folder, f"{stem}-out", [""])
    return scene, out


def run_command(scene: Path, out: Path, frames: int) -> list[str]:
    """The command a drape runs: this Python's `taichi_cloth run`, with the still pictures."""
    return [sys.executable, "-m", "taichi_cloth", "run", str(scene), "--out", str(out), "--frames", str(int(frames)),
            "--png"]


_PROGRESS = re.compile(r"(\d+)/(\d+) \[")


class DrapeJob:
    """One drape at a time: start() it, status() while and after it runs, cancel() it. The paths it reports are
    relative to `root` (the start folder)."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.lock = threading.Lock()
        self.proc = None
        self._state = {"state": "idle"}

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def start(self, argv: list, out: Path, frames: int, spacing_note: str = "") -> None:
        """Run `argv` in the start folder, its outputs going to `out`."""
        with self.lock:
            self.out = Path(out)
            self.frames, self.done, self.cancelled = int(frames), 0, False
            self.stdout, self.stderr = [], []
            self._state = {"state": "running", "frames": self.frames, "done": 0, "progress": 0.0,
                           "note": spacing_note, "command": " ".join(str(a) for a in argv)}
            env = dict(os.environ, PYTHONUNBUFFERED="1")
            self.proc = subprocess.Popen(argv, cwd=self.root, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                         stdin=subprocess.DEVNULL, env=env)
            readers = [threading.Thread(target=self._read_lines, args=(self.proc.stdout, self.stdout), daemon=True),
                       threading.Thread(target=self._read_progress, args=(self.proc.stderr,), daemon=True)]
            for t in readers:
                t.start()
            threading.Thread(target=self._finish, args=(self.proc, readers), daemon=True).start()

    def _read_lines(self, stream, into: list) -> None:
        for raw in stream:
            into.append(raw.decode("utf-8", "replace").rstrip("\r\n"))

    def _read_progress(self, stream) -> None:
        """stderr: the progress bar rewrites its line with carriage returns; every other line is kept."""
        buf = b""
        while True:
            chunk = stream.read1(4096) if hasattr(stream, "read1") else stream.read(4096)
            if not chunk:
                break
            buf += chunk
            *parts, buf = re.split(rb"[\r\n]", buf)
            for part in parts:
                self._stderr_part(part.decode("utf-8", "replace"))
        if buf:
            self._stderr_part(buf.decode("utf-8", "replace"))

    def _stderr_part(self, text: str) -> None:
        m = _PROGRESS.search(text)
        if m:
            self.done = int(m.group(1))
        elif text.strip():
            self.stderr.append(text.strip())

    def _finish(self, proc, readers) -> None:
        rc = proc.wait()
        for t in readers:
            t.join(10)
        with self.lock:
            if proc is self.proc:
                self._state = self._result(rc)

    def cancel(self) -> bool:
        with self.lock:
            if not self.running:
                return False
            self.cancelled = True
            self.proc.terminate()
            return True

    def stop(self) -> None:
        """End a running drape (the studio is closing) and wait for it."""
        if self.cancel():
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()

    def status(self) -> dict:
        with self.lock:
            if self._state.get("state") == "running":
                done = min(self.done, self.frames)
                self._state.update(done=done, progress=done / self.frames if self.frames else 1.0)
            return dict(self._state)

    def _result(self, rc: int) -> dict:
        """How the finished run went (module docstring)."""
        out, err = self.stdout, self.stderr
        pictures = sorted(self.out.glob("*.png")) if self.out.is_dir() else []
        rrd = sorted(self.out.glob("*.rrd")) if self.out.is_dir() else []
        rel = [p.relative_to(self.root).as_posix() for p in pictures]
        quality = [line for line in out if line.startswith("|") or line.startswith(("seam gap:", "note:"))]
        opener = next((line.split(":", 1)[1].strip() for line in out if line.startswith("open the recording with")),
                      None)
        state, reason = "done", None
        if self.cancelled:
            state, reason = "cancelled", "stopped from the page"
        elif rc != 0:
            errors = [line for line in err + out if line.startswith(("error:", "interrupted:"))]
            reason = (errors[-1] if errors else (err[-1] if err else f"the run exited with code {rc}"))
            state = "failed"
        else:
            gave_up = next((line.strip() for line in out if "sewing gave up" in line), None)
            still_open = next((line for line in out if line.startswith("note: seams still open")), None)
            if gave_up:
                state, reason = "failed", gave_up.removeprefix("warning:").strip()
            elif still_open:
                state, reason = "failed", (still_open.removeprefix("note: ") + " when the run ended: drape more "
                                           "frames")
        if reason:
            reason = reason.removeprefix("error: ").strip()
            reason = reason.replace(str(self.root) + os.sep, "")
        return {"state": state, "reason": reason, "frames": self.frames, "done": self.frames if state == "done"
                else min(self.done, self.frames), "progress": 1.0 if state == "done" else
                (min(self.done, self.frames) / self.frames if self.frames else 0.0),
                "pictures": rel, "recording": rrd[0].relative_to(self.root).as_posix() if rrd else None,
                "open_command": opener.replace(str(self.root) + os.sep, "") if opener else None,
                "quality": quality, "log": (out + err)[-40:], "note": self._state.get("note", ""),
                "command": self._state.get("command")}
