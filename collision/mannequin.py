"""The mannequin: a CC0 human body mesh (MakeHuman hm08, body group only) with its measurement targets.

The data ships as collision/data/mannequin.npz (derived by collision/data/derive_mannequin.py; provenance,
licence and key layout in collision/data/MANNEQUIN.md). This module only loads it; morphing with the
targets and measuring girths are not done here. Imports numpy and the standard library only.
"""
from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["DEFAULT_PATH", "JOINTS_PATH", "Mannequin", "load_mannequin", "load_joints"]

DEFAULT_PATH = Path(__file__).resolve().parent / "data" / "mannequin.npz"
#: the centres of MakeHuman's default skeleton joints on the mannequin (derived by collision/data/derive_rig.py)
JOINTS_PATH = Path(__file__).resolve().parent / "data" / "mannequin_joints.json"


@dataclass(frozen=True, eq=False)
class Mannequin:
    """A closed, outward-wound triangle mesh of an adult body standing on y = 0, plus blend-shape targets.

    Attributes:
        vertices: (V, 3) float64, metres, Y up, soles at y = 0, x to the body's left/right (symmetric
            about x = 0), +z to the front. V = 13380 for the shipped file.
        triangles: (T, 3) int64 indices into `vertices`, counter-clockwise seen from outside (normals
            point outward, the enclosed volume is positive). T = 26756 for the shipped file.
        targets: name -> (index, delta): index (K,) int64 sorted unique vertex indices, delta (K, 3)
            float64 metres, the displacement of those vertices at weight 1.0 (a morphed body is
            `vertices[index] += w * delta`). Names are the MakeHuman measurement targets, e.g.
            "measure-waist-circ-incr" / "measure-waist-circ-decr".
        source: provenance and licence text (CC0 1.0).
        path: the file it was loaded from.

    The arrays are read-only; copy them before modifying.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    targets: dict[str, tuple[np.ndarray, np.ndarray]]
    source: str = ""
    path: Path | None = None

    def target_names(self) -> list[str]:
        """The target names, sorted."""
        return sorted(self.targets)


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def load_mannequin(path: str | Path | None = None) -> Mannequin:
    """Load the mannequin .npz (default: collision/data/mannequin.npz beside this module).

    Raises FileNotFoundError if the file does not exist and ValueError (naming the path) if it is not a
    readable npz with the expected keys, shapes and index ranges.
    """
    path = DEFAULT_PATH if path is None else Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mannequin data not found: {path}")

    def bad(msg: str) -> ValueError:
        return ValueError(f"malformed mannequin file {path}: {msg}")

    try:
        z = np.load(path, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise ValueError(f"a single {type(z).__name__}, not an archive of arrays")
        with z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise bad(f"not a readable .npz ({e})") from e

    for key in ("vertices", "triangles", "target_names"):
        if key not in data:
            raise bad(f"missing key {key!r}")
    vertices, triangles, names = data["vertices"], data["triangles"], data["target_names"]
    if not np.issubdtype(vertices.dtype, np.floating):
        raise bad(f"'vertices' must be floating point, got {vertices.dtype}")
    vertices = vertices.astype(np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0 or not np.isfinite(vertices).all():
        raise bad(f"'vertices' must be a finite (V, 3) array, got shape {vertices.shape}")
    if triangles.ndim != 2 or triangles.shape[1] != 3 or not np.issubdtype(triangles.dtype, np.integer):
        raise bad(f"'triangles' must be an integer (T, 3) array, got {triangles.dtype} {triangles.shape}")
    triangles = triangles.astype(np.int64)
    if len(triangles) and (triangles.min() < 0 or triangles.max() >= len(vertices)):
        raise bad("'triangles' index out of range")

    targets: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    if names.ndim != 1 or names.dtype.kind != "U":
        raise bad("'target_names' must be a 1-D array of strings")
    for name in names.tolist():
        ikey, dkey = f"target/{name}/index", f"target/{name}/delta"
        if ikey not in data or dkey not in data:
            raise bad(f"target {name!r} lacks {ikey!r} or {dkey!r}")
        index, delta = data[ikey], data[dkey]
        if index.ndim != 1 or not np.issubdtype(index.dtype, np.integer):
            raise bad(f"{ikey!r} must be a 1-D integer array")
        if not np.issubdtype(delta.dtype, np.floating):
            raise bad(f"{dkey!r} must be floating point, got {delta.dtype}")
        delta = delta.astype(np.float64)
        if delta.shape != (len(index), 3) or not np.isfinite(delta).all():
            raise bad(f"{dkey!r} must be a finite ({len(index)}, 3) array, got shape {delta.shape}")
        index = index.astype(np.int64)
        if len(index) and (index.min() < 0 or index.max() >= len(vertices)):
            raise bad(f"{ikey!r} index out of range")
        targets[name] = (_read_only(index), _read_only(delta))

    source = str(data["source"]) if "source" in data else ""
    return Mannequin(_read_only(vertices), _read_only(triangles), targets, source, path)


def load_joints(path: str | Path | None = None) -> dict[str, np.ndarray]:
    """name -> (3,) float64 [m]: the joint centres of MakeHuman's default skeleton on the shipped mannequin
    ("pelvis", "spine-1" (chest) ... "spine-4" (lowest), "neck", "head", "l-shoulder", "l-elbow", "l-hand", "r-...";
    l is the body's left, +x). Raises ValueError naming the file if it is not the expected JSON."""
    path = JOINTS_PATH if path is None else Path(path)
    try:
        joints = json.loads(path.read_text(encoding="utf-8"))["joints"]
        return {str(k): np.asarray(v, dtype=np.float64).reshape(3) for k, v in joints.items()}
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ValueError(f"malformed mannequin joints file {path}: {e}") from e
