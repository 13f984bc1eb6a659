"""Sewing (seeds 003 and 004; ALGORITHMS.md 4.2): seam springs pull the partners of every seam pair together,
then the pairs are joined and the drape goes on.

A seam spring is a zero-rest-length spring F = k_s (x_b - x_a). Started at full strength across a gap of tens
of centimetres it would fling the boundary through the body, so its rest length starts at the initial gap and
shrinks every step by close_speed * dt (a ramp), and never below l - max_force / k_s (a cap: the pull of one
pair stays below max_force). The springs live in the Model with the cloth's own, so every integrator treats them
alike (implicitly where the integrator is implicit) and they count in the step-limit bound. With a stiff seam
spring and an implicit step, a pair closes by at most about max_force / k_s per step (the step all but reaches the
spring's rest length), so the closing speed is min(close_speed, max_force / (k_s dt)): with the defaults
(5 N, k_s = 1091 N/m for cotton, dt = 1/120 s) that is 0.5 m/s, the ramp's.

Sewing stops when every pair is closer than `epsilon` and the elastic energy changed by less than
`energy_tolerance` (relative) over the last frame (seed 004). Then the pairs are joined: merged into one
particle each (default; seed 003's alternative, a very stiff short spring, is join = "spring"), the seam edges
get bend springs across them, gravity comes back on if it was off while sewing, and the drape continues.
"""

import time
from dataclasses import dataclass

import numpy as np
import taichi as ti

from ..builder import ClothData, SpringKind
from ..mesh import interior_edge_opposites

JOINS = ("merge", "spring", "none")


