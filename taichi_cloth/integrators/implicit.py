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

per spring (u = unit direction, l = length, L0 = rest length):
    K_s = k [ u u^T + max(0, 1 - L0/l) (I - u u^T) ]   (stiffness; the clamp keeps A SPD, Choi and Ko 2002)
    D_s = kd u u^T + c I                               (spring damping, viscous dashpot)
so (A q)_i = m_i (1 + h gamma) q_i + sum_s [ (h kd + h^2 k (1-g)) u (u.dq) + (h^2 k g + h c) dq ], dq = q_i - q_j,
evaluated matrix-free with a per-particle gather. Then a line search: IP at v_k + alpha dv for alpha = 1, 1/2, 1/4,
1/8 in one kernel, the largest alpha with IP(v_k + alpha dv) <= IP(v_k) + 1e-4 alpha grad.dv is taken (on the
device: no host read-back). One Newton iteration with alpha = 1 is the classical one-solve-per-step implicit
Euler; the line search is what keeps large steps from gaining energy (one linearised solve overshoots a spring
that rotates, and at 1/30 s a sheet dropped on a ball gained 4 x its weight x size of energy).

Pinned particles are filtered out of the solve (BW98 section 5.3, S_i = 0), and a particle in contact with a
collider in the last step has its normal component filtered (S_i = I - n n^T: its normal velocity does not
change in the solve, the collider handles it).

