"""The studio's state and its operations, without HTTP: what the page edits is the content of a garment file.

The set-up (`Session.doc`) is the dict a garment file holds (docs/scene-files.md, garment files), with a `dxf`
path relative to the start folder. Every edit builds a new dict and checks it as a garment file is checked
(taichi_cloth.garment.garmentfile.garment_from_dict), plus what only building the garment would find: a seam side
from a corner to itself or half way round, an outline stretch sewn twice, an unknown anchor, a spacing the
machine has no memory for. An edit that fails changes nothing and raises PatternError (or Refused) with one
message. One that passes is pushed on the undo stack and autosaved.

A seam whose sides differ in length by more than its tolerance is kept (the page shows both lengths) but will
not build: flip it, pick another stretch or raise its tolerance.

Autosave: after every change the set-up is written to AUTOSAVE in the start folder (a garment file that loads as
any other); a save removes it, since the saved file then holds the set-up. At start an AUTOSAVE left by a closed
tab or a crash is moved to PREVIOUS and offered for restore; restoring is an edit like any other (undo goes back).
"""
from __future__ import annotations

import copy
import math
import os
import re
import threading
import time
from pathlib import Path

from ..errors import PatternError
from ..garment.dxf import dxf_units, read_dxf
from ..garment.garmentcode import read_specification
from ..garment.garment import RESOLUTIONS, FreePlacement
from ..garment.garmentfile import GARMENT_SCHEMA, garment_from_dict
from ..garment.pattern import unit_scale
from ..garment.seams import DEFAULT_LENGTH_TOLERANCE, plan_counts
from ..guards import check_memory, sheet_particles
from ..material import MATERIALS
from ..paths import free_path
from ..schema import read_toml
from .folder import OPENS, Folder, Refused
from .layout import layout, segment_lengths
from .tomlfile import garment_text

AUTOSAVE = ".studio-autosave.toml"
PREVIOUS = ".studio-autosave-previous.toml"
#: [m] the spacing a pattern opened from a DXF starts with (garment tools draft at 2 cm: docs/garments.md)
DEFAULT_SPACING = 0.02
#: the most edits undo goes back
UNDO_DEPTH = 200
MATERIAL_KEYS = ("density", "stretch", "shear", "bend", "damping", "viscosity")
PLACEMENT_KEYS = ("anchor", "at", "offset", "height", "angle", "wrap")
#: a DXF piece's pattern options in a garment file and their defaults (the garment file's schema says them)
PIECE_PATTERN_DEFAULTS = {k: GARMENT_SCHEMA.fields["pieces"].table.fields[k].default
                          for k in ("rotate", "unfold", "seam_allowance")}
#: the DXF file's options at a garment file's top level and their defaults
DXF_DEFAULTS = {k: GARMENT_SCHEMA.fields[k].default for k in ("dxf_units", "dxf_size", "seam_allowance")}


def guess_anchor(piece: str) -> str:
    """A first placement for a piece opened from a DXF, from its name: a sleeve goes on an arm (the right one when
    the name says R or right), a back on the torso's back, a skirt panel at the waist, anything else on the torso's
    front. The page shows it; the user sets the real one."""
    words = [w for w in re.split(r"[^a-z]+", piece.lower()) if w]
    right = any(w in ("r", "right") for w in words)
    back = any(w in ("b", "back") for w in words)
    if any(w.startswith("sleeve") or w == "arm" for w in words):
        return "arm_right" if right else "arm_left"
    if any(w.startswith("skirt") for w in words):
        return "waist_back" if back else "waist_front"
    return "torso_back" if back else "torso_front"