@dataclass(frozen=True)
class SewingOptions:
    """close_speed [m/s]: how fast the seam rest lengths shrink; max_force [N]: cap on one pair's pull;
    epsilon [m]: a seam pair counts as closed below this gap; energy_tolerance: largest relative change of the
    elastic energy over one frame when sewing stops; gravity: gravity on while sewing; join: "merge" (pairs
    become one particle), "spring" (a stiff zero-length spring of join_stiffness [N/m], default 10 x the seam
    stiffness) or "none" (leave the seam springs as they are); max_time [s]: give up sewing after this much
    simulated time (the open seams are reported)."""

    close_speed: float = 0.5
    max_force: float = 5.0
    epsilon: float = 0.002
    energy_tolerance: float = 1e-2
    gravity: bool = False
    join: str = "merge"
    join_stiffness: float | None = None
    max_time: float = 10.0

    def __post_init__(self):
        for name in ("close_speed", "max_force", "epsilon", "energy_tolerance", "max_time"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise ValueError(f"sewing {name} must be a positive number, got {v!r}")
        if self.join not in JOINS:
            raise ValueError(f"sewing join must be one of {', '.join(JOINS)}, got {self.join!r}")
        if self.join_stiffness is not None and not self.join_stiffness > 0:
            raise ValueError(f"sewing join_stiffness must be > 0 N/m, got {self.join_stiffness!r}")


@dataclass
class SeamGap:
    """One frame of the sewing history: t [s], largest and mean pair distance [m]."""

    t: float
    max: float
    mean: float


@ti.data_oriented
class Sewing:
    """Closes the seams of a scene whose cloth is a GarmentCloth (built by Scene; one kernel, compiled once).

    active:     True while sewing; closed_at: simulated time [s] the seams closed (None before)
    wall:       wall-clock seconds from the start of sewing (the first run, or the first step) to the join,
                kernel compiles included
    history:    list of SeamGap, one per observed frame (also after joining, measured on the joined pairs)
    current_of: (P0,) int64 the current particle of every original particle (identity until a merge)
    """

    def __init__(self, scene, garment, options: SewingOptions):
        self.scene, self.garment, self.options = scene, garment, options
        self.model, self.x = scene.model, scene.state.x  # the kernel reads these fields
        self.pairs = garment.seam_pairs.copy()  # in the current numbering
        self.first = garment.first_seam_spring
        self.count = len(self.pairs)
        self.current_of = np.arange(garment.data.n_particles, dtype=np.int64)
        self.gravity = scene.forces.gravity_value.copy()
        self.history: list[SeamGap] = []
        self.reset()

    def reset(self) -> None:
        self.active = self.count > 0
        self.closed_at = None
        self.wall = None
        self._wall0 = None
        self.joined = False
        self.gave_up = False
        self._energy = None
        self.t0 = self.scene.state.t
        if self.active and not self.options.gravity:
            self.scene.forces.set_gravity((0.0, 0.0, 0.0))

    # ------------------------------------------------------------------ per step
    def step(self, dt: float) -> None:
        """Shrink the seam springs' rest lengths (ramp and force cap)."""
        self.start_clock()
        self._ramp(self.first, self.count, self.options.close_speed * dt, self.options.max_force)

    def start_clock(self) -> None:
        """Start the wall clock of `wall` (once)."""
        if self._wall0 is None:
            self._wall0 = time.perf_counter()

    @ti.kernel
    def _ramp(self, first: ti.i32, count: ti.i32, shrink: ti.f64, max_force: ti.f64):
        m = self.model
        for k in range(count):
            s = first + k
            l = ti.cast((self.x[m.spring_b[s]] - self.x[m.spring_a[s]]).norm(), ti.f64)
            L0 = ti.max(0.0, ti.cast(m.rest_length[s], ti.f64) - shrink)
            L0 = ti.max(L0, l - max_force / ti.cast(m.stiffness[s], ti.f64))
            m.rest_length[s] = ti.cast(L0, self.model.fp)

    # ------------------------------------------------------------------ per frame
    def gaps(self, x: np.ndarray | None = None) -> np.ndarray:
        """(K,) distance [m] between the two particles of every seam pair now (0 for merged pairs)."""
        x = self.scene.positions() if x is None else x
        p = self.current_of[self.garment.seam_pairs]
        return np.linalg.norm(x[p[:, 1]] - x[p[:, 0]], axis=1)

    def open_seams(self, gaps: np.ndarray) -> dict:
        """seam name -> largest gap [m], for the seams with a pair wider than epsilon."""
        out = {}
        for s, seam in enumerate(self.garment.spec.seams):
            g = gaps[self.garment.seam_of_pair == s]
            if len(g) and g.max() >= self.options.epsilon:
                out[seam.name] = float(g.max())
        return out

    def observe(self, m) -> bool:
        """Feed one frame's measurement: record the seam gap, and join the seams once they are closed and the
        elastic energy has settled. Returns True when the cloth's topology changed (a merge)."""
        g = self.gaps()
        self.history.append(SeamGap(self.scene.state.t, float(g.max()) if len(g) else 0.0,
                                    float(g.mean()) if len(g) else 0.0))
        if not self.active:
            return False
        previous, self._energy = self._energy, m.elastic
        settled = previous is not None and abs(m.elastic - previous) <= self.options.energy_tolerance * max(
            abs(m.elastic), 1e-12)
        if len(g) and g.max() < self.options.epsilon and settled:
            self.closed_at = self.scene.state.t
            return self._join()
        if self.scene.state.t - self.t0 >= self.options.max_time:
            self.gave_up = True
            self.active = False
            self.scene.forces.set_gravity(self.gravity)
            opened = ", ".join(f"{k} ({1e3 * v:.1f} mm)" for k, v in self.open_seams(g).items())
            self.scene.warnings.append(f"sewing gave up after {self.options.max_time:g} s: open seams {opened or 'none'}"
                                       f" (largest gap {1e3 * g.max():.1f} mm, epsilon "
                                       f"{1e3 * self.options.epsilon:g} mm); the seam springs stay")
        return False

    # ------------------------------------------------------------------ joining
    def _join(self) -> bool:
        self.wall = time.perf_counter() - self._wall0 if self._wall0 is not None else 0.0
        self.active = False
        self.joined = True
        self.scene.forces.set_gravity(self.gravity)
        join = self.options.join
        if join == "none":
            return False
        scene = self.scene
        if join == "spring":
            data = scene.model.data
            seam = data.kind == int(SpringKind.SEAM)
            k = self.options.join_stiffness or 10.0 * float(data.stiffness[seam].max())
            stiffness = np.where(seam, k, data.stiffness)
            new = ClothData(scene.positions(), data.mass, data.springs, np.where(seam, 0.0, data.rest_length),
                            stiffness, np.where(seam, self.garment.material.damping * k, data.damping), data.kind,
                            data.triangles)
            x, v = scene.positions(), scene.velocities()
            scene._load_level(new)
            scene.state.set(x=x, v=v)
            scene._topology_changed()
            return False
        new, x, v, self.current_of = merge_seams(scene.model.data, self.garment, scene.positions(),
                                                 scene.velocities())
        scene._load_level(new)
        scene.state.set(x=x, v=v)
        scene._topology_changed()
        return True


def merge_seams(data: ClothData, garment, x: np.ndarray, v: np.ndarray):
    """Merge every seam pair of `garment` into one particle (union-find: a corner on two seams merges with
    all its partners). Mass adds up; position and velocity are mass-weighted means (momentum is conserved).
    Seam springs go; springs whose ends merged go; new bend springs span every seam edge, with the rest length
    of the two pattern triangles unfolded flat. Returns (ClothData, x, v, current_of (P0,) int64)."""
    P = data.n_particles
    parent = np.arange(P)

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in garment.seam_pairs:
        ra, rb = find(int(a)), find(int(b))
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([find(i) for i in range(P)])
    uniq, current_of = np.unique(roots, return_inverse=True)
    n = len(uniq)
    mass = np.bincount(current_of, data.mass, minlength=n)
    mx = np.stack([np.bincount(current_of, data.mass * x[:, c], minlength=n) for c in range(3)], 1) / mass[:, None]
    mv = np.stack([np.bincount(current_of, data.mass * v[:, c], minlength=n) for c in range(3)], 1) / mass[:, None]

    keep = data.kind != int(SpringKind.SEAM)
    springs = current_of[data.springs[keep]]
    alive = springs[:, 0] != springs[:, 1]
    springs = springs[alive]
    rest, k, kd, kind = (arr[keep][alive] for arr in (data.rest_length, data.stiffness, data.damping, data.kind))
    tris = current_of[data.triangles]

    # bend springs across the new (seam) edges: interior edges of the merged mesh not bent before
    bend = interior_edge_opposites(tris)
    have = {tuple(p) for p in np.sort(springs[kind == int(SpringKind.BEND)], axis=1)}
    new_bend = np.array([p for p in bend if tuple(p) not in have], np.int64).reshape(-1, 2)
    if len(new_bend):
        L0 = _hinge_rest_lengths(garment, tris, new_bend)
        kb = garment.material.bend / np.maximum(L0, 1e-9) ** 2
        springs = np.concatenate([springs, new_bend])
        rest = np.concatenate([rest, L0])
        k = np.concatenate([k, kb])
        kd = np.concatenate([kd, garment.material.damping * kb])
        kind = np.concatenate([kind, np.full(len(new_bend), int(SpringKind.BEND), np.int64)])
    merged = ClothData(mx, mass, springs, rest, k, kd, kind, tris)
    return merged, mx, mv, current_of


def _hinge_rest_lengths(garment, tris: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Rest distance [m] between the two apexes r, s of the triangles hinged on an edge (p, q) when both pattern
    triangles are unfolded into one plane (each keeps its own 2D side lengths)."""
    tri_uv = garment.rest_uv()[garment.data.triangles]  # (T, 3, 2) per-triangle pattern coordinates
    # edge -> the (triangle, apex corner) entries that see it
    apex_of = {}
    for t, tri in enumerate(tris):
        for c in range(3):
            e = (min(tri[(c + 1) % 3], tri[(c + 2) % 3]), max(tri[(c + 1) % 3], tri[(c + 2) % 3]))
            apex_of.setdefault(e, []).append((t, c))
    out = np.zeros(len(pairs))
    wanted = {tuple(p): i for i, p in enumerate(pairs)}
    for e, seen in apex_of.items():
        if len(seen) != 2:
            continue
        (t1, c1), (t2, c2) = seen
        r, s = tris[t1][c1], tris[t2][c2]
        key = (min(r, s), max(r, s))
        if key not in wanted:
            continue
        sides = []
        for t, c in ((t1, c1), (t2, c2)):
            uv = tri_uv[t]
            p_, q_ = (c + 1) % 3, (c + 2) % 3
            if tris[t][p_] != e[0]:
                p_, q_ = q_, p_
            sides.append((np.linalg.norm(uv[c] - uv[p_]), np.linalg.norm(uv[c] - uv[q_]), np.linalg.norm(uv[q_] - uv[p_])))
        L = 0.5 * (sides[0][2] + sides[1][2])
        pts = []
        for sign, (dp, dq, _) in zip((1.0, -1.0), sides):
            u = (dp * dp - dq * dq + L * L) / (2 * L)
            pts.append(np.array([u, sign * np.sqrt(max(dp * dp - u * u, 0.0))]))
        out[wanted[key]] = np.linalg.norm(pts[0] - pts[1])
    return out
