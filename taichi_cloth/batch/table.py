"""The results table of a batch: one row per job, as Parquet (pyarrow) and CSV beside it.

Columns, in this order (COLUMNS), then one `area_error_<piece>` per piece name met in the batch:
  key, label, garment, body, material, the body's girths [cm] (`chest_cm`...; empty for the mannequin),
  status, reason, attempts, wall_s (the job's run in its worker), process_wall_s (the worker's start and end too),
  init_s (Taichi's start), first_frame_s (frame 1: kernels compiled or loaded), step_s (frames 2..), frames, steps,
  sim_time_s, rest_time_s (at rest since, simulated), particles, max_strain, mean_strain, area_error_max,
  seam_gap_max_mm, inside (particles inside the body), gap_chest_mm, gap_waist_mm, gap_hips_mm (median distance of
  the cloth to the body at the girth: taichi_cloth.batch.figures), max_speed_mm_s, outputs (file names in the job's
  folder), worker (host:pid), started.
Both files are written to a temporary name and renamed: a reader never sees half a table.
"""
from __future__ import annotations

import os
from pathlib import Path

from ..scenefile import BODY_GIRTHS

PARQUET, CSV = "results.parquet", "results.csv"
_STR, _INT, _FLOAT = "string", "int64", "float64"
COLUMNS = ([("key", _STR), ("label", _STR), ("garment", _STR), ("body", _STR), ("material", _STR)]
           + [(f"{g}_cm", _FLOAT) for g in BODY_GIRTHS]
           + [("status", _STR), ("reason", _STR), ("attempts", _INT), ("wall_s", _FLOAT), ("process_wall_s", _FLOAT),
              ("init_s", _FLOAT), ("first_frame_s", _FLOAT), ("step_s", _FLOAT), ("frames", _INT), ("steps", _INT),
              ("sim_time_s", _FLOAT), ("rest_time_s", _FLOAT), ("particles", _INT), ("max_strain", _FLOAT),
              ("mean_strain", _FLOAT), ("area_error_max", _FLOAT), ("seam_gap_max_mm", _FLOAT), ("inside", _INT),
              ("gap_chest_mm", _FLOAT), ("gap_waist_mm", _FLOAT), ("gap_hips_mm", _FLOAT),
              ("max_speed_mm_s", _FLOAT), ("outputs", _STR), ("worker", _STR), ("started", _STR)])


def columns(rows: list[dict]) -> list[tuple[str, str]]:
    """(name, type) of the table's columns: COLUMNS, less the girths no row has, then the per-piece area errors."""
    present = {k for row in rows for k in row}
    fixed = [(n, t) for n, t in COLUMNS if not (n.endswith("_cm") and n not in present)]
    pieces = sorted(k for k in present if k.startswith("area_error_") and k != "area_error_max")
    return fixed + [(p, _FLOAT) for p in pieces]


def write_table(rows: list[dict], folder: str | Path) -> tuple[Path, Path]:
    """Write the rows (in job order) to folder/results.parquet and folder/results.csv. Returns both paths."""
    import pyarrow as pa  # 0.3 s to import: only when a table is written
    import pyarrow.csv
    import pyarrow.parquet

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cols = columns(rows)
    table = pa.table({name: pa.array([row.get(name) for row in rows], type=kind) for name, kind in cols})
    out = []
    for name, write in ((PARQUET, pyarrow.parquet.write_table), (CSV, pyarrow.csv.write_csv)):
        path = folder / name
        tmp = folder / f".{name}.{os.getpid()}"
        write(table, tmp)
        os.replace(tmp, path)
        out.append(path)
    return out[0], out[1]


def read_table(path: str | Path) -> list[dict]:
    """The rows of a results.parquet, as dicts (tests, and a user's script)."""
    import pyarrow.parquet

    return pyarrow.parquet.read_table(path).to_pylist()
