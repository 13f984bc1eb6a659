"""Linear-blend skinning of the mannequin: a skeleton on MakeHuman's default joints, weights by heat diffusion, poses
as joint rotations.

The skeleton's joints are the centres MakeHuman gives its default rig (collision.mannequin.load_joints). Each bone
turns about its joint and carries its children; its weight over the skin comes from heat diffusion (Baran and
Popovic 2007, "Automatic rigging and animation of 3D characters", section 4): with d(v) the distance from vertex v
to the nearest bone it sees (the bone lies behind the surface there: (c - v) . n(v) < 0, c its closest point on the
bone) and p_b(v) = 1 where that bone is b,

    (L / h^2 + H) w_b = H p_b,    H = diag(1 / d(v)^2),

L the mesh's graph Laplacian and h its mean edge [m]; each vertex's weights are then clipped to [0, 1], those below
WEIGHT_FLOOR dropped, and normalised. A posed vertex is sum_b w_b(v) G_b v, G_b the bone's rest-to-posed rigid
transform (its rotation about its joint, after its parent's). All zero rotations give the rest body exactly.
Numpy, and scipy's sparse LU (lazily).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clothbase.meshes import vertex_normals
from collision.mannequin import load_joints, load_mannequin

__all__ = ["Bone", "MANNEQUIN_BONES", "Skeleton", "SkinnedBody", "heat_weights", "skin"]

#: c of the heat H = c / d^2: the weights blend over about d / sqrt(c) (Baran and Popovic take 1; a larger one keeps
#: a bone's weight nearer to it: the belly follows the spine, not the legs)
HEAT = 4.0
#: weights below this are dropped before the normalisation (a vertex follows a few bones, not all)
WEIGHT_FLOOR = 1e-3


@dataclass(frozen=True)
class Bone:
    """A bone: its name, the joint it turns about, its parent bone (None: the root, which never moves), and the joint
    pairs whose segments are its body (what the weights measure the distance to)."""

    name: str
    joint: str
    parent: str | None
    segments: tuple[tuple[str, str], ...]


def _side(s: str) -> tuple[Bone, ...]:
    return (Bone(f"{s}-clavicle", f"{s}-clavicle", "chest", ((f"{s}-clavicle", f"{s}-shoulder"),)),
            Bone(f"{s}-upperarm", f"{s}-shoulder", f"{s}-clavicle", ((f"{s}-shoulder", f"{s}-elbow"),)),
            Bone(f"{s}-forearm", f"{s}-elbow", f"{s}-upperarm", ((f"{s}-elbow", f"{s}-hand"),)),
            Bone(f"{s}-hand", f"{s}-hand", f"{s}-forearm", ((f"{s}-hand", f"{s}-finger-3-4"),)))


#: the mannequin's bones, parents first: the legs stay with the hips (the root); the spine turns in four joints
MANNEQUIN_BONES = (
    Bone("hips", "pelvis", None, (("pelvis", "spine-4"), ("pelvis", "l-upper-leg"), ("pelvis", "r-upper-leg"),
                                  ("l-upper-leg", "l-knee"), ("l-knee", "l-ankle"), ("l-ankle", "l-foot-2"),
                                  ("r-upper-leg", "r-knee"), ("r-knee", "r-ankle"), ("r-ankle", "r-foot-2"))),
    Bone("spine-4", "spine-4", "hips", (("spine-4", "spine-3"),)),
    Bone("spine-3", "spine-3", "spine-4", (("spine-3", "spine-2"),)),
    Bone("spine-2", "spine-2", "spine-3", (("spine-2", "spine-1"),)),
    Bone("chest", "spine-1", "spine-2", (("spine-1", "neck"),)),
    Bone("head", "neck", "chest", (("neck", "head"), ("head", "head-2"))),
    *_side("l"), *_side("r"))


class Skeleton:
    """Bones (parents before children) on joint centres (name -> (3,) [m]). Raises ValueError naming a joint or a
    parent that is missing."""

    def __init__(self, joints: dict, bones=MANNEQUIN_BONES):
        self.joints = {k: np.asarray(v, dtype=np.float64).reshape(3) for k, v in joints.items()}
        self.bones = tuple(bones)
        self.names = [b.name for b in self.bones]
        seen = set()
        for b in self.bones:
            for j in (b.joint, *(x for seg in b.segments for x in seg)):
                if j not in self.joints:
                    raise ValueError(f"bone {b.name!r}: no joint {j!r} in the skeleton's joints")
            if b.parent is not None and b.parent not in seen:
                raise ValueError(f"bone {b.name!r}: its parent {b.parent!r} must come before it")
            seen.add(b.name)

    def transforms(self, rotations: dict | None = None) -> np.ndarray:
        """(B, 3, 4): each bone's rest-to-posed transform [R | t] (x -> R x + t) for rotations: bone name -> (3, 3)
        rotation about its joint (relative to its parent; absent: none). Raises ValueError on an unknown name."""
        rotations = rotations or {}
        unknown = sorted(set(rotations) - set(self.names))
        if unknown:
            raise ValueError(f"no bone {unknown[0]!r} (bones: {', '.join(self.names)})")
        out, index = np.zeros((len(self.bones), 3, 4)), {}
        for k, b in enumerate(self.bones):
            R = np.asarray(rotations.get(b.name, np.eye(3)), dtype=np.float64)
            c = self.joints[b.joint]
            local = np.hstack([R, (c - R @ c)[:, None]])  # a turn about the joint's rest position
            if b.parent is None:
                out[k] = local
            else:
                P = out[index[b.parent]]
                out[k] = np.hstack([P[:, :3] @ R, (P[:, :3] @ local[:, 3] + P[:, 3])[:, None]])
            index[b.name] = k
        return out


def skin(vertices: np.ndarray, weights: np.ndarray, transforms: np.ndarray) -> np.ndarray:
    """Linear-blend skinning: vertices (V, 3) [m], weights (V, B) (rows summing to 1), transforms (B, 3, 4) ->
    posed vertices (V, 3) [m]."""
    blended = np.einsum("vb,bij->vij", weights, transforms)  # each vertex's blended [R | t]
    return np.einsum("vij,vj->vi", blended[:, :, :3], vertices) + blended[:, :, 3]


def _closest_on_segments(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, S, 3): the closest point of each segment a[s] -> b[s] to each point."""
    ab = b - a
    t = np.einsum("nsk,sk->ns", points[:, None, :] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-30)
    return a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]


