"""Energy, strain, motion and sanity measurements of a state, in one Taichi kernel (run once per frame)."""

import math
from dataclasses import dataclass

import taichi as ti

from clothbase.fields import FieldBlock

from .cloth import SpringKind
from .runtime import one_thread_loops

_KINETIC, _ELASTIC, _GRAVITY, _MAX_STRAIN, _MAX_SPEED, _NONFINITE, _MOTION, _FAST = range(8)


@dataclass(frozen=True)
class Measurement:
    """kinetic, elastic, gravity [J] (gravity potential -sum m g.x), total [J], max_strain [-] over structural
    springs (l/L0 - 1), max_speed [m/s] (of the velocities), nonfinite: count of particles with a NaN/inf (or > 1e30)
    coordinate; motion_speed [m/s]: the fastest free particle's displacement since the previous measurement divided
    by the simulated time between them (inf when there is none: the first, or the first after the particles
    changed); motion_fast: the fraction of free particles whose motion speed exceeds Diagnostics.fast_speed."""

    kinetic: float
    elastic: float
    gravity: float
    max_strain: float
    max_speed: float
    nonfinite: int
    motion_speed: float = math.inf
    motion_fast: float = 1.0

    @property
    def potential(self) -> float:
        return self.elastic + self.gravity

    @property
    def total(self) -> float:
        return self.kinetic + self.potential


@ti.data_oriented
class Diagnostics:
    """Measures the state of (model, state, forces). fast_speed [m/s]: the threshold of Measurement.motion_fast."""

    #: slots of the measurement's read that controllers may fill (Controller.report_slots)
    REPORT_CAPACITY = 16

    def __init__(self, model, state, forces, fast_speed: float = 1e-3, staggered: bool = False):
        self.model, self.state, self.forces = model, state, forces
        self.fast_speed = float(fast_speed)
        #: the velocities are half a step behind the positions (the explicit family): the kinetic energy is read with
        #: v + h/2 a, the velocity at the positions' time (centred), so that a symplectic scheme's energy does not
        #: seem to drift: an undamped swing read 1.7e-3 of its kinetic energy off with the one-sided velocity
        self.staggered = bool(staggered)
        #: the sums in one thread, in a fixed order, wherever the arch allows (the CPU): the rest stop and sewing's
        #: "settled" test decide on them, so a run repeats itself; once a frame, a pass costs little
        self.fixed_order = one_thread_loops()
        blk = FieldBlock()
        self.out = blk.scalar(ti.f64, 8 + self.REPORT_CAPACITY)
        self.x_last = blk.vector(3, model.fp, model.capacity[0])  # the positions at the last measurement [m]
        blk.finalize(self)
        self._reporters: list[tuple[object, int]] = []  # (controller, its first slot in out)
        self._t_last: float | None = None  # simulated time of x_last; None: no valid x_last
        self._motion = (math.inf, 1.0)

    def forget(self) -> None:
        """The particles changed (a refill): the next measurement has no motion to report."""
        self._t_last = None
        self._motion = (math.inf, 1.0)

    def add_reporter(self, controller) -> None:
        """Carry `controller`'s per-frame values (Controller.report_slots) in every measurement's one read."""
        used = sum(c.report_slots for c, _ in self._reporters)
        if used + controller.report_slots > self.REPORT_CAPACITY:
            raise ValueError(f"the controllers' reports need more than {self.REPORT_CAPACITY} slots")
        self._reporters.append((controller, 8 + used))

    def measure(self, dt: float = 0.0) -> Measurement:
        """The state now, and the reporting controllers' values, in one read of the device; dt [s]: the last step
        (staggered velocities are read half of it ahead)."""
        t = float(self.state.t)
        elapsed = 0.0 if self._t_last is None else t - self._t_last
        update = self._t_last is None or elapsed > 0  # a second measurement at the same time keeps the motion
        self._measure(elapsed if elapsed > 0 else 0.0, self.fast_speed, int(update), 0.5 * float(dt))
        for controller, offset in self._reporters:
            controller.report(self.out, offset)
        o = self.out.to_numpy()
        for controller, offset in self._reporters:
            controller.reported(o[offset:offset + controller.report_slots])
        if update:
            self._motion = (float(o[_MOTION]), float(o[_FAST])) if elapsed > 0 else (math.inf, 1.0)
            self._t_last = t
        return Measurement(float(o[_KINETIC]), float(o[_ELASTIC]), float(o[_GRAVITY]), float(o[_MAX_STRAIN]),
                           float(o[_MAX_SPEED]), int(o[_NONFINITE]), *self._motion)

    @ti.kernel
    def _measure(self, elapsed: ti.f64, fast_speed: ti.f64, update: ti.i32, half_step: ti.f64):
        """Energies, strain, speed; with `update`, the motion since x_last over `elapsed` [s] (when > 0) and x_last
        set to the positions now; staggered velocities read `half_step` [s] ahead for the kinetic energy."""
        m, s = self.model, self.state
        # kernel-local accumulators: Taichi reduces them per thread, no contended global atomics
        kinetic = ti.cast(0.0, ti.f64)
        gravity = ti.cast(0.0, ti.f64)
        elastic = ti.cast(0.0, ti.f64)
        max_speed = ti.cast(0.0, ti.f64)
        max_strain = ti.cast(0.0, ti.f64)
        nonfinite = 0
        motion = ti.cast(0.0, ti.f64)
        fast = 0
        free = 0
        ti.loop_config(serialize=self.fixed_order)
        for i in range(m.n_particles[None]):
            # gravity read in the loop: a float64 vector kept at kernel scope and read in a loop that also sums
            # float64 faults on CUDA (misaligned address, Taichi 1.7.4)
            g = ti.cast(self.forces.gravity[None], ti.f64)
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
                vc = v
                if ti.static(self.staggered):
                    if m.inv_mass[i] != 0:
                        vc += half_step * ti.cast(self.forces.particle_force(i, False) * m.inv_mass[i], ti.f64)
                kinetic += 0.5 * mass * vc.dot(vc)
                gravity -= mass * g.dot(x)
                ti.atomic_max(max_speed, v.norm())
            if update != 0:
                if elapsed > 0 and m.inv_mass[i] != 0:
                    speed = (x - ti.cast(self.x_last[i], ti.f64)).norm() / elapsed
                    ti.atomic_max(motion, speed)
                    free += 1
                    if speed > fast_speed:
                        fast += 1
                self.x_last[i] = s.x[i]
        ti.loop_config(serialize=self.fixed_order)
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
        self.out[_MOTION] = motion
        self.out[_FAST] = ti.cast(fast, ti.f64) / ti.cast(ti.max(free, 1), ti.f64)
