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
change in the solve, the collider handles it). Jacobi preconditioner.
CG stops when sqrt(r.Pr / b.Pb) <= cg_tolerance or after cg_max_iterations.
"""

import math

import taichi as ti

from clothbase.fields import FieldBlock

from .base import Integrator, Option, at_least_one, positive


@ti.data_oriented
class Implicit(Integrator):
    name = "implicit"
    unconditionally_stable = True
    OPTIONS = {
        "cg_tolerance": Option(float, 1e-3, "relative CG residual (preconditioned norm) to stop at", positive),
        "cg_max_iterations": Option(int, 200, "CG iteration cap per step", at_least_one),
    }

    #: CG iterations unrolled into one kernel launch; iterations past convergence inside a chunk are no-ops
    CHUNK = 8
    _DELTA, _THRESH, _BETA, _ACTIVE, _ITER, _MAXIT, _DELTA0 = range(7)  # slots of self.cg

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
        self.cg = blk.scalar(ti.f64, 7)               # CG scalars (see the indices above), kept on the device
        blk.finalize(self)
        self.stats = {"cg_iterations": 0, "cg_unconverged_steps": 0}
        self.last_residual = 0.0  # sqrt(r.Pr / b.Pb) at the end of the last step

    def _advance(self, dt: float) -> None:
        self._assemble(dt, self.options["cg_tolerance"] ** 2, self.options["cg_max_iterations"])
        h_gamma = dt * self.forces.air_damping_value
        while True:
            self._cg_chunk(h_gamma)
            cg = self.cg.to_numpy()  # one transfer for all scalars
            active, it, delta, delta0 = cg[[self._ACTIVE, self._ITER, self._DELTA, self._DELTA0]]
            if not active:
                break
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
        for sp in range(m.n_springs[None]):
            d = s.x[m.spring_b[sp]] - s.x[m.spring_a[sp]]
            l = d.norm()
            u = d / ti.max(l, 1e-12)
            g = ti.max(0.0, 1.0 - m.rest_length[sp] / ti.max(l, 1e-12))
            k = m.stiffness[sp]
            self.spring_u[sp] = u
            self.spring_axial[sp] = h * m.damping[sp] + h * h * k * (1.0 - g)
            self.spring_iso[sp] = h * h * k * g
        delta = ti.cast(0.0, ti.f64)
        for i in range(m.n_particles[None]):
            zero = ti.Vector.zero(m.fp, 3)
            self.dv[i] = zero
            if m.inv_mass[i] == 0:
                self.b[i] = zero
                self.r[i] = zero
                self.z[i] = zero
                self.p[i] = zero
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
                b = self.contact_filter(i, h * f - kv)
                self.b[i] = b
                self.inv_diag[i] = 1.0 / diag
                self.r[i] = b
                z = self.contact_filter(i, b * self.inv_diag[i])
                self.z[i] = z
                self.p[i] = zero
                delta += ti.cast(b.dot(z), ti.f64)
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
            for i in range(m.n_particles[None]):
                if m.inv_mass[i] != 0 and cg[self._ACTIVE] != 0:
                    self.p[i] = self.z[i] + self.p[i] * ti.cast(cg[self._BETA], m.fp)
            pq = ti.cast(0.0, ti.f64)
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
    def _integrate(self, dt: ti.f64):
        m, s = self.model, self.state
        h = ti.cast(dt, m.fp)
        for i in range(m.n_particles[None]):
            if m.inv_mass[i] != 0:
                s.v[i] += self.dv[i]
                s.x[i] += h * s.v[i]