def heat_weights(vertices: np.ndarray, triangles: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """(V, B) skinning weights of a closed outward-wound mesh (vertices (V, 3) [m], triangles (T, 3)) by heat
    diffusion from the skeleton's bones (module docstring). Rows sum to 1."""
    from scipy.sparse import coo_matrix, diags
    from scipy.sparse.linalg import splu

    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    V, B = len(v), len(skeleton.bones)
    owner = np.array([k for k, b in enumerate(skeleton.bones) for _ in b.segments])
    a = np.array([skeleton.joints[s[0]] for b in skeleton.bones for s in b.segments])
    b = np.array([skeleton.joints[s[1]] for bone in skeleton.bones for s in bone.segments])
    closest = _closest_on_segments(v, a, b)                                  # (V, S, 3)
    distance = np.linalg.norm(closest - v[:, None], axis=2)                  # (V, S)
    behind = np.einsum("vsk,vk->vs", closest - v[:, None], vertex_normals(v, t)) < 0
    per_bone = np.full((V, B), np.inf)
    seen = np.full((V, B), np.inf)
    for s in range(len(owner)):
        per_bone[:, owner[s]] = np.minimum(per_bone[:, owner[s]], distance[:, s])
        seen[:, owner[s]] = np.minimum(seen[:, owner[s]], np.where(behind[:, s], distance[:, s], np.inf))
    nearest = np.where(np.isfinite(seen).any(1), seen.argmin(1), per_bone.argmin(1))
    d = np.maximum(per_bone[np.arange(V), nearest], 1e-4)
    edges = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    length2 = (np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1) ** 2)
    ends = np.r_[edges[:, 0], edges[:, 1]]
    valence = np.bincount(ends, minlength=V)
    h2 = np.bincount(ends, np.r_[length2, length2], minlength=V) / valence  # each vertex's mean squared edge
    adjacency = coo_matrix((np.ones(2 * len(edges)), (ends, np.r_[edges[:, 1], edges[:, 0]])), shape=(V, V)).tocsr()
    laplacian = diags(valence.astype(np.float64)) - adjacency
    # each row times 1.5 h^2 (the graph Laplacian over 1.5 h^2 is -Laplace on a regular triangle mesh): symmetric
    heat = HEAT * 1.5 * h2 / d ** 2
    lu = splu((laplacian + diags(heat)).tocsc())
    rhs = np.zeros((V, B))
    rhs[np.arange(V), nearest] = heat
    w = np.clip(lu.solve(rhs), 0.0, 1.0)
    w[w < WEIGHT_FLOOR] = 0.0
    w[np.arange(V), nearest] += (w.sum(1) == 0)  # never all dropped
    return w / w.sum(1, keepdims=True)


class SkinnedBody:
    """A body mesh (vertices (V, 3) [m], triangles (T, 3)) on a skeleton, with heat-diffusion weights (V, B)
    (computed if not given). pose(rotations) -> the posed vertices (V, 3) [m]."""

    def __init__(self, vertices, triangles, skeleton: Skeleton, weights: np.ndarray | None = None):
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64)
        self.skeleton = skeleton
        self.weights = heat_weights(self.vertices, self.triangles, skeleton) if weights is None else weights

    @classmethod
    def mannequin(cls, vertices=None) -> "SkinnedBody":
        """The shipped mannequin (or its morph: `vertices`, same topology) on MakeHuman's default joints."""
        m = load_mannequin()
        return cls(m.vertices if vertices is None else vertices, m.triangles, Skeleton(load_joints()))

    def pose(self, rotations: dict | None = None) -> np.ndarray:
        """The vertices (V, 3) [m] with bone name -> (3, 3) rotation about its joint (module docstring)."""
        return skin(self.vertices, self.weights, self.skeleton.transforms(rotations))
