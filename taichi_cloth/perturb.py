"""Starts moved by a hair: how a result of the model is told from one run's round-off.

A drape near a threshold (a rest time, the step at which two layers touch) follows the last bits of its start: another
CPU, which rounds differently, is a start moved by about float32's round-off (1e-7 m on a metre). A figure that
depends on a trajectory is therefore measured over a few starts, each moved by `amplitude` [m] in a seeded random
direction per particle, and given as a range; a test that asserts such an outcome bounds its worst case over them
(docs/performance.md, "Keeping clear of chaos").
"""
from __future__ import annotations

import numpy as np

#: the distance [m] a perturbed start moves each free particle by: float32's round-off on a metre
ROUND_OFF = 1e-7


def perturbed_positions(positions: np.ndarray, free: np.ndarray, amplitude: float, seed: int) -> np.ndarray:
    """(P,3) float64 copy of `positions` [m] with each particle where `free` (P,) bool is True moved by `amplitude`
    [m] in its own random direction (numpy's default generator seeded with `seed`: the same seed, the same start)."""
    if not np.isfinite(amplitude) or amplitude < 0:
        raise ValueError(f"a start's perturbation must be a distance >= 0 m, got {amplitude}")
    x = np.array(positions, dtype=np.float64)
    d = np.random.default_rng(seed).normal(size=x.shape)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-300)
    x[free] += amplitude * d[free]
    return x


def perturb_start(scene, amplitude: float = ROUND_OFF, seed: int = 0) -> None:
    """Move every free (unpinned) particle of `scene` (a taichi_cloth.Scene, before its run) by `amplitude` [m] in a
    random direction drawn from `seed`. Velocities are kept; `scene.reset()` goes back to the unmoved start."""
    x = scene.positions()
    free = ~np.asarray(scene.model.pinned[: len(x)], dtype=bool)
    scene.state.set(x=perturbed_positions(x, free, amplitude, seed))
