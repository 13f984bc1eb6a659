"""Model (static particle and spring fields) and State (positions and velocities).

Fields are allocated once at a capacity and carry a live count, so a later refinement can refill
them in place without recompiling a kernel. Kernels loop to the live counts n_particles[None] and
n_springs[None].
"""
from __future__ import annotations

import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock, fill_prefix

from .cloth import ClothData
from .runtime import PARALLEL_FROM_CPU, ensure_initialized, serial_loops
from .stability import omega_max_bound, omega_max_estimate, stiffness_sum

_PRECISIONS = {"f32": ti.f32, "f64": ti.f64}


def csr(owner: np.ndarray, n_owners: int, *payloads: np.ndarray):
    """Group `payloads` by `owner` (stable): returns offsets (n_owners+1,) and the regrouped payloads."""
    order = np.argsort(owner, kind="stable")
    offsets = np.zeros(n_owners + 1, np.int64)
    np.cumsum(np.bincount(owner, minlength=n_owners), out=offsets[1:])
    return (offsets,) + tuple(p[order] for p in payloads)


@ti.data_oriented
class Model:
    """The static part of a cloth, in Taichi fields (P = particle capacity, S = spring capacity).

    n_particles, n_springs, n_triangles: 0-d i32 fields, the live counts.
    rest_x:       (P,) vec3 fp [m]     rest/initial positions
    mass:         (P,) fp [kg]
    inv_mass:     (P,) fp [1/kg]       0 for a pinned particle
    spring_a/b:   (S,) i32             endpoint indices
    rest_length:  (S,) fp [m]
    stiffness:    (S,) fp [N/m]
    damping:      (S,) fp [N*s/m]      axial (along the spring)
    viscous:      (S,) fp [N*s/m]      isotropic dashpot of a mesh edge (ClothData.viscous_damping)
    spring_kind:  (S,) i32             SpringKind
    stiffness_sum:(P,) fp [N/m]        sum of the spring constants at each particle (derived)
    adj_offset:   (P+1,) i32           CSR: the incidences of particle i are adj_offset[i]..adj_offset[i+1]
    adj_spring:   (2S,) i32            spring of an incidence
    adj_other:    (2S,) i32            the particle at the other end
    triangles:    (T,) vec3 i32
    tri_offset:   (P+1,) i32           CSR of the triangles around each vertex (for vertex normals)
    tri_list:     (3T,) i32

    `data` keeps the numpy description (ClothData) the fields were filled from; pin flags are
    mirrored in `pinned` (numpy bool, (P,)).
    """

    def __init__(self, data: ClothData, precision: str = "f32", capacity: tuple[int, int, int] | None = None,
                 parallel_from: int = PARALLEL_FROM_CPU):
        ensure_initialized()
        if precision not in _PRECISIONS:
            raise ValueError(f"precision must be 'f32' or 'f64', got {precision!r}")
        self.precision = precision
        self.fp = _PRECISIONS[precision]
        P, S, T = data.n_particles, data.n_springs, len(data.triangles)
        cp, cs, ct = capacity or (P, S, T)
        if cp < P or cs < S or ct < T:
            raise ValueError(f"capacity {capacity} is below the cloth's size {(P, S, T)}")
        self.capacity = (cp, cs, ct)
        #: the kernels of this cloth run their loops in one thread (small cloths on the CPU: runtime.serial_loops;
        #: parallel_from: the integrator's count, Integrator.parallel_from_cpu)
        self.serial = serial_loops(cp, parallel_from)
        fp = self.fp
        blk = FieldBlock()
        self.n_particles = blk.scalar(ti.i32, ())
        self.n_springs = blk.scalar(ti.i32, ())
        self.n_triangles = blk.scalar(ti.i32, ())
        self.rest_x = blk.vector(3, fp, cp)
        self.mass = blk.scalar(fp, cp)
        self.inv_mass = blk.scalar(fp, cp)
        self.spring_a = blk.scalar(ti.i32, max(cs, 1))
        self.spring_b = blk.scalar(ti.i32, max(cs, 1))
        self.rest_length = blk.scalar(fp, max(cs, 1))
        self.stiffness = blk.scalar(fp, max(cs, 1))
        self.damping = blk.scalar(fp, max(cs, 1))
        self.viscous = blk.scalar(fp, max(cs, 1))
        self.spring_kind = blk.scalar(ti.i32, max(cs, 1))
        self.stiffness_sum = blk.scalar(fp, cp)
        self.adj_offset = blk.scalar(ti.i32, cp + 1)
        self.adj_spring = blk.scalar(ti.i32, max(2 * cs, 1))
        self.adj_other = blk.scalar(ti.i32, max(2 * cs, 1))
        self.triangles = blk.vector(3, ti.i32, max(ct, 1))
        self.tri_offset = blk.scalar(ti.i32, cp + 1)
        self.tri_list = blk.scalar(ti.i32, max(3 * ct, 1))
        blk.finalize(self)
        self.load(data)

    # ------------------------------------------------------------------ filling (host side, once)
    def load(self, data: ClothData) -> None:
        """Refill every field from `data` (must fit the capacity); pins are cleared."""
        P, S, T = data.n_particles, data.n_springs, len(data.triangles)
        cp, cs, ct = self.capacity
        if P > cp or S > cs or T > ct:
            raise ValueError(f"cloth {(P, S, T)} exceeds the model capacity {self.capacity}")
        if np.any(data.mass <= 0):
            raise ValueError("every particle needs a positive mass")
        self.data = data
        self.pinned = np.zeros(P, dtype=bool)
        self._omega = None  # omega_max, estimated on demand
        self.n_particles[None], self.n_springs[None], self.n_triangles[None] = P, S, T
        npfp = self.np_dtype
        fill_prefix(self.rest_x, data.positions.astype(npfp))
        fill_prefix(self.mass, data.mass.astype(npfp))
        fill_prefix(self.inv_mass, (1.0 / data.mass).astype(npfp))
        a, b = data.springs[:, 0], data.springs[:, 1]
        fill_prefix(self.spring_a, a.astype(np.int32))
        fill_prefix(self.spring_b, b.astype(np.int32))
        fill_prefix(self.rest_length, data.rest_length.astype(npfp))
        fill_prefix(self.stiffness, data.stiffness.astype(npfp))
        fill_prefix(self.damping, data.axial_damping().astype(npfp))
        fill_prefix(self.viscous, data.viscous_damping().astype(npfp))
        fill_prefix(self.spring_kind, data.kind.astype(np.int32))
        fill_prefix(self.stiffness_sum, self.stiffness_sum_np().astype(npfp))
        sid = np.arange(S)
        offsets, adj_spring, adj_other = csr(np.concatenate([a, b]), P, np.concatenate([sid, sid]),
                                             np.concatenate([b, a]))
        fill_prefix(self.adj_offset, offsets.astype(np.int32))
        fill_prefix(self.adj_spring, adj_spring.astype(np.int32))
        fill_prefix(self.adj_other, adj_other.astype(np.int32))
        tri = data.triangles.astype(np.int32)
        fill_prefix(self.triangles, tri)
        toff, tlist = csr(tri.reshape(-1).astype(np.int64), P, np.repeat(np.arange(T), 3))
        fill_prefix(self.tri_offset, toff.astype(np.int32))
        fill_prefix(self.tri_list, tlist.astype(np.int32))

    def pin(self, indices) -> None:
        """Make particles immovable (inverse mass 0). Their mass still counts for energy and weight."""
        idx = np.unique(np.asarray(indices, dtype=np.int64))
        if len(idx) and (idx.min() < 0 or idx.max() >= self.data.n_particles):
            raise ValueError(f"pin index out of range 0..{self.data.n_particles - 1}")
        self.pinned[idx] = True
        self._omega = None
        inv = np.where(self.pinned, 0.0, 1.0 / self.data.mass)
        fill_prefix(self.inv_mass, inv.astype(self.np_dtype))

    def set_stiffness(self, stiffness) -> None:
        """Replace the spring constants [N/m] (scalar or (S,)); kernels read the field, nothing recompiles.
        The damping coefficients keep their ratio kd/k."""
        k_old = self.data.stiffness
        k = np.broadcast_to(np.asarray(stiffness, dtype=np.float64), k_old.shape).copy()
        ratio = np.divide(self.data.damping, k_old, out=np.zeros_like(k_old), where=k_old != 0)
        self.data.stiffness, self.data.damping = k, ratio * k
        self._omega = None
        fill_prefix(self.stiffness, k.astype(self.np_dtype))
        fill_prefix(self.stiffness_sum, self.stiffness_sum_np().astype(self.np_dtype))
        fill_prefix(self.damping, self.data.axial_damping().astype(self.np_dtype))
        fill_prefix(self.viscous, self.data.viscous_damping().astype(self.np_dtype))

    def set_mass(self, mass) -> None:
        """Replace the particle masses [kg] (scalar or (P,)); pins are kept."""
        m = np.broadcast_to(np.asarray(mass, dtype=np.float64), (self.data.n_particles,)).copy()
        if np.any(m <= 0):
            raise ValueError("every particle needs a positive mass")
        self.data.mass = m
        self._omega = None
        fill_prefix(self.mass, m.astype(self.np_dtype))
        fill_prefix(self.viscous, self.data.viscous_damping().astype(self.np_dtype))
        fill_prefix(self.inv_mass, np.where(self.pinned, 0.0, 1.0 / m).astype(self.np_dtype))

    @property
    def np_dtype(self):
        """The numpy dtype of the fields (float32 or float64)."""
        return np.float32 if self.precision == "f32" else np.float64

    # ------------------------------------------------------------------ host-side derived quantities
    @property
    def total_mass(self) -> float:
        return float(self.data.mass.sum())

    def stiffness_sum_np(self) -> np.ndarray:
        """(P,) sum of the spring constants at each particle [N/m]."""
        return stiffness_sum(self.data)

    def omega_max_bound(self) -> float:
        """Gershgorin upper bound [rad/s] on the highest linear frequency: sqrt(max_i 2 sum_j k_ij / m_i)
        over free particles (docs/algorithms.md, step limits). 0 if every particle is pinned."""
        return omega_max_bound(self.data, self.pinned)

    def omega_max(self) -> float:
        """The highest linear frequency [rad/s] of the free particles at the cloth's positions, estimated from above
        (stability.omega_max_estimate: within a few per cent); computed again only when the cloth or its pins
        changed."""
        if self._omega is None:
            self._omega = omega_max_estimate(self.data, self.pinned)
        return self._omega

    def damping_ratio_max(self) -> float:
        """max over springs of (kd + c)/k [s]: the stiffness-proportional damping, with the viscous dashpot c of a
        mesh edge (ClothData.viscous_damping) counted as more of it, which bounds the explicit steps alike."""
        k, kd = self.data.stiffness, self.data.axial_damping() + self.data.viscous_damping()
        r = np.divide(kd, k, out=np.zeros_like(k), where=k != 0)
        return float(r.max()) if len(r) else 0.0