def _number(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise PatternError(f"{what} must be a number, got {value!r}")
    return value


def _side(data, what: str) -> dict:
    """A seam side from the page: {"piece", "from", "to"} (corner names or indices)."""
    if not isinstance(data, dict) or any(k not in data for k in ("piece", "from", "to")):
        raise PatternError(f"{what} must give piece, from and to, got {data!r}")
    for k in ("piece", "from", "to"):
        v = data[k]
        if not (isinstance(v, str) or (k != "piece" and isinstance(v, int) and not isinstance(v, bool))):
            raise PatternError(f"{what} {k} must be a name, got {v!r}")
    return {"piece": data["piece"], "from": data["from"], "to": data["to"]}


class Session:
    """The studio's state: the set-up `doc` (None until a pattern is opened), where Save writes (`target`, relative
    to the folder), the undo and redo stacks, the restore offer, and a `version` that every change increases.

    folder: the start folder (Folder); anchors: the placement anchors the mannequin has (names, in order)."""

    def __init__(self, folder: Folder, anchors):
        self.folder = folder
        self.anchors = list(anchors)
        self.doc: dict | None = None
        self.spec = None
        self.target: str | None = None
        self.source: str | None = None
        self.version = 0
        self.saved_version = 0
        self.autosaved_version = -1
        self.undo_stack: list = []
        self.redo_stack: list = []
        self.restore_offer: dict | None = None
        self.autosave_error: str | None = None
        self.lock = threading.RLock()
        self._dxf_cache: dict = {}
        self._layout = (None, None)

    # ------------------------------------------------------------------------------------------ reading files
    def _read_dxf(self, path, units: str | None = None, size: str | None = None, as_drawn: bool = False) -> list:
        """read_dxf, kept while the file and the options are unchanged (every edit checks the set-up, which names
        the DXF)."""
        path = Path(path)
        if not path.resolve().is_relative_to(self.folder.root):
            raise Refused(f"{path.name}: refused: the DXF file lies outside the studio's folder {self.folder.root}",
                          403)
        st = path.stat() if path.is_file() else None
        key = (str(path.resolve()), st.st_mtime_ns, st.st_size, units, size, as_drawn) if st else None
        if key is None or key not in self._dxf_cache:
            pieces = read_dxf(path, units=units, size=size, as_drawn=as_drawn)
            if key is None:
                return pieces
            self._dxf_cache = {key: pieces}
        return self._dxf_cache[key]

    def short(self, exc) -> str:
        """An error's message with the folder's own path left out (the page names files relative to it)."""
        return str(exc).replace(str(self.folder.root) + os.sep, "").replace(str(self.folder.root), ".")

    def doc_from_dxf(self, path: Path, units: str | None = None) -> dict:
        """A new set-up from a DXF file: its pieces, a first placement each (guess_anchor), no seams, cotton, the
        DXF's own units (or `units`, kept as the set-up's dxf_units, for a file that gives none), DEFAULT_SPACING."""
        pieces = self._read_dxf(path, units)
        name = units or dxf_units(path)
        scale = unit_scale(name)
        doc = {"name": path.stem, "dxf": self.folder.relative(path), "units": name, "material": "cotton",
               "spacing": round(DEFAULT_SPACING / scale, 9),
               "pieces": [{"name": p.name, "placement": {"anchor": guess_anchor(p.name)}} for p in pieces],
               "seams": []}
        return doc if units is None else {**doc, "dxf_units": units}

    def doc_from(self, path: Path, units: str | None = None) -> dict:
        """The set-up of a file the studio opens (OPENS): a DXF pattern, a garment file or a GarmentCode
        specification (read as the garment file taichi_cloth.garment.garmentcode makes of it: saved, it becomes
        one)."""
        suffix = path.suffix.lower()
        if suffix == ".dxf":
            return self.doc_from_dxf(path, units)
        return read_specification(path) if suffix == ".json" else self.doc_from_toml(path)

    def doc_from_toml(self, path: Path) -> dict:
        """The set-up of a garment file, its `dxf` made relative to the folder (refused if it leads outside)."""
        doc = read_toml(path, str(self.folder.relative(path)), "garment", PatternError)
        if isinstance(doc.get("dxf"), str):
            full = Path(doc["dxf"]) if Path(doc["dxf"]).is_absolute() else path.parent / doc["dxf"]
            real = full.resolve()
            if not real.is_relative_to(self.folder.root):
                raise Refused(f"{self.folder.relative(path)}: dxf = {doc['dxf']!r} leads outside the studio's folder "
                              f"{self.folder.root}", 403)
            doc["dxf"] = os.path.relpath(full, self.folder.root).replace(os.sep, "/")
        return doc

    # ------------------------------------------------------------------------------------------ checking
    def check(self, doc: dict):
        """The GarmentSpec of a set-up, or PatternError/Refused with one message (module docstring)."""
        try:  # as if it were a file in the folder (its dxf is relative to the folder); the messages name no file
            spec = garment_from_dict(doc, self.folder.root / "garment.toml", dxf_reader=self._read_dxf)
        except PatternError as exc:
            raise PatternError(self.short(exc).removeprefix("garment.toml: ")) from None
        for name, pl in spec.placements.items():
            if not isinstance(pl, FreePlacement) and pl.anchor not in self.anchors:
                raise PatternError(f"piece {name!r}: unknown anchor {pl.anchor!r}; the anchors are "
                                   f"{', '.join(self.anchors)}")
        # what plan_counts refuses before meshing, except a length mismatch, which the page shows instead
        pieces = {p.name: p for p in spec.pieces}
        lengths = {n: segment_lengths(p) for n, p in pieces.items()}
        lax = [type(s)(s.name, s.a, s.b, math.inf) for s in spec.seams]
        plan_counts(pieces, lax, spec.spacing, lengths)
        check_memory(self.particles(spec), f"spacing {doc.get('spacing', spec.spacing)} {doc.get('units', 'm')}",
                     error=PatternError, advice="use a larger spacing")
        return spec

    @staticmethod
    def particles(spec) -> int:
        """About how many particles the garment meshes to (taichi_cloth.guards.sheet_particles)."""
        return sheet_particles(sum(p.area() for p in spec.pieces), sum(p.perimeter() for p in spec.pieces),
                               spec.spacing, spec.levels)

    # ------------------------------------------------------------------------------------------ changing
    def _commit(self, doc: dict, opened: bool = False) -> None:
        """Check `doc` and make it the set-up (undo goes back to the one before). `opened`: it is a file just
        opened, so there is nothing unsaved to autosave yet."""
        spec = self.check(doc)
        if self.doc is not None:
            self.undo_stack = (self.undo_stack + [(self.doc, self.target)])[-UNDO_DEPTH:]
            self.redo_stack = []
        self.doc, self.spec = doc, spec
        self.version += 1
        if not opened:
            self.autosave()

    def _edit(self) -> dict:
        if self.doc is None:
            raise Refused("no pattern open: open a DXF or garment file first", 409)
        return copy.deepcopy(self.doc)

    def open(self, relative: str, units: str | None = None) -> None:
        """Open a DXF pattern or a garment file under the folder (undo goes back to what was open before); `units`:
        a DXF's unit where the file gives none ("m", "cm", "mm" or "in"; None: the file's own)."""
        with self.lock:
            path = self.folder.resolve(relative, suffixes=OPENS, must_exist=True)
            doc = self.doc_from(path, units)
            old_target = self.target
            self.target = self.folder.relative(path) if path.suffix.lower() == ".toml" else None
            try:
                self._commit(doc, opened=True)
            except Exception:
                self.target = old_target
                raise
            self.source = self.folder.relative(path)
            if self.target is not None:
                self.saved_version = self.version

    def open_upload(self, name: str, data: bytes, units: str | None = None) -> str:
        """Open a DXF pattern or garment file sent from the page: checked first under a temporary name, then kept
        in the folder as `name` (or name-2, name-3...: nothing is overwritten). A file that does not open is
        removed again and changes nothing. `units` as for open. Returns its name in the folder."""
        with self.lock:
            name = Path(str(name).replace("\\", "/")).name
            suffix = Path(name).suffix.lower()
            if suffix not in OPENS or name.startswith("."):
                raise Refused(f"{name or 'the upload'}: the studio opens .dxf, .toml and .json (GarmentCode) files",
                              400)
            tmp = self.folder.root / f".studio-upload{suffix}"
            tmp.write_bytes(data)
            try:
                doc = self.doc_from(tmp, units)
                if suffix != ".toml":
                    doc["name"] = Path(name).stem
                self.check(doc)
            except Exception as exc:
                tmp.unlink(missing_ok=True)
                if isinstance(exc, Refused):
                    raise Refused(str(exc).replace(tmp.name, name), exc.status) from None
                if isinstance(exc, PatternError):
                    raise PatternError(str(exc).replace(tmp.name, name)) from None
                raise
            final = free_path(self.folder.root / name)
            os.replace(tmp, final)
            kept = self.folder.relative(final)
            if suffix == ".dxf":
                doc["dxf"] = kept
            old_target = self.target
            self.target = kept if suffix == ".toml" else None
            try:
                self._commit(doc, opened=True)
            except Exception:
                self.target = old_target
                raise
            self.source = kept
            if self.target is not None:
                self.saved_version = self.version
            return kept

    def set_name(self, name) -> None:
        with self.lock:
            if not isinstance(name, str) or not name.strip():
                raise PatternError(f"the garment's name must be a non-empty text, got {name!r}")
            doc = self._edit()
            doc["name"] = name.strip()
            self._commit(doc)

    def add_seam(self, a, b, name=None, tolerance=None) -> int:
        """Sew side a to side b ({"piece", "from", "to"}: point i of a's pick meets point i of b's); returns its
        index. name: default "seam N"; tolerance: default the garment files' (10 %)."""
        with self.lock:
            doc = self._edit()
            seams = doc.setdefault("seams", [])
            taken = {s.get("name") for s in seams}
            if name is None or (isinstance(name, str) and not name.strip()):
                k = len(seams) + 1
                while f"seam {k}" in taken:
                    k += 1
                name = f"seam {k}"
            if not isinstance(name, str):
                raise PatternError(f"a seam's name must be a text, got {name!r}")
            seam = {"name": name.strip(), "a": _side(a, "side a"), "b": _side(b, "side b")}
            if tolerance is not None:
                seam["tolerance"] = _number(tolerance, "the seam's tolerance")
            seams.append(seam)
            self._commit(doc)
            return len(seams) - 1

    def _seam(self, doc: dict, index) -> dict:
        seams = doc.get("seams") or []
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(seams):
            raise Refused(f"no seam #{index} (there are {len(seams)})", 404)
        return seams[index]

    def edit_seam(self, index, name=None, tolerance=None) -> None:
        """Rename a seam and/or set its tolerance (relative length difference it accepts)."""
        with self.lock:
            doc = self._edit()
            seam = self._seam(doc, index)
            if name is not None:
                if not isinstance(name, str) or not name.strip():
                    raise PatternError(f"a seam's name must be a non-empty text, got {name!r}")
                seam["name"] = name.strip()
            if tolerance is not None:
                seam["tolerance"] = _number(tolerance, "the seam's tolerance")
            self._commit(doc)

    def flip_seam(self, index, side: str) -> None:
        """Reverse one side of a seam (its from and to swap), so that it is sewn the other way along its partner."""
        with self.lock:
            if side not in ("a", "b"):
                raise PatternError(f"flip side must be 'a' or 'b', got {side!r}")
            doc = self._edit()
            s = self._seam(doc, index)[side]
            s["from"], s["to"] = s["to"], s["from"]
            self._commit(doc)

    def delete_seam(self, index) -> None:
        with self.lock:
            doc = self._edit()
            self._seam(doc, index)
            del doc["seams"][index]
            self._commit(doc)

    def set_placement(self, piece, placement) -> None:
        """Place a piece around the body: placement {"anchor", "at": [u, v] or None (the middle of the piece),
        "offset", "height", "angle" [deg], "wrap"}, lengths in the file's units; keys left out (or at their
        defaults: height 0, angle 0, wrap true) are not written."""
        with self.lock:
            doc = self._edit()
            entry = next((p for p in doc.get("pieces", []) if p.get("name") == piece), None)
            if entry is None:
                raise Refused(f"no piece {piece!r}", 404)
            if not isinstance(placement, dict):
                raise PatternError(f"a placement must be a table, got {placement!r}")
            unknown = sorted(set(placement) - set(PLACEMENT_KEYS))
            if unknown:
                raise PatternError(f"placement of {piece!r}: unknown keys {', '.join(unknown)} (known: "
                                   f"{', '.join(PLACEMENT_KEYS)})")
            new = {"anchor": placement.get("anchor")}
            if placement.get("at") is not None:
                new["at"] = placement["at"]
            if placement.get("offset") is not None:
                new["offset"] = placement["offset"]
            for k, default in (("height", 0), ("angle", 0), ("wrap", True)):
                if placement.get(k) is not None and placement[k] != default:
                    new[k] = placement[k]
            entry["placement"] = new
            self._commit(doc)

    def set_piece_pattern(self, piece, options) -> None:
        """A DXF piece's pattern options: {"rotate": [deg] counter-clockwise, or None to turn it by its grain
        line; "unfold": whether a half on a fold is unfolded; "seam_allowance": taken off its cut line, in the
        file's units, or None for the file's}; keys left out (or at their defaults) are not written."""
        with self.lock:
            doc = self._edit()
            entry = next((p for p in doc.get("pieces", []) if p.get("name") == piece), None)
            if entry is None:
                raise Refused(f"no piece {piece!r}", 404)
            self._set_options(entry, options, PIECE_PATTERN_DEFAULTS, f"pattern options of {piece!r}")
            self._commit(doc)

    def set_dxf_options(self, options) -> None:
        """The DXF file's options: {"dxf_units": its unit where it gives none, "dxf_size": the size of a graded
        file, "seam_allowance": taken off its cut lines, in the file's units}; keys left out (or at their defaults:
        the file's unit, its sample size, none) are not written."""
        with self.lock:
            doc = self._edit()
            if not doc.get("dxf"):
                raise PatternError("the set-up takes no pieces from a DXF file: it has no DXF options")
            self._set_options(doc, options, DXF_DEFAULTS, "DXF options")
            self._commit(doc)

    @staticmethod
    def _set_options(table: dict, options, defaults: dict, what: str) -> None:
        """Write `options` into `table`, leaving out those at their defaults (the garment file checks the rest)."""
        if not isinstance(options, dict):
            raise PatternError(f"{what} must be a table, got {options!r}")
        unknown = sorted(set(options) - set(defaults))
        if unknown:
            raise PatternError(f"{what}: unknown keys {', '.join(unknown)} (known: {', '.join(defaults)})")
        for key, default in defaults.items():
            table.pop(key, None)
            if options.get(key) is not None and options[key] != default:
                table[key] = options[key]

    def set_material(self, preset, values=None) -> None:
        """The material: a preset, and any of its numbers replaced (values: key -> number; a value equal to the
        preset's, or None, keeps the preset's)."""
        with self.lock:
            if preset not in MATERIALS:
                raise PatternError(f"unknown material preset {preset!r}: choose one of {', '.join(MATERIALS)}")
            values = values or {}
            unknown = sorted(set(values) - set(MATERIAL_KEYS))
            if unknown:
                raise PatternError(f"unknown material keys {', '.join(unknown)} (known: {', '.join(MATERIAL_KEYS)})")
            base = MATERIALS[preset]
            changed = {k: _number(v, f"material {k}") for k, v in values.items()
                       if v is not None and v != getattr(base, k)}
            doc = self._edit()
            doc["material"] = {"preset": preset, **changed} if changed else preset
            self._commit(doc)

    def set_spacing(self, spacing) -> None:
        """The particle spacing, in the file's units (it replaces a resolution preset)."""
        with self.lock:
            value = _number(spacing, "the spacing")
            if value <= 0:
                raise PatternError(f"the spacing must be > 0, got {spacing!r}")
            doc = self._edit()
            doc["spacing"] = value
            doc.pop("resolution", None)
            self._commit(doc)

    def undo(self) -> None:
        with self.lock:
            if not self.undo_stack:
                raise Refused("nothing to undo", 409)
            doc, target = self.undo_stack[-1]
            spec = self.check(doc)  # a file it names may have gone since
            self.undo_stack.pop()
            self.redo_stack.append((self.doc, self.target))
            self.doc, self.spec, self.target = doc, spec, target
            self.version += 1
            self.autosave()

    def redo(self) -> None:
        with self.lock:
            if not self.redo_stack:
                raise Refused("nothing to redo", 409)
            doc, target = self.redo_stack[-1]
            spec = self.check(doc)
            self.redo_stack.pop()
            self.undo_stack.append((self.doc, self.target))
            self.doc, self.spec, self.target = doc, spec, target
            self.version += 1
            self.autosave()

    # ------------------------------------------------------------------------------------------ saving
    def doc_for(self, path: Path) -> dict:
        """The set-up as a garment file at `path` holds it: its `dxf` relative to that file's folder."""
        doc = copy.deepcopy(self.doc)
        if isinstance(doc.get("dxf"), str):
            doc["dxf"] = os.path.relpath(self.folder.root / doc["dxf"], path.parent).replace(os.sep, "/")
        return doc

    def write(self, path: Path, comments=()) -> None:
        """Write the set-up to `path` as a garment file, whole or not at all (a temporary file renamed over it)."""
        text = garment_text(self.doc_for(path), comments)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.studio-tmp")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)

    def save(self, relative=None, overwrite: bool = False) -> str:
        """Save the set-up as a garment file under the folder (default: where it was opened or last saved, else
        NAME.toml); another existing file is overwritten only with `overwrite` (else Refused 409). Returns the path
        written, relative to the folder."""
        with self.lock:
            if self.doc is None:
                raise Refused("no pattern open: nothing to save", 409)
            relative = relative or self.target or f"{self.doc.get('name') or 'garment'}.toml"
            path = self.folder.resolve(relative, suffixes=(".toml",))
            if path.name in (AUTOSAVE, PREVIOUS):
                raise Refused(f"{relative}: that name is the studio's autosave; choose another", 400)
            own = self.target is not None and self.folder.resolve(self.target) == path
            if path.exists() and not own and not overwrite:
                raise Refused(f"{self.folder.relative(path)} exists: save again to overwrite it", 409)
            if path.is_dir():
                raise Refused(f"{self.folder.relative(path)} is a folder", 400)
            self.write(path, ["Garment set-up saved by the pattern studio (python -m taichi_cloth studio)."])
            self.target = self.folder.relative(path)
            self.saved_version = self.version
            try:
                (self.folder.root / AUTOSAVE).unlink(missing_ok=True)  # the saved file now holds the set-up
            except OSError:
                pass
            return self.target

    def autosave(self) -> None:
        """Write the set-up to AUTOSAVE (module docstring); a failure is kept in autosave_error for the page."""
        if self.doc is None:
            return
        try:
            self.write(self.folder.root / AUTOSAVE,
                       ["Pattern studio autosave: the set-up with changes not yet saved.",
                        f"target = {self.target or ''}", f"written {time.strftime('%Y-%m-%d %H:%M:%S')}"])
            self.autosave_error = None
            self.autosaved_version = self.version
        except OSError as exc:
            self.autosave_error = f"the autosave could not be written: {exc.strerror or exc}"

    def find_autosave(self) -> None:
        """At start: move an AUTOSAVE left by an earlier studio to PREVIOUS and offer it for restore."""
        with self.lock:
            found = self.folder.root / AUTOSAVE
            if not found.is_file():
                return
            previous = self.folder.root / PREVIOUS
            os.replace(found, previous)
            text = previous.read_text(encoding="utf-8", errors="replace")
            target = re.search(r"^# target = (.*)$", text, re.M)
            self.restore_offer = {"file": PREVIOUS, "target": (target.group(1).strip() or None) if target else None,
                                  "written": time.strftime("%Y-%m-%d %H:%M:%S",
                                                           time.localtime(previous.stat().st_mtime))}

    def restore(self) -> None:
        """Make the offered autosave the set-up (an edit: undo goes back)."""
        with self.lock:
            if self.restore_offer is None:
                raise Refused("there is no autosave to restore", 409)
            path = self.folder.root / PREVIOUS
            if not path.is_file():
                self.restore_offer = None
                raise Refused(f"the autosave {PREVIOUS} is gone", 404)
            doc = self.doc_from_toml(path)
            old_target = self.target
            self.target = self.restore_offer["target"]
            try:
                self._commit(doc)
            except Exception:
                self.target = old_target
                raise
            self.source = PREVIOUS
            self.restore_offer = None
            path.unlink(missing_ok=True)  # the set-up is the autosave again now

    def dismiss_restore(self) -> None:
        """Leave the autosave where it is (PREVIOUS: open it by name) and stop offering it."""
        with self.lock:
            self.restore_offer = None

    # ------------------------------------------------------------------------------------------ the page
    def material_state(self) -> dict:
        m = self.doc.get("material", "cotton") if self.doc else "cotton"
        preset = m if isinstance(m, str) else (m.get("preset") or "cotton")
        overrides = {} if isinstance(m, str) else {k: v for k, v in m.items() if k != "preset"}
        base = MATERIALS[preset]
        return {"preset": preset, "overrides": overrides,
                "values": {k: overrides.get(k, getattr(base, k)) for k in MATERIAL_KEYS}}

    def state(self) -> dict:
        """Everything the page shows (docs/studio.md)."""
        with self.lock:
            out = {"version": self.version, "folder": str(self.folder.root), "anchors": self.anchors,
                   "presets": {n: {k: getattr(m, k) for k in MATERIAL_KEYS} for n, m in MATERIALS.items()},
                   "resolutions": {n: s for n, (s, _) in RESOLUTIONS.items()},
                   "undo": len(self.undo_stack), "redo": len(self.redo_stack), "restore": self.restore_offer,
                   "autosave": {"file": AUTOSAVE, "error": self.autosave_error,
                                "current": self.autosaved_version == self.version},
                   "default_tolerance": DEFAULT_LENGTH_TOLERANCE, "open": self.doc is not None}
            if self.doc is None:
                return out
            scale = unit_scale(self.doc.get("units", "m"))
            if self._layout[0] != self.version:
                self._layout = (self.version, layout(self.spec, scale))
            drawing = self._layout[1]
            warnings = [f"seam {s['number']} {s['name']!r}: side a ({s['a']['piece']} {s['a']['from']} to "
                        f"{s['a']['to']}) is {s['a']['length']:.1f} {self.doc.get('units', 'm')} and side b "
                        f"({s['b']['piece']} {s['b']['from']} to {s['b']['to']}) is {s['b']['length']:.1f} "
                        f"{self.doc.get('units', 'm')}: {100 * s['mismatch']:.1f} % apart, more than its tolerance "
                        f"{100 * s['tolerance']:.0f} %; it will not sew" for s in drawing["seams"] if not s["pairs"]]
            out.update({
                "name": self.spec.name, "units": self.doc.get("units", "m"), "source": self.source,
                "target": self.target, "saved": self.version == self.saved_version, "dxf": self.doc.get("dxf"),
                "pieces": drawing["pieces"], "seams": drawing["seams"], "warnings": warnings,
                "placements": {p["name"]: p.get("placement", {}) for p in self.doc.get("pieces", [])},
                "pattern_options": {p["name"]: {k: p[k] for k in PIECE_PATTERN_DEFAULTS if k in p}
                                    for p in self.doc.get("pieces", [])},
                "dxf_options": {k: self.doc[k] for k in DXF_DEFAULTS if k in self.doc},
                "material": self.material_state(),
                "spacing": round(self.spec.spacing / scale, 9), "resolution": self.doc.get("resolution"),
                "levels": self.spec.levels, "particles": self.particles(self.spec),
            })
            return out
