"""The explicit family's step: a force pass and an update pass over the particles, fused over substeps.

A subclass implements `_update(i, h, c, first)` (a @ti.func: particle i's update over h [s] from the forces in
forces.f, with its scheme's damping parameter c and `first` = 1 on the first step after a reset) and
`_damping_factor(dt)`; `with_drag` says whether the force pass includes the air drag.

Where nothing between two steps needs the host (no moving pins, no wind, no sewing or stretch limit; colliders only
spheres, capsules and planes, whose resolve touches one particle at a time) the scene lets the integrator fuse its
steps (`fuse`, option `fused`): the colliders' resolve runs inside the update pass, and a frame's steps run in few
launches. A small cloth, whose loops run in one thread (`runtime.serial_loops`), takes all of a frame's steps in
one launch; a large one CHUNK steps per launch (each pass stays a parallel loop). The fused steps do what the
unfused ones do, in the same order (a test compares the trajectories).
"""
import taichi as ti

from ..contacts import require_bound
from .base import Integrator, Option


@ti.data_oriented
class FusedSteps(Integrator):
    OPTIONS = {
        "fused": Option(bool, True, "run a frame's steps in few kernel launches where nothing between them needs "
                        "the host (no moving pins, wind, sewing or stretch limit; colliders only primitives)"),
    }
    #: steps per launch of a cloth whose loops run in parallel
    CHUNK = 8
    #: whether the force pass includes the air drag (the position schemes damp in their update)
    with_drag = True
    staggered_velocity = True  # v = (x - x_prev) / h in every scheme of the family

    def __init__(self, model, state, forces, **options):
        super().__init__(model, state, forces, **options)
        self.inline = None  # the colliders the fused update resolves (a tuple, fixed once a fused kernel compiled)
        self._started = False

    def reset(self) -> None:
        self._started = False

    def _damping_factor(self, dt: float) -> float:
        """The scheme's per-step damping parameter c, passed to `_update`."""
        return 0.0

    # ------------------------------------------------------------------ one step
    def _advance(self, dt: float) -> None:
        self._step(dt, self._damping_factor(dt), int(not self._started))
        self._started = True

    @ti.kernel
    def _step(self, dt: ti.f64, c_: ti.f64, first: ti.i32):
        h, c = ti.cast(dt, self.model.fp), ti.cast(c_, self.model.fp)
        ti.loop_config(serialize=self.model.serial)
        for i in range(self.model.n_particles[None]):
            self._force(i)
        ti.loop_config(serialize=self.model.serial)
        for i in range(self.model.n_particles[None]):
            self._update(i, h, c, first)

    @ti.func
    def _force(self, i):
        self.forces.f[i] = self.forces.particle_force(i, ti.static(self.with_drag))

    @ti.func
    def _update_and_resolve(self, i, h, c, first):
        start = self.state.x[i]
        self._update(i, h, c, first)
        if ti.static(self.has_contacts):  # the colliders' after-step clears every normal, then records contacts
            self.contacts.normal[i] = ti.Vector.zero(self.model.fp, 3)
        for k in ti.static(range(len(self.inline))):
            self.inline[k].resolve_particle(i, start)

    # ------------------------------------------------------------------ fused steps
    def fuse(self, colliders: tuple) -> bool:
        if not self.options["fused"] or self.forces.sources:
            return False  # force sources are prepared on the host before every step
        if self.inline is not None and self.inline != colliders:
            return False  # the fused kernels compiled with other colliders baked in
        self.inline = colliders
        return True

    def advance_fused(self, state, contacts, n: int, dt: float) -> None:
        require_bound(self, state, contacts)
        c = self._damping_factor(dt)
        first = int(not self._started)
        if self.model.serial:
            self._serial_steps(dt, c, first, n)
        else:
            done = 0
            if first and n:
                self._parallel_steps(dt, c, 1, 1)
                done = 1
            for _ in range((n - done) // self.CHUNK):
                self._parallel_steps(dt, c, 0, self.CHUNK)
            for _ in range((n - done) % self.CHUNK):
                self._parallel_steps(dt, c, 0, 1)
        self._started = self._started or n > 0
        for _ in range(n):  # as n single steps would add it
            state.t += dt

    @ti.kernel
    def _serial_steps(self, dt: ti.f64, c_: ti.f64, first: ti.i32, count: ti.i32):
        h, c = ti.cast(dt, self.model.fp), ti.cast(c_, self.model.fp)
        ti.loop_config(serialize=True)
        for k in range(count):  # one thread: the passes inside run in order
            for i in range(self.model.n_particles[None]):
                self._force(i)
            for i in range(self.model.n_particles[None]):
                self._update_and_resolve(i, h, c, first * ti.cast(k == 0, ti.i32))

    @ti.kernel
    def _parallel_steps(self, dt: ti.f64, c_: ti.f64, first: ti.i32, count: ti.template()):
        h, c = ti.cast(dt, self.model.fp), ti.cast(c_, self.model.fp)
        for _ in ti.static(range(count)):  # unrolled: every pass stays a parallel top-level loop
            for i in range(self.model.n_particles[None]):
                self._force(i)
            for i in range(self.model.n_particles[None]):
                self._update_and_resolve(i, h, c, first)
