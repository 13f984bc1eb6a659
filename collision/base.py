"""What every collider shares: binding to the cloth's fields, start-of-step positions, the velocity response."""
import taichi as ti

from clothbase.fields import FieldBlock


@ti.data_oriented
class ParticleCollider:
    #: run the kernels' loops in one thread (a small cloth on the CPU: the scene says so when it attaches)
    serial = False

    """Base of the colliders. After `attach`, x, v [m, m/s] and inv_mass [1/kg] are the cloth's (P,) fields,
    n_particles its 0-d live count, x_start (P,) the positions at the start of the step, and contact_normal
    (optional (P,) vec3 field) receives the unit normal of each contact made, for the implicit integrators."""

    def attach(self, x, v, inv_mass, n_particles, contact_normal=None, serial: bool = False) -> None:
        self.x, self.v, self.inv_mass, self.n_particles = x, v, inv_mass, n_particles
        self.serial = bool(serial)
        self.contact_normal = contact_normal
        self.records_contacts = contact_normal is not None
        blk = FieldBlock()
        self.x_start = blk.vector(3, x.dtype, x.shape[0])
        blk.finalize(self)
        self.x_start.copy_from(x)
        self._attached = True
        self._on_attach()

    def _on_attach(self) -> None:
        """Per-collider scratch allocation, once the cloth is known."""

    def begin_step(self) -> None:
        """Remember where every particle starts the step."""
        self._copy_start()

    @ti.kernel
    def _copy_start(self):
        ti.loop_config(serialize=self.serial)
        for i in range(self.n_particles[None]):
            self.x_start[i] = self.x[i]

    @ti.func
    def respond(self, i, normal, reference_velocity, friction):
        """Zero restitution and Coulomb friction for particle i at a contact with unit `normal`: of its velocity
        relative to `reference_velocity` (the collider's, 0 for a static body), an approaching normal part is
        removed and the tangential part scaled by max(0, 1 - friction |v_n| / |v_t|) (Bridson et al. 2002)."""
        rel = self.v[i] - reference_velocity
        vn = rel.dot(normal)
        if vn < 0:
            vt = rel - vn * normal
            vt_len = vt.norm()
            scale = ti.cast(0.0, self.x.dtype)
            if vt_len > 0:
                scale = ti.max(0.0, 1.0 - friction * (-vn) / vt_len)
            self.v[i] = reference_velocity + scale * vt
