"""A body that morphs during a run: the scene's mesh collider moves from one set of blend-shape weights to another
over a time window, and the cloth draped on it follows (it is pushed by the collider as the surface moves).

The collider's vertices, normals and voxel grid are rebuilt at every step of the window (MeshCollider.set_vertices,
about 9 ms for the 13k-vertex mannequin on this 2-core CPU), so the surface moves a little per step: the window
must be long enough that no vertex moves more than the collider's thickness in one step, else a particle could
end up inside the body. `MorphingBody.check_speed` refuses windows that are too short.
"""

import numpy as np

__all__ = ["MorphingBody"]


class MorphingBody:
    """Morph `collider` (a collision.MeshCollider of `blend`'s base body) from weights `start_weights` (default: all
    zero, the base body) to `weights` over `duration` [s] with a smooth ramp (zero speed at both ends).

    blend: taichi_cloth.body.BlendShapes; weights: channel -> weight in [-1, 1]; start: the simulated time [s]
    the morph begins, or "sewn": when the garment's seams are joined (at once for a scene without sewing).
    """

    def __init__(self, blend, weights: dict, collider, duration: float, start=0.0, start_weights: dict | None = None):
        if not duration > 0:
            raise ValueError(f"body morph: duration must be > 0 s, got {duration}")
        if start != "sewn" and not (isinstance(start, (int, float)) and start >= 0):
            raise ValueError(f"body morph: start must be a time >= 0 s or 'sewn', got {start!r}")
        self.blend, self.collider = blend, collider
        self.duration = float(duration)
        self.start = start
        names = sorted(set(weights) | set(start_weights or {}))
        self.w0 = {k: float((start_weights or {}).get(k, 0.0)) for k in names}
        self.w1 = {k: float(weights.get(k, 0.0)) for k in names}
        self.begin = None if start == "sewn" else float(start)
        self.fraction = 0.0
        self.vertices = blend.morph(self.w0)
        self.changed = False  # set when the vertices moved since the recorder last logged them
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

    def update(self, t: float, sewing_active: bool = False) -> None:
        """Move the collider to the morph at simulated time t [s]."""
        if self.done:
            return
        if self.begin is None:
            if sewing_active:
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
