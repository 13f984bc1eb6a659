"""Symplectic (semi-implicit) Euler, Chen 2013: v += h F/m ; x += h v."""

import taichi as ti

from .base import Integrator


@ti.data_oriented
class SymplecticEuler(Integrator):
    name = "explicit"

    @ti.kernel
    def _advance(self, dt: ti.f64):
        m, s, fm = self.model, self.state, self.forces
        h = ti.cast(dt, m.fp)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            fm.f[i] = fm.particle_force(i, True)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            if m.inv_mass[i] != 0:
                s.v[i] += h * m.inv_mass[i] * fm.f[i]
                s.x[i] += h * s.v[i]

    @classmethod
    def is_stable(cls, h, omega, gamma, beta):
        # v+ = v + h(-w^2 x - g v) ; x+ = x + h v+  is stable iff h^2 w^2 + 2 h g < 4, g = gamma + beta w^2
        return h * h * omega * omega + 2.0 * h * (gamma + beta * omega * omega) < 4.0
