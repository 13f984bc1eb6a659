"""Output file names: a run never overwrites an earlier run's files."""
from __future__ import annotations

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
