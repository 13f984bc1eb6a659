"""Backward Euler with the full spring Jacobians (Baraff and Witkin 1998), solved by modified PCG.

One linearised solve per step (BW98 eq. 15):
    A dv = b,  A = M(1 + h gamma) - h df/dv - h^2 df/dx,  b = h (f0 + h (df/dx) v0)
then v += dv, x += h v. Per spring (u = unit direction, l = length, L0 = rest length):
    K_s = k [ u u^T + max(0, 1 - L0/l) (I - u u^T) ]   (stiffness; the clamp keeps A SPD, Choi and Ko 2002)
    D_s = kd u u^T                                     (spring damping)
so the product is (A q)_i = m_i (1 + h gamma) q_i + sum_s [ (h kd + h^2 k (1-g)) u (u.dq) + h^2 k g dq ],
dq = q_i - q_j, g = max(0, 1 - L0/l). It is evaluated matrix-free with a per-particle gather.
Pinned particles are filtered out of the solve (BW98 section 5.3, S_i = 0), and a particle in contact with a
collider in the last step has its normal component filtered (S_i = I - n n^T: its normal velocity does not
change in the solve, the collider handles it).

Preconditioners (option `preconditioner`):
  jacobi     the diagonal of A, inline in the CG kernels, CHUNK iterations per launch;
  multigrid  a V(1,1) cycle over the cloth's nested 4-8 levels (multilevel.spring_multigrid: the same system
             rediscretised on every level), applied as z = S V(S r), which keeps the preconditioner symmetric on
             the free subspace; one V-cycle per CG iteration;
  auto       (the default) multigrid where the cloth has nested 4-8 levels (a [multilevel] grid with global
             refinement), jacobi elsewhere. The run summary names the one used.
CG stops when sqrt(r.z / b.z0) <= cg_tolerance (z = the preconditioned residual: D^-1 r, or the V-cycle's) or after
cg_max_iterations. (A test on |r| alone stopped multigrid-CG at bad points: twice the error at a tolerance of 0.1.)
"""

import math

import taichi as ti

from clothbase.fields import FieldBlock

from .base import Integrator, Option, at_least_one, one_of, positive

PRECONDITIONERS = ("auto", "jacobi", "multigrid")


