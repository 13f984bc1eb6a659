"""Analytic colliders: spheres (Zhang et al. 2017), capsules and planes, for fast tests and a stand-in body.

Zhang et al. 2017's rule for spheres: a particle collides when |S - C| <= r_sphere + r_particle and is pushed along
(S - C) by alpha (r_sphere + r_particle - |S - C|), the pushes summed over all spheres (the norm is not
squared; docs/algorithms.md). We add what a stand-in body needs: capsules (the same rule about the closest
point of the axis), half-space planes (floors), a segment test so a particle that passes right through a
sphere or capsule within one step is caught at its entry, and the body response of collision.body (inward
normal velocity removed, Coulomb friction on the rest).
"""
import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock

from .base import ParticleCollider


@ti.func
def _closest_on_segment(x, a, b):
    ab = b - a
    s = ti.min(ti.max((x - a).dot(ab) / ti.max(ab.dot(ab), 1e-20), 0.0), 1.0)
    return a + s * ab


@ti.data_oriented
class PrimitiveColliders(ParticleCollider):
    """spheres: list of (center (3,) [m], radius [m]); capsules: list of (a (3,), b (3,), radius); planes: list
    of (point (3,), normal (3,)). thickness [m] is the particle radius r_p; alpha the paper's push fraction
    (1 = fully out); friction the Coulomb coefficient. Fields hold the shapes so they can move (set_*). motion: a
    scripted rigid motion of them all (clothbase.keyframes.RigidMotion), or None."""

    def __init__(self, spheres=(), capsules=(), planes=(), thickness: float = 0.003, alpha: float = 1.0,
                 friction: float = 0.3, motion=None):
        if not (spheres or capsules or planes):
            raise ValueError("PrimitiveColliders needs at least one sphere, capsule or plane")
        if not 0 < alpha <= 1:
            raise ValueError(f"alpha must lie in (0, 1], got {alpha}")
        self.thickness, self.alpha, self.friction = float(thickness), float(alpha), float(friction)
        self.motion = motion
        self.n_spheres, self.n_capsules, self.n_planes = len(spheres), len(capsules), len(planes)
        blk = FieldBlock()
        self.sphere = blk.vector(4, ti.f32, max(len(spheres), 1))       # cx, cy, cz, r
        self.capsule_a = blk.vector(4, ti.f32, max(len(capsules), 1))   # ax, ay, az, r
        self.capsule_b = blk.vector(3, ti.f32, max(len(capsules), 1))
        self.plane = blk.vector(6, ti.f32, max(len(planes), 1))         # point, unit normal
        blk.finalize(self)
        self.set_spheres(spheres)
        self.set_capsules(capsules)
        self.set_planes(planes)
        self._attached = False

    def set_spheres(self, spheres) -> None:
        self.spheres_np = [(np.asarray(c, float), float(r)) for c, r in spheres]
        for k, (c, r) in enumerate(self.spheres_np):
            if not r > 0:
                raise ValueError(f"sphere {k}: radius must be > 0 m, got {r}")
            self.sphere[k] = [*c, r]

    def set_capsules(self, capsules) -> None:
        self.capsules_np = [(np.asarray(a, float), np.asarray(b, float), float(r)) for a, b, r in capsules]
        for k, (a, b, r) in enumerate(self.capsules_np):
            if not r > 0:
                raise ValueError(f"capsule {k}: radius must be > 0 m, got {r}")
            self.capsule_a[k] = [*a, r]
            self.capsule_b[k] = b.tolist()

    def set_planes(self, planes) -> None:
        self.planes_np = []
        for k, (p, n) in enumerate(planes):
            n = np.asarray(n, float)
            if not np.linalg.norm(n) > 0:
                raise ValueError(f"plane {k}: the normal must be non-zero")
            n = n / np.linalg.norm(n)
            self.planes_np.append((np.asarray(p, float), n))
            self.plane[k] = [*p, *n]

    def resolve(self, dt: float) -> None:
        self._resolve()

    def _on_attach(self) -> None:
        blk = FieldBlock()
        self.speculative = blk.scalar(ti.i32, self.x.shape[0])
        blk.finalize(self)

    def begin_step(self, dt: float | None = None) -> None:
        """Remember where every particle starts the step; with the step dt [s], make the speculative contacts."""
        self._copy_start()
        if dt is not None:
            self._speculate(dt)

    @ti.func
    def _touching(self, i):
        """Whether particle i had a contact after the last step (always False without contact fields)."""
        touching = False
        if ti.static(self.records_contacts):
            touching = self.contact_normal[i].norm() > 0
        return touching

    @ti.func
    def _nearest(self, q):
        """The gap [m] from q to the nearest shape's surface offset by the thickness (negative inside), and that
        shape's outward unit normal."""
        rp = ti.cast(self.thickness, ti.f32)
        gap = ti.cast(1e30, ti.f32)
        nrm = ti.Vector.zero(ti.f32, 3)
        for k in range(self.n_spheres):
            d = q - self.sphere[k].xyz
            g = d.norm() - self.sphere[k].w - rp
            if g < gap:
                gap, nrm = g, d.normalized(1e-20)
        for k in range(self.n_capsules):
            d = q - _closest_on_segment(q, self.capsule_a[k].xyz, self.capsule_b[k])
            g = d.norm() - self.capsule_a[k].w - rp
            if g < gap:
                gap, nrm = g, d.normalized(1e-20)
        for k in range(self.n_planes):
            n = ti.Vector([self.plane[k][3], self.plane[k][4], self.plane[k][5]])
            g = (q - ti.Vector([self.plane[k][0], self.plane[k][1], self.plane[k][2]])).dot(n) - rp
            if g < gap:
                gap, nrm = g, n
        return gap, nrm

    @ti.kernel
    def _speculate(self, dt: ti.f64):
        """Speculative contacts: a free particle not in contact but moving fast enough to reach a shape within this step
        of dt [s] has its approach cut to the speed that closes the gap in the step (with Coulomb friction for that
        impulse; relative to a moving collider's surface), before the integrator's solve, so that the solve moves its
        neighbours with it. Pushed out only after the step, it stopped on the surface while they fell on by up to a
        step's travel, and the stretch of the springs between them was elastic energy from nowhere (docs/collision.md).
        No constraint goes to the solve: holding the approach there let the constraint pull the particle in against its
        neighbours, and a step gained energy."""
        ti.loop_config(serialize=self.serial)
        for i in range(self.n_particles[None]):
            self.speculative[i] = 0
            if self.inv_mass[i] != 0 and not self._touching(i):
                h = ti.cast(dt, ti.f32)
                q = ti.cast(self.x[i], ti.f32)
                surface = ti.Vector.zero(ti.f32, 3)  # a moving collider: its velocity there, and its frame
                if ti.static(self.moving):
                    r = self.to_rest(0, self.x[i])
                    q = ti.cast(r, ti.f32)
                    surface = ti.cast(self.surface_velocity(r), ti.f32)
                gap, n = self._nearest(q)
                if ti.static(self.moving):
                    n = ti.cast(self.turn(0, n), ti.f32)
                v = ti.cast(self.v[i], ti.f32) - surface
                vn = v.dot(n)
                if gap > 0 and gap + vn * h < 0:
                    target = -gap / h
                    vt = v - vn * n
                    vt_len = vt.norm()
                    scale = ti.cast(0.0, ti.f32)
                    if vt_len > 0:
                        scale = ti.max(0.0, 1.0 - ti.cast(self.friction, ti.f32) * (target - vn) / vt_len)
                    self.v[i] = ti.cast(surface + target * n + scale * vt, self.x.dtype)
                    self.speculative[i] = 1

    @ti.func
    def _entry(self, p, q, c, r):
        """If segment p -> q passes through the ball (c, r) with both ends outside, the entry point; else q."""
        d = q - p
        out = q
        dd = d.dot(d)
        if dd > 0 and (p - c).norm() > r and (q - c).norm() > r:
            s = ti.min(ti.max((c - p).dot(d) / dd, 0.0), 1.0)
            if (p + s * d - c).norm() < r:
                f = p - c
                bq = f.dot(d)
                disc = bq * bq - dd * (f.dot(f) - r * r)
                out = p + ti.max((-bq - ti.sqrt(ti.max(disc, 0.0))) / dd, 0.0) * d
        return out

    @ti.kernel
    def _resolve(self):
        ti.loop_config(serialize=self.serial)
        for i in range(self.n_particles[None]):
            self.resolve_particle(i, self.x_start[i])

    @ti.func
    def resolve_particle(self, i, start):
        """Particle i, which moved from `start` to x[i] in this step: out of the shapes (entry point first, then the
        pushes), its velocity answered by `respond` (relative to the surface's velocity, for a moving collider, whose
        tests run in its frame as built on the particle's motion relative to it). Touches particle i only, so an
        integrator may inline it in its own particle loop (the explicit step's fused substeps)."""
        if self.inv_mass[i] != 0:
            p = ti.cast(start, ti.f32)
            q = ti.cast(self.x[i], ti.f32)
            if ti.static(self.moving):  # the particle's motion relative to the collider, in its frame as built
                p = ti.cast(self.to_rest(0, start), ti.f32)
                q = ti.cast(self.to_rest(1, self.x[i]), ti.f32)
            end = q
            rp = ti.cast(self.thickness, ti.f32)
            band_width = self.band(i) * rp
            for k in range(self.n_spheres):  # tunnelling first: stop at the entry point
                q = self._entry(p, q, self.sphere[k].xyz, self.sphere[k].w + rp)
            for k in range(self.n_capsules):
                a = self.capsule_a[k].xyz
                axis = _closest_on_segment(0.5 * (p + q), a, self.capsule_b[k])
                q = self._entry(p, q, axis, self.capsule_a[k].w + rp)
            push = ti.Vector.zero(ti.f32, 3)
            band = ti.Vector.zero(ti.f32, 3)  # outward directions of the shapes within the contact band
            for k in range(self.n_spheres):  # Zhang et al. 2017: pushes summed over all spheres
                c = self.sphere[k].xyz
                reach = self.sphere[k].w + rp
                d = q - c
                dist = d.norm()
                if dist <= reach:
                    push += self.alpha * (reach - dist) * d.normalized(1e-20)
                if dist <= reach + band_width:
                    band += d.normalized(1e-20)
            for k in range(self.n_capsules):
                c = _closest_on_segment(q, self.capsule_a[k].xyz, self.capsule_b[k])
                reach = self.capsule_a[k].w + rp
                d = q - c
                dist = d.norm()
                if dist <= reach:
                    push += self.alpha * (reach - dist) * d.normalized(1e-20)
                if dist <= reach + band_width:
                    band += d.normalized(1e-20)
            for k in range(self.n_planes):
                pt = ti.Vector([self.plane[k][0], self.plane[k][1], self.plane[k][2]])
                nrm = ti.Vector([self.plane[k][3], self.plane[k][4], self.plane[k][5]])
                dist = (q + push - pt).dot(nrm)
                if dist < rp:
                    push += (rp - dist) * nrm
                if dist < rp + band_width:
                    band += nrm
            moved = (q + push) - end
            friction = ti.cast(self.friction, self.x.dtype)
            surface = ti.Vector.zero(self.x.dtype, 3)  # the collider's velocity where the particle ends
            if ti.static(self.moving):
                surface = ti.cast(self.surface_velocity(q + push), self.x.dtype)
            if push.norm() > 0 or moved.norm() > 0:
                self.x[i] = ti.cast(q + push, self.x.dtype)
                nrm = ti.cast(push.normalized(1e-20), self.x.dtype)
                if ti.static(self.moving):
                    self.x[i] = ti.cast(self.to_world(1, q + push), self.x.dtype)
                    nrm = ti.cast(self.turn(1, nrm), self.x.dtype)
                if push.norm() > 0:
                    self.record_contact(i, nrm, friction, surface)
                self.respond(i, nrm, surface, friction)
            elif band.norm() > 0:  # resting just above a surface: a contact for the solve, nothing to undo
                nrm = ti.cast(band.normalized(1e-20), self.x.dtype)
                if ti.static(self.moving):
                    nrm = ti.cast(self.turn(1, nrm), self.x.dtype)
                self.record_contact(i, nrm, friction, surface)
                if self.speculative[i] != 0:  # arrived at the surface: the rest of its approach ends here
                    self.respond(i, nrm, surface, friction)
            self.speculative[i] = 0

    def signed_distance(self, points) -> np.ndarray:
        """Signed distance [m] of points (N,3) to the union of the shapes (where they are now), negative inside."""
        x = np.asarray(self.rest_points(points), dtype=np.float64)
        d = np.full(len(x), np.inf)
        for c, r in self.spheres_np:
            d = np.minimum(d, np.linalg.norm(x - c, axis=1) - r)
        for a, b, r in self.capsules_np:
            ab = b - a
            s = np.clip((x - a) @ ab / max(ab @ ab, 1e-20), 0, 1)
            d = np.minimum(d, np.linalg.norm(x - (a + s[:, None] * ab), axis=1) - r)
        for p, n in self.planes_np:
            d = np.minimum(d, (x - p) @ n)
        return d

    def describe(self) -> dict:
        return {"kind": "primitives", "spheres": self.spheres_np, "capsules": self.capsules_np,
                "planes": self.planes_np}


