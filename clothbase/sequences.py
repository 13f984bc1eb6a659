"""A deforming body as a mesh sequence: per-frame vertex positions of one triangle mesh (fixed topology), at a frame
rate, interpolated linearly between frames and held at the first frame before it starts and at the last after it
ends. This is what body-model pipelines write (an SMPL-style fit per motion-capture frame, a retargeted clip).

Files (`load_mesh_sequence`):
  - a `.npz` with `vertices` (F, V, 3) [file units], `triangles` (T, 3) and optionally `fps` (a scalar);
  - a folder of OBJ or PLY frames, one file per frame, in the order of the number in their names (`frame_2.obj`
    before `frame_10.obj`); every frame must have the same vertex count and the same triangles.
Vertices that coincide in every frame (the copies an OBJ writes along texture seams) are merged.
Imports numpy (and trimesh to read a folder of frames).
"""
from __future__ import annotations

import re
import zipfile
from pathlib import Path

import numpy as np

from .errors import MeshError
from .meshes import read_mesh_arrays, validate_triangle_mesh

__all__ = ["MeshSequence", "load_mesh_sequence", "save_mesh_sequence", "FRAME_SUFFIXES"]

FRAME_SUFFIXES = (".obj", ".ply")


class MeshSequence:
    """frames (F, V, 3) float64 [m], triangles (T, 3) int64 (outward winding), fps [frames/s]; source names it in
    messages. Frame k is the body at time k / fps [s] after the sequence starts."""

    def __init__(self, frames, triangles, fps: float, source: str = "mesh sequence"):
        frames = np.asarray(frames, dtype=np.float64)
        triangles = np.asarray(triangles, dtype=np.int64)
        if frames.ndim != 3 or frames.shape[2] != 3 or len(frames) == 0:
            raise MeshError(f"{source}: the frames must be an (F, V, 3) array of vertex positions, got shape "
                            f"{frames.shape}")
        if not (isinstance(fps, (int, float, np.number)) and np.isfinite(fps) and fps > 0):
            raise MeshError(f"{source}: the frame rate must be a number > 0 frames/s, got {fps!r}")
        bad = np.flatnonzero(~np.isfinite(frames).all(axis=(1, 2)))
        if len(bad):
            raise MeshError(f"{source}: frame {bad[0]} has NaN or infinite coordinates")
        validate_triangle_mesh(frames[0], triangles, f"{source} (frame 0)")
        self.frames, self.triangles, self.fps, self.source = frames, triangles, float(fps), source

    @property
    def n_frames(self) -> int:
        return len(self.frames)

    @property
    def duration(self) -> float:
        """[s] from the first frame to the last."""
        return (self.n_frames - 1) / self.fps

    def position(self, s: float) -> tuple[int, float]:
        """(frame k, weight w) of time s [s] into the sequence: the body is (1 - w) frames[k] + w frames[k + 1],
        with k + 1 clipped to the last frame; held outside [0, duration]."""
        f = min(max(float(s) * self.fps, 0.0), float(self.n_frames - 1))
        k = min(int(np.floor(f)), max(self.n_frames - 2, 0))
        return k, f - k

    def at(self, s: float) -> np.ndarray:
        """The vertices (V, 3) [m] at time s [s] into the sequence."""
        k, w = self.position(s)
        a = self.frames[k]
        return a if w == 0.0 else (1.0 - w) * a + w * self.frames[min(k + 1, self.n_frames - 1)]

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo (3,), hi (3,)) [m]: the box every frame lies in."""
        return self.frames.min(axis=(0, 1)), self.frames.max(axis=(0, 1))

    def max_speed(self) -> float:
        """The fastest a vertex moves between two frames [m/s]."""
        if self.n_frames < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.frames, axis=0), axis=2).max() * self.fps)


def _frame_number(path: Path) -> tuple:
    numbers = re.findall(r"\d+", path.stem)
    return (int(numbers[-1]) if numbers else -1, path.name)


def _merge_coincident(frames: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge the vertices that coincide in every frame (an OBJ's copies along texture seams)."""
    track = frames.transpose(1, 0, 2).reshape(frames.shape[1], -1)
    _, first, inverse = np.unique(track, axis=0, return_index=True, return_inverse=True)
    if len(first) == frames.shape[1]:
        return frames, triangles
    keep = np.sort(first)
    remap = np.empty(len(first), np.int64)
    remap[np.argsort(first)] = np.arange(len(first))  # unique rows in first-seen order
    return frames[:, keep], remap[inverse.reshape(-1)][triangles]


