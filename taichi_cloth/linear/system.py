"""The block system of one Newton iteration of the implicit step, and the constraint filter CG solves it under.

    A = M' + E + sum over springs s = (a, b) of B_s (dv_a - dv_b) at a, -B_s (...) at b,    M' = M (1 + h gamma),
    B_s = (h kd + h^2 k (1 - g)) u u^T + (h^2 k g + h c) I,    g = max(0, 1 - L0 / l),

u the spring's unit direction and l its length at the iterate, k, kd, c, L0 [N/m, N s/m, N s/m, m] its stiffness,
axial damping, isotropic dashpot and rest length (the clamp g >= 0 keeps A symmetric positive definite, Choi and Ko
2002), E the diagonal extra_mass h c_i of a dashpot c_i on particle i alone (a sliding contact's friction). Stored
as one (u, axial, iso) per spring; the diagonal blocks and products are per-particle gathers over the model's CSR
adjacency. `spring_coefficients` and `spring_block` are the one place the formula is written: the 4-8
V-cycle rediscretises every level with them, the aggregation cycle sums its coarse levels from them.

The filter (Baraff and Witkin 1998, section 5.3): CG solves S A S dv = S b with S_i = 0 at a pin or at a contact
static friction holds, I - n n^T on a sliding contact, I elsewhere.
"""

import taichi as ti

from clothbase.fields import FieldBlock


@ti.func
def spring_coefficients(d, h, k, kd, c, rest):
    """A spring with end-to-end vector d [m] at the step h [s]: its unit direction u and the coefficients axial,
    iso [kg] of its block B_s (see the module docstring)."""
    length = ti.max(d.norm(), 1e-12)
    u = d / length
    g = ti.max(0.0, 1.0 - rest / length)
    return u, h * kd + h * h * k * (1.0 - g), h * h * k * g + h * c


@ti.func
def spring_block(u, axial, iso):
    """B_s = axial u u^T + iso I (3x3, in the precision of u)."""
    B = axial * u.outer_product(u)
    for c in ti.static(range(3)):
        B[c, c] += iso
    return B


@ti.func
def filtered_block(S, D, mass):
    """The 3x3 block S D S + M' (I - S) of the filtered operator at a row with filter S, A's block D and mass M'
    [kg]: A on range(S), M' on its complement, so invertible where D is (a pinned row: M' I)."""
    complement = -S  # I - S, exactly 0 where S = I
    for c in ti.static(range(3)):
        complement[c, c] += 1.0
    return S @ D @ S + mass * complement


@ti.func
def diagonal_block(fp: ti.template(), mass, mass_scale, begin, end, adj_spring: ti.template(), u: ti.template(),
                   axial: ti.template(), iso: ti.template()):
    """A row's 3x3 diagonal block M' + sum of its springs' B_s [kg]: mass [kg] times mass_scale, the springs
    adj_spring[begin:end] (indices into u, axial, iso)."""
    D = ti.Matrix.identity(fp, 3) * mass * mass_scale
    for e in range(begin, end):
        q = adj_spring[e]
        D += spring_block(u[q], axial[q], iso[q])
    return D


@ti.func
def spring_row(out, i, begin, end, adj_spring: ti.template(), adj_other: ti.template(), u: ti.template(),
               axial: ti.template(), iso: ti.template(), vec: ti.template()):
    """out plus row i of (A - M') vec: the sum over its springs adj_spring[begin:end], to the rows
    adj_other[begin:end], of B_s (vec_i - vec_j)."""
    acc = out
    for e in range(begin, end):
        q = adj_spring[e]
        dq = vec[i] - vec[adj_other[e]]
        uq = u[q]
        acc += axial[q] * uq.dot(dq) * uq + iso[q] * dq
    return acc


