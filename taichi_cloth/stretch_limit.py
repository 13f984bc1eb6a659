"""Provot 1995 stretch limiting as a position correction after each step (docs/algorithms.md, stretch limiting).

For every limited spring longer than (1 + max_strain) L0, its endpoints move toward each other along
the spring, in proportion to their inverse masses (a pinned end does not move). Parallel form: each
particle gathers the corrections of its springs and moves by omega times their average (over-relaxed
Jacobi). A uniformly over-stretched column only shortens from its free end, one particle per pass,
so a fixed small number of passes does not hold the limit on a soft hanging sheet (8 passes left
17 % strain against a 10 % limit in our test, 100-200 passes reach 10.1 %); the passes therefore repeat until the largest excess
strain is below `tolerance` or `iterations` passes are done. A particle's velocity loses its component against
its correction, up to |dx| / h (the stretching motion goes), and gains none along it (`_inelastic`), so the limit
never gives kinetic energy.

Where a body holds the cloth (a particle with a contact normal from the colliders' last step), the limit treats the
particle as fixed, like a pin: a spring from it to a free particle moves the free one only, and a spring with both
ends on the body is left to the body. Moving them, the limit pulled them into the body, the collider pushed them
back out after the step, and the two fought every step (20 unconverged passes a step): a waistband or a neckline
tighter than the body under it kept the garment below moving at 25-30 mm/s for good. What the limit leaves on the
body, the run summary reports (springs over the limit while no particle is inside a collider).

The test is made on the device. A cloth whose loops run in one thread (the CPU's small and medium cloths) takes
every pass of a step in one launch, a device loop that ends when the limit holds: no read. A parallel one runs
CHUNK passes per launch, each only while the last left an excess above the tolerance, and the host reads one flag
per launch (a step that converges in a few passes costs one launch and one read); where no loop may run in one
thread (a GPU), it launches the passes of a plan instead and reads nothing (`reported`). The pass counters stay on
the device until `stats` is read.
"""
import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock

from .cloth import SpringKind
from .control import Controller
from .runtime import next_plan, one_thread_loops