def _read_frames(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    files = sorted((p for p in folder.iterdir() if p.suffix.lower() in FRAME_SUFFIXES), key=_frame_number)
    if not files:
        raise MeshError(f"{folder}: no OBJ or PLY frames in this folder")
    frames, triangles = [], None
    for p in files:
        v, t = read_mesh_arrays(p)
        if triangles is None:
            triangles = t
        elif len(v) != len(frames[0]) or not np.array_equal(t, triangles):
            raise MeshError(f"{p}: not the topology of {files[0].name} ({len(v)} vertices and {len(t)} triangles "
                            f"against {len(frames[0])} and {len(triangles)}): a sequence keeps one mesh")
        frames.append(v)
    return np.stack(frames), triangles


def load_mesh_sequence(path, fps: float | None = None, scale: float = 1.0, translate=(0.0, 0.0, 0.0)) -> MeshSequence:
    """A MeshSequence from a `.npz` or a folder of OBJ/PLY frames (module docstring). fps [frames/s]: required for
    a folder; for an npz it overrides the file's. scale multiplies the file's coordinates into metres, then
    translate [m] is added. Raises MeshError naming the file and what is wrong."""
    path = Path(path)
    if path.is_dir():
        if fps is None:
            raise MeshError(f"{path}: a folder of frames needs its frame rate (fps)")
        frames, triangles = _read_frames(path)
    elif path.suffix.lower() == ".npz":
        if not path.is_file():
            raise MeshError(f"{path}: no such mesh sequence file")
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
            raise MeshError(f"{path}: not a readable .npz ({e})") from None
        for key in ("vertices", "triangles"):
            if key not in data:
                raise MeshError(f"{path}: missing array {key!r} (a sequence holds vertices (F, V, 3) and "
                                "triangles (T, 3))")
        frames, triangles = data["vertices"], data["triangles"]
        if not np.issubdtype(triangles.dtype, np.integer) or triangles.ndim != 2 or triangles.shape[1:] != (3,):
            raise MeshError(f"{path}: 'triangles' must be an integer (T, 3) array, got {triangles.dtype} "
                            f"{triangles.shape}")
        if fps is None:
            if "fps" not in data:
                raise MeshError(f"{path}: no frame rate: store 'fps' in the file or give fps")
            fps = float(data["fps"])
    else:
        if not path.exists():
            raise MeshError(f"{path}: no such mesh sequence (a .npz file or a folder of OBJ/PLY frames)")
        raise MeshError(f"{path}: a mesh sequence is a .npz file or a folder of OBJ/PLY frames")
    frames = np.asarray(frames, dtype=np.float64)
    if frames.ndim != 3 or frames.shape[2:] != (3,):
        raise MeshError(f"{path}: 'vertices' must be an (F, V, 3) array, got shape {frames.shape}")
    frames, triangles = _merge_coincident(frames, np.asarray(triangles, np.int64))
    frames = frames * float(scale) + np.asarray(translate, dtype=np.float64)
    return MeshSequence(frames, triangles, fps, str(path))


def save_mesh_sequence(path, sequence: MeshSequence) -> Path:
    """Write `sequence` as the `.npz` load_mesh_sequence reads (vertices in float32 [m], triangles, fps)."""
    path = Path(path)
    np.savez_compressed(path, vertices=sequence.frames.astype(np.float32),
                        triangles=sequence.triangles.astype(np.int32), fps=np.float64(sequence.fps))
    return path
