"""Position Verlet with the damping of Zhang et al. 2017:  x+ = (2 - c) x - (1 - c) x- + a h^2.

c is the per-step damping factor; we set c = 1 - exp(-gamma h) from the air drag rate gamma [1/s]
so the drag does not depend on the step (docs/algorithms.md, step limits).

Implemented in displacement form: with d = x - x- (= h v), the update is d+ = (1 - c) d + a h^2,
x+ = x + d+, which is the same recursion but keeps float32 precision when h is small (the position
form loses a h^2 below the rounding of x). Velocities v = d / h feed spring damping, wind and energy.
Start-up: x- = x0 - h v0 + h^2 a0 / 2, which makes a constant acceleration exact.
"""
import math

import taichi as ti

from .fused import FusedSteps


@ti.data_oriented
class HistoryIntegrator(FusedSteps):
    """The two-level position schemes (Verlet, central difference): the history x - x- is h v. Their steps fuse
    over substeps (integrators.fused); the air drag acts in their update, not in the force pass."""

    position_based = True
    with_drag = False

    def topology_changed(self, level: int | None = None) -> None:
        """Nothing to do: the history x - x_prev = h v was prolonged with v."""

    @ti.func
    def _update(self, i, h, c, first):
        m, s = self.model, self.state
        if m.inv_mass[i] != 0:
            a = m.inv_mass[i] * self.forces.f[i]
            d = h * s.v[i]
            if first:
                d -= 0.5 * h * h * a  # x0 - x(-h) from the Taylor start-up
            d = self.displacement(d, a, h, c)
            s.v[i] = d / h
            s.x[i] += d


@ti.data_oriented
class Verlet(HistoryIntegrator):
    name = "verlet"

    def _damping_factor(self, dt: float) -> float:
        return 1.0 - math.exp(-self.forces.air_damping_value * dt)

    @ti.func
    def displacement(self, d, a, h, c):
        """x+ - x from d = x - x-: Zhang et al. 2017, (1 - c) d + a h^2."""
        return (1.0 - c) * d + a * h * h

    @classmethod
    def is_stable(cls, h, omega, gamma, beta):
        # modal recursion x+ = (2 - a - h^2 w^2) x - (1 - a) x-, a = c + h beta w^2 (lagged spring damping):
        # stable iff h^2 w^2 < 4 - 2a (docs/algorithms.md, step limits with c_d -> a)
        a = 1.0 - math.exp(-gamma * h) + h * beta * omega * omega
        return h * h * omega * omega < 4.0 - 2.0 * a