@ti.data_oriented
class ConstraintFilter:
    """S_i of the filtered system: 0 at a pin (inverse mass 0) or where static friction holds, I - n n^T on a
    sliding contact, I elsewhere. model: taichi_cloth.model.Model; contacts: taichi_cloth.contacts.Contacts or None
    (no colliders: no contact code is compiled)."""

    def __init__(self, model, contacts=None):
        self.model, self.contacts = model, contacts
        self.has_contacts = contacts is not None

    @ti.func
    def projector(self, i):
        """S_i as a 3x3 matrix (the model's precision)."""
        S = ti.Matrix.identity(self.model.fp, 3)
        if self.model.inv_mass[i] == 0:
            S = ti.Matrix.zero(self.model.fp, 3, 3)
        elif ti.static(self.has_contacts):
            S = self.contacts.projector(i)
        return S

    @ti.func
    def apply(self, i, vec):
        """S_i vec."""
        out = ti.Vector.zero(self.model.fp, 3)
        if self.model.inv_mass[i] != 0:
            out = vec
            if ti.static(self.has_contacts):
                out = self.contacts.filter(i, vec)
        return out


@ti.data_oriented
class BlockSystem:
    """The Newton system's operator A on the model's particles and springs (see the module docstring).

    model:  taichi_cloth.model.Model (masses, spring constants, CSR adjacency adj_offset / adj_spring / adj_other)
    x:      the (P,) vec3 positions [m] the springs are evaluated at (the state's: the implicit step writes the
            iterate there)
    Fields, sized at the model's capacity: u (S,) vec3 unit directions, axial and iso (S,) [kg], mass_scale () = 1 +
    h gamma, extra_mass (P,) [kg]: h c_i of a viscous term c_i (v_i - w_i) of particle i alone, added to its mass
    term on the diagonal (the contacts' friction: taichi_cloth.integrators.implicit; 0 elsewhere), live () int32: 1
    while the step's Newton iterations go on (the implicit step decides on the device; the kernels of an iteration
    past its end loop over nothing: `gated`). h [s] and h_gamma [-] of the current system
    are kept on the host for the V-cycles' own levels.
    """

    def __init__(self, model, x):
        fp = model.fp
        S = max(model.capacity[1], 1)
        self.model, self.x = model, x
        blk = FieldBlock()
        self.u = blk.vector(3, fp, S)
        self.axial = blk.scalar(fp, S)
        self.iso = blk.scalar(fp, S)
        self.mass_scale = blk.scalar(fp, ())
        self.extra_mass = blk.scalar(fp, max(model.capacity[0], 1))
        self.live = blk.scalar(ti.i32, ())
        blk.finalize(self)
        self.live[None] = 1
        self.h = self.h_gamma = 0.0

    def set_step(self, h: float, gamma: float) -> None:
        """The step h [s] and air drag gamma [1/s] of the systems to come (host values; the kernels that assemble
        write mass_scale)."""
        self.h, self.h_gamma = float(h), float(h * gamma)

    @ti.func
    def gated(self, n):
        """n while the step's Newton iterations go on, else 0: the range of a loop of an iteration's kernels."""
        return ti.select(self.live[None] != 0, n, 0)

    @ti.func
    def set_spring(self, sp, d, h):
        """Spring sp's (u, axial, iso) for its end-to-end vector d [m] at the step h [s]."""
        m = self.model
        u, axial, iso = spring_coefficients(d, h, m.stiffness[sp], m.damping[sp], m.viscous[sp], m.rest_length[sp])
        self.u[sp] = u
        self.axial[sp] = axial
        self.iso[sp] = iso

    @ti.func
    def diagonal(self, i, mass_scale):
        """A's 3x3 diagonal block of particle i, M'_i + E_i + sum of its springs' B_s [kg]."""
        m = self.model
        return diagonal_block(m.fp, m.mass[i], mass_scale, m.adj_offset[i], m.adj_offset[i + 1], m.adj_spring,
                              self.u, self.axial, self.iso) + ti.Matrix.identity(m.fp, 3) * self.extra_mass[i]

    @ti.func
    def spring_product(self, i, vec: ti.template()):
        """(A vec)_i without the mass term: sum over i's springs of B_s (vec_i - vec_j)."""
        m = self.model
        return spring_row(ti.Vector.zero(m.fp, 3), i, m.adj_offset[i], m.adj_offset[i + 1], m.adj_spring,
                          m.adj_other, self.u, self.axial, self.iso, vec)

    @ti.func
    def product(self, i, vec: ti.template(), filt: ti.template()):
        """(S A vec)_i (0 at a pin)."""
        m = self.model
        return filt.apply(i, (m.mass[i] * self.mass_scale[None] + self.extra_mass[i]) * vec[i]
                          + self.spring_product(i, vec))
