"""Preconditioned conjugate gradients on the filtered block system (Baraff and Witkin 1998's modified PCG): solves
S A S x = S b for x in range(S). The convergence test is decided on the device. The whole solve is one launch
where the loops run in one thread (the CPU); elsewhere a planned number of iterations is launched with no read (a
GPU), or the host reads after each launch whether CG goes on (the CPU's parallel cloths): see `solve`.

The preconditioner is either inline (`inline = True`: a Taichi function `precondition(i, r)` evaluated inside the
CG kernels, CHUNK iterations unrolled per launch) or applied by its own kernels (`apply(r, z)` once per iteration,
then one CG kernel); the iteration is the same: z = S P(r), stop when sqrt(r.z / b.z_b) <= tolerance or at the cap
(z_b the preconditioned b, so that a good start stops early), else p = z + beta p, q = S A p, x += alpha p,
r -= alpha q. A preconditioner applied by kernels starts from x = 0, where r = b: its first look gives b.z_b.
"""

import taichi as ti

from clothbase.fields import FieldBlock
from clothbase.ordered_sum import OrderedSums


@ti.data_oriented
class PCG:
    """The CG vectors and scalars, sized at the model's particle capacity P.

    b, x, r, z, p, q: (P,) vec3 fields of the model's precision: the right-hand side [kg m/s], the solution and
    start [m/s] (the caller writes both), the residual, the preconditioned residual, the direction and A p.
    The scalars, kept on the device: rz = r.z of the last look, rz_b = b.z_b, threshold = tolerance^2 rz_b and beta
    (0-d float64 fields); active (1 while iterating), iterations, max_iterations and spent (the iterations of the
    step's earlier solves, which its cap counts: the implicit step keeps it) (0-d int32 fields).
    The dot products are summed in a fixed order: in particle order where the model's loops run in one thread, else
    through `sums` (clothbase.ordered_sum), so that alpha and beta, and with them the state, do not follow the
    threads' timing.
    """

    #: CG iterations unrolled into one kernel launch with an inline preconditioner; iterations past convergence
    #: inside a chunk are no-ops
    CHUNK = 8

    def __init__(self, model):
        self.model = model
        fp, P = model.fp, model.capacity[0]
        blk = FieldBlock()
        self.b, self.x, self.r, self.z, self.p, self.q = (blk.vector(3, fp, P) for _ in range(6))
        self.rz, self.rz_b, self.threshold, self.beta = (blk.scalar(ti.f64, ()) for _ in range(4))
        self.active, self.iterations, self.max_iterations, self.spent = (blk.scalar(ti.i32, ()) for _ in range(4))
        blk.finalize(self)
        #: the dot products' terms of a model whose loops run in parallel, added in a fixed order (None: one thread)
        self.sums = None if model.serial else OrderedSums(2, P)

    def solve(self, system, filt, preconditioner, tolerance: float, max_iterations: int,
              planned: int | None = None) -> None:
        """x = the CG solution of S A S x = S b from the start in x, with `system` (linear.BlockSystem), `filt`
        (linear.ConstraintFilter) and a prepared `preconditioner`, in at most max_iterations less `spent` iterations
        (none once system.live is 0: a Newton iteration past the step's end); iterations, rz and rz_b stay on the
        device.

        A model whose loops run in one thread (the CPU's small and medium cloths) takes the whole solve in one
        launch, its iterations a device loop that ends at convergence, when the preconditioner can run there too
        (`in_thread`: inline, or a cycle that is one thread's work). Otherwise a launch per chunk (inline) or per
        iteration: with `planned`, that many iterations are launched and the host reads nothing (those past
        convergence are no-ops; a solve that needs more stops there with `active` still 1: the caller counts it);
        without, the host reads after each launch whether CG goes on."""
        tol2 = tolerance * tolerance
        if self.model.serial and (preconditioner.inline or preconditioner.in_thread):
            self._solve_in_thread(system, filt, preconditioner, tol2, max_iterations)
            return
        self._start(system, filt, preconditioner, tol2, max_iterations)
        if planned is not None:
            if preconditioner.inline:
                for _ in range(-(-planned // self.CHUNK)):
                    self._iterate_quietly(system, filt, preconditioner, self.CHUNK, 0, tol2)
                return
            for k in range(planned):
                preconditioner.apply(self.r, self.z)
                self._iterate_quietly(system, filt, preconditioner, 1, int(k == 0), tol2)
            return
        if preconditioner.inline:
            while self._iterate(system, filt, preconditioner, self.CHUNK, 0, tol2):
                pass
            return
        first = 1
        while True:
            preconditioner.apply(self.r, self.z)
            if not self._iterate(system, filt, preconditioner, 1, first, tol2):
                break
            first = 0

    @ti.func
    def _sum(self, acc: ti.template(), i, term):
        """acc += term (float64), in particle order where the model's loops run in one thread; else particle i's
        term is kept for sums.total (its order fixed by the index, not by the threads)."""
        if ti.static(self.model.serial):
            acc += ti.cast(term, ti.f64)
        else:
            self.sums.put(i, ti.Vector([term, 0.0], ti.f64))

    @ti.func
    def _look(self, rz, first, tol2):
        """The test on r.z of the current residual (first: the start, r = b): stop, or beta for the next p."""
        if first != 0:
            self.rz_b[None] = rz
            self.threshold[None] = tol2 * rz
            self.active[None] = ti.select(rz > self.threshold[None] and self.max_iterations[None] > 0, 1, 0)
            self.rz[None] = rz
        elif self.active[None] != 0:
            if rz <= self.threshold[None] or self.iterations[None] >= self.max_iterations[None]:
                self.active[None] = 0
            elif self.rz[None] > 0:
                self.beta[None] = rz / self.rz[None]
            else:
                self.beta[None] = 0.0
            self.rz[None] = rz

    @ti.kernel
    def _start(self, system: ti.template(), filt: ti.template(), pre: ti.template(), tol2: ti.f64,
               max_iterations: ti.i32):
        self._start_pass(system, filt, pre, tol2, max_iterations)

    @ti.kernel
    def _solve_in_thread(self, system: ti.template(), filt: ti.template(), pre: ti.template(), tol2: ti.f64,
                         max_iterations: ti.i32):
        """The whole solve in one thread: the start, then iterations until CG stops (a preconditioner applied by
        its cycle runs it in this thread before each)."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            self._start_pass(system, filt, pre, tol2, max_iterations)
            first = 1
            go = system.live[None]
            while go != 0:
                if ti.static(not pre.inline):
                    pre.cycle_in_thread(self.r, self.z)
                self._iteration(system, filt, pre, first, tol2)
                first = 0
                go = self.active[None]

    @ti.func
    def _start_pass(self, system: ti.template(), filt: ti.template(), pre: ti.template(), tol2, max_iterations):
        """r = S (b - A x); with an inline preconditioner also z, r.z, b.z_b and the first look."""
        m = self.model
        cap = ti.select(system.live[None] != 0, max_iterations - self.spent[None], 0)
        self.iterations[None] = 0
        self.beta[None] = 0.0
        self.max_iterations[None] = cap
        self.active[None] = 0
        rz = ti.cast(0.0, ti.f64)
        bz = ti.cast(0.0, ti.f64)
        ti.loop_config(serialize=m.serial)
        for i in range(system.gated(m.n_particles[None])):
            zero = ti.Vector.zero(m.fp, 3)
            self.p[i] = zero
            self.r[i] = zero
            self.z[i] = zero
            if m.inv_mass[i] != 0:
                r = self.b[i] - system.product(i, self.x, filt)
                self.r[i] = r
                if ti.static(pre.inline):
                    z = filt.apply(i, pre.precondition(i, r))
                    self.z[i] = z
                    terms = ti.Vector([r.dot(z), self.b[i].dot(filt.apply(i, pre.precondition(i, self.b[i])))], ti.f64)
                    if ti.static(m.serial):
                        rz += terms[0]
                        bz += terms[1]
                    else:
                        self.sums.put(i, terms)
            if ti.static(pre.inline and not m.serial):
                if m.inv_mass[i] == 0:
                    self.sums.put(i, ti.Vector.zero(ti.f64, 2))
        if ti.static(pre.inline and not m.serial):
            both = self.sums.total(system.gated(m.n_particles[None]))
            rz, bz = both[0], both[1]
        if ti.static(pre.inline):
            self.rz_b[None] = bz
            self.threshold[None] = tol2 * bz
            self.rz[None] = rz
            self.active[None] = ti.select(rz > tol2 * bz and cap > 0, 1, 0)

    @ti.kernel
    def _iterate(self, system: ti.template(), filt: ti.template(), pre: ti.template(), n: ti.template(),
                 first: ti.i32, tol2: ti.f64) -> ti.i32:
        """n CG iterations; a preconditioner applied by kernels wrote z = P(r) before (n = 1). Returns whether CG
        goes on (0: it had converged or reached its cap, and this call changed nothing)."""
        for _ in ti.static(range(n)):
            self._iteration(system, filt, pre, first, tol2)
        return self.active[None]

    @ti.kernel
    def _iterate_quietly(self, system: ti.template(), filt: ti.template(), pre: ti.template(), n: ti.template(),
                         first: ti.i32, tol2: ti.f64):
        """_iterate, returning nothing: the host does not wait for it."""
        for _ in ti.static(range(n)):
            self._iteration(system, filt, pre, first, tol2)

    @ti.func
    def _iteration(self, system: ti.template(), filt: ti.template(), pre: ti.template(), first, tol2):
        """One CG iteration, a no-op once CG stopped (a preconditioner applied by its cycle wrote z = P(r) before:
        its look comes first)."""
        m = self.model
        if ti.static(not pre.inline):  # the look at the cycle's z
            rz = ti.cast(0.0, ti.f64)
            ti.loop_config(serialize=m.serial)
            for i in range(m.n_particles[None]):
                z = filt.apply(i, self.z[i])
                self.z[i] = z
                self._sum(rz, i, self.r[i].dot(z))
            if ti.static(not m.serial):
                rz = self.sums.total(m.n_particles[None])[0]
            self._look(rz, first, tol2)
        beta = ti.cast(self.beta[None], m.fp)
        ti.loop_config(serialize=m.serial)
        for i in range(m.n_particles[None]):
            if m.inv_mass[i] != 0 and self.active[None] != 0:
                self.p[i] = self.z[i] + self.p[i] * beta
        pq = ti.cast(0.0, ti.f64)
        ti.loop_config(serialize=m.serial)
        for i in range(m.n_particles[None]):
            q = ti.Vector.zero(m.fp, 3)
            if m.inv_mass[i] != 0 and self.active[None] != 0:
                q = system.product(i, self.p, filt)
            self.q[i] = q
            self._sum(pq, i, self.p[i].dot(q))
        if ti.static(not m.serial):
            pq = self.sums.total(m.n_particles[None])[0]
        alpha = ti.cast(0.0, ti.f64)
        if self.active[None] != 0 and pq > 0:
            alpha = self.rz[None] / pq
        a = ti.cast(alpha, m.fp)
        rz_new = ti.cast(0.0, ti.f64)
        ti.loop_config(serialize=m.serial)
        for i in range(m.n_particles[None]):
            term = ti.cast(0.0, ti.f64)
            if m.inv_mass[i] != 0 and self.active[None] != 0:
                self.x[i] += a * self.p[i]
                r = self.r[i] - a * self.q[i]
                self.r[i] = r
                if ti.static(pre.inline):
                    z = filt.apply(i, pre.precondition(i, r))
                    self.z[i] = z
                    term = ti.cast(r.dot(z), ti.f64)
            if ti.static(pre.inline):
                self._sum(rz_new, i, term)
        if ti.static(pre.inline and not m.serial):
            rz_new = self.sums.total(m.n_particles[None])[0]
        if self.active[None] != 0:
            self.iterations[None] += 1
            if pq <= 0:
                self.active[None] = 0
        if ti.static(pre.inline):
            self._look(rz_new, 0, tol2)
