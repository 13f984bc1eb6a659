"""Blend shapes: a base body and named channels that grow or shrink one part of it (Zhang et al. 2017, section 1).

A channel has a larger and a smaller limit shape of the base (same vertices, same triangles), stored sparsely
as the vertices that move and how far:

    Shape.index (K,) int64 sorted unique vertex ids, Shape.delta (K,3) float64 [m] = limit - base on them,
    Shape.position (K,3) float64 [m] = the limit's own coordinates of those vertices.

A weight w in [-1, 1] per channel picks the morph (Zhang et al. 2017 eq. 1, m = sum_k w_k b_k with every limit's weight
in [0, 1]): w > 0 moves toward the larger limit by w, w < 0 toward the smaller one by |w|:

    v = base.copy();  v[index] += |w| * delta   (of the larger shape if w > 0, the smaller if w < 0)

Channels add up. A vertex whose total displacement is exactly one limit's delta at |w| = 1 takes that limit's
stored position, so a limit mesh is reproduced bit for bit (in floating point base + (limit - base) may differ
from limit in the last bit).

Overlaps. Zhang et al. 2017 keep channels disjoint (no vertex moved by two channels), so one channel's weight changes
one girth only. The MakeHuman measurement targets shipped with the mannequin do overlap at their borders (on
the shipped body: chest/underbust 917 vertices, underbust/waist 671, chest/waist 495, hips/thigh 312,
waist/hips 260, ...; `BlendShapes.overlaps()`): there the displacements add, and growing the waist moves the
lower underbust and the top of the hips a little. The fit (taichi_cloth.body.fit) therefore solves all asked
girths together (Gauss-Seidel sweeps) instead of one channel at a time.

Sources: `BlendShapes.from_mannequin()` (the shipped CC0 MakeHuman body and its measure-*-circ-incr/decr
targets) and `BlendShapes.from_meshes(base, limits)` (user meshes of one topology: files or arrays).
"""
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from collision.mannequin import load_mannequin

from ..errors import BodyError, MeshError

__all__ = ["MANNEQUIN_CHANNELS", "BlendShapes", "Channel", "Shape", "read_mesh"]

#: channel name -> MakeHuman target stem on the shipped mannequin (measure-<stem>-circ-incr / -decr)
MANNEQUIN_CHANNELS = {"chest": "bust", "underbust": "underbust", "waist": "waist", "hips": "hips",
                      "neck": "neck", "upper_arm": "upperarm", "thigh": "thigh"}


@dataclass(frozen=True, eq=False)
class Shape:
    """One limit of a channel, sparse: index (K,) int64 sorted unique vertex ids; delta (K,3) float64 [m], the
    displacement at weight 1; position (K,3) float64 [m], the limit's coordinates of those vertices."""

    index: np.ndarray
    delta: np.ndarray
    position: np.ndarray

    def __len__(self) -> int:
        return len(self.index)


@dataclass(frozen=True, eq=False)
class Channel:
    """A named channel: its larger limit (weights > 0) and smaller limit (weights < 0); either may be None."""

    name: str
    larger: Shape | None
    smaller: Shape | None

    @property
    def bounds(self) -> tuple:
        """(lo, hi): the weights this channel accepts, [-1, 1] narrowed to 0 on a side without a limit."""
        return (-1.0 if self.smaller is not None else 0.0, 1.0 if self.larger is not None else 0.0)

    def vertices(self) -> np.ndarray:
        """(K,) int64: the vertices either limit moves."""
        ids = [s.index for s in (self.larger, self.smaller) if s is not None]
        return np.unique(np.concatenate(ids)) if ids else np.zeros(0, np.int64)


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _shape(base: np.ndarray, index, delta, position=None) -> Shape:
    index = np.asarray(index, dtype=np.int64)
    delta = np.asarray(delta, dtype=np.float64)
    order = np.argsort(index, kind="stable")
    index, delta = index[order], delta[order]
    position = base[index] + delta if position is None else np.asarray(position, dtype=np.float64)[order]
    return Shape(_read_only(index), _read_only(delta), _read_only(position))


