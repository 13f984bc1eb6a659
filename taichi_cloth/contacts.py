"""Contact normals shared between the colliders and the implicit integrators.

The colliders write, for each particle they pushed out in the last step or left within the contact band (up to
1.25 x the collider's thickness from the surface: where a push leaves a resting particle), the unit normal of
that contact and the collider's friction coefficient. The implicit integrators then constrain the particle's
normal velocity change inside their solve (the constraint filter S_i = I - n n^T of Baraff and Witkin 1998,
section 5.3): without it the solve, unaware of
the body, lets a particle's falling neighbours drag it into the body every step, the projection puts it
back, and the cloth stretches around every contact (we measured 30-260 % strain on a 10 cm ball at
h = 1/120 s; with the filter it stays at a few per cent). The implicit integrator also decides, before its solve,
which contacts stick (static friction: the particle is held, S_i = 0) from the force that presses them on the body,
and gives a sliding one the dashpot of its kinetic friction in the solve (taichi_cloth.integrators.implicit). Built
only when a scene has colliders.
"""
import taichi as ti

from clothbase.fields import FieldBlock


@ti.data_oriented
class Contacts:
    """normal: (P,) vec3 fp, the unit contact normal of each particle touched in the last step (0 if none); friction:
    (P,) fp, the Coulomb coefficient of that contact; velocity: (P,) vec3 fp, the surface's velocity [m/s] there (0 on a
    still collider: the contact's friction and resting act on the velocity relative to it); stuck: (P,) i32, 1 where the
    integrator holds the particle by static friction this step (every direction filtered); released: (P,) i32, 1 where
    the integrator lets a touching particle leave the body this step (the force pulls it away: no direction filtered).
    The normal of a released particle stays as the colliders wrote it: the stretch limit still sees it on the body.
    before: (P,) i32, 1 where the particle had a contact after the step before (the colliders give it a wider band);
    previous, previous2: (P,) vec3, that contact's normal and the one of the step before it (0 if none); crease: (P,)
    vec3, a second unit normal the integrator holds the particle against this step, 0 if none (a crease of the body
    where the contact alternates between two faces: see `projector`)."""

    def __init__(self, model):
        self.model = model
        blk = FieldBlock()
        self.normal = blk.vector(3, model.fp, model.capacity[0])
        self.velocity = blk.vector(3, model.fp, model.capacity[0])
        self.friction = blk.scalar(model.fp, model.capacity[0])
        self.stuck = blk.scalar(ti.i32, model.capacity[0])
        self.released = blk.scalar(ti.i32, model.capacity[0])
        self.before = blk.scalar(ti.i32, model.capacity[0])
        self.previous = blk.vector(3, model.fp, model.capacity[0])
        self.previous2 = blk.vector(3, model.fp, model.capacity[0])
        self.crease = blk.vector(3, model.fp, model.capacity[0])
        self.friction_scale = blk.scalar(model.fp, ())  # 0 switches friction off (sewing: pieces slide into place)
        blk.finalize(self)
        self.friction_scale[None] = 1.0

    def clear(self) -> None:
        """No contact (the collision stage writes them afresh); what static friction holds is kept."""
        self._clear(0)

    def reset(self) -> None:
        """No contact and nothing held (a scene back at its start). Compiles nothing after a first clear()."""
        self._clear(1)

    @ti.kernel
    def _clear(self, held: ti.i32):
        ti.loop_config(serialize=self.model.serial)
        for i in range(self.model.n_particles[None]):
            n = self.normal[i]
            self.before[i] = ti.cast(n.dot(n) > 0 and held == 0, ti.i32)
            zero = ti.Vector.zero(self.model.fp, 3)
            self.previous2[i] = self.previous[i] if held == 0 else zero
            self.previous[i] = n if held == 0 else zero
            self.normal[i] = ti.Vector.zero(self.model.fp, 3)
            self.velocity[i] = ti.Vector.zero(self.model.fp, 3)
            self.released[i] = 0
            if held != 0:
                self.stuck[i] = 0
                self.crease[i] = ti.Vector.zero(self.model.fp, 3)

    @ti.func
    def sliding_normal(self, i):
        """The normal the solve filters for particle i: its contact normal, or 0 when it has none or is released."""
        n = self.normal[i]
        if self.released[i] != 0:
            n = ti.Vector.zero(self.model.fp, 3)
        return n

    @ti.func
    def projector(self, i):
        """Particle i's filter S_i (3x3): 0 when stuck, I - n n^T / |n|^2 on a contact (divided by |n|^2: a normal
        written in float32 is unit only to 1e-7, and S must be a projector), else I (no contact, or released). In a
        crease (a second normal p held this step) also without the part of p across n: the particle slides along
        the crease's line only."""
        n = self.sliding_normal(i)
        nn = n.dot(n)
        S = ti.Matrix.identity(self.model.fp, 3)
        if self.stuck[i] != 0:
            S = ti.Matrix.zero(self.model.fp, 3, 3)
        elif nn > 0:
            S -= n.outer_product(n) / nn
            q = S @ self.crease[i]
            qq = q.dot(q)
            if qq > 0:
                S -= q.outer_product(q) / qq
        return S

    @ti.func
    def filter(self, i, vec):
        """vec without its component along particle i's contact normal (vec itself when i is not in contact, 0
        when it is stuck)."""
        return self.projector(i) @ vec


def require_bound(owner, state, contacts) -> None:
    """Refuse a State or Contacts other than those `owner` (an integrator, the colliders) was built for: a Taichi
    kernel of a @ti.data_oriented object binds the fields it reads when it compiles, so it cannot step another."""
    if state is not owner.state or contacts is not owner.contacts:
        which = "state" if state is not owner.state else "contacts"
        raise ValueError(f"{type(owner).__name__} was built for another {which}: its kernels read the fields they "
                         "were compiled for; build the scene's parts for this state (taichi_cloth.assembly.assemble), "
                         "or copy it into the bound one (State.set)")
