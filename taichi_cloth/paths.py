"""Output file names: a run never overwrites an earlier run's files; and the check that an output folder can be one."""
from __future__ import annotations

import errno
import os
from pathlib import Path


def free_stem(folder: str | Path, name: str, suffixes) -> str:
    """`name`, or the first `name-2`, `name-3`... for which no file `folder/<stem><suffix>` exists yet, for every
    suffix in `suffixes` (e.g. [".rrd", ".obj", ".ply"]: the files of one run share their stem)."""
    stem, k = name, 2
    while any((Path(folder) / f"{stem}{s}").exists() for s in suffixes):
        stem, k = f"{name}-{k}", k + 1
    return stem


def free_path(path: str | Path) -> Path:
    """`path` if no file is there yet, else the first free `stem-2.suffix`, `stem-3.suffix`... beside it."""
    path = Path(path)
    return path.with_name(free_stem(path.parent, path.stem, [path.suffix]) + path.suffix)


def check_output_folder(path: str | Path) -> Path:
    """`path` as a folder to write into, checked before any work is done and without creating anything: an OSError
    naming `path` (its strerror says why, in words that read after the path) when it is a file, lies below a file,
    or it (or, when it does not exist yet, the nearest folder above it that does) cannot be written to."""
    p = Path(path)
    q = next((q for q in (p, *p.parents) if q.exists()), Path.cwd())
    if not q.is_dir():
        where = "is a file" if q == p else f"lies below the file {q}"
        raise NotADirectoryError(errno.ENOTDIR, f"{where}, not a folder", str(p))
    if not os.access(q, os.W_OK | os.X_OK):
        where = "is a read-only folder" if q == p else f"lies in the read-only folder {q}"
        raise PermissionError(errno.EACCES, f"{where} (permission denied)", str(p))
    return p


#: the reasons of the file-system errors whose system wording misleads here (mkdir's "File exists" for a file in
#: the way), by errno; the others keep the system's own (e.g. "Permission denied", "No space left on device")
REASONS = {errno.EEXIST: "is a file, not a folder", errno.ENOTDIR: "a part of the path is a file, not a folder",
           errno.EISDIR: "is a folder, not a file"}


def os_error_text(exc: OSError, where=None) -> str:
    """`<path>: <reason>` of a file-system error: the path is the exception's (both, for a rename or copy), else
    `where`; the reason in words (REASONS, or the system's text), e.g. `out/t.rrd: no space left on device`."""
    path = exc.filename if exc.filename is not None else where
    if exc.filename2 is not None:
        path = f"{path} -> {exc.filename2}"
    reason = exc.strerror or str(exc) or type(exc).__name__
    if exc.errno in REASONS and reason == os.strerror(exc.errno):
        reason = REASONS[exc.errno]
    reason = reason[:1].lower() + reason[1:]
    return f"{path}: {reason}" if path is not None else reason
