"""Backward Euler with the full spring Jacobians (Baraff and Witkin 1998), as the minimisation of the incremental
potential, by Newton iterations with a line search; each Newton system solved by preconditioned CG.

A step from (x0, v0) finds the velocity v that minimises (Martin et al. 2011, "example-based elastic materials";
Gast et al. 2015, "optimization integrator for large time steps")

    IP(v) = 1/2 (v - v0)^T M (v - v0) + Phi(x0 + h v) + h/2 v^T C v - h F_ext . v,

Phi = spring + gravity potential [J], C = gamma M + sum_s (kd u u^T + c I) (air drag, spring damping and the
viscous dashpots of the mesh edges, u frozen per Newton iteration), F_ext the wind and body repulsion at the
iterate. Its gradient is M (v - v0) - h f(x0 + h v, v) with f the engine's total force, so IP is stationary
exactly at the backward-Euler step. Newton iteration k, from v_k (x_k = x0 + h v_k):

    A dv = b,  A = M (1 + h gamma) + h D + h^2 K(x_k),  b = h f(x_k, v_k) - M (v_k - v0)

except the first (v_0 = v0), which linearises f(x0 + h v0) about x0: A = A(x0), b = h (f0 - h K(x0) v0), the
classical one-solve step of Baraff and Witkin (equal to Newton's first iteration from v = 0);

with K and D the spring stiffness and damping Jacobians. The system, its constraint filter, the preconditioned CG
and its preconditioners are taichi_cloth.linear's (linear.system writes the spring blocks, linear.policy picks the
preconditioner of option `preconditioner`: auto | jacobi | multigrid). Then a line search: IP at v_k + alpha dv
for alpha = 1, 1/2, 1/4, 1/8 in one kernel, the largest alpha with IP(v_k + alpha dv) <= IP(v_k) + 1e-4 alpha
grad.dv is taken (on the device: no host read-back). One Newton iteration with alpha = 1 is the classical
one-solve-per-step implicit Euler; the line search is what keeps large steps from gaining energy (one linearised solve overshoots a spring
that rotates, and at 1/30 s a sheet dropped on a ball gained 4 x its weight x size of energy).

Pinned particles are filtered out of the solve (BW98 section 5.3, S_i = 0), and a particle in contact with a
collider in the last step has its normal component filtered (S_i = I - n n^T: its normal velocity does not
change in the solve, the collider handles it). A contact the force pulls off the body is released (nothing
filtered), for leaving only: the line search removes from every candidate the velocity into the body it would give
such a particle, and a particle it had to correct is held (filtered) in any further Newton iteration (an active set).
Friction at a contact is in the solve too: a sticking particle is held (S_i = 0), a sliding one carries a dashpot of
the force mu lambda at its speed, and one in a crease of the body (its contact alternating between two faces) is held
against both faces' normals (_contact_friction).
"""

import taichi as ti

from clothbase.errors import warn
from clothbase.fields import FieldBlock
from clothbase.ordered_sum import OrderedSums

from ..linear import PCG, PRECONDITIONERS, BlockSystem, ConstraintFilter, PreconditionerPolicy
from ..runtime import PARALLEL_FROM_CPU_SOLVE, next_plan, one_thread_loops
from .base import Integrator, Option, at_least_one, one_of, positive

#: the slots of Implicit.tally (Implicit.TALLY names them)
_CG, _UNCONVERGED, _NEWTON, _CUTS, _RESIDUAL, _CAPPED_RISE, _CAPPED_RESIDUAL, _NONFINITE, _LARGEST, _SHORT = range(10)


