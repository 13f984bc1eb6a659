"""Symplectic (semi-implicit) Euler, Chen 2013: v += h F/m ; x += h v. Its steps fuse over substeps
(integrators.fused)."""

import taichi as ti

from .fused import FusedSteps


@ti.data_oriented
class SymplecticEuler(FusedSteps):
    name = "explicit"

    @ti.func
    def _update(self, i, h, c, first):
        m, s = self.model, self.state
        if m.inv_mass[i] != 0:
            s.v[i] += h * m.inv_mass[i] * self.forces.f[i]
            s.x[i] += h * s.v[i]

    @classmethod
    def is_stable(cls, h, omega, gamma, beta):
        # v+ = v + h(-w^2 x - g v) ; x+ = x + h v+  is stable iff h^2 w^2 + 2 h g < 4, g = gamma + beta w^2
        return h * h * omega * omega + 2.0 * h * (gamma + beta * omega * omega) < 4.0
