"""The mannequin's shipped motion: the arms from the A-pose down to the sides over 1 s, then a torso twist of
+-30 degrees, posed by linear-blend skinning (skinning.SkinnedBody) and written as a mesh sequence, so that a scene
reads it as it reads a user's own (clothbase.sequences).

    from taichi_cloth.body.clip import mannequin_clip
    from clothbase.sequences import save_mesh_sequence
    save_mesh_sequence("out/mannequin_clip.npz", mannequin_clip())

Between two keys each angle eases in and out (smoothstep), so the body starts and stops without a jerk.
"""
from __future__ import annotations

import numpy as np

from clothbase.keyframes import rotation_xyz
from clothbase.sequences import MeshSequence

from .skinning import SkinnedBody

__all__ = ["ARMS_DOWN", "CLIP_KEYS", "TWIST", "clip_rotations", "mannequin_clip"]

#: [degrees] the upper arms turn down this far from the A-pose (about 40 degrees from vertical, to about 10: a
#: sleeve still fits between arm and side)
ARMS_DOWN = 20.0
#: [degrees] the torso's twist about the vertical, each way
TWIST = 30.0
#: (t [s], fraction of ARMS_DOWN, fraction of TWIST) at each key
CLIP_KEYS = ((0.0, 0.0, 0.0), (1.0, 1.0, 0.0), (1.5, 1.0, 1.0), (2.5, 1.0, -1.0), (3.0, 1.0, 0.0))
#: how the twist is shared among the spine's joints, lowest first
SPINE_SHARE = (("spine-4", 0.2), ("spine-3", 0.3), ("spine-2", 0.3), ("chest", 0.2))


def _eased(t: float, column: int) -> float:
    keys = CLIP_KEYS
    if t <= keys[0][0]:
        return keys[0][column]
    for a, b in zip(keys, keys[1:]):
        if t <= b[0]:
            s = (t - a[0]) / (b[0] - a[0])
            return a[column] + (b[column] - a[column]) * s * s * (3.0 - 2.0 * s)
    return keys[-1][column]


def clip_rotations(t: float, arms: float = ARMS_DOWN, twist: float = TWIST) -> dict:
    """Bone name -> (3, 3) rotation of the clip at time t [s] (arms and twist in degrees)."""
    down, turn = arms * _eased(t, 1), twist * _eased(t, 2)
    out = {"l-upperarm": rotation_xyz([0.0, 0.0, -down]), "r-upperarm": rotation_xyz([0.0, 0.0, down])}
    for bone, share in SPINE_SHARE:
        out[bone] = rotation_xyz([0.0, share * turn, 0.0])
    return out


def mannequin_clip(fps: float = 30.0, arms: float = ARMS_DOWN, twist: float = TWIST,
                   body: SkinnedBody | None = None) -> MeshSequence:
    """The clip as a MeshSequence of the mannequin (or `body`: a SkinnedBody of it, e.g. a morph) at `fps`
    [frames/s]: CLIP_KEYS's last time, 3 s."""
    body = body or SkinnedBody.mannequin()
    n = int(round(CLIP_KEYS[-1][0] * fps)) + 1
    frames = np.stack([body.pose(clip_rotations(k / fps, arms, twist)) for k in range(n)])
    return MeshSequence(frames, body.triangles, fps, "the mannequin's clip (arms down, torso twist)")