@ti.data_oriented
class Implicit(Integrator):
    name = "implicit"
    unconditionally_stable = True
    parallel_from_cpu = PARALLEL_FROM_CPU_SOLVE  # a solve's many short loops gain little from threads
    OPTIONS = {
        "cg_tolerance": Option(float, 1e-3, "relative CG residual (preconditioned norm) to stop at", positive),
        "cg_max_iterations": Option(int, 200, "CG iteration cap per step, shared by its Newton iterations",
                                    at_least_one),
        "preconditioner": Option(str, "auto", "jacobi | multigrid (V-cycles over the cloth's 4-8 levels, or over "
                                 "aggregates of its particles with their rotations: a garment) | auto (multigrid on "
                                 "4-8 levels, aggregation from 2,000 particles)",
                                 one_of(PRECONDITIONERS)),
        "newton_iterations": Option(int, 4, "the most Newton iterations per step (each one CG solve and a line "
                                    "search); the first is enough when the step does not gain energy, unless "
                                    "newton_converge", at_least_one),
        "newton_tolerance": Option(float, 1e-2, "or stop when the Newton decrement (-grad.dv [J]) falls below this "
                                   "fraction of the first one's", positive),
        "newton_converge": Option(bool, False, "iterate every step to newton_tolerance, not only the steps that "
                                  "would gain energy: a fine garment comes to rest sooner, at 2-4 times the cost per "
                                  "step (docs/garments.md, resolution)"),
        "line_search": Option(bool, True, "halve the Newton step (down to 1/8) until the incremental potential "
                              "decreases: large steps do not gain energy"),
        "warm_start": Option(bool, True, "Jacobi-preconditioned CG starts from the last step's velocity change "
                             "(fewer iterations, a closer trajectory in free motion, and small steady forces such as a "
                             "closing seam's add up over the steps; off where a drape keeps fluttering at rest: at a "
                             "loose tolerance it can carry a flutter from step to step)"),
    }
    #: [m/s] a contact slower than this with its force within the friction cone sticks (_contact_friction); the
    #: sliding friction's dashpot is mu lambda / eps at most. A tenth of the rest criterion's p99 speed
    STICK_SPEED = 1e-4
    #: [-] cosine of the angle (10 degrees) by which a particle's contact normal must differ from its last step's for
    #: the two to make a crease (_contact_friction)
    CREASE_COS = 0.985
    #: the step lengths the line search tries, longest first, and the sufficient decrease it asks for
    ALPHAS = (1.0, 0.5, 0.25, 0.125)
    #: the terms a particle or a spring adds to the step's sums: IP(alpha = 0), IP(ALPHAS...), grad.dv, then
    #: E(alpha = 0), E(ALPHAS...), E at the start, then the external work (see _add_terms)
    TERMS = 2 * (len(ALPHAS) + 2) + 1
    ARMIJO = 1e-4
    #: the device tally's slots: the four counters `stats` reports, the last step's relative residual, the largest
    #: energy rise [J] of a step that spent its CG budget and that step's residual, the solves that gave a
    #: non-finite value, and since the last report (planned CG) the most iterations of one solve and the solves
    #: that the plan stopped short
    TALLY = ("cg_iterations", "cg_unconverged_steps", "newton_iterations", "line_search_cuts", "last_residual",
             "capped_rise", "capped_residual", "nonfinite_solves", "largest_solve", "short_solves")

    def __init__(self, model, state, forces, **options):
        super().__init__(model, state, forces, **options)
        fp, P = model.fp, model.capacity[0]
        self.system = BlockSystem(model, state.x)     # A of the Newton iteration
        self.filter = ConstraintFilter(model, self.contacts)
        self.pcg = PCG(model)
        self.policy = PreconditionerPolicy(self.options["preconditioner"], model)
        self.b, self.dv = self.pcg.b, self.pcg.x      # the Newton system's right-hand side [kg m/s], its dv [m/s]
        blk = FieldBlock()
        self.x0, self.v0 = blk.vector(3, fp, P), blk.vector(3, fp, P)  # the step's start [m], [m/s]
        self.dv_total = blk.vector(3, fp, P)          # v_k - v0 [m/s] (after the step: its whole velocity change)
        self.warm = blk.scalar(ti.i32, ())            # 1: start CG from the last step's dv_total (Jacobi only)
        self.ip = blk.scalar(ti.f64, len(self.ALPHAS) + 2)  # IP(alpha = 0), IP(ALPHAS...), grad.dv [J]
        self.energy = blk.scalar(ti.f64, len(self.ALPHAS) + 2)  # E(alpha = 0), E(ALPHAS...), E at the start [J]
        self.work = blk.scalar(ti.f64, ())            # the external forces' work over the step [J]
        self.cut = blk.scalar(ti.i32, ())             # line-search cuts in this step
        #: the step's Newton decisions, on the device: the first decrement [J], the last rise [J] and residual, and
        #: whether a solve stopped short of the tolerance
        self.newton = blk.scalar(ti.f64, 4)
        #: the counters of every step so far, kept on the device and read when `stats` is asked for (TALLY order)
        self.tally = blk.scalar(ti.f64, len(self.TALLY))
        blk.finalize(self)
        #: the terms of IP, E and the work (TERMS) of every particle or spring, added in a fixed order where the
        #: loops run in parallel (clothbase.ordered_sum); in one thread they are added in item order as they come
        self.sums = None if model.serial else OrderedSums(self.TERMS, max(P, model.capacity[1]))
        #: where no loop may run in one thread (a GPU), CG launches a planned number of iterations and the host reads
        #: nothing: the plan follows the largest solve of the last frame, read with its measurement (report)
        self.planned_cg = not one_thread_loops()
        self._plan = self.options["cg_max_iterations"]
        self._warned_cap = False
        self._warned_nan = False
        # Jacobi-PCG starts from the previous step's dv: it carries over the smooth part Jacobi is slow to find;
        # multigrid finds it itself and starts from 0. On a drape at rest the carried-over dv can keep a flutter
        # alive that the tolerance, relative to a small b, accepts every step; the other way round it carries small
        # steady forces (a closing seam's) that one cold solve drops. Figures: docs/performance.md, preconditioners.
        self.warm[None] = int(self.options["warm_start"])
        self.reset()

    def reset(self) -> None:
        """Forget the previous step's velocity change (the warm start)."""
        self.dv.fill(0)
        self.dv_total.fill(0)

    @property
    def stats(self) -> dict[str, float]:
        """The cumulative counters (CG and Newton iterations, unconverged steps, line-search cuts): one read of the
        device tally. Says once, as a warning, when a step spent its CG budget and gained energy, or a solve gave a
        non-finite value, since the last read."""
        t = dict(zip(self.TALLY, (float(v) for v in self.tally.to_numpy())))
        if t["capped_rise"] > 0 and not self._warned_cap:
            self._warned_cap = True  # backward Euler only dissipates: say it once when the cap let a step gain energy
            warn(f"implicit: CG stopped at its cap of {self.options['cg_max_iterations']} iterations (relative "
                 f"residual {t['capped_residual']:.2g}) and the step gained {t['capped_rise']:.3g} J; raise "
                 "cg_max_iterations" + (' or set preconditioner = "multigrid"'
                                        if self.policy.current is self.policy.jacobi else ""))
        if t["nonfinite_solves"] > 0 and not self._warned_nan:
            self._warned_nan = True
            warn(f"implicit: the CG solve gave a non-finite value with {self.policy.detail}; the step took no "
                 "implicit correction")
        return {k: t[k] for k in self.TALLY[:4]}

    @stats.setter
    def stats(self, values: dict[str, float]) -> None:
        if values:  # (the base class's empty dict at construction: the tally is not built yet)
            for k, v in values.items():
                self.tally[self.TALLY.index(k)] = v

    @property
    def last_residual(self) -> float:
        """sqrt(r.Pr / b.Pb) at the end of the last step (inf after a non-finite solve); one device read."""
        return float(self.tally[self.TALLY.index("last_residual")])

    # ------------------------------------------------------------------ the CG plan (no loop in one thread)
    @property
    def report_slots(self) -> int:
        """Planned CG reports its largest solve and its short solves with every measurement (Controller protocol)."""
        return 2 if self.planned_cg else 0

    @ti.kernel
    def report(self, out: ti.template(), offset: ti.i32):
        out[offset] = self.tally[_LARGEST]
        out[offset + 1] = self.tally[_SHORT]
        self.tally[_LARGEST] = 0.0
        self.tally[_SHORT] = 0.0

    def reported(self, values) -> None:
        """The next solves' plan (runtime.next_plan; iterations past convergence are no-ops, but a multigrid's cycle
        still runs in them)."""
        self._plan = next_plan(self._plan, int(values[0]), int(values[1]), self.pcg.CHUNK,
                               self.options["cg_max_iterations"])

    # ------------------------------------------------------------------ the preconditioner
    @property
    def needs_levels(self) -> bool:
        """Whether this integrator wants the cloth's 4-8 levels (attach_levels) when it has nested ones."""
        return self.options["preconditioner"] != "jacobi"

    def attach_levels(self, nested, why: str | None, garment: bool = False) -> str | None:
        """The cloth's nested 4-8 levels (linear.NestedLevels; None, and why, where it has none) and whether it is a
        garment: the preconditioner policy picks what CG uses (linear.policy). Returns a note for the run when it
        cannot honour the option."""
        note = self.policy.attach(nested, why, garment)
        self.warm[None] = int(self.options["warm_start"] and self.policy.current.warm_start)
        return note

    def topology_changed(self, level: int | None = None) -> None:
        """A refill of the model: on the 4-8 level `level` (a level switch, a garment's seams merged on its start
        level), or with no level named: on the level it was on when its particle count is that level's (new spring
        constants), else off the levels again (a garment's pieces apart after a reset)."""
        self.reset()
        self.policy.topology_changed(level)
        self.warm[None] = int(self.options["warm_start"] and self.policy.current.warm_start)

    @property
    def detail(self) -> str:
        return self.policy.detail

    # ------------------------------------------------------------------ the step
    def _advance(self, dt: float) -> None:
        """The step's Newton iterations, decided on the device: each launches its kernels, and once an iteration
        decided that the step is done (the line search's end) the later ones loop over nothing (system.live 0).
        Where CG reads the device anyway (its parallel chunks on the CPU), the host reads that decision too and
        stops launching."""
        o = self.options
        self.system.set_step(dt, self.forces.air_damping_value)
        if self.has_contacts:
            self._contact_friction(dt)  # before the step's start is kept: it changes velocities
        self._begin()
        n = o["newton_iterations"]
        for k in range(n):
            self._assemble(dt, self.system.h_gamma, int(k == 0))
            preconditioner = self.policy.current
            preconditioner.prepare(self.system, self.filter)
            self.pcg.solve(self.system, self.filter, preconditioner, o["cg_tolerance"], o["cg_max_iterations"],
                           self._plan if self.planned_cg else None)
            self._line_search(dt, int(o["line_search"]), k, n, o["cg_max_iterations"], o["cg_tolerance"],
                              o["newton_tolerance"], int(o["newton_converge"]))
            in_thread = self.model.serial and (preconditioner.inline or preconditioner.in_thread)
            if not (in_thread or self.planned_cg) and k + 1 < n and self.system.live[None] == 0:
                break
        self._finish(dt, o["cg_max_iterations"])

    @ti.kernel
    def _contact_friction(self, dt: ti.f64):
        """Coulomb friction at the contacts of the last step, decided before the solve (Baraff and Witkin 1998,
        section 5: the constraint decides what the solve may change). For a particle with a contact normal n and the
        force f on it now (springs, gravity, drag, sources), lambda = -f.n presses it on the body:
          * lambda <= 0 and not moving in: released (no constraint this step);
          * else its normal velocity is removed (it rests on the body; the filter keeps it so in the solve), and
            - slower than eps = STICK_SPEED with the tangential force within the cone (|f_t| <= mu lambda): it
              sticks, held where it is (every direction filtered, v = 0);
            - else it slides, and friction enters the solve as the lagged dissipation of Li et al. 2020 (IPC,
              section 5) with lambda and a speed s frozen over the step: a dashpot c = mu lambda / max(s, eps) on
              the velocity relative to the surface, a force mu lambda against the motion at the speed s, the larger
              of |v_t| at the step's start and |v_t + h f_t / m| - h mu lambda / m (its speed at the end of a step
              under Coulomb friction alone: a sheet sliding down a slope then has the Coulomb acceleration to 1 %,
              tests/test_friction.py). It is in A's diagonal (BlockSystem.extra_mass = h c), in b and in the
              incremental potential (1/2 h c |v - w|^2) the line search weighs: the solve sees what friction takes
              in the step, and friction only dissipates.
        Applied after the solve instead, as a velocity cut at the next step's start, the solve moved a sliding
        particle by its whole force in every step: a skirt on a loose waistband crept down the body at 0.5 mm/s
        in stick-slip bursts for 10 s (docs/garments.md). In a crease (below) the particle is held against a second
        normal too, and lambda is the force of both faces. Velocities are relative to the contact's surface
        (Contacts.velocity: a moving collider's). The velocities change in a second pass, after every force was
        read at the old ones."""
        m, s, c = self.model, self.state, self.contacts
        h = ti.cast(dt, m.fp)
        eps = ti.static(self.STICK_SPEED)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            n = c.normal[i]
            w = c.velocity[i]  # the surface's: friction and resting act on the velocity relative to it
            v = s.v[i] - w
            released = 0
            stuck = 0
            drag = ti.cast(0.0, m.fp)
            crease = ti.Vector.zero(m.fp, 3)
            if m.inv_mass[i] != 0 and n.dot(n) > 0:
                n = n.normalized()
                f = self.forces.particle_force(i, True)
                fn = -f.dot(n)
                vn = v.dot(n)
                if fn <= 0 and vn >= 0:
                    # pulled away: free this step. Its normal stays for the stretch limit, which treats a particle
                    # on the body as fixed; zeroed, the limit moved it as a free particle every other step (a skirt's
                    # waist particle went 0.7 mm up and back at 85 mm/s for good)
                    released = 1
                else:
                    # resting on the body: no normal velocity. An approaching one is removed; so is a leaving one, which
                    # the filter would otherwise keep against the force that presses (the T-shirt at rest gained
                    # 3e-5 J a step that way), and which freed would fall back and be pushed out every step
                    v -= vn * n
                    ft = f + fn * n
                    press = fn
                    # a crease (under the arm, between the legs): held against its one normal n, the solve moved the
                    # particle along n's plane into the next face, the collider pushed it out along that face's
                    # normal, and the next step the other way: a 2-cycle of 0.1 mm at 20-30 mm/s under the arm of a
                    # top that kept it from resting. Where the contact alternates between two faces (the normal two
                    # steps ago is n's face, the last step's another's, p), the particle touches both: held against
                    # both while the force or the motion presses it into p, it slides along the crease's line, and
                    # stays in the crease while its contact is either face. (A particle sliding over the body meets
                    # one face after another and never comes back: no crease.)
                    if c.before[i] != 0 and c.friction_scale[None] > 0:
                        p = c.previous[i]
                        held = c.crease[i]
                        crease_now = 0
                        same = p.dot(p) > 0 and p.normalized().dot(n) >= ti.static(self.CREASE_COS)
                        if held.dot(held) > 0:  # in a crease the last step, between p and held
                            if same:
                                p = held
                                crease_now = 1
                            elif held.normalized().dot(n) >= ti.static(self.CREASE_COS):
                                crease_now = 1
                        elif p.dot(p) > 0 and not same:
                            p2 = c.previous2[i]
                            crease_now = ti.select(p2.dot(p2) > 0 and p2.normalized().dot(n) >= ti.static(
                                self.CREASE_COS), 1, 0)
                        if crease_now != 0:
                            p = p.normalized()
                            if -0.5 < p.dot(n) < ti.static(self.CREASE_COS):  # facing faces: a thin part, no crease
                                q = (p - p.dot(n) * n).normalized()
                                fq = -ft.dot(q)
                                vq = v.dot(q)
                                if fq > 0 or vq < 0:
                                    crease = p
                                    v -= vq * q
                                    ft += fq * q
                                    press = ti.sqrt(ti.max(fn, 0.0) ** 2 + fq ** 2)
                    slide = v.norm()
                    mu = c.friction[i] * c.friction_scale[None]
                    if slide < eps and ft.norm() <= mu * press:
                        stuck = 1
                        v = ti.Vector.zero(m.fp, 3)
                    else:
                        # the dashpot's force is mu lambda at the larger of the speed at the start and at the end of
                        # a step under Coulomb friction alone: at the start's alone, a sheet starting to slide down a
                        # slope was held 10-40 % more; at the end's alone, a particle its neighbours hold back
                        # stopped, and with it the sheet
                        press = ti.max(press, 0.0)
                        end = (v + h * m.inv_mass[i] * ft).norm() - h * m.inv_mass[i] * mu * press
                        drag = h * mu * press / ti.max(ti.max(end, slide), eps)
            self.pcg.q[i] = w + v  # scratch: the new velocity
            c.released[i] = released
            c.stuck[i] = stuck
            c.crease[i] = crease
            self.system.extra_mass[i] = drag
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            s.v[i] = self.pcg.q[i]

    @ti.kernel
    def _begin(self):
        """Keep the step's start (x0, v0) and its energy; the last step's velocity change stays in dv_total for the
        warm start."""
        m, s = self.model, self.state
        NA = ti.static(len(self.ALPHAS))
        E = ti.static(NA + 2)  # where the energies start among the terms
        self.cut[None] = 0
        self.energy[NA + 1] = 0.0
        self.system.live[None] = 1
        self.pcg.spent[None] = 0
        for j in ti.static(range(4)):
            self.newton[j] = 0.0
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            self.x0[i] = s.x[i]
            self.v0[i] = s.v[i]
            terms = ti.Vector.zero(ti.f64, self.TERMS)
            if m.inv_mass[i] != 0:
                grav = ti.cast(self.forces.gravity[None], ti.f64)  # in the loop: see _line_search
                mass, v, x = ti.cast(m.mass[i], ti.f64), ti.cast(s.v[i], ti.f64), ti.cast(s.x[i], ti.f64)
                terms[E + NA + 1] = 0.5 * mass * v.dot(v) - mass * grav.dot(x)
            self._add_terms(i, terms, E + NA + 1, E + NA + 2)
        self._close_terms(m.n_particles[None])
        ti.loop_config(serialize=self.model.serial)
        for sp in range(m.n_springs[None]):
            terms = ti.Vector.zero(ti.f64, self.TERMS)
            stretch = ti.cast((s.x[m.spring_b[sp]] - s.x[m.spring_a[sp]]).norm() - m.rest_length[sp], ti.f64)
            terms[E + NA + 1] = 0.5 * ti.cast(m.stiffness[sp], ti.f64) * stretch * stretch
            self._add_terms(sp, terms, E + NA + 1, E + NA + 2)
        self._close_terms(m.n_springs[None])

    @ti.func
    def _add_terms(self, item, terms, lo: ti.template(), hi: ti.template()):
        """A particle's or a spring's terms (a TERMS-vector of float64, zero outside lo <= k < hi) into the step's
        sums: IP (ip), E (energy) and the work. In one thread at once, in item order; else kept for _close_terms,
        which adds every item's in a fixed order (float atomics would add them in the threads' order)."""
        if ti.static(self.model.serial):
            self._add_to_sums(terms, lo, hi)
        else:
            self.sums.put(item, terms)

    @ti.func
    def _close_terms(self, n):
        """Where the loops run in parallel, the terms of items 0..n-1 kept by _add_terms, summed in a fixed order,
        into ip, energy and the work (at a kernel's top level, after the loop that kept them)."""
        if ti.static(not self.model.serial):
            self._add_to_sums(self.sums.total(n), 0, self.TERMS)

    @ti.func
    def _add_to_sums(self, terms, lo: ti.template(), hi: ti.template()):
        """ip, energy and the work += the entries lo <= k < hi of `terms` (TERMS,) in that layout."""
        for k in ti.static(range(lo, hi)):
            if ti.static(k < self.TERMS // 2):
                self.ip[k] += terms[k]
            elif ti.static(k < self.TERMS - 1):
                self.energy[k - self.TERMS // 2] += terms[k]
            else:
                self.work[None] += terms[k]

    @ti.kernel
    def _assemble(self, dt: ti.f64, h_gamma: ti.f64, first: ti.i32):
        """The Newton system at v_k = v0 + dv_total (x_k = x0 + h v_k, written into the state so that the force
        code evaluates there): the system's spring blocks, b = S (h f(x_k, v_k) - M dv_total), and CG's start (the
        last step's velocity change on the first iteration where the preconditioner allows it, else 0). The first
        iteration linearises f(x0 + h v0) about x0 instead (x_0 = x0, b = S h (f0 + h (df/dx) v0)): the classical
        one-solve step of Baraff and Witkin, which is Newton's first iteration from v = 0, not from v0. Started
        from the predicted x0 + h v0, a sheet at 1/120 s slid off the mannequin's head where runs at a tenth of
        the step stay on it."""
        m, s, fm, sy = self.model, self.state, self.forces, self.system
        h = ti.cast(dt, m.fp)
        sy.mass_scale[None] = 1.0 + ti.cast(h_gamma, m.fp)
        ti.loop_config(serialize=self.model.serial)
        for i in range(sy.gated(m.n_particles[None])):
            guess = ti.Vector.zero(m.fp, 3)
            if first != 0:  # the velocity change of the last step, the first iteration's initial guess
                guess = self.dv_total[i]
                self.dv_total[i] = ti.Vector.zero(m.fp, 3)
            if m.inv_mass[i] != 0:
                v = self.v0[i] + self.dv_total[i]
                s.v[i] = v
                s.x[i] = self.x0[i] + h * v * ti.cast(1 - first, m.fp)
                self.dv[i] = self.filter.apply(i, guess) * ti.cast(self.warm[None] * first, m.fp)
            else:
                self.dv[i] = ti.Vector.zero(m.fp, 3)
        ti.loop_config(serialize=self.model.serial)
        for sp in range(sy.gated(m.n_springs[None])):
            sy.set_spring(sp, s.x[m.spring_b[sp]] - s.x[m.spring_a[sp]], h)
        ti.loop_config(serialize=self.model.serial)
        for i in range(sy.gated(m.n_particles[None])):
            b = ti.Vector.zero(m.fp, 3)
            if m.inv_mass[i] != 0:
                kv = ti.Vector.zero(m.fp, 3)  # h^2 K v0 on the first iteration (K = -df/dx)
                if first != 0:
                    for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                        sp = m.adj_spring[e]
                        u = sy.u[sp]
                        dvel = s.v[i] - s.v[m.adj_other[e]]
                        kv += (sy.axial[sp] - h * m.damping[sp]) * u.dot(dvel) * u \
                            + (sy.iso[sp] - h * m.viscous[sp]) * dvel
                if ti.static(self.has_contacts):  # the friction's lagged dashpot (_contact_friction)
                    kv += sy.extra_mass[i] * (s.v[i] - self.contacts.velocity[i])
                b = self.filter.apply(i, h * fm.particle_force(i, True) - kv - m.mass[i] * self.dv_total[i])
            self.b[i] = b

    @ti.func
    def _admissible(self, i, v):
        """Particle i's velocity v [m/s] as float64, less any part into the body where its contact was released
        at the step's start: the release holds for leaving only. The line search projects every candidate it
        weighs, and the step it takes (a projected line search). Without it the solve moved such a particle in at
        up to 0.35 m/s, pulled by its neighbours; the collider pushed it back out and the next step released it
        again, in a cycle of three steps that kept a 1 cm T-shirt from resting."""
        out = ti.cast(v, ti.f64)
        if ti.static(self.has_contacts):
            n = self.contacts.normal[i]
            if self.contacts.released[i] != 0 and n.dot(n) > 0:
                unit = ti.cast(n.normalized(), ti.f64)
                out -= ti.min(out.dot(unit), 0.0) * unit
        return out

    @ti.func
    def _particle_potential(self, i, hh, gamma, ext, terms: ti.template(), j0: ti.template(), j1: ti.template()):
        """Adds particle i's inertia, gravity, air drag and external-force terms of IP, and its kinetic and gravity
        energy, for the candidates j0 <= j < j1 (j = 0: alpha = 0, j: ALPHAS[j - 1]), to `terms` (TERMS,)."""
        m = self.model
        A = ti.static(self.ALPHAS)
        grav = ti.cast(self.forces.gravity[None], ti.f64)
        mass = ti.cast(m.mass[i], ti.f64)
        d = ti.cast(self.dv[i], ti.f64)
        base = ti.cast(self.dv_total[i], ti.f64)
        v0 = ti.cast(self.v0[i], ti.f64)
        x0 = ti.cast(self.x0[i], ti.f64)
        for j in ti.static(range(j0, j1)):
            a = 0.0 if j == 0 else A[j - 1]
            v = self._admissible(i, v0 + base + a * d)
            dvt = v - v0
            x = x0 + hh * v
            terms[j] = 0.5 * mass * dvt.dot(dvt) - mass * grav.dot(x) + 0.5 * hh * gamma * mass * v.dot(v) \
                - hh * ext.dot(a * d)
            if ti.static(self.has_contacts):  # the friction's dissipation (_contact_friction)
                slip = v - ti.cast(self.contacts.velocity[i], ti.f64)
                terms[j] += 0.5 * ti.cast(self.system.extra_mass[i], ti.f64) * slip.dot(slip)
            terms[self.TERMS // 2 + j] = 0.5 * mass * v.dot(v) - mass * grav.dot(x)

    @ti.func
    def _spring_potential(self, sp, hh, terms: ti.template(), j0: ti.template(), j1: ti.template()):
        """Adds spring sp's elastic and damping terms of IP, and its elastic energy, for the candidates j0 <= j < j1,
        to `terms` (TERMS,)."""
        m = self.model
        A = ti.static(self.ALPHAS)
        ia, ib = m.spring_a[sp], m.spring_b[sp]
        k = ti.cast(m.stiffness[sp], ti.f64)
        kd = ti.cast(m.damping[sp], ti.f64)
        c = ti.cast(m.viscous[sp], ti.f64)
        L0 = ti.cast(m.rest_length[sp], ti.f64)
        u = ti.cast(self.system.u[sp], ti.f64)
        wa = ti.cast(m.inv_mass[ia] != 0, ti.f64)
        wb = ti.cast(m.inv_mass[ib] != 0, ti.f64)
        for j in ti.static(range(j0, j1)):
            a = 0.0 if j == 0 else A[j - 1]
            va = self._admissible(ia, ti.cast(self.v0[ia], ti.f64) + wa * ti.cast(self.dv_total[ia] + a * self.dv[ia],
                                                                                 ti.f64))
            vb = self._admissible(ib, ti.cast(self.v0[ib], ti.f64) + wb * ti.cast(self.dv_total[ib] + a * self.dv[ib],
                                                                                 ti.f64))
            xa = ti.cast(self.x0[ia], ti.f64) + wa * hh * va
            xb = ti.cast(self.x0[ib], ti.f64) + wb * hh * vb
            stretch = (xb - xa).norm() - L0
            dvel = vb - va
            rel = dvel.dot(u)
            terms[j] = 0.5 * k * stretch * stretch + 0.5 * hh * (kd * rel * rel + c * dvel.dot(dvel))
            terms[self.TERMS // 2 + j] = 0.5 * k * stretch * stretch

    @ti.kernel
    def _line_search(self, dt: ti.f64, search: ti.i32, k: ti.i32, newton_iterations: ti.i32, budget: ti.i32,
                     cg_tolerance: ti.f64, newton_tolerance: ti.f64, converge: ti.i32):
        """dv_total += alpha dv, with alpha the longest of ALPHAS whose incremental potential IP satisfies the
        sufficient decrease (1 without the search; 1/8 when none does). The full step is evaluated first, the shorter
        ones only when it fails (in the same launch). IP and the total energy E (kinetic + spring + gravity) of every
        candidate are summed in float64 over the free particles and every spring, with the state still at the
        iterate (its spring directions, its external forces), each candidate projected (_admissible). Then
        Newton iteration k (of newton_iterations) decides whether the step goes on (system.live): not when the
        iterate has not gained energy on the step's start (backward Euler only dissipates; a global test, blind to
        one particle speeding up: hence `converge`, which iterates to newton_tolerance), when the Newton decrement
        fell below newton_tolerance of the first one, when the step's `budget` of CG iterations is spent, or at the
        last iteration. A no-op once the step is done."""
        m, s, fm = self.model, self.state, self.forces
        A = ti.static(self.ALPHAS)
        NA = ti.static(len(self.ALPHAS))
        hh = ti.cast(dt, ti.f64)
        gamma = ti.cast(fm.air_damping[None], ti.f64)
        # gravity is read inside the loops (_particle_potential): a float64 vector kept at kernel scope and read in
        # a loop that also sums float64 faults on CUDA (misaligned address, Taichi 1.7.4)
        for j in ti.static(range(NA + 2)):
            self.ip[j] = 0.0
        for j in ti.static(range(NA + 1)):
            self.energy[j] = 0.0
        self.work[None] = 0.0
        E = ti.static(NA + 2)  # where the energies start among the terms
        # first the full step (j = 1, against j = 0); the shorter ones only where it does not decrease enough
        ti.loop_config(serialize=self.model.serial)
        for i in range(self.system.gated(m.n_particles[None])):
            terms = ti.Vector.zero(ti.f64, self.TERMS)
            if m.inv_mass[i] != 0:
                ext = ti.cast(fm.source_force(i, s.x[i], s.v[i]), ti.f64)
                d = ti.cast(self.dv[i], ti.f64)
                terms[NA + 1] = -ti.cast(self.b[i], ti.f64).dot(d)  # grad . dv (b = -S grad)
                terms[self.TERMS - 1] = hh * ext.dot(ti.cast(self.v0[i] + self.dv_total[i], ti.f64) + d)
                self._particle_potential(i, hh, gamma, ext, terms, 0, 2)
            self._add_terms(i, terms, 0, 2)
            self._add_terms(i, terms, NA + 1, NA + 2)
            self._add_terms(i, terms, E, E + 2)
            self._add_terms(i, terms, self.TERMS - 1, self.TERMS)
        self._close_terms(self.system.gated(m.n_particles[None]))
        ti.loop_config(serialize=self.model.serial)
        for sp in range(self.system.gated(m.n_springs[None])):
            terms = ti.Vector.zero(ti.f64, self.TERMS)
            self._spring_potential(sp, hh, terms, 0, 2)
            self._add_terms(sp, terms, 0, 2)
            self._add_terms(sp, terms, E, E + 2)
        self._close_terms(self.system.gated(m.n_springs[None]))
        full = self.ip[1] <= self.ip[0] + self.ARMIJO * self.ip[NA + 1]
        shorter = ti.cast(search != 0, ti.i32) * (1 - ti.cast(full, ti.i32))
        ti.loop_config(serialize=self.model.serial)
        for i in range(self.system.gated(m.n_particles[None]) * shorter):
            terms = ti.Vector.zero(ti.f64, self.TERMS)
            if m.inv_mass[i] != 0:
                ext = ti.cast(fm.source_force(i, s.x[i], s.v[i]), ti.f64)
                self._particle_potential(i, hh, gamma, ext, terms, 2, NA + 1)
            self._add_terms(i, terms, 2, NA + 1)
            self._add_terms(i, terms, E + 2, E + NA + 1)
        self._close_terms(self.system.gated(m.n_particles[None]) * shorter)
        ti.loop_config(serialize=self.model.serial)
        for sp in range(self.system.gated(m.n_springs[None]) * shorter):
            terms = ti.Vector.zero(ti.f64, self.TERMS)
            self._spring_potential(sp, hh, terms, 2, NA + 1)
            self._add_terms(sp, terms, 2, NA + 1)
            self._add_terms(sp, terms, E + 2, E + NA + 1)
        self._close_terms(self.system.gated(m.n_springs[None]) * shorter)
        alpha = ti.cast(A[NA - 1], ti.f64)  # the shortest, when none decreases enough
        energy = self.energy[NA]
        for jj in ti.static(range(NA)):
            j = ti.static(NA - 1 - jj)  # shortest first, so that the longest that decreases enough wins
            ok = self.ip[j + 1] <= self.ip[0] + self.ARMIJO * A[j] * self.ip[NA + 1]
            alpha = ti.select(ok, A[j], alpha)
            energy = ti.select(ok, self.energy[j + 1], energy)
        if search == 0 or full:
            alpha = 1.0
            energy = self.energy[1]
        if alpha < 1.0 and self.system.live[None] != 0:
            self.cut[None] += 1
        decrement = -self.ip[NA + 1]  # the Newton decrement dv^T A dv [J]
        # the rise of the total energy above the step's start, beyond the external forces' work and round-off (E is
        # summed in float64 from the state's float32 or float64 positions and velocities: round-off of a few 1e-7 of
        # E in float32, which must not count as a gain that calls for another Newton iteration)
        start = self.energy[NA + 1]
        roundoff = ti.static(1e-6 if self.model.fp == ti.f32 else 1e-12)
        rise = energy - start - ti.max(self.work[None], 0.0) - roundoff * ti.abs(start)
        ti.loop_config(serialize=self.model.serial)
        for i in range(self.system.gated(m.n_particles[None])):
            if m.inv_mass[i] != 0:
                v0 = self.v0[i]
                step = v0 + self.dv_total[i] + ti.cast(alpha, m.fp) * self.dv[i]
                v = self._admissible(i, step)
                self.dv_total[i] = ti.cast(v, m.fp) - v0
                if ti.static(self.has_contacts):
                    if (v - ti.cast(step, ti.f64)).norm_sqr() > 0:
                        # held from here on: a further Newton iteration filters its normal (an active set), else
                        # it would ask for the same inward motion again and stall
                        self.contacts.released[i] = 0
        if self.system.live[None] != 0:
            self._decide(k, newton_iterations, budget, cg_tolerance, newton_tolerance, converge, decrement, rise)

    @ti.func
    def _decide(self, k, newton_iterations, budget, cg_tolerance, newton_tolerance, converge, decrement, rise):
        """The host's old per-iteration bookkeeping, on the device: CG's iterations and residual into the step's
        record and the tally, and whether another Newton iteration follows (see _line_search)."""
        cg = self.pcg
        cg.spent[None] += cg.iterations[None]
        self.tally[_LARGEST] = ti.max(self.tally[_LARGEST], ti.cast(cg.iterations[None], ti.f64))
        if cg.active[None] != 0:  # planned CG: stopped by the plan, short of its tolerance and its cap
            self.tally[_SHORT] += 1.0
        rz, rz_b = cg.rz[None], cg.rz_b[None]
        residual = ti.cast(0.0, ti.f64)
        if ti.math.isnan(rz) or ti.math.isinf(rz) or ti.math.isnan(rz_b) or ti.math.isinf(rz_b):
            residual = ti.math.inf  # a preconditioner that returned NaN: CG stopped at once, the step is explicit
            self.tally[_NONFINITE] += 1.0
        elif rz_b > 0:
            residual = ti.sqrt(ti.max(rz, 0.0) / rz_b)
        if residual > cg_tolerance:
            self.newton[3] = 1.0
        self.tally[_NEWTON] += 1.0
        if k == 0:
            self.newton[0] = decrement
        self.newton[1] = rise
        self.newton[2] = residual
        converged = decrement <= newton_tolerance * self.newton[0]
        if (rise <= 0.0 and converge == 0) or converged or cg.spent[None] >= budget or k + 1 >= newton_iterations:
            self.system.live[None] = 0

    @ti.kernel
    def _finish(self, dt: ti.f64, budget: ti.i32):
        """v = v0 + dv_total, x = x0 + h v (pinned particles keep their start; the pins place the moving ones); the
        step's record into the tally (a step that spent its `budget` of CG iterations and still gained energy is
        kept for the warning), and the system live again for whatever solves next."""
        m, s = self.model, self.state
        self.tally[_CG] += ti.cast(self.pcg.spent[None], ti.f64)
        self.tally[_UNCONVERGED] += self.newton[3]
        self.tally[_CUTS] += ti.cast(self.cut[None], ti.f64)
        self.tally[_RESIDUAL] = self.newton[2]
        if self.newton[1] > self.tally[_CAPPED_RISE] and self.pcg.spent[None] >= budget:
            self.tally[_CAPPED_RISE] = self.newton[1]
            self.tally[_CAPPED_RESIDUAL] = self.newton[2]
        self.system.live[None] = 1
        self.pcg.spent[None] = 0
        h = ti.cast(dt, m.fp)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            v = self.v0[i]
            x = self.x0[i]
            if m.inv_mass[i] != 0:
                v += self.dv_total[i]
                x += h * v
            s.v[i] = v
            s.x[i] = x