#: Zhang et al. 2017's idea of a body made of sphere colliders, as spheres and capsules sized from cross-sections of
#: the shipped mannequin (A-pose, Y up, feet on y = 0, front +z): (center, radius) and (a, b, radius), metres.
STANDIN_SPHERES = [((0.0, 1.55, 0.06), 0.085)]  # head
STANDIN_CAPSULES = [
    ((0.0, 1.40, 0.03), (0.0, 1.47, 0.04), 0.05),          # neck
    ((-0.17, 1.33, 0.02), (0.17, 1.33, 0.02), 0.06),       # shoulders
    ((-0.06, 0.95, 0.03), (-0.06, 1.28, 0.03), 0.105),     # torso, left and right halves
    ((0.06, 0.95, 0.03), (0.06, 1.28, 0.03), 0.105),
    ((-0.09, 0.85, 0.0), (0.09, 0.85, 0.0), 0.10),         # hips
    ((-0.20, 1.305, 0.01), (-0.32, 1.16, 0.04), 0.045),   # upper arms
    ((0.20, 1.305, 0.01), (0.32, 1.16, 0.04), 0.045),
    ((-0.32, 1.16, 0.04), (-0.45, 1.01, 0.21), 0.033),     # forearms (the hands are in front)
    ((0.32, 1.16, 0.04), (0.45, 1.01, 0.21), 0.033),
    ((-0.09, 0.80, 0.02), (-0.145, 0.50, 0.028), 0.065),   # thighs (the legs stand apart)
    ((0.09, 0.80, 0.02), (0.145, 0.50, 0.028), 0.065),
    ((-0.145, 0.50, 0.028), (-0.215, 0.10, 0.0), 0.042),   # shins
    ((0.145, 0.50, 0.028), (0.215, 0.10, 0.0), 0.042),
]


def mannequin_standin(thickness: float = 0.003, friction: float = 0.3) -> PrimitiveColliders:
    """A cheap analytic stand-in for the mannequin (1 sphere, 13 capsules) for fast tests and previews."""
    return PrimitiveColliders(STANDIN_SPHERES, STANDIN_CAPSULES, thickness=thickness, friction=friction)