class BlendShapes:
    """A base body and its channels (module docstring).

    base: (V,3) float64 [m]; triangles: (T,3) int64; channels: name -> Channel (insertion order kept);
    source: where it came from (for messages).
    """

    def __init__(self, base, triangles, channels, source: str = "blend shapes"):
        self.base = _read_only(np.array(base, dtype=np.float64))
        self.triangles = _read_only(np.array(triangles, dtype=np.int64))
        self.channels = dict(channels)
        self.source = source

    def __repr__(self) -> str:
        parts = [f"{name} (+{len(c.larger) if c.larger else 0}/-{len(c.smaller) if c.smaller else 0})"
                 for name, c in self.channels.items()]
        return (f"BlendShapes({self.source}: {len(self.base)} vertices, {len(self.triangles)} triangles; "
                f"channels {', '.join(parts)})")

    @property
    def names(self) -> list:
        return list(self.channels)

    # ------------------------------------------------------------------------------------ construction
    @classmethod
    def from_mannequin(cls, mannequin=None) -> "BlendShapes":
        """The shipped CC0 mannequin (collision.mannequin.load_mannequin(), or the Mannequin given) with channels
        chest, underbust, waist, hips, neck, upper_arm, thigh from its measure-*-circ-incr/decr targets."""
        if mannequin is None:
            mannequin = load_mannequin()
        base = np.asarray(mannequin.vertices, dtype=np.float64)
        channels = {}
        for name, stem in MANNEQUIN_CHANNELS.items():
            shapes = []
            for kind in ("incr", "decr"):
                key = f"measure-{stem}-circ-{kind}"
                if key not in mannequin.targets:
                    raise BodyError(f"mannequin {mannequin.path}: target {key!r} missing (channel {name!r})")
                shapes.append(_shape(base, *mannequin.targets[key]))
            channels[name] = Channel(name, *shapes)
        return cls(base, mannequin.triangles, channels, source=f"mannequin {Path(mannequin.path).name}"
                   if mannequin.path is not None else "mannequin")

    @classmethod
    def from_meshes(cls, base, limits: dict) -> "BlendShapes":
        """Blend shapes from user meshes of one topology.

        base: a mesh file (OBJ/PLY/OFF/STL... read by trimesh without merging or reordering vertices; other
        formats by meshio) or a (vertices (V,3), triangles (T,3)) pair [m]. limits: {channel: (larger, smaller)},
        each a file, a (vertices, triangles) pair or a bare (V,3) vertex array, either may be None. Each limit
        must have the base's vertex count and triangles (in the same order); the deltas are limit - base in
        float64, rows that do not move dropped. Raises MeshError for an unreadable, empty or non-finite mesh and
        BodyError for another topology; the message names the file (or channel) and the counts.
        """
        bv, bt, bname = read_mesh(base, "base mesh")
        if not isinstance(limits, dict) or not limits:
            raise BodyError("from_meshes: limits must be a non-empty dict {channel: (larger, smaller)}")
        channels = {}
        for name, pair in limits.items():
            if not isinstance(name, str) or not name:
                raise BodyError(f"from_meshes: channel names must be non-empty strings, got {name!r}")
            if not isinstance(pair, (tuple, list)) or len(pair) != 2:
                raise BodyError(f"from_meshes: channel {name!r} needs a pair (larger, smaller), got {pair!r}")
            if pair[0] is None and pair[1] is None:
                raise BodyError(f"from_meshes: channel {name!r} has neither a larger nor a smaller limit")
            shapes = []
            for side, limit in zip(("larger", "smaller"), pair):
                if limit is None:
                    shapes.append(None)
                    continue
                what = f"channel {name!r} {side} limit"
                if isinstance(limit, np.ndarray):   # bare vertices: the base's triangles
                    lv, lt, lname = _check_vertices(limit, what), bt, what
                else:
                    lv, lt, lname = read_mesh(limit, what)
                if len(lv) != len(bv):
                    raise BodyError(f"{lname}: {len(lv)} vertices, but the base mesh {bname} has {len(bv)}; "
                                    "a limit shape must have the base's vertices and triangles")
                if lt.shape != bt.shape or not np.array_equal(lt, bt):
                    detail = (f"{len(lt)} triangles, the base has {len(bt)}" if lt.shape != bt.shape else
                              f"{int(np.any(lt != bt, axis=1).sum())} of {len(bt)} triangles differ from the base's")
                    raise BodyError(f"{lname}: different topology from the base mesh {bname}: {detail}; a limit "
                                    "shape must have the base's vertices and triangles in the same order")
                delta = lv - bv
                moved = np.flatnonzero(np.any(delta != 0, axis=1))
                shapes.append(_shape(bv, moved, delta[moved], lv[moved]))
            channels[name] = Channel(name, *shapes)
        return cls(bv, bt, channels, source=bname)

    # ---------------------------------------------------------------------------------------- queries
    def check_weights(self, weights) -> dict:
        """{channel: float weight}, validated: BodyError for an unknown channel (listing the valid ones) or a
        weight outside the channel's range ([-1, 1], or [0, 1] / [-1, 0] for a channel with one limit)."""
        if weights is None:
            return {}
        if not isinstance(weights, dict):
            raise BodyError(f"weights must be a dict {{channel: weight}}, got {type(weights).__name__}")
        out = {}
        for name, w in weights.items():
            if name not in self.channels:
                raise BodyError(f"unknown blend-shape channel {name!r}; valid channels: {', '.join(self.channels)}")
            try:
                x = float(w)
            except (TypeError, ValueError):
                raise BodyError(f"channel {name!r}: weight must be a number in [-1, 1], got {w!r}") from None
            lo, hi = self.channels[name].bounds
            if not (lo <= x <= hi):   # NaN fails too
                why = "" if (lo, hi) == (-1.0, 1.0) else (" (it has no larger limit)" if hi == 0
                                                           else " (it has no smaller limit)")
                raise BodyError(f"channel {name!r}: weight {x:g} is outside [{lo:g}, {hi:g}]{why}")
            out[name] = x
        return out

    def displacement(self, weights) -> np.ndarray:
        """(V,3) float64 [m]: the summed displacement of the channels at these weights (validated)."""
        w = self.check_weights(weights)
        d = np.zeros_like(self.base)
        for name, x in w.items():
            shape = self._shape(name, x)
            if shape is not None:
                d[shape.index] += abs(x) * shape.delta   # indices are unique within a shape
        return d

    def morph(self, weights=None) -> np.ndarray:
        """(V,3) float64 [m]: the base moved by the channels at these weights ({channel: w in [-1, 1]})."""
        w = self.check_weights(weights)
        d = self.displacement(w)
        v = self.base + d
        for name, x in w.items():
            shape = self._shape(name, x)
            if abs(x) == 1.0 and shape is not None:
                # where this limit alone moved the vertex, take the limit's own coordinates (bit-exact limits)
                alone = np.all(d[shape.index] == shape.delta, axis=1)
                v[shape.index[alone]] = shape.position[alone]
        return v

    def _shape(self, name: str, w: float):
        c = self.channels[name]
        return c.larger if w > 0 else c.smaller if w < 0 else None

    def add_channel(self, vertices: np.ndarray, name: str, w: float) -> np.ndarray:
        """vertices (V,3) moved in place by one channel at weight w (checked); returns them. The fit uses it to
        vary one weight on top of a fixed morph of the others without recomputing them."""
        x = self.check_weights({name: w})[name]
        shape = self._shape(name, x)
        if shape is not None:
            vertices[shape.index] += abs(x) * shape.delta
        return vertices

    def overlaps(self) -> dict:
        """{(a, b): n} for channel pairs (in channel order) whose vertex sets (either limit) share n > 0
        vertices. The paper assumes none; where there are some, displacements add (module docstring)."""
        names = list(self.channels)
        sets = {n: self.channels[n].vertices() for n in names}
        out = {}
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                n = len(np.intersect1d(sets[a], sets[b], assume_unique=True))
                if n:
                    out[(a, b)] = n
        return out


