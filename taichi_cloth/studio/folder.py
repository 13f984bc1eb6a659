"""The start folder: the studio reads and writes only under the folder it was started in.

A path from the page is relative to that folder, written with `/`. It is refused before anything is opened:
an absolute path (400), a `..` part (403), a path whose real location (symlinks followed) is outside the folder
(403), a file kind the route does not take (400). A missing file is a 404.
"""
from __future__ import annotations

import os
from pathlib import Path, PurePosixPath

from ..errors import TaichiClothError

#: the files the studio opens: a DXF pattern, a garment file, a GarmentCode specification
OPENS = (".dxf", ".toml", ".json")


class Refused(TaichiClothError):
    """A request the studio will not carry out: `status` is the HTTP status, the message says why."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.status = status


class Folder:
    """The start folder `root` (resolved once, at start)."""

    def __init__(self, root):
        self.root = Path(root).resolve()

    def resolve(self, relative: str, suffixes=None, must_exist: bool = False) -> Path:
        """The real path of `relative` under the folder; Refused when it is empty, absolute, has a `..` part, lies
        outside the folder (symlinks followed), has a suffix not in `suffixes` (e.g. (".toml", ".dxf")) or is
        missing while `must_exist`."""
        if not isinstance(relative, str) or not relative.strip():
            raise Refused("no file named: give a path inside the studio's folder", 400)
        text = relative.strip().replace("\\", "/")
        pure = PurePosixPath(text)
        if pure.is_absolute() or os.path.isabs(text) or (len(text) > 1 and text[1] == ":"):
            raise Refused(f"{text}: refused: an absolute path (the studio reads and writes only in {self.root}; give "
                          "a path relative to it)", 400)
        if ".." in pure.parts:
            raise Refused(f"{text}: refused: '..' leads outside the studio's folder {self.root}", 403)
        path = (self.root / pure).resolve()
        if not path.is_relative_to(self.root):
            raise Refused(f"{text}: refused: it leads outside the studio's folder {self.root} (a symbolic link)", 403)
        if suffixes is not None and path.suffix.lower() not in suffixes:
            raise Refused(f"{text}: the studio takes {' or '.join(suffixes)} files here", 400)
        if must_exist and not path.is_file():
            raise Refused(f"{text}: no such file in {self.root}", 404)
        return path

    def relative(self, path) -> str:
        """`path` (under the folder) as the page names it: relative, with `/`."""
        return Path(path).resolve().relative_to(self.root).as_posix()

    def files(self, suffixes=OPENS, depth: int = 3, limit: int = 500) -> list[str]:
        """The files under the folder with one of `suffixes`, at most `depth` folders down, hidden ones (a leading
        dot: the autosave, .venv) and what symlinks lead outside left out; sorted, at most `limit`."""
        out = []
        for top, dirs, names in os.walk(self.root):
            rel = Path(top).relative_to(self.root)
            dirs[:] = sorted(d for d in dirs if not d.startswith(".") and len(rel.parts) < depth)
            for name in sorted(names):
                path = Path(top) / name
                if name.startswith(".") or path.suffix.lower() not in suffixes:
                    continue
                if path.resolve().is_relative_to(self.root):
                    out.append(path.relative_to(self.root).as_posix())
                if len(out) >= limit:
                    return sorted(out)
        return sorted(out)
