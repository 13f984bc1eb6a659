"""Energy, strain and sanity measurements of a state, in one Taichi kernel (run once per frame)."""

from dataclasses import dataclass

import taichi as ti

from clothbase.fields import FieldBlock

from .cloth import SpringKind

_KINETIC, _ELASTIC, _GRAVITY, _MAX_STRAIN, _MAX_SPEED, _NONFINITE = range(6)


@dataclass(frozen=True)
class Measurement:
    """kinetic, elastic, gravity [J] (gravity potential -sum m g.x), total [J], max_strain [-] over structural
    springs (l/L0 - 1), max_speed [m/s], nonfinite: count of particles with a NaN/inf (or > 1e30) coordinate."""

    kinetic: float
    elastic: float
    gravity: float
    max_strain: float
    max_speed: float
    nonfinite: int

    @property
    def potential(self) -> float:
        return self.elastic + self.gravity

    @property
    def total(self) -> float:
        return self.kinetic + self.potential


@ti.data_oriented
class Diagnostics:
    def __init__(self, model, state, forces):
        self.model, self.state, self.forces = model, state, forces
        blk = FieldBlock()
        self.out = blk.scalar(ti.f64, 6)
        blk.finalize(self)

    def measure(self) -> Measurement:
        self._measure()
        o = self.out.to_numpy()
        return Measurement(float(o[_KINETIC]), float(o[_ELASTIC]), float(o[_GRAVITY]), float(o[_MAX_STRAIN]),
                           float(o[_MAX_SPEED]), int(o[_NONFINITE]))

    @ti.kernel
    def _measure(self):
        m, s = self.model, self.state
        # kernel-local accumulators: Taichi reduces them per thread, no contended global atomics
        kinetic = ti.cast(0.0, ti.f64)
        gravity = ti.cast(0.0, ti.f64)
        elastic = ti.cast(0.0, ti.f64)
        max_speed = ti.cast(0.0, ti.f64)
        max_strain = ti.cast(0.0, ti.f64)
        nonfinite = 0
        g = ti.cast(self.forces.gravity[None], ti.f64)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            x = ti.cast(s.x[i], ti.f64)
            v = ti.cast(s.v[i], ti.f64)
            mass = ti.cast(m.mass[i], ti.f64)
            bad = 0
            for c in ti.static(range(3)):
                if not (ti.abs(x[c]) < 1e30 and ti.abs(v[c]) < 1e30):  # false for NaN too
                    bad = 1
            if bad:
                nonfinite += 1
            else:
                kinetic += 0.5 * mass * v.dot(v)
                gravity -= mass * g.dot(x)
                ti.atomic_max(max_speed, v.norm())
        ti.loop_config(serialize=self.model.serial)
        for sp in range(m.n_springs[None]):
            d = ti.cast(s.x[m.spring_b[sp]] - s.x[m.spring_a[sp]], ti.f64)
            l = d.norm()
            L0 = ti.cast(m.rest_length[sp], ti.f64)
            if l < 1e30:
                elastic += 0.5 * ti.cast(m.stiffness[sp], ti.f64) * (l - L0) ** 2
                if m.spring_kind[sp] == ti.static(int(SpringKind.STRUCTURAL)) and L0 > 0:
                    ti.atomic_max(max_strain, l / L0 - 1.0)
        self.out[_KINETIC] = kinetic
        self.out[_ELASTIC] = elastic
        self.out[_GRAVITY] = gravity
        self.out[_MAX_STRAIN] = max_strain
        self.out[_MAX_SPEED] = max_speed
        self.out[_NONFINITE] = nonfinite