@ti.data_oriented
class Implicit(Integrator):
    name = "implicit"
    unconditionally_stable = True
    OPTIONS = {
        "cg_tolerance": Option(float, 1e-3, "relative CG residual (preconditioned norm) to stop at", positive),
        "cg_max_iterations": Option(int, 200, "CG iteration cap per step", at_least_one),
        "preconditioner": Option(str, "auto", "jacobi | multigrid (V-cycles over the cloth's nested 4-8 levels) | "
                                 "auto (multigrid where the cloth has them)", one_of(PRECONDITIONERS)),
    }

    #: CG iterations unrolled into one kernel launch; iterations past convergence inside a chunk are no-ops
    CHUNK = 8
    _DELTA, _THRESH, _BETA, _ACTIVE, _ITER, _MAXIT, _DELTA0, _RR = range(8)  # slots of self.cg

    def __init__(self, model, state, forces, **options):
        super().__init__(model, state, forces, **options)
        fp = model.fp
        P, S = model.capacity[0], max(model.capacity[1], 1)
        blk = FieldBlock()
        self.spring_u = blk.vector(3, fp, S)  # unit direction a -> b
        self.spring_axial = blk.scalar(fp, S)         # h kd + h^2 k (1 - g)   [kg/s]
        self.spring_iso = blk.scalar(fp, S)           # h^2 k g                 [kg]
        self.b = blk.vector(3, fp, P)
        self.inv_diag = blk.vector(3, fp, P)
        self.dv, self.r, self.z, self.p, self.q = (blk.vector(3, fp, P) for _ in range(5))
        self.cg = blk.scalar(ti.f64, 8)               # CG scalars (see the indices above), kept on the device
        self.warm = blk.scalar(ti.i32, ())            # 1: start CG from the previous step's dv (Jacobi only)
        blk.finalize(self)
        self.stats = {"cg_iterations": 0, "cg_unconverged_steps": 0}
        self.last_residual = 0.0  # sqrt(r.Pr / b.Pb) at the end of the last step
        self.multigrid = None
        # Jacobi-PCG starts from the previous step's dv: it carries over the smooth part Jacobi is slow to find
        # (measured on a 65 x 65 cotton sheet held by one edge at 1/60 s: 43 mm RMS from the exact step's
        # trajectory after 0.5 s instead of 190 mm, with 15 % fewer iterations). Multigrid finds the smooth part
        # itself and starts from 0 (a warm start cost it iterations and accuracy there).
        self.warm[None] = 1
        self.reset()

    def reset(self) -> None:
        """Forget the previous step's dv (the warm start)."""
        self.dv.fill(0)

    # ------------------------------------------------------------------ the preconditioner
    #: without levels the preconditioner falls back to Jacobi (approx-implicit's multigrid cannot)
    levels_required = False

    @property
    def needs_levels(self) -> bool:
        """Whether this integrator wants the cloth's 4-8 levels (attach_levels) when it has nested ones."""
        return self.options["preconditioner"] != "jacobi"

    def attach_levels(self, levels, cloth_levels, pinned, level: int) -> None:
        """Build the multigrid preconditioner over a nested 4-8 hierarchy: `levels` (multilevel Level list),
        `cloth_levels` (ClothData per level: masses, springs, spring constants, rest lengths), `pinned` (unused:
        the pins are read from the inverse masses at every step) and the current level (0-based)."""
        from multilevel.spring_multigrid import SERIAL_BELOW, SpringMultigrid

        self.multigrid = SpringMultigrid(levels, [d.springs for d in cloth_levels], [d.stiffness for d in cloth_levels],
                                         [d.damping for d in cloth_levels], [d.rest_length for d in cloth_levels],
                                         [d.mass for d in cloth_levels], fp=self.model.fp,
                                         serial_below=1 << 62 if self.model.serial else SERIAL_BELOW)
        self.multigrid.set_active_level(level)
        self.warm[None] = 0

    def topology_changed(self, level: int | None = None) -> None:
        self.reset()
        if self.multigrid is not None and level is not None:
            self.multigrid.set_active_level(level)

    @property
    def detail(self) -> str:
        if self.multigrid is not None:
            return f"CG preconditioned by V-cycles over {self.multigrid.n_levels} 4-8 levels"
        return "Jacobi-preconditioned CG"

    # ------------------------------------------------------------------ the step
    def _advance(self, dt: float) -> None:
        tol2 = self.options["cg_tolerance"] ** 2
        self._assemble(dt, tol2, self.options["cg_max_iterations"])
        h_gamma = dt * self.forces.air_damping_value
        if self.multigrid is None:
            self._cg_chunk(h_gamma)
            while self._active():
                self._cg_chunk(h_gamma)
            cg = self.cg.to_numpy()  # one transfer for all scalars
            it, delta, delta0 = cg[[self._ITER, self._DELTA, self._DELTA0]]
        else:
            mg = self.multigrid
            mg.prepare(self.state.x, self.model.inv_mass, dt, self.forces.air_damping_value)
            first = 1
            while first or self._active():
                mg.apply(self.r, self.z)
                self._mg_iteration(h_gamma, tol2, first)
                first = 0
            cg = self.cg.to_numpy()
            it, delta, delta0 = cg[[self._ITER, self._RR, self._DELTA0]]
        self._integrate(dt)
        self.last_residual = math.sqrt(max(delta, 0.0) / delta0) if delta0 > 0 else 0.0
        self.stats["cg_iterations"] += int(it)
        self.stats["cg_unconverged_steps"] += int(self.last_residual > self.options["cg_tolerance"])

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

    @ti.kernel
    def _assemble(self, dt: ti.f64, tol2: ti.f64, max_iterations: ti.i32):
        m, s, fm = self.model, self.state, self.forces
        h = ti.cast(dt, m.fp)
        ti.loop_config(serialize=self.model.serial)
        for sp in range(m.n_springs[None]):
            d = s.x[m.spring_b[sp]] - s.x[m.spring_a[sp]]
            l = d.norm()
            u = d / ti.max(l, 1e-12)
            g = ti.max(0.0, 1.0 - m.rest_length[sp] / ti.max(l, 1e-12))
            k = m.stiffness[sp]
            self.spring_u[sp] = u
            self.spring_axial[sp] = h * m.damping[sp] + h * h * k * (1.0 - g)
            self.spring_iso[sp] = h * h * k * g
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            zero = ti.Vector.zero(m.fp, 3)
            # the previous step's dv is the initial guess (filtered by this step's pins and contacts)
            self.dv[i] = self.contact_filter(i, self.dv[i]) * ti.cast(self.warm[None], m.fp) \
                if m.inv_mass[i] != 0 else zero
            if m.inv_mass[i] == 0:
                self.b[i] = zero
            else:
                f = fm.particle_force(i, True)
                # h^2 (df/dx) v0 = -h^2 sum_s K_s (v_i - v_j); K_s = (spring_iso + spring_axial_stiff) / h^2
                kv = ti.Vector.zero(m.fp, 3)
                diag = ti.Vector.one(m.fp, 3) * m.mass[i] * (1.0 + h * fm.air_damping[None])
                for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                    sp = m.adj_spring[e]
                    dvel = s.v[i] - s.v[m.adj_other[e]]
                    u = self.spring_u[sp]
                    axial_k = self.spring_axial[sp] - h * m.damping[sp]
                    kv += axial_k * u.dot(dvel) * u + self.spring_iso[sp] * dvel
                    diag += self.spring_axial[sp] * u * u + self.spring_iso[sp]
                self.b[i] = self.contact_filter(i, h * f - kv)
                self.inv_diag[i] = 1.0 / diag
        delta = ti.cast(0.0, ti.f64)
        mass_scale = 1.0 + h * fm.air_damping[None]
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
                z = self.contact_filter(i, r * self.inv_diag[i])
                self.z[i] = z
                delta += ti.cast(r.dot(z), ti.f64)
        self.cg[self._DELTA] = delta
        self.cg[self._DELTA0] = delta
        self.cg[self._THRESH] = tol2 * delta
        self.cg[self._ITER] = 0.0
        self.cg[self._BETA] = 0.0
        self.cg[self._MAXIT] = ti.cast(max_iterations, ti.f64)
        self.cg[self._ACTIVE] = 1.0 if delta > tol2 * delta and max_iterations > 0 else 0.0

    @ti.kernel
    def _cg_chunk(self, h_gamma: ti.f64):
        """CHUNK preconditioned CG iterations (BW98 modified PCG with the pinned rows filtered out).
        Scalars live in self.cg; once converged (or at the cap) the remaining iterations change nothing."""
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
                q = ti.Vector.zero(m.fp, 3)
                if m.inv_mass[i] != 0 and cg[self._ACTIVE] != 0:
                    q = self.contact_filter(i, m.mass[i] * mass_scale * self.p[i] + self._product(i, self.p))
                self.q[i] = q
                pq += ti.cast(self.p[i].dot(q), ti.f64)
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
                    z = self.contact_filter(i, r * self.inv_diag[i])
                    self.z[i] = z
                    delta_new += ti.cast(r.dot(z), ti.f64)
            if cg[self._ACTIVE] != 0:
                cg[self._ITER] += 1.0
                cg[self._BETA] = delta_new / cg[self._DELTA] if pq > 0 else 0.0
                cg[self._DELTA] = delta_new
                if delta_new <= cg[self._THRESH] or cg[self._ITER] >= cg[self._MAXIT] or pq <= 0:
                    cg[self._ACTIVE] = 0.0

    @ti.kernel
    def _active(self) -> ti.i32:
        """Whether the CG on the device is still iterating (a scalar read, cheaper than a field transfer)."""
        return ti.cast(self.cg[self._ACTIVE] != 0, ti.i32)

    @ti.kernel
    def _mg_iteration(self, h_gamma: ti.f64, tol2: ti.f64, first: ti.i32):
        """One CG iteration after the V-cycle wrote z = V(r): z = S z and the convergence test on r.z (it stops
        before any update: the V-cycle is the measure), then p = z + beta p, q = S A p, dv and r. Scalars stay in
        self.cg."""
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
            q = ti.Vector.zero(m.fp, 3)
            if m.inv_mass[i] != 0 and cg[self._ACTIVE] != 0:
                q = self.contact_filter(i, m.mass[i] * mass_scale * self.p[i] + self._product(i, self.p))
            self.q[i] = q
            pq += ti.cast(self.p[i].dot(q), ti.f64)
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

    @ti.kernel
    def _integrate(self, dt: ti.f64):
        m, s = self.model, self.state
        h = ti.cast(dt, m.fp)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            if m.inv_mass[i] != 0:
                s.v[i] += self.dv[i]
                s.x[i] += h * s.v[i]