# ------------------------------------------------------------------------------------------------ meshes

def _check_vertices(v, what: str) -> np.ndarray:
    try:
        v = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        raise MeshError(f"{what}: vertices must be numbers, shape (V, 3)") from None
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise MeshError(f"{what}: vertices must have shape (V, 3) with V > 0, got {v.shape}")
    bad = int(np.count_nonzero(~np.all(np.isfinite(v), axis=1)))
    if bad:
        raise MeshError(f"{what}: {bad} of {len(v)} vertices have NaN or infinite coordinates")
    return v


def read_mesh(source, what: str = "mesh"):
    """(vertices (V,3) float64, triangles (T,3) int64, name) from a mesh file or a (vertices, triangles) pair.

    Files keep their vertex order: trimesh reads OBJ/PLY/OFF/STL/GLB with process=False (no merging, no
    reordering; STL stores no shared vertices, so every triangle has its own three), meshio anything else.
    Raises MeshError (naming the file or `what`) for a missing, unreadable, empty or non-finite mesh or one
    that is not all triangles."""
    if isinstance(source, (str, Path)):
        path = Path(source)
        name = str(path)
        if not path.is_file():
            raise MeshError(f"{what} {name}: no such file")
        if path.suffix.lower() in (".obj", ".ply", ".off", ".stl", ".glb", ".gltf"):
            import trimesh  # 0.7 s to import: only when a mesh file is read
            try:
                mesh = trimesh.load(path, force="mesh", process=False)
            except Exception as exc:  # trimesh raises many types for unreadable files
                raise MeshError(f"{what} {name}: cannot read the mesh ({exc})") from None
            v, t = np.asarray(mesh.vertices), np.asarray(getattr(mesh, "faces", np.zeros((0, 3))))
        else:
            import meshio  # 0.2 s to import: only when a mesh file is read
            try:
                m = meshio.read(path)
            except Exception as exc:  # meshio raises many types for unreadable files
                raise MeshError(f"{what} {name}: cannot read the mesh ({exc})") from None
            tris = [c.data for c in m.cells if c.type == "triangle"]
            if any(c.type != "triangle" for c in m.cells):
                raise MeshError(f"{what} {name}: only triangle cells are supported, got "
                                f"{', '.join(sorted({c.type for c in m.cells}))}")
            v, t = np.asarray(m.points), (np.concatenate(tris) if tris else np.zeros((0, 3)))
        label = f"{what} {name}"
    else:
        try:
            v, t = source
        except (TypeError, ValueError):
            raise MeshError(f"{what}: expected a mesh file or a (vertices, triangles) pair") from None
        name, label = what, what
    v = _check_vertices(v, label)
    try:
        t = np.asarray(t)
    except (TypeError, ValueError):
        raise MeshError(f"{label}: triangles must be integers, shape (T, 3)") from None
    if t.ndim != 2 or t.shape[1] != 3 or len(t) == 0:
        raise MeshError(f"{label}: triangles must have shape (T, 3) with T > 0, got {t.shape}")
    if not np.issubdtype(t.dtype, np.integer):
        if not np.all(t == np.round(t)):
            raise MeshError(f"{label}: triangle indices must be integers")
    t = t.astype(np.int64)
    if t.min() < 0 or t.max() >= len(v):
        raise MeshError(f"{label}: triangle indices out of range 0..{len(v) - 1}")
    return v, t, name
