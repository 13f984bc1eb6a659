"""A body that morphs during a run: the scene's mesh collider moves from one set of blend-shape weights to another
over a time window, and the cloth draped on it follows (it is pushed by the collider as the surface moves).

The collider's vertices, normals and voxel grid are rebuilt at every step of the window (MeshCollider.set_vertices;
its cost: docs/performance.md), so the surface moves a little per step: the window
must be long enough that no vertex moves more than the collider's thickness in one step, else a particle could
end up inside the body. `MorphingBody.check_speed` refuses windows that are too short.
"""

from typing import Callable

import numpy as np

from ..control import Controller, ModelChange

__all__ = ["MorphingBody"]


class MorphingBody(Controller):
    """Morph `collider` (a collision.MeshCollider of `blend`'s base body) from weights `start_weights` (default: all
    zero, the base body) to `weights` over `duration` [s] with a smooth ramp (zero speed at both ends). A
    controller: the body moves before every step of the window.

    blend: taichi_cloth.body.BlendShapes; weights: channel -> weight in [-1, 1]; start: the simulated time [s]
    the morph begins, or "sewn": once `ready()` is true (a garment scene passes "the seams are joined"; without
    `ready` it begins at once); index: the collider's place among the scene's colliders (what the recording calls
    it).
    """

    name = "body_morph"

    def __init__(self, blend, weights: dict, collider, duration: float, start=0.0, start_weights: dict | None = None,
                 ready: Callable[[], bool] | None = None, index: int = 0):
        if not duration > 0:
            raise ValueError(f"body morph: duration must be > 0 s, got {duration}")
        if start != "sewn" and not (isinstance(start, (int, float)) and start >= 0):
            raise ValueError(f"body morph: start must be a time >= 0 s or 'sewn', got {start!r}")
        self.blend, self.collider = blend, collider
        self.duration = float(duration)
        self.start = start
        self.ready = ready
        self.index = index
        names = sorted(set(weights) | set(start_weights or {}))
        self.w0 = {k: float((start_weights or {}).get(k, 0.0)) for k in names}
        self.w1 = {k: float(weights.get(k, 0.0)) for k in names}
        self._restart()

    def _restart(self) -> None:
        self.begin = None if self.start == "sewn" else float(self.start)
        self.fraction = 0.0
        self.vertices = self.blend.morph(self.w0)
        self.changed = False  # the vertices moved since the last recorded frame
        self.reported = False  # the run summary has its event

    @property
    def done(self) -> bool:
        return self.fraction >= 1.0

    def max_displacement(self) -> float:
        """The largest distance [m] a body vertex travels over the whole morph."""
        return float(np.linalg.norm(self.blend.morph(self.w1) - self.blend.morph(self.w0), axis=1).max())

    def check_speed(self, dt: float) -> None:
        """Refuse a window in which a vertex would move more than the collider's thickness in one step of dt [s]
        (the ramp's peak speed is 1.5 x the mean)."""
        per_step = 1.5 * self.max_displacement() * dt / self.duration
        if per_step > self.collider.thickness:
            need = 1.5 * self.max_displacement() * dt / self.collider.thickness
            raise ValueError(f"body morph: the surface would move {1e3 * per_step:.2f} mm per step, more than the "
                             f"collider thickness {1e3 * self.collider.thickness:.1f} mm; make morph_time at least "
                             f"{need:.2f} s")

    def update(self, t: float) -> None:
        """Move the collider to the morph at simulated time t [s]."""
        if self.done:
            return
        if self.begin is None:
            if self.ready is not None and not self.ready():
                return
            self.begin = t
        s = min(max((t - self.begin) / self.duration, 0.0), 1.0)
        if s == self.fraction:
            return
        self.fraction = s
        ramp = s * s * (3.0 - 2.0 * s)  # smoothstep: the body starts and stops gently
        w = {k: self.w0[k] + ramp * (self.w1[k] - self.w0[k]) for k in self.w0}
        self.vertices = self.blend.morph(w)
        self.collider.set_vertices(self.vertices)
        self.changed = True

    # ------------------------------------------------------------------ as a controller
    def before_step(self, t: float, dt: float) -> None:
        self.update(t)

    def after_frame(self, frame) -> ModelChange | None:
        if self.done and not self.reported:
            self.reported = True
            return ModelChange(event=f"body morphed from t = {self.begin:.3f} s to {self.begin + self.duration:.3f} s "
                                     f"(max vertex travel {1e3 * self.max_displacement():.1f} mm)")
        return None

    def reset(self) -> None:
        """Back to the start weights (the collider is moved back)."""
        moved = self.fraction > 0
        self._restart()
        if moved:
            self.collider.set_vertices(self.vertices)
            self.changed = True
        return None

    def record(self, frame) -> None:
        if self.changed:
            frame.meshes[self.index] = self.vertices.astype(np.float32)
            self.changed = False
