"""What every collider shares: binding to the cloth's fields, start-of-step positions, the velocity response."""
import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock

#: a particle up to this fraction of a collider's thickness beyond it still counts as in contact: it rests where
#: the last push left it (recorded for the implicit integrators' friction, not pushed)
BAND = 0.25
#: the band of a particle that was in contact in the last step: wider, so that a particle resting at the band's edge
#: does not leave and touch again every other step (hysteresis). A skirt's waist particle 5.07 mm from the body
#: (thickness 4 mm) left the band, the stretch limit then moved it as a free particle 0.6 mm towards a neighbour held
#: on the body, the solve brought it back into the band, in a cycle of three steps for as long as the run lasted
BAND_HELD = 0.5


@ti.data_oriented
class ParticleCollider:
    #: run the kernels' loops in one thread (a small cloth on the CPU: the scene says so when it attaches)
    serial = False
    #: a scripted rigid motion (clothbase.keyframes.RigidMotion), given before attach: the collider's tests then
    #: run in its own frame as built, on each particle's motion relative to it (move: the poses of the step)
    motion = None

    """Base of the colliders. After `attach`, x, v [m, m/s] and inv_mass [1/kg] are the cloth's (P,) fields,
    n_particles its 0-d live count, x_start (P,) the positions at the start of the step, and contact_normal,
    contact_friction (optional (P,) fields) receive the unit normal and the friction coefficient of each contact
    made, and contact_velocity (optional (P,) vec3) the surface's velocity there, for the implicit integrators
    (record_contact); contact_before (optional (P,) i32 field) is 1 where a
    particle had a contact in the last step (its band is then BAND_HELD)."""

    def attach(self, x, v, inv_mass, n_particles, contact_normal=None, serial: bool = False,
               contact_friction=None, contact_before=None, contact_velocity=None) -> None:
        self.x, self.v, self.inv_mass, self.n_particles = x, v, inv_mass, n_particles
        self.serial = bool(serial)
        self.contact_normal = contact_normal
        self.contact_friction = contact_friction
        self.contact_before = contact_before
        self.contact_velocity = contact_velocity
        self.records_velocity = contact_velocity is not None
        self.records_contacts = contact_normal is not None
        self.records_friction = contact_friction is not None
        self.knows_before = contact_before is not None
        blk = FieldBlock()
        self.x_start = blk.vector(3, x.dtype, x.shape[0])
        # the collider's poses at the start (0) and the end (1) of the step: world = rot r + shift for a point r of
        # the collider as built; inv_dt [1/s] of the step (surface velocities)
        self.rot = blk.matrix(3, 3, ti.f64, 2)
        self.shift = blk.vector(3, ti.f64, 2)
        self.inv_dt = blk.scalar(ti.f64, ())
        blk.finalize(self)
        self.x_start.copy_from(x)
        self.t_pose = 0.0
        self.move(0.0, 0.0)
        self._attached = True
        self._on_attach()

    @property
    def moving(self) -> bool:
        """On a scripted rigid motion (its tests run in its frame as built)."""
        return self.motion is not None

    @property
    def animated(self) -> bool:
        """Its surface moves during a run (posed before every step): a rigid motion, or a deforming body."""
        return self.moving

    def rewind(self) -> None:
        """Back to t = 0: where it starts."""
        self.move(0.0, 0.0)

    def move(self, t0: float, t1: float) -> None:
        """The poses of a step from t0 to t1 [s] (a moving collider; nothing for a still one)."""
        if self.motion is None:
            return
        for k, t in enumerate((t0, t1)):
            R, d = self.motion.pose(t)
            self.rot[k] = R.tolist()
            self.shift[k] = (self.motion.pivot + d - R @ self.motion.pivot).tolist()
        self.inv_dt[None] = 1.0 / (t1 - t0) if t1 > t0 else 0.0
        self.t_pose = t1

    def pose_now(self) -> tuple[np.ndarray, np.ndarray]:
        """(R (3,3), translation (3,)) of a moving collider now (the last step's end): world = R r + translation."""
        R, d = self.motion.pose(self.t_pose)
        return R, self.motion.pivot + d - R @ self.motion.pivot

    def rest_points(self, points) -> np.ndarray:
        """World points (N,3) [m] in the collider's frame as built, at its pose now (the last step's end)."""
        return self.motion.to_rest(points, self.t_pose) if self.motion is not None else np.asarray(points)

    @ti.func
    def to_rest(self, k, x):
        """World point x in the collider's frame as built, at pose k (0: the step's start, 1: its end); float64."""
        return self.rot[k].transpose() @ (ti.cast(x, ti.f64) - self.shift[k])

    @ti.func
    def to_world(self, k, r):
        """A point r of the collider as built, in the world at pose k; float64."""
        return self.rot[k] @ ti.cast(r, ti.f64) + self.shift[k]

    @ti.func
    def turn(self, k, n):
        """A direction n of the collider as built, in the world at pose k; float64."""
        return self.rot[k] @ ti.cast(n, ti.f64)

    @ti.func
    def surface_velocity(self, r):
        """The velocity [m/s] over the step of the collider's point r (as built): where pose 1 puts it less where
        pose 0 put it, over dt; float64."""
        return (self.to_world(1, r) - self.to_world(0, r)) * self.inv_dt[None]

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
    def band(self, i):
        """Particle i's contact band, as a fraction of the thickness: BAND, or BAND_HELD where it touched in the
        last step."""
        b = ti.cast(BAND, ti.f32)
        if ti.static(self.knows_before):
            if self.contact_before[i] != 0:
                b = ti.cast(BAND_HELD, ti.f32)
        return b

    @ti.func
    def record_contact(self, i, normal, friction, velocity):
        """Hand the contact of particle i (unit `normal`, Coulomb `friction`, the surface's `velocity` [m/s] there:
        0 for a still collider) to the implicit integrators (nothing when the scene has none)."""
        if ti.static(self.records_contacts):
            self.contact_normal[i] = normal
            if ti.static(self.records_friction):
                self.contact_friction[i] = friction
            if ti.static(self.records_velocity):
                self.contact_velocity[i] = velocity

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
