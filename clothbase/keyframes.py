"""Scripted motion: piecewise-linear keyframes (a pin group's offset, a collider's translation and rotation) and the
rigid pose they give a collider.

A collider's pose at time t maps a point r of the collider as built (its rest frame) to the world:
    world(r) = R(t) (r - pivot) + pivot + d(t),
with d(t) the translation keyframes [[t, dx, dy, dz], ...] [s, m] and R(t) = Rz(c) Ry(b) Rx(a) from the rotation
keyframes [[t, a, b, c], ...] [s, degrees] (each angle linear between keys, about the world axes through `pivot`
[m], x first). Both are held at their first key before it and at their last after it, as a pin's keyframes are.
"""
from __future__ import annotations

import numpy as np


class KeyframePath:
    """Piecewise-linear value (3,) through keyframes (t [s], x, y, z); held constant outside them."""

    def __init__(self, keyframes):
        k = np.asarray(keyframes, dtype=np.float64)
        if k.ndim != 2 or k.shape[1] != 4 or len(k) == 0:
            raise ValueError("keyframes must be a list of [t, dx, dy, dz] rows")
        if np.any(np.diff(k[:, 0]) <= 0):
            raise ValueError("keyframe times must increase strictly")
        self.t, self.offsets = k[:, 0], k[:, 1:]

    def __call__(self, t: float) -> np.ndarray:
        return np.array([np.interp(t, self.t, self.offsets[:, c]) for c in range(3)])


def rotation_xyz(angles_deg) -> np.ndarray:
    """R = Rz(c) Ry(b) Rx(a) (3,3) for angles (a, b, c) [degrees] about the x, y and z axes."""
    a, b, c = np.radians(np.asarray(angles_deg, dtype=np.float64))
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


class RigidMotion:
    """A collider's scripted rigid motion (module docstring). keyframes: translation rows [t, dx, dy, dz] [s, m] or
    None; rotation: rows [t, a, b, c] [s, degrees] or None; pivot (3,) [m] (default the origin)."""

    def __init__(self, keyframes=None, rotation=None, pivot=(0.0, 0.0, 0.0)):
        if keyframes is None and rotation is None:
            raise ValueError("a motion needs keyframes or rotation")
        self.translation = KeyframePath(keyframes) if keyframes is not None else None
        self.rotation = KeyframePath(rotation) if rotation is not None else None
        self.pivot = np.asarray(pivot, dtype=np.float64).reshape(3)

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(R (3,3), d (3,)) at time t [s]."""
        R = rotation_xyz(self.rotation(t)) if self.rotation is not None else np.eye(3)
        d = self.translation(t) if self.translation is not None else np.zeros(3)
        return R, d

    def to_world(self, points, t: float) -> np.ndarray:
        """points (N,3) of the collider as built [m] -> where they are at time t [m]."""
        R, d = self.pose(t)
        return (np.asarray(points, dtype=np.float64) - self.pivot) @ R.T + self.pivot + d

    def to_rest(self, points, t: float) -> np.ndarray:
        """The inverse of to_world: world points (N,3) at time t -> the collider's frame as built [m]."""
        R, d = self.pose(t)
        return (np.asarray(points, dtype=np.float64) - self.pivot - d) @ R + self.pivot
