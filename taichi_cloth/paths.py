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