@ti.data_oriented
class StretchLimit(Controller):
    """The scene's stretch limit, applied after every step (a controller).

    contacts: the scene's Contacts (None without colliders); max_strain: allowed relative elongation (0.1 = 10 %); iterations: the most Jacobi passes per step;
    tolerance: stop once every limited spring is within max_strain + tolerance (strain units);
    omega: over-relaxation of the averaged correction; kinds: spring kinds limited (default structural
    and shear, as Provot); after_join: for a garment, whether the limit goes on once the seams are joined (False: it
    holds the pieces while they are sewn, and the drape is left to the fabric's own stiffness; `sewing`, the scene's
    sewing controller, is set by the scene)."""

    def __init__(self, model, state, contacts=None, max_strain: float = 0.1, iterations: int = 100, tolerance: float = 1e-3,
                 omega: float = 1.5, kinds=(SpringKind.STRUCTURAL, SpringKind.SHEAR), after_join: bool = True):
        if max_strain <= 0:
            raise ValueError(f"stretch limit max_strain must be > 0, got {max_strain}")
        if iterations < 1:
            raise ValueError(f"stretch limit iterations must be >= 1, got {iterations}")
        if tolerance < 0:
            raise ValueError(f"stretch limit tolerance must be >= 0, got {tolerance}")
        if not 0 < omega < 2:
            raise ValueError(f"stretch limit omega must lie in (0, 2), got {omega}")
        self.model, self.state = model, state
        #: the contact normals of the scene's colliders (None without colliders): see _correction
        self.contacts = contacts
        self.has_contacts = self.contacts is not None  # compile-time: no colliders, no contact code
        self.max_strain, self.iterations = float(max_strain), int(iterations)
        self.tolerance, self.omega = float(tolerance), float(omega)
        self.kinds = tuple(SpringKind(k) for k in kinds)
        self.after_join = bool(after_join)
        self.sewing = None
        blk = FieldBlock()
        self.limited = blk.scalar(ti.i32, max(model.capacity[1], 1))
        self.dx = blk.vector(3, model.fp, model.capacity[0])
        self.worst = blk.scalar(ti.f64, ())       # the largest excess strain of the last pass
        # active, passes this step, passes in all, unconverged steps; since the last report (planned passes) the most
        # passes of a step and the steps the plan stopped short
        self.counters = blk.scalar(ti.i32, 6)
        blk.finalize(self)
        #: where no loop may run in one thread (a GPU), a step launches the passes its plan allows and the host reads
        #: nothing: the plan follows the last frame's largest step, read with its measurement (report)
        self.planned = not one_thread_loops()
        self._plan = self.iterations
        self.refresh()

    #: passes per launch
    CHUNK = 8
    _ACTIVE, _PASSES, _TOTAL, _UNCONVERGED, _LARGEST, _SHORT = range(6)

    @property
    def stats(self) -> dict:
        c = self.counters.to_numpy()
        return {"stretch_passes": int(c[self._TOTAL]), "stretch_unconverged_steps": int(c[self._UNCONVERGED])}

    name = "stretch_limit"

    def after_step(self, t: float, dt: float) -> None:
        if self.after_join or self.sewing is None or not self.sewing.joined:
            self.apply(dt)

    def model_changed(self, change, t: float, dt: float) -> None:
        if change.refills:
            self.refresh()

    def refresh(self) -> None:
        """Re-read which springs are limited (after the model's springs change)."""
        flags = np.isin(self.model.data.kind, [int(k) for k in self.kinds]).astype(np.int32)
        buf = np.zeros(self.limited.shape[0], np.int32)
        buf[: len(flags)] = flags
        self.limited.from_numpy(buf)

    def apply(self, dt: float) -> None:
        """Correct positions (and velocities) after a step of dt [s]. The largest excess strain left before the last
        pass stays in `worst` on the device (reading it would stall the step). A cloth whose loops run in one thread
        takes every pass in one launch, the test a device loop: no read at all."""
        if self.model.serial:
            self._passes_in_thread(dt, self.max_strain, self.omega, self.tolerance, self.iterations)
            return
        if self.planned:
            for k in range(-(-self._plan // self.CHUNK)):
                self._passes(dt, self.max_strain, self.omega, self.tolerance, self.iterations, int(k == 0))
            self._end_planned()
            return
        first = 1
        while first or self.counters[self._ACTIVE]:
            self._passes(dt, self.max_strain, self.omega, self.tolerance, self.iterations, first)
            first = 0

    @ti.kernel
    def _passes(self, dt: ti.f64, max_strain: ti.f64, omega: ti.f64, tolerance: ti.f64, iterations: ti.i32,
                first: ti.i32):
        c = ti.static(self.counters)
        if first != 0:
            c[self._ACTIVE] = 1
            c[self._PASSES] = 0
        for _ in ti.static(range(self.CHUNK)):  # unrolled: every pass stays a top-level loop
            self._pass(dt, max_strain, omega, tolerance, iterations)

    @ti.kernel
    def _end_planned(self):
        """A step whose plan ran out before the limit held: counted short and unconverged."""
        c = ti.static(self.counters)
        if c[self._ACTIVE] != 0:
            c[self._ACTIVE] = 0
            c[self._SHORT] += 1
            c[self._UNCONVERGED] += 1
        c[self._LARGEST] = ti.max(c[self._LARGEST], c[self._PASSES])

    # ------------------------------------------------------------------ the plan (no loop in one thread)
    @property
    def report_slots(self) -> int:
        return 2 if self.planned else 0

    @ti.kernel
    def report(self, out: ti.template(), offset: ti.i32):
        c = ti.static(self.counters)
        out[offset] = ti.cast(c[self._LARGEST], ti.f64)
        out[offset + 1] = ti.cast(c[self._SHORT], ti.f64)
        c[self._LARGEST] = 0
        c[self._SHORT] = 0

    def reported(self, values) -> None:
        """The next steps' plan of passes (runtime.next_plan)."""
        self._plan = next_plan(self._plan, int(values[0]), int(values[1]), self.CHUNK, self.iterations)

    @ti.kernel
    def _passes_in_thread(self, dt: ti.f64, max_strain: ti.f64, omega: ti.f64, tolerance: ti.f64,
                          iterations: ti.i32):
        c = ti.static(self.counters)
        ti.loop_config(serialize=True)
        for _ in range(1):
            c[self._ACTIVE] = 1
            c[self._PASSES] = 0
            go = 1  # (a while on the field itself fails Taichi's IR check, 1.7.4)
            while go != 0:
                self._pass(dt, max_strain, omega, tolerance, iterations)
                go = c[self._ACTIVE]

    @ti.func
    def _pass(self, dt, max_strain, omega, tolerance, iterations):
        """One Jacobi pass while the last one left an excess above the tolerance (a no-op once none did)."""
        m, s = self.model, self.state
        c = ti.static(self.counters)
        h = ti.cast(dt, m.fp)
        limit = 1.0 + ti.cast(max_strain, m.fp)
        w = ti.cast(omega, m.fp)
        if c[self._ACTIVE] != 0:
            self.worst[None] = 0.0
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            if c[self._ACTIVE] != 0:
                self._correction(i, limit, w)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            if c[self._ACTIVE] != 0:
                dx = self.dx[i]
                s.x[i] += dx
                s.v[i] += self._inelastic(s.v[i], dx, h)
        if c[self._ACTIVE] != 0:
            c[self._PASSES] += 1
            c[self._TOTAL] += 1
            if self.worst[None] <= tolerance:
                c[self._ACTIVE] = 0
            elif c[self._PASSES] >= iterations:
                c[self._ACTIVE] = 0
                c[self._UNCONVERGED] += 1

    @ti.func
    def _inelastic(self, v, dx, h):
        """The velocity change [m/s] that goes with a correction dx [m] over a step h [s]: the velocity against dx (the
        motion that stretched the springs) is taken away, up to |dx| / h, and none is added along it. Adding dx / h
        itself, as Provot does, gave a particle that the over-relaxed passes moved further than its stretch a velocity
        toward its neighbours that the next step carried past them: a flutter that kept 30-40 % of a resting T-shirt
        above 1 mm/s (the demo's hem, 15 Hz, 0.5 mm) where the same drape without the limit rested at once."""
        size = dx.norm()
        dv = ti.Vector.zero(self.model.fp, 3)
        if size > 0:
            n = dx / size
            dv = n * ti.min(size / h, ti.max(0.0, -v.dot(n)))
        return dv

    @ti.func
    def _weight(self, i):
        """Particle i's share of a correction: its inverse mass, 0 when pinned or resting on a body."""
        w = self.model.inv_mass[i]
        if ti.static(self.has_contacts):
            n = self.contacts.normal[i]
            if n.dot(n) > 0:
                w = 0.0
        return w

    @ti.func
    def _correction(self, i, limit, w):
        """dx[i]: omega times the average of particle i's corrections over its over-stretched limited springs."""
        m, s = self.model, self.state
        acc = ti.Vector.zero(m.fp, 3)
        count = 0
        wi = self._weight(i)
        if wi != 0:
            for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                sp = m.adj_spring[e]
                if self.limited[sp]:
                    j = m.adj_other[e]
                    d = s.x[j] - s.x[i]
                    l = d.norm()
                    L0 = m.rest_length[sp]
                    lmax = limit * L0
                    if l > lmax and L0 > 0:
                        ti.atomic_max(self.worst[None], ti.cast(l / L0 - limit, ti.f64))
                        acc += wi / (wi + self._weight(j)) * (l - lmax) / l * d
                        count += 1
        self.dx[i] = w * acc / ti.max(count, 1)
