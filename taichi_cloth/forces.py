"""Forces on the particles: springs (Hooke with spring damping), gravity, air drag, and optional sources
(wind, body repulsion).

`particle_force(i)` is a @ti.func, so each integrator inlines the same force code into its own
kernel (one way to compute a force, no per-integrator copies). A source is any object with
`prepare(t)` and a @ti.func `force(i, x_i, v_i)`; the sources a scene names are unrolled into the
kernel at compile time, the others cost nothing. Parameters live in 0-d fields: changing gravity,
drag or wind writes a field and never recompiles.
"""

import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock


@ti.data_oriented
class ForceModel:
    """Forces for one Model/State.

    gravity:     0-d vec3 fp [m/s^2]
    air_damping: 0-d fp [1/s]; drag force -air_damping * m * v (mass-proportional, so the
                 terminal speed m g / (air_damping m) = g / air_damping is resolution-independent)
    f:           (P,) vec3 fp [N] force buffer written by `compute`
    sources:     extra force sources (Wind, collision.Repulsion, ...)
    """

    def __init__(self, model, state, gravity=(0.0, -9.81, 0.0), air_damping: float = 0.0, sources=()):
        self.model, self.state = model, state
        self.sources = tuple(sources)
        fp = model.fp
        blk = FieldBlock()
        self.gravity = blk.vector(3, fp, ())
        self.air_damping = blk.scalar(fp, ())
        self.f = blk.vector(3, fp, model.capacity[0])
        blk.finalize(self)
        self.set_gravity(gravity)
        self.set_air_damping(air_damping)

    def set_gravity(self, g) -> None:
        """Gravity acceleration [m/s^2] as a 3-vector."""
        self.gravity_value = np.asarray(g, dtype=np.float64).reshape(3)
        self.gravity[None] = self.gravity_value.tolist()

    def set_air_damping(self, rate: float) -> None:
        """Air drag rate [1/s] (>= 0)."""
        if rate < 0:
            raise ValueError(f"air_damping must be >= 0 1/s, got {rate}")
        self.air_damping_value = float(rate)
        self.air_damping[None] = float(rate)

    def prepare(self, t: float) -> None:
        """Per-step set-up before forces are evaluated at time t [s] (wind gusts and normals)."""
        for src in self.sources:
            src.prepare(t)

    @ti.func
    def spring_force(self, e, xi, vi):
        """Force [N] on the particle of incidence e (at xi, moving at vi) from that incidence's spring."""
        m = self.model
        s = m.adj_spring[e]
        j = m.adj_other[e]
        d = self.state.x[j] - xi
        l = d.norm()
        u = d / ti.max(l, 1e-12)
        dv = self.state.v[j] - vi
        return m.stiffness[s] * (l - m.rest_length[s]) * u + m.damping[s] * dv.dot(u) * u + m.viscous[s] * dv

    @ti.func
    def source_force(self, i, xi, vi):
        """The force [N] of the scene's sources (wind, body repulsion) on particle i at xi, vi (0 without any)."""
        f = ti.Vector.zero(self.model.fp, 3)
        for k in ti.static(range(len(self.sources))):
            f += self.sources[k].force(i, xi, vi)
        return f

    @ti.func
    def particle_force(self, i, with_drag: ti.template()):
        """Total force [N] on particle i: gravity, springs, drag (if with_drag), and the scene's sources."""
        m = self.model
        xi = self.state.x[i]
        vi = self.state.v[i]
        f = m.mass[i] * self.gravity[None]
        if ti.static(with_drag):
            f -= self.air_damping[None] * m.mass[i] * vi
        for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
            f += self.spring_force(e, xi, vi)
        for k in ti.static(range(len(self.sources))):
            f += self.sources[k].force(i, xi, vi)
        return f

    @ti.kernel
    def compute(self, with_drag: ti.template()):
        """f[i] = particle_force(i) for every particle (pinned ones included: the residual test reads them)."""
        ti.loop_config(serialize=self.model.serial)
        for i in range(self.model.n_particles[None]):
            self.f[i] = self.particle_force(i, with_drag)

    def net_forces(self) -> np.ndarray:
        """(P,3) total force [N] on each particle now, drag included (a static residual when v = 0)."""
        self.prepare(self.state.t)
        self.compute(True)
        return self.f.to_numpy()[: self.model.data.n_particles].astype(np.float64)
