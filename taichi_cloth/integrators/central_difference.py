"""Explicit central differences with viscous damping, Fan et al. 1998 eq. (14):

    (m/h^2 + g/(2h)) X(t+h) = f(X_t) + (2m/h^2) X_t - (m/h^2 - g/(2h)) X(t-h)

with the viscous coefficient g = gamma * m (gamma = air drag rate [1/s]) and the forces f lagged at t.
In displacement form (d = X_t - X(t-h), as Verlet, for float32 precision at small steps):
    d+ = (h^2 f/m + (1 - gh/2m) d) / (1 + gh/2m),  X(t+h) = X_t + d+.
Start-up as Verlet (X(-h) from a Taylor step; the paper's X(-h) = X(0) is its v0 = 0, h -> 0 limit).
"""
import taichi as ti

from .verlet import HistoryIntegrator


@ti.data_oriented
class CentralDifference(HistoryIntegrator):
    name = "central-difference"

    def _damping_factor(self, dt: float) -> float:
        return 0.5 * self.forces.air_damping_value * dt  # g h / (2 m)

    @ti.func
    def displacement(self, d, a, h, c):
        """x+ - x from d = x - x-: eq. (14) divided by m/h^2, with c = g h / (2 m)."""
        return (h * h * a + (1.0 - c) * d) / (1.0 + c)

    @classmethod
    def is_stable(cls, h, omega, gamma, beta):
        # centred viscous damping does not limit h; the lagged spring damping does: h^2 w^2 + 2 h beta w^2 < 4
        return h * h * omega * omega + 2.0 * h * beta * omega * omega < 4.0