Preconditioners (option `preconditioner`):
  jacobi     the 3x3 diagonal blocks of S A S + M'(I - S) (block Jacobi), inline in the CG kernels, CHUNK
             iterations per launch; CG starts from the last step's velocity change;
  multigrid  a V(1,1) cycle per CG iteration, applied as z = S V(S r), which keeps the preconditioner symmetric on
             the free subspace: over the cloth's nested 4-8 levels where it has them (multilevel.spring_multigrid:
             the same system rediscretised on every level; a garment's levels once its seams are merged, the ones
             its refiner switches between), else over levels made by aggregating neighbouring
             particles (multilevel.aggregation: Galerkin coarse operators of the filtered system; any cloth, a
             sewn garment or a mesh file);
  auto       (the default) multigrid over 4-8 levels where the cloth has them (not a garment's: GARMENT_LEVELS),
             over aggregates on a cloth of at least AGGREGATION_FROM particles, else jacobi. The run summary names
             the one used.
CG stops when sqrt(r.z / b.z_b) <= cg_tolerance (z = the preconditioned residual: D^-1 r, or the V-cycle's; z_b the
preconditioned b, so that a warm start that begins close stops early) or after cg_max_iterations. (A test on |r|
alone stopped multigrid-CG at bad points: twice the error at a tolerance of 0.1.)
"""

import math

import taichi as ti

from clothbase.errors import warn
from clothbase.fields import FieldBlock
from multilevel.aggregation import AggregationMultigrid

from .base import Integrator, Option, at_least_one, one_of, positive

PRECONDITIONERS = ("auto", "jacobi", "multigrid")


@ti.data_oriented
class Implicit(Integrator):
    name = "implicit"
    unconditionally_stable = True
    OPTIONS = {
        "cg_tolerance": Option(float, 1e-3, "relative CG residual (preconditioned norm) to stop at", positive),
        "cg_max_iterations": Option(int, 200, "CG iteration cap per step, shared by its Newton iterations",
                                    at_least_one),
        "preconditioner": Option(str, "auto", "jacobi | multigrid (V-cycles over the cloth's 4-8 levels, or over "
                                 "aggregates of its particles) | auto (multigrid on 4-8 levels and on cloths of "
                                 "2,000 particles or more)",
                                 one_of(PRECONDITIONERS)),
        "newton_iterations": Option(int, 4, "the most Newton iterations per step (each one CG solve and a line "
                                    "search); the first is enough when the step does not gain energy", at_least_one),
        "newton_tolerance": Option(float, 1e-2, "or stop when the Newton decrement (-grad.dv [J]) falls below this "
                                   "fraction of the first one's", positive),
        "line_search": Option(bool, True, "halve the Newton step (down to 1/8) until the incremental potential "
                              "decreases: large steps do not gain energy"),
        "warm_start": Option(bool, True, "Jacobi-preconditioned CG starts from the last step's velocity change "
                             "(fewer iterations, a closer trajectory in free motion, and small steady forces such as a "
                             "closing seam's add up over the steps; off where a drape keeps fluttering at rest: at a "
                             "loose tolerance it can carry a flutter from step to step)"),
    }
    #: the step lengths the line search tries, longest first, and the sufficient decrease it asks for
    ALPHAS = (1.0, 0.5, 0.25, 0.125)
    ARMIJO = 1e-4

    #: `auto` aggregates a cloth without 4-8 levels from this many particles. Measured (CG to 1e-3, 2-core CPU):
    #: the T-shirt (1,464 particles) 7.4 ms per step against Jacobi's 8.2 (34 CG iterations against 196), but even
    #: at the demo's 1e-2 (4.1 against 4.0 ms); a 64 x 64 grid held by one edge 22.9 against 27.0 ms (33 against
    #: 198 = the cap). Below it the cycle's kernels cost more to compile (about 6 s) than they save.
    AGGREGATION_FROM = 2000
    #: whether `auto` preconditions a garment by V-cycles over its own 4-8 levels once its seams are merged. No:
    #: over a run to rest on a 2-core CPU, the demo T-shirt on 5 levels (1,370 particles) took 29 CG iterations
    #: per step over them against Jacobi's 96 but 27.8 ms per step against 14.3 (on its finest level 11.5 against
    #: 8.7: a cycle costs four Jacobi iterations, the coarsest factor 0.9 ms). "multigrid" asks for it.
    GARMENT_LEVELS = False
    #: CG iterations unrolled into one kernel launch; iterations past convergence inside a chunk are no-ops
    CHUNK = 8
    _DELTA, _THRESH, _BETA, _ACTIVE, _ITER, _MAXIT, _DELTA0, _RR, _DECREMENT, _RISE = range(10)  # slots of self.cg

    def __init__(self, model, state, forces, **options):
        super().__init__(model, state, forces, **options)
        fp = model.fp
        P, S = model.capacity[0], max(model.capacity[1], 1)
        blk = FieldBlock()
        self.spring_u = blk.vector(3, fp, S)  # unit direction a -> b
        self.spring_axial = blk.scalar(fp, S)         # h kd + h^2 k (1 - g)   [kg/s]
        self.spring_iso = blk.scalar(fp, S)           # h^2 k g + h c           [kg]
        self.b = blk.vector(3, fp, P)
        self.inv_diag = blk.matrix(3, 3, fp, P)  # Jacobi: the inverse 3x3 diagonal blocks of the filtered A
        self.dv, self.r, self.z, self.p, self.q = (blk.vector(3, fp, P) for _ in range(5))
        self.x0, self.v0 = blk.vector(3, fp, P), blk.vector(3, fp, P)  # the step's start [m], [m/s]
        self.dv_total = blk.vector(3, fp, P)          # v_k - v0 [m/s] (after the step: its whole velocity change)
        self.cg = blk.scalar(ti.f64, 10)              # CG scalars (see the indices above), kept on the device
        self.warm = blk.scalar(ti.i32, ())            # 1: start CG from the last step's dv_total (Jacobi only)
        self.ip = blk.scalar(ti.f64, len(self.ALPHAS) + 2)  # IP(alpha = 0), IP(ALPHAS...), grad.dv [J]
        self.energy = blk.scalar(ti.f64, len(self.ALPHAS) + 2)  # E(alpha = 0), E(ALPHAS...), E at the start [J]
        self.cut = blk.scalar(ti.i32, ())             # line-search cuts in this step
        blk.finalize(self)
        self.stats = {"cg_iterations": 0, "cg_unconverged_steps": 0, "newton_iterations": 0, "line_search_cuts": 0}
        self.last_residual = 0.0  # sqrt(r.Pr / b.Pb) at the end of the last step
        self._warned_cap = False
        self.multigrid = None        # the preconditioner in use: None (Jacobi), 4-8 levels or aggregation levels
        self.level_multigrid = None  # over the cloth's 4-8 levels, when it has nested ones
        self.off_levels = None       # what is used while the model is on none of them: None or aggregation
        self.starts_off_levels = False  # the model starts on none of the levels (a garment's pieces apart)
        # Jacobi-PCG starts from the previous step's dv: it carries over the smooth part Jacobi is slow to find
        # (measured on a 65 x 65 cotton sheet held by one edge at 1/60 s: 43 mm RMS from the exact step's
        # trajectory after 0.5 s instead of 190 mm, with 15 % fewer iterations). Multigrid finds the smooth part
        # itself and starts from 0 (a warm start cost it iterations and accuracy there). On a drape at rest the
        # carried-over dv can keep a flutter alive that the tolerance, relative to a small b, accepts every step: the
        # 4-8 T-shirt sewn on its finest level still moved at 16 mm/s after 30 s at CG 1e-3 with it, and rested at
        # 8-13 s without it. The other way round, it carries small steady forces that one cold solve at 1e-3 drops:
        # the demo T-shirt's shoulder seams closed with it and held 3.2 mm open without it.
        self.warm[None] = int(self.options["warm_start"])
        self.reset()

    def reset(self) -> None:
        """Forget the previous step's velocity change (the warm start)."""
        self.dv.fill(0)
        self.dv_total.fill(0)

    # ------------------------------------------------------------------ the preconditioner
    #: without levels the preconditioner falls back to Jacobi (approx-implicit's multigrid cannot)
    levels_required = False

    @property
    def needs_levels(self) -> bool:
        """Whether this integrator wants the cloth's 4-8 levels (attach_levels) when it has nested ones."""
        return self.options["preconditioner"] != "jacobi"

    def attach_levels(self, levels, cloth_levels, pinned, level: int | None) -> None:
        """Build the multigrid preconditioner over a nested 4-8 hierarchy: `levels` (multilevel Level list),
        `cloth_levels` (ClothData per level: masses, springs, spring constants), `pinned` (unused: the pins are
        read from the inverse masses at every step) and the current level (0-based), or None while the model is on
        none of them (a garment's pieces apart before their seams merge on its start level): CG keeps the
        preconditioner it has (Jacobi, or aggregation levels) until a topology change names a level. Raises
        ValueError when the levels are not nested (multilevel.spring_multigrid.copies) or the coarsest is too large."""
        from multilevel.spring_multigrid import SERIAL_BELOW, SpringMultigrid

        self.level_multigrid = SpringMultigrid(
            levels, [d.springs for d in cloth_levels], [d.stiffness for d in cloth_levels],
            [d.damping for d in cloth_levels], [d.rest_length for d in cloth_levels], [d.mass for d in cloth_levels],
            fp=self.model.fp, viscous=[d.viscous_damping() for d in cloth_levels],
            # every loop serial for a cloth the CPU runs serially; on a GPU none (the CPU's threshold ran every loop
            # in one GPU thread: an H100 took 170 ms per step, 4.7 V-cycles, on a 65 x 65 sheet)
            serial_below=1 << 62 if self.model.serial else
            (SERIAL_BELOW if ti.lang.impl.current_cfg().arch == ti.cpu else 0))
        self.starts_off_levels = level is None
        if level is not None:
            self.level_multigrid.set_active_level(level)
            self.multigrid = self.level_multigrid
            self.warm[None] = 0

    def attach_aggregation(self) -> None:
        """Build the multigrid preconditioner over aggregates of the cloth's particles (multilevel.aggregation),
        for a cloth without nested 4-8 levels (or before it is on them); rebuilt at every topology change. Raises
        ValueError when the cloth does not coarsen (it stays on Jacobi)."""
        amg = AggregationMultigrid(self.model.capacity[:2], fp=self.model.fp,
                                   serial=ti.lang.impl.current_cfg().arch == ti.cpu)
        amg.rebuild(self.model.data.springs, self.model.data.n_particles)
        self.multigrid = self.off_levels = amg
        self.warm[None] = 0

    def topology_changed(self, level: int | None = None) -> None:
        """A refill of the model: on the 4-8 level `level` (a level switch, a garment's seams merged on its start
        level), or with no level named: on the level it was on when its particle count is that level's (new spring
        constants), else off the levels again (a garment's pieces apart after a reset)."""
        self.reset()
        mg = self.level_multigrid
        if mg is not None:
            if level is not None:
                mg.set_active_level(level)
                self.multigrid = mg
            elif self.model.data.n_particles != mg.sizes[mg.active]:
                self.multigrid = self.off_levels
        if isinstance(self.multigrid, AggregationMultigrid):
            self.multigrid.rebuild(self.model.data.springs, self.model.data.n_particles)
        self.warm[None] = int(self.options["warm_start"] and self.multigrid is None)

    @property
    def detail(self) -> str:
        if isinstance(self.multigrid, AggregationMultigrid):
            sizes = " > ".join(str(n) for n in self.multigrid.sizes)
            return f"CG preconditioned by V-cycles over {len(self.multigrid.sizes)} aggregation levels ({sizes})"
        if self.multigrid is not None:
            before = ""
            if self.level_multigrid is not None and self.starts_off_levels:
                before = " once on them (before: " + ("aggregation levels)" if self.off_levels is not None else
                                                      "Jacobi)")
            return f"CG preconditioned by V-cycles over {self.multigrid.n_levels} 4-8 levels{before}"
        return "Jacobi-preconditioned CG"

    def _prepare_multigrid(self, dt: float) -> None:
        """The multigrid's operators for the Newton system just assembled."""
        mg = self.multigrid
        if isinstance(mg, AggregationMultigrid):
            mg.prepare(self.spring_u, self.spring_axial, self.spring_iso, self.model.mass, self.model.inv_mass,
                       self.contacts if self.has_contacts else None,
                       1.0 + dt * self.forces.air_damping_value)
        else:
            mg.prepare(self.state.x, self.model.inv_mass, dt, self.forces.air_damping_value,
                       self.contacts if self.has_contacts else None)

    # ------------------------------------------------------------------ the step
    def _advance(self, dt: float) -> None:
        tol2 = self.options["cg_tolerance"] ** 2
        h_gamma = dt * self.forces.air_damping_value
        if self.has_contacts:
            self._contact_friction(dt)  # before the step's start is kept: it changes velocities
        self._begin()
        its, unconverged, residual, first_decrement = 0, 0, 0.0, None
        budget = self.options["cg_max_iterations"]  # per step: a further Newton iteration spends what is left
        for k in range(self.options["newton_iterations"]):
            self._assemble(dt, tol2, budget - its, int(k == 0))
            if self.multigrid is None:
                while self._cg_chunk(h_gamma):
                    pass
            else:
                mg = self.multigrid
                self._prepare_multigrid(dt)
                first = 1
                while True:
                    mg.apply(self.r, self.z)
                    if not self._mg_iteration(h_gamma, tol2, first):
                        break
                    first = 0
            # the line search returns what the host needs of this iteration: one read per Newton iteration
            it, delta, delta0, decrement, rise = self._line_search(dt, int(self.options["line_search"]),
                                                                   int(self.multigrid is not None))
            residual = math.sqrt(max(delta, 0.0) / delta0) if delta0 > 0 else 0.0
            its += int(it)
            unconverged += int(residual > self.options["cg_tolerance"])
            self.stats["newton_iterations"] += 1
            if first_decrement is None:
                first_decrement = decrement
            # enough: the iterate has not gained energy on the step's start (backward Euler only dissipates), Newton
            # has converged, or the step's CG budget is spent
            if rise <= 0.0 or decrement <= self.options["newton_tolerance"] * first_decrement or its >= budget:
                break
        self._finish(dt)
        if rise > 0.0 and its >= budget and not self._warned_cap:
            self._warned_cap = True  # backward Euler only dissipates: say it once when the cap lets a step gain energy
            warn(f"implicit: CG stopped at its cap of {budget} iterations (relative residual {residual:.2g}) and the "
                 f"step gained {rise:.3g} J; raise cg_max_iterations"
                 + ("" if self.multigrid is not None else ' or set preconditioner = "multigrid"'))
        self.last_residual = residual
        self.stats["cg_iterations"] += its
        self.stats["cg_unconverged_steps"] += min(unconverged, 1)
        self.stats["line_search_cuts"] += int(self.cut[None])

    @ti.func
    def _product(self, i, vec: ti.template()):
        """(A vec)_i without the mass term, from the per-spring axial/isotropic coefficients."""
        m = self.model
        out = ti.Vector.zero(m.fp, 3)
        for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
            sp = m.adj_spring[e]
            dq = vec[i] - vec[m.adj_other[e]]
            u = self.spring_u[sp]
            out += self.spring_axial[sp] * u.dot(dq) * u + self.spring_iso[sp] * dq
        return out

    @ti.func
    def _system_product(self, i, mass_scale, active):
        """q[i] = (S A p)_i (0 for a pinned particle or once CG stopped); returns p[i].q[i] in float64."""
        m = self.model
        q = ti.Vector.zero(m.fp, 3)
        if m.inv_mass[i] != 0 and active != 0:
            q = self.contact_filter(i, m.mass[i] * mass_scale * self.p[i] + self._product(i, self.p))
        self.q[i] = q
        return ti.cast(self.p[i].dot(q), ti.f64)

    @ti.kernel
    def _contact_friction(self, dt: ti.f64):
        """Coulomb friction at the contacts of the last step, before the solve (Baraff and Witkin 1998, section 5:
        the constraint decides what the solve may change). For a particle with a contact normal n and the force f on
        it now (springs, gravity, drag, sources), f_n = -f.n presses it on the body:
          * f_n <= 0 and not moving in: released (no constraint this step);
          * else its normal velocity is removed (it rests on the body), and friction can take up to
            dv = mu f_n h / m of its tangential velocity in this step: where that stops it and the tangential force
            is within the friction cone (|f_t| <= mu f_n), it sticks (held where it is: every direction filtered,
            v = 0); otherwise it slides (its normal direction filtered), its tangential velocity reduced by dv.
        The velocities change in a second pass, after every force was read at the old ones."""
        m, s, c = self.model, self.state, self.contacts
        h = ti.cast(dt, m.fp)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            n = c.normal[i]
            v = s.v[i]
            stuck = 0
            if m.inv_mass[i] != 0 and n.dot(n) > 0:
                n = n.normalized()
                f = self.forces.particle_force(i, True)
                fn = -f.dot(n)
                vn = v.dot(n)
                if fn <= 0 and vn >= 0:
                    c.normal[i] = ti.Vector.zero(m.fp, 3)  # pulled away: free
                else:
                    vt = v - vn * n
                    ft = f + fn * n
                    mu = c.friction[i] * c.friction_scale[None]
                    take = mu * ti.max(fn, 0.0) * h * m.inv_mass[i]
                    if vt.norm() <= take and ft.norm() <= mu * fn:
                        stuck = 1
                        vt = ti.Vector.zero(m.fp, 3)
                    else:
                        vt *= ti.max(0.0, 1.0 - take / ti.max(vt.norm(), 1e-30))
                    # resting on the body: no normal velocity. An approaching one is removed; so is a leaving one, which
                    # the filter would otherwise keep against the force that presses (the T-shirt at rest gained
                    # 3e-5 J a step that way), and which freed would fall back and be pushed out every step
                    v = vt
            self.q[i] = v  # scratch: the new velocity
            c.stuck[i] = stuck
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            s.v[i] = self.q[i]

    @ti.kernel
    def _begin(self):
        """Keep the step's start (x0, v0) and its energy; the last step's velocity change stays in dv_total for the
        warm start."""
        m, s = self.model, self.state
        NA = ti.static(len(self.ALPHAS))
        self.cut[None] = 0
        self.energy[NA + 1] = 0.0
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            self.x0[i] = s.x[i]
            self.v0[i] = s.v[i]
            if m.inv_mass[i] != 0:
                grav = ti.cast(self.forces.gravity[None], ti.f64)  # in the loop: see _line_search
                mass, v, x = ti.cast(m.mass[i], ti.f64), ti.cast(s.v[i], ti.f64), ti.cast(s.x[i], ti.f64)
                self.energy[NA + 1] += 0.5 * mass * v.dot(v) - mass * grav.dot(x)
        ti.loop_config(serialize=self.model.serial)
        for sp in range(m.n_springs[None]):
            stretch = ti.cast((s.x[m.spring_b[sp]] - s.x[m.spring_a[sp]]).norm() - m.rest_length[sp], ti.f64)
            self.energy[NA + 1] += 0.5 * ti.cast(m.stiffness[sp], ti.f64) * stretch * stretch

    @ti.kernel
    def _assemble(self, dt: ti.f64, tol2: ti.f64, max_iterations: ti.i32, first: ti.i32):
        """The Newton system at v_k = v0 + dv_total (x_k = x0 + h v_k, written into the state so that the force
        code evaluates there): spring coefficients, b = S (h f(x_k, v_k) - M dv_total), the Jacobi diagonal, and
        CG's start (the last step's velocity change for Jacobi on the first iteration, else 0). The first
        iteration linearises f(x0 + h v0) about x0 instead (x_0 = x0, b = S h (f0 + h (df/dx) v0)): the classical
        one-solve step of Baraff and Witkin, which is Newton's first iteration from v = 0, not from v0. Started
        from the predicted x0 + h v0, a sheet at 1/120 s slid off the mannequin's head where runs at a tenth of
        the step stay on it."""
        m, s, fm = self.model, self.state, self.forces
        h = ti.cast(dt, m.fp)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            guess = ti.Vector.zero(m.fp, 3)
            if first != 0:  # the velocity change of the last step, the first iteration's initial guess
                guess = self.dv_total[i]
                self.dv_total[i] = ti.Vector.zero(m.fp, 3)
            if m.inv_mass[i] != 0:
                v = self.v0[i] + self.dv_total[i]
                s.v[i] = v
                s.x[i] = self.x0[i] + h * v * ti.cast(1 - first, m.fp)
                self.dv[i] = self.contact_filter(i, guess) * ti.cast(self.warm[None] * first, m.fp)
            else:
                self.dv[i] = ti.Vector.zero(m.fp, 3)
        ti.loop_config(serialize=self.model.serial)
        for sp in range(m.n_springs[None]):
            d = s.x[m.spring_b[sp]] - s.x[m.spring_a[sp]]
            length = ti.max(d.norm(), 1e-12)
            u = d / length
            g = ti.max(0.0, 1.0 - m.rest_length[sp] / length)
            k = m.stiffness[sp]
            self.spring_u[sp] = u
            self.spring_axial[sp] = h * m.damping[sp] + h * h * k * (1.0 - g)
            self.spring_iso[sp] = h * h * k * g + h * m.viscous[sp]
        mass_scale = 1.0 + h * fm.air_damping[None]
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            zero = ti.Vector.zero(m.fp, 3)
            if m.inv_mass[i] == 0:
                self.b[i] = zero
            else:
                f = fm.particle_force(i, True)
                eye = ti.Matrix.identity(m.fp, 3)
                diag = eye * m.mass[i] * mass_scale
                kv = ti.Vector.zero(m.fp, 3)  # h^2 K v0 on the first iteration (K = -df/dx)
                for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                    sp = m.adj_spring[e]
                    u = self.spring_u[sp]
                    diag += self.spring_axial[sp] * u.outer_product(u) + self.spring_iso[sp] * eye
                    if first != 0:
                        dvel = s.v[i] - s.v[m.adj_other[e]]
                        kv += (self.spring_axial[sp] - h * m.damping[sp]) * u.dot(dvel) * u \
                            + (self.spring_iso[sp] - h * m.viscous[sp]) * dvel
                self.b[i] = self.contact_filter(i, h * f - kv - m.mass[i] * self.dv_total[i])
                # the block of the filtered system S A S + M' (I - S): on a contact the tangential block, whose
                # inverse is not the per-axis one (on the T-shirt resting on the body: 143 -> 80 CG its per step)
                S = self.contact_projector(i)
                self.inv_diag[i] = (S @ diag @ S + m.mass[i] * mass_scale * (eye - S)).inverse()
        delta = ti.cast(0.0, ti.f64)
        bz = ti.cast(0.0, ti.f64)  # b.D^-1 b: the tolerance is relative to b, so that a good start stops early
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            zero = ti.Vector.zero(m.fp, 3)
            self.p[i] = zero
            if m.inv_mass[i] == 0:
                self.r[i] = zero
                self.z[i] = zero
            else:
                r = self.b[i] - self.contact_filter(i, m.mass[i] * mass_scale * self.dv[i]
                                                    + self._product(i, self.dv))
                self.r[i] = r
                z = self.contact_filter(i, self.inv_diag[i] @ r)
                self.z[i] = z
                delta += ti.cast(r.dot(z), ti.f64)
                bz += ti.cast(self.b[i].dot(self.contact_filter(i, self.inv_diag[i] @ self.b[i])), ti.f64)
        self.cg[self._DELTA] = delta
        self.cg[self._DELTA0] = bz
        self.cg[self._THRESH] = tol2 * bz
        self.cg[self._ITER] = 0.0
        self.cg[self._BETA] = 0.0
        self.cg[self._MAXIT] = ti.cast(max_iterations, ti.f64)
        self.cg[self._ACTIVE] = 1.0 if delta > tol2 * bz and max_iterations > 0 else 0.0

    @ti.kernel
    def _cg_chunk(self, h_gamma: ti.f64) -> ti.i32:
        """CHUNK preconditioned CG iterations (BW98 modified PCG with the pinned rows filtered out); returns whether
        CG is still iterating. Scalars live in self.cg; once converged (or at the cap) the remaining iterations
        change nothing."""
        m = self.model
        cg = ti.static(self.cg)
        mass_scale = 1.0 + ti.cast(h_gamma, m.fp)
        for _ in ti.static(range(self.CHUNK)):
            # p = z + beta p (beta = 0 on the first iteration since p = 0), then q = A p and p.q
            ti.loop_config(serialize=self.model.serial)
            for i in range(m.n_particles[None]):
                if m.inv_mass[i] != 0 and cg[self._ACTIVE] != 0:
                    self.p[i] = self.z[i] + self.p[i] * ti.cast(cg[self._BETA], m.fp)
            pq = ti.cast(0.0, ti.f64)
            ti.loop_config(serialize=self.model.serial)
            for i in range(m.n_particles[None]):
                pq += self._system_product(i, mass_scale, cg[self._ACTIVE])
            alpha = ti.cast(0.0, ti.f64)
            if cg[self._ACTIVE] != 0 and pq > 0:
                alpha = cg[self._DELTA] / pq
            a = ti.cast(alpha, m.fp)
            delta_new = ti.cast(0.0, ti.f64)
            ti.loop_config(serialize=self.model.serial)
            for i in range(m.n_particles[None]):
                if m.inv_mass[i] != 0:
                    self.dv[i] += a * self.p[i]
                    r = self.r[i] - a * self.q[i]
                    self.r[i] = r
                    z = self.contact_filter(i, self.inv_diag[i] @ r)
                    self.z[i] = z
                    delta_new += ti.cast(r.dot(z), ti.f64)
            if cg[self._ACTIVE] != 0:
                cg[self._ITER] += 1.0
                cg[self._BETA] = delta_new / cg[self._DELTA] if pq > 0 else 0.0
                cg[self._DELTA] = delta_new
                if delta_new <= cg[self._THRESH] or cg[self._ITER] >= cg[self._MAXIT] or pq <= 0:
                    cg[self._ACTIVE] = 0.0
        return ti.cast(cg[self._ACTIVE] != 0, ti.i32)

    @ti.kernel
    def _mg_iteration(self, h_gamma: ti.f64, tol2: ti.f64, first: ti.i32) -> ti.i32:
        """One CG iteration after the V-cycle wrote z = V(r): z = S z and the convergence test on r.z (it stops
        before any update: the V-cycle is the measure), then p = z + beta p, q = S A p, dv and r. Scalars stay in
        self.cg; returns whether CG goes on (0: this call found it converged or at its cap, and changed nothing)."""
        m = self.model
        cg = ti.static(self.cg)
        mass_scale = 1.0 + ti.cast(h_gamma, m.fp)
        rz = ti.cast(0.0, ti.f64)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            z = ti.Vector.zero(m.fp, 3)
            if m.inv_mass[i] != 0:
                z = self.contact_filter(i, self.z[i])
            self.z[i] = z
            rz += ti.cast(self.r[i].dot(z), ti.f64)
        beta = ti.cast(0.0, ti.f64)
        if first != 0:
            cg[self._DELTA0] = rz
            cg[self._THRESH] = tol2 * rz
            cg[self._ACTIVE] = 1.0 if rz > 0 and cg[self._MAXIT] > 0 else 0.0
        elif cg[self._ACTIVE] != 0:
            if rz <= cg[self._THRESH] or cg[self._ITER] >= cg[self._MAXIT]:
                cg[self._ACTIVE] = 0.0
            elif cg[self._DELTA] > 0:
                beta = rz / cg[self._DELTA]
        cg[self._RR] = rz  # the residual's measure, also when this was the last look
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            if m.inv_mass[i] != 0 and cg[self._ACTIVE] != 0:
                self.p[i] = self.z[i] + self.p[i] * ti.cast(beta, m.fp)
        pq = ti.cast(0.0, ti.f64)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            pq += self._system_product(i, mass_scale, cg[self._ACTIVE])
        alpha = ti.cast(0.0, ti.f64)
        if cg[self._ACTIVE] != 0 and pq > 0:
            alpha = rz / pq
        a = ti.cast(alpha, m.fp)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            if m.inv_mass[i] != 0 and cg[self._ACTIVE] != 0:
                self.dv[i] += a * self.p[i]
                self.r[i] -= a * self.q[i]
        if cg[self._ACTIVE] != 0:
            cg[self._ITER] += 1.0
            cg[self._DELTA] = rz
            if pq <= 0:
                cg[self._ACTIVE] = 0.0
        return ti.cast(cg[self._ACTIVE] != 0, ti.i32)

    @ti.func
    def _particle_potential(self, i, hh, gamma, ext, j0: ti.template(), j1: ti.template()):
        """Adds particle i's inertia, gravity, air drag and external-force terms of IP, and its kinetic and gravity
        energy, for the candidates j0 <= j < j1 (j = 0: alpha = 0, j: ALPHAS[j - 1])."""
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
            dvt = base + a * d
            v = v0 + dvt
            x = x0 + hh * v
            self.ip[j] += 0.5 * mass * dvt.dot(dvt) - mass * grav.dot(x) + 0.5 * hh * gamma * mass * v.dot(v) \
                - hh * ext.dot(a * d)
            self.energy[j] += 0.5 * mass * v.dot(v) - mass * grav.dot(x)

    @ti.func
    def _spring_potential(self, sp, hh, j0: ti.template(), j1: ti.template()):
        """Adds spring sp's elastic and damping terms of IP, and its elastic energy, for the candidates j0 <= j < j1."""
        m = self.model
        A = ti.static(self.ALPHAS)
        ia, ib = m.spring_a[sp], m.spring_b[sp]
        k = ti.cast(m.stiffness[sp], ti.f64)
        kd = ti.cast(m.damping[sp], ti.f64)
        c = ti.cast(m.viscous[sp], ti.f64)
        L0 = ti.cast(m.rest_length[sp], ti.f64)
        u = ti.cast(self.spring_u[sp], ti.f64)
        wa = ti.cast(m.inv_mass[ia] != 0, ti.f64)
        wb = ti.cast(m.inv_mass[ib] != 0, ti.f64)
        for j in ti.static(range(j0, j1)):
            a = 0.0 if j == 0 else A[j - 1]
            va = ti.cast(self.v0[ia], ti.f64) + wa * ti.cast(self.dv_total[ia] + a * self.dv[ia], ti.f64)
            vb = ti.cast(self.v0[ib], ti.f64) + wb * ti.cast(self.dv_total[ib] + a * self.dv[ib], ti.f64)
            xa = ti.cast(self.x0[ia], ti.f64) + wa * hh * va
            xb = ti.cast(self.x0[ib], ti.f64) + wb * hh * vb
            stretch = (xb - xa).norm() - L0
            dvel = vb - va
            rel = dvel.dot(u)
            self.ip[j] += 0.5 * k * stretch * stretch + 0.5 * hh * (kd * rel * rel + c * dvel.dot(dvel))
            self.energy[j] += 0.5 * k * stretch * stretch

    @ti.kernel
    def _line_search(self, dt: ti.f64, search: ti.i32, multigrid: ti.i32) -> ti.types.vector(5, ti.f64):
        """dv_total += alpha dv, with alpha the longest of ALPHAS whose incremental potential IP satisfies the
        sufficient decrease (1 without the search; 1/8 when none does). The full step is evaluated first, the shorter
        ones only when it fails (in the same launch). IP and the total energy E (kinetic + spring + gravity) of every
        candidate are summed in float64 over the free particles and every spring, with the state still at the
        iterate (its spring directions, its external forces). Returns (CG iterations, the residual's
        measure r.z at the end (multigrid: its last look), b.z_b, the Newton decrement [J], the rise of E above the
        step's start [J])."""
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
        work = ti.cast(0.0, ti.f64)  # of the external forces over the step [J]
        # first the full step (j = 1, against j = 0); the shorter ones only where it does not decrease enough
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            if m.inv_mass[i] != 0:
                ext = ti.cast(fm.source_force(i, s.x[i], s.v[i]), ti.f64)
                d = ti.cast(self.dv[i], ti.f64)
                self.ip[NA + 1] -= ti.cast(self.b[i], ti.f64).dot(d)  # grad . dv (b = -S grad)
                work += hh * ext.dot(ti.cast(self.v0[i] + self.dv_total[i], ti.f64) + d)
                self._particle_potential(i, hh, gamma, ext, 0, 2)
        ti.loop_config(serialize=self.model.serial)
        for sp in range(m.n_springs[None]):
            self._spring_potential(sp, hh, 0, 2)
        full = self.ip[1] <= self.ip[0] + self.ARMIJO * self.ip[NA + 1]
        shorter = ti.cast(search != 0, ti.i32) * (1 - ti.cast(full, ti.i32))
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            if shorter != 0 and m.inv_mass[i] != 0:
                ext = ti.cast(fm.source_force(i, s.x[i], s.v[i]), ti.f64)
                self._particle_potential(i, hh, gamma, ext, 2, NA + 1)
        ti.loop_config(serialize=self.model.serial)
        for sp in range(m.n_springs[None]):
            if shorter != 0:
                self._spring_potential(sp, hh, 2, NA + 1)
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
        if alpha < 1.0:
            self.cut[None] += 1
        self.cg[self._DECREMENT] = -self.ip[NA + 1]  # the Newton decrement dv^T A dv [J]
        # the rise of the total energy above the step's start, beyond the external forces' work and round-off (E is
        # summed in float64 from the state's float32 or float64 positions and velocities: round-off of a few 1e-7 of
        # E in float32, which must not count as a gain that calls for another Newton iteration)
        start = self.energy[NA + 1]
        roundoff = ti.static(1e-6 if self.model.fp == ti.f32 else 1e-12)
        self.cg[self._RISE] = energy - start - ti.max(work, 0.0) - roundoff * ti.abs(start)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            if m.inv_mass[i] != 0:
                self.dv_total[i] += ti.cast(alpha, m.fp) * self.dv[i]
        measure = self.cg[self._DELTA]
        if multigrid != 0:
            measure = self.cg[self._RR]
        return ti.Vector([self.cg[self._ITER], measure, self.cg[self._DELTA0], self.cg[self._DECREMENT],
                          self.cg[self._RISE]], ti.f64)

    @ti.kernel
    def _finish(self, dt: ti.f64):
        """v = v0 + dv_total, x = x0 + h v (pinned particles keep their start; the pins place the moving ones)."""
        m, s = self.model, self.state
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
