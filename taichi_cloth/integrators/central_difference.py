"""Explicit central differences with viscous damping, seed 004 eq. (14):

    (m/h^2 + g/(2h)) X(t+h) = f(X_t) + (2m/h^2) X_t - (m/h^2 - g/(2h)) X(t-h)

with the viscous coefficient g = gamma * m (gamma = air drag rate [1/s]) and the forces f lagged at t.
In displacement form (d = X_t - X(t-h), as Verlet, for float32 precision at small steps):
    d+ = (h^2 f/m + (1 - gh/2m) d) / (1 + gh/2m),  X(t+h) = X_t + d+.
Start-up as Verlet (X(-h) from a Taylor step; the seed's X(-h) = X(0) is its v0 = 0, h -> 0 limit).
"""
import taichi as ti

from .verlet import HistoryIntegrator


@ti.data_oriented
class CentralDifference(HistoryIntegrator):
    name = "central-difference"

    def _damping_factor(self, dt: float) -> float:
        return 0.5 * self.forces.air_damping_value * dt  # g h / (2 m)

    @ti.kernel
    def _step(self, dt: ti.f64, half_gh: ti.f64, first: ti.i32):
        m, s, fm = self.model, self.state, self.forces
        h = ti.cast(dt, m.fp)
        g = ti.cast(half_gh, m.fp)
        for i in range(m.n_particles[None]):
            fm.f[i] = fm.particle_force(i, False)
        for i in range(m.n_particles[None]):
            if m.inv_mass[i] != 0:
                a = m.inv_mass[i] * fm.f[i]
                d = h * s.v[i]
                if first:
                    d -= 0.5 * h * h * a
                d = (h * h * a + (1.0 - g) * d) / (1.0 + g)
                s.v[i] = d / h
                s.x[i] += d

    @classmethod
    def is_stable(cls, h, omega, gamma, beta):
        # centred viscous damping does not limit h; the lagged spring damping does: h^2 w^2 + 2 h beta w^2 < 4
        return h * h * omega * omega + 2.0 * h * beta * omega * omega < 4.0
