"""The approximate implicit step of Hsiao 2006 eq. (2) (Kang, Choi, Cho, Lee 2001).

Linearised backward Euler (M - h^2 J) dv = h f with the spring Jacobian replaced by the isotropic
"linear spring" matrix J~ (J~_ii = -sum_j k_ij I, J~_ij = k_ij I), solved by Jacobi sweeps:

    dv_i <- ( h f_i + h^2 sum_j k_ij dv_j ) / ( m_i + h^2 sum_j k_ij )

Published form (the default, exactly as in Hsiao 2006): two sweeps from dv = 0 and no h J~ v term, i.e.
    dv~_j = h f_j / (m_j + h^2 k n_j),  dv_i = (h f_i + h^2 k sum_j dv~_j) / (m_i + h^2 k n_i),
with per-spring k_ij in place of the single k (docs/algorithms.md, approximate implicit step). Then v += dv, x += h v.

Its known weakness: it damps low-frequency motion. A uniform fall gets dv = h g (1 - r^2),
r = h^2 K / (m + h^2 K), so a stiff free-falling sheet falls at a fraction of g; statics stay right
(dv = 0 iff f = 0). Variants (docs/algorithms.md, approximate implicit variants), as options:
  warm_start: start the sweeps from the previous step's dv (a uniform fall then converges to dv = h g,
              at the rate r^2 per step). Measured: it is linearly UNSTABLE on spring modes (modal analysis of
              the two-sweep map: spectral radius 1.08 at r = 0.5, 1.22 at r = 0.9) and blew up on every hanging
              cloth we tried, with or without jv_term; offered to study the free-fall bias, not for drapes;
  jv_term:    add h^2 sum_j k_ij (v_j - v_i) (the h J~ v term) to the right-hand side, which is what
              makes more than two sweeps safe (without it, more sweeps blew up in our tests);
  sweeps:     the number of Jacobi sweeps (Hsiao 2006 uses 2).
Where the sweeps are not enough, the implicit integrator solves the full system (its V-cycles run over the same
4-8 levels): docs/integrators.md.
Pinned particles have dv = 0 in the solve; a particle in contact with a collider in the last step has the
normal component of its dv removed after every sweep (the BW98 constraint filter, see taichi_cloth.contacts).
"""

import taichi as ti

from clothbase.errors import warn
from clothbase.fields import FieldBlock

from ..runtime import PARALLEL_FROM_CPU_SOLVE
from .base import Integrator, Option, at_least_one


@ti.data_oriented
class ApproxImplicit(Integrator):
    name = "approx-implicit"
    unconditionally_stable = True
    parallel_from_cpu = PARALLEL_FROM_CPU_SOLVE  # a solve's many short loops gain little from threads
    OPTIONS = {
        "sweeps": Option(int, 2, "Jacobi sweeps per step (2 is the published form)", at_least_one),
        "warm_start": Option(bool, False, "start the sweeps from the previous step's dv instead of 0"),
        "jv_term": Option(bool, False, "include the h J~ v term in the right-hand side (needed for sweeps > 2)"),
    }

    def __init__(self, model, state, forces, **options):
        super().__init__(model, state, forces, **options)
        if self.options["warm_start"]:
            warn("approx-implicit warm_start is linearly unstable on spring modes (spectral radius up to ~1.2 per "
                 "step); expect a blow-up on stiff cloth")
        if self.options["sweeps"] > 2 and not self.options["jv_term"]:
            warn("approx-implicit with more than 2 sweeps and no jv_term is known to go unstable on cloth (see "
                 "docs/integrators.md); set jv_term = true")
        P = model.capacity[0]
        blk = FieldBlock()
        self.rhs = blk.vector(3, model.fp, P)      # h f (+ h^2 J~ v) [kg m/s]
        self.inv_diag = blk.scalar(model.fp, P)           # 1 / (m + h^2 sum k) [1/kg]
        self.dv = blk.vector(3, model.fp, (2, P))  # ping-pong Jacobi iterates [m/s]; row 0 keeps the last dv
        blk.finalize(self)
        # sweeps and warm start are fixed per integrator: the sweeps unroll into one kernel (one launch per step)
        self.warm = bool(self.options["warm_start"])
        self.extra_sweeps = self.options["sweeps"] - (0 if self.warm else 1)
        self.reset()

    def reset(self) -> None:
        self.dv.fill(0)

    def unstable_advice(self) -> str | None:
        if self.options["sweeps"] > 2 and not self.options["jv_term"]:
            return "more than 2 sweeps need jv_term = true"
        return None

    def _advance(self, dt: float) -> None:
        self._sweeps(dt)

    @ti.func
    def _system_row(self, i, h):
        """Right-hand side h f (+ h^2 J~ v) [kg m/s] and 1 / diagonal [1/kg] of free particle i's row."""
        m, s, fm = self.model, self.state, self.forces
        f = fm.particle_force(i, True)
        jv = ti.Vector.zero(m.fp, 3)
        if ti.static(self.options["jv_term"]):
            for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                jv += m.stiffness[m.adj_spring[e]] * (s.v[m.adj_other[e]] - s.v[i])
        return h * f + h * h * jv, 1.0 / (m.mass[i] + h * h * m.stiffness_sum[i])

    # ------------------------------------------------------------------ the paper's Jacobi sweeps
    @ti.kernel
    def _sweeps(self, dt: ti.f64):
        m, s = self.model, self.state
        h = ti.cast(dt, m.fp)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            if m.inv_mass[i] == 0:
                self.rhs[i] = ti.Vector.zero(m.fp, 3)
                self.dv[0, i] = ti.Vector.zero(m.fp, 3)
                self.dv[1, i] = ti.Vector.zero(m.fp, 3)
            else:
                rhs, inv_diag = self._system_row(i, h)
                self.rhs[i] = rhs
                self.inv_diag[i] = inv_diag
                if ti.static(not self.warm):
                    self.dv[0, i] = self.contact_filter(i, rhs * inv_diag)  # sweep 1 from dv = 0
        for k in ti.static(range(self.extra_sweeps)):
            ti.loop_config(serialize=self.model.serial)
            for i in range(m.n_particles[None]):
                if m.inv_mass[i] != 0:
                    acc = ti.Vector.zero(m.fp, 3)
                    for e in range(m.adj_offset[i], m.adj_offset[i + 1]):
                        acc += m.stiffness[m.adj_spring[e]] * self.dv[k % 2, m.adj_other[e]]
                    self.dv[(k + 1) % 2, i] = self.contact_filter(i, (self.rhs[i] + h * h * acc) * self.inv_diag[i])
        last = ti.static(self.extra_sweeps % 2)
        ti.loop_config(serialize=self.model.serial)
        for i in range(m.n_particles[None]):
            if m.inv_mass[i] != 0:
                dv = self.dv[last, i]
                if ti.static(last == 1):
                    self.dv[0, i] = dv  # keep the last dv in row 0 for a warm start
                s.v[i] += dv
                s.x[i] += h * s.v[i]
