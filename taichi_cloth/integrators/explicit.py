"""Symplectic (semi-implicit) Euler, Chen 2013: v += h F/m ; x += h v.

A step is two passes over the particles (forces, then the update). Where nothing between two steps needs the host
(no moving pins, no wind, no sewing; colliders only spheres, capsules and planes, whose resolve touches one particle
at a time), the scene lets the integrator fuse its steps (`fuse`, option `fused`): the colliders' resolve runs inside
the update pass, and a frame's steps run in few launches. A small cloth, whose loops run in one thread
(`runtime.serial_loops`), takes all of a frame's steps in one launch; a large one takes CHUNK steps per launch
(each pass stays a parallel loop). The fused steps do what the unfused ones do, in the same order.
"""

import taichi as ti

from .base import Integrator, Option


@ti.data_oriented
class SymplecticEuler(Integrator):
    name = "explicit"
    OPTIONS = {
        "fused": Option(bool, True, "run a frame's steps in few kernel launches where nothing between them needs "
                        "the host (no moving pins, wind or sewing; colliders only primitives)"),
    }
    #: steps per launch of a cloth whose loops run in parallel
    CHUNK = 8

    def __init__(self, model, state, forces, **options):
        super().__init__(model, state, forces, **options)
        self.inline = None  # the colliders the fused update resolves (a tuple, fixed once a fused kernel compiled)

    @ti.kernel
    def _advance(self, dt: ti.f64):
        h = ti.cast(dt, self.model.fp)
        ti.loop_config(serialize=self.model.serial)
        for i in range(self.model.n_particles[None]):
            self._force(i)
        ti.loop_config(serialize=self.model.serial)
        for i in range(self.model.n_particles[None]):
            self._update(i, h)

    @ti.func
    def _force(self, i):
        self.forces.f[i] = self.forces.particle_force(i, True)

    @ti.func
    def _update(self, i, h):
        m, s = self.model, self.state
        if m.inv_mass[i] != 0:
            s.v[i] += h * m.inv_mass[i] * self.forces.f[i]
            s.x[i] += h * s.v[i]

    @ti.func
    def _update_and_resolve(self, i, h):
        start = self.state.x[i]
        self._update(i, h)
        if ti.static(self.has_contacts):
            self.contacts.normal[i] = ti.Vector.zero(self.model.fp, 3)
        for c in ti.static(self.inline):
            c.resolve_particle(i, start)

    # ------------------------------------------------------------------ fused steps
    def fuse(self, colliders: tuple) -> bool:
        if not self.options["fused"] or self.forces.sources:
            return False  # force sources are prepared on the host before every step
        if self.inline is not None and self.inline != colliders:
            return False  # the fused kernels compiled with other colliders baked in
        self.inline = colliders
        return True

    def advance_fused(self, n: int, dt: float) -> None:
        if self.model.serial:
            self._serial_steps(dt, n)
        else:
            for _ in range(n // self.CHUNK):
                self._parallel_steps(dt, self.CHUNK)
            for _ in range(n % self.CHUNK):
                self._parallel_steps(dt, 1)
        for _ in range(n):  # as n single steps would add it
            self.state.t += dt

    @ti.kernel
    def _serial_steps(self, dt: ti.f64, count: ti.i32):
        h = ti.cast(dt, self.model.fp)
        ti.loop_config(serialize=True)
        for _ in range(count):  # one thread: the passes inside run in order
            for i in range(self.model.n_particles[None]):
                self._force(i)
            for i in range(self.model.n_particles[None]):
                self._update_and_resolve(i, h)

    @ti.kernel
    def _parallel_steps(self, dt: ti.f64, count: ti.template()):
        h = ti.cast(dt, self.model.fp)
        for _ in ti.static(range(count)):  # unrolled: every pass stays a parallel top-level loop
            for i in range(self.model.n_particles[None]):
                self._force(i)
            for i in range(self.model.n_particles[None]):
                self._update_and_resolve(i, h)

    @classmethod
    def is_stable(cls, h, omega, gamma, beta):
        # v+ = v + h(-w^2 x - g v) ; x+ = x + h v+  is stable iff h^2 w^2 + 2 h g < 4, g = gamma + beta w^2
        return h * h * omega * omega + 2.0 * h * (gamma + beta * omega * omega) < 4.0