@ti.data_oriented
class State:
    """The moving part of a cloth.

    x: (P,) vec3 fp [m]    positions
    v: (P,) vec3 fp [m/s]  velocities
    t: float [s]           simulated time (host side)
    """

    def __init__(self, model: Model):
        self.model = model
        blk = FieldBlock()
        self.x = blk.vector(3, model.fp, model.capacity[0])
        self.v = blk.vector(3, model.fp, model.capacity[0])
        blk.finalize(self)
        self.t = 0.0
        self.reset()

    def reset(self) -> None:
        """Back to the rest positions, zero velocity, t = 0."""
        self.to_rest()
        self.t = 0.0

    def to_rest(self) -> None:
        """Every particle at its rest position with zero velocity (t unchanged)."""
        self.x.copy_from(self.model.rest_x)
        self.v.fill(0)

    def positions(self) -> np.ndarray:
        """(P,3) float64 copy of the live positions [m]."""
        return self.x.to_numpy()[: self.model.data.n_particles].astype(np.float64)

    def velocities(self) -> np.ndarray:
        """(P,3) float64 copy of the live velocities [m/s]."""
        return self.v.to_numpy()[: self.model.data.n_particles].astype(np.float64)

    def set(self, x=None, v=None) -> None:
        """Overwrite positions [m] and/or velocities [m/s] ((P,3) arrays)."""
        for f, val in ((self.x, x), (self.v, v)):
            if val is not None:
                fill_prefix(f, np.asarray(val, dtype=self.model.np_dtype))
