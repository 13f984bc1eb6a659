"""Sewing (Chen 2013; Fan et al. 1998; docs/algorithms.md, sewing): seam springs pull the partners of every seam
pair together, then the pairs are joined and the drape goes on.

A seam spring is a zero-rest-length spring F = k_s (x_b - x_a). Started at full strength across a gap of tens
of centimetres it would fling the boundary through the body, so its rest length starts at the initial gap and
shrinks every step by close_speed * dt (a ramp), and never below l - REACH * close_speed * dt (a cap: the spring is
never stretched more than one step's closing beyond its rest length). The pull of a pair is then at most
k_s * REACH * close_speed * dt, and k_s is the pieces' own sheet modulus / 2, so the pull scales with what resists
it: a denim seam pulls 4.6 times as hard as a cotton one (23 N against 5.0 N a pair at dt = 1/120 s). A fixed cap
(`max_force` [N], the pull of one pair) is still there for a user who sets one: 5 N, the old default, held denim's
side seams 5.6 mm open against its own stiffness for good while cotton's closed. The springs live in the Model
with the cloth's own, so every integrator treats them alike (implicitly where the integrator is implicit) and they
count in the step-limit bound. With a stiff seam spring and an implicit step, a pair closes by at most about the
cap's reach per step (the step all but reaches the spring's rest length), so the closing speed is about
REACH * close_speed, the ramp's, for every fabric.

Sewing stops when every pair is closer than `epsilon` and the elastic energy changed by less than
`energy_tolerance` over the last frame, relative to the energy itself or, when that is smaller, to the energy of
one seam pair held at the closing gap (below that a change is round-off: two flat squares sewn in zero gravity
end with 1e-11 J whose frame-to-frame noise is tens of per cent). A seam can also stall short of `epsilon`: once
the ramp has reached zero rest length the pull k_s l of a pair balances the cloth's tension and the body's
contact, at a gap that round-off decides (a skirt on a coarse level held 3.3 mm on one machine and closed below
2 mm on another). So a largest gap that has stopped shrinking (by less than STALL_SHRINK over STALL_TIME) and is
below `stall_gap` of the seams' particle spacing also counts as closed: the merge then moves each partner by at
most an eighth of a spacing by default, where the pull would move it no further. Then the pairs are joined: merged into one
particle each (default; Chen 2013's alternative, a very stiff short spring, is join = "spring"), the seam edges
get bend springs across them, gravity comes back on if it was off while sewing, and the drape continues.
"""

import math
import time
from dataclasses import dataclass

import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock
from clothbase.meshes import connected_components, edges_of, rows_in

from ..bending import quadratic_bending
from ..cloth import ClothData, SpringKind
from ..control import Controller, FrameInfo, ModelChange

JOINS = ("merge", "spring", "none")


@dataclass(frozen=True)
class SewingOptions:
    """close_speed [m/s]: how fast the seam rest lengths shrink; max_force [N]: a fixed cap on one pair's pull (None,
    the default: the pull scales with the seam's stiffness, k_s * REACH * close_speed * dt; module docstring);
    epsilon [m]: a seam pair counts as closed below this gap; energy_tolerance: largest relative change of the
    elastic energy over one frame when sewing stops; gravity: gravity on while sewing; join: "merge" (pairs
    become one particle), "spring" (a stiff zero-length spring of join_stiffness [N/m], default 10 x the seam
    stiffness) or "none" (leave the seam springs as they are); max_time [s]: give up sewing after this much
    simulated time (the open seams are reported); stall_gap: a seam whose largest gap has stopped shrinking counts
    as closed below this fraction of the seams' particle spacing (the median distance between neighbouring pairs'
    particles as placed)."""

    close_speed: float = 0.5
    max_force: float | None = None
    epsilon: float = 0.002
    energy_tolerance: float = 1e-2
    gravity: bool = False
    join: str = "merge"
    join_stiffness: float | None = None
    max_time: float = 10.0
    stall_gap: float = 0.25

    def __post_init__(self):
        for name in ("close_speed", "max_force", "epsilon", "energy_tolerance", "max_time", "stall_gap"):
            v = getattr(self, name)
            if name == "max_force" and v is None:
                continue
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
class Sewing(Controller):
    """Closes the seams of a scene whose cloth is a GarmentCloth (a controller; one kernel, compiled once).

    model, state, forces, contacts: the scene's (contacts None without colliders); garment: the GarmentCloth; options: SewingOptions; levels: for a garment run
    coarse to fine, its MultilevelGarment (taichi_cloth.garment.levels): `garment` is then its start level's, and
    after a level switch `garment` and `current_of` are the new level's (the seam gaps, the recording and the
    quality table follow the level).
    active:     True while sewing; closed_at: simulated time [s] the seams closed (None before)
    joined:     the seams were joined; gave_up: sewing stopped at max_time with seams open
    wall:       wall-clock seconds from the first step while sewing to the join, kernel compiles included
    history:    list of SeamGap, one per observed frame (also after joining, measured on the joined pairs)
    current_of: (P0,) int64 the current particle of every original particle (identity until a merge)
    """

    name = "sewing"
    #: the seam spring's largest stretch beyond its rest length, in steps of closing at close_speed (module docstring):
    #: 1.1 gives cotton's seams at 1/120 s exactly the pull of the old fixed cap, 5 N a pair
    REACH = 1.1
    #: a seam has stalled when its largest gap shrank by less than this fraction over the last STALL_TIME [s]
    STALL_SHRINK = 0.05
    STALL_TIME = 0.1

    def __init__(self, model, state, forces, contacts, garment, options: SewingOptions, levels=None):
        self.model, self.state, self.forces, self.contacts = model, state, forces, contacts
        self.x = state.x  # the kernel reads this field
        self.garment, self.options, self.levels = garment, options, levels
        if levels is not None and options.join != "merge":
            raise ValueError(f"a garment run coarse to fine needs join = \"merge\" (the levels are merged ones), got "
                             f"join = {options.join!r}")
        self.changes_topology = options.join == "merge"
        self.first = garment.first_seam_spring
        self.count = len(garment.seam_pairs)
        self.gravity = forces.gravity_value.copy()
        # the elastic energy of one seam pair held at the closing gap: a change below tolerance x this is noise
        k_seam = garment.data.stiffness[self.first:].max() if self.count else 0.0
        self.energy_floor = max(0.5 * float(k_seam) * options.epsilon ** 2, 1e-12)
        self.history: list[SeamGap] = []
        blk = FieldBlock()
        self.pair_ends = blk.vector(2, ti.i32, max(self.count, 1))  # the seam pairs' particles before a join
        self.merged = blk.scalar(ti.i32, ())  # 1 once the pairs are merged (every gap is then 0)
        blk.finalize(self)
        if self.count:
            self.pair_ends.from_numpy(np.ascontiguousarray(garment.seam_pairs, dtype=np.int32))
        self._gap: tuple[float, float] | None = None  # (largest, mean) [m] read with the frame's measurement
        self._start()

    def _start(self) -> None:
        if self.levels is not None:
            self.garment = self.levels.garment
        self.stall_gap = self.options.stall_gap * seam_spacing(self.garment)  # [m]
        self._sewing_from = len(self.history)  # the history of this sewing (a reset starts another)
        self.active = self.count > 0
        self.current_of = np.arange(self.garment.data.n_particles, dtype=np.int64)
        self.closed_at = None
        self.wall = None
        self._wall0 = None
        self.joined = False
        self.gave_up = False
        self._energy = None
        self.merged[None] = 0
        if self.active and not self.options.gravity:
            self.forces.set_gravity((0.0, 0.0, 0.0))
        self._body_friction(not self.active)

    def _body_friction(self, on: bool) -> None:
        """Friction against the colliders in the implicit step: off while sewing, so that the seams pull the pieces
        over the body into place (with it the T-shirt's seams held 2.4 mm apart against the 2 mm to join)."""
        if self.contacts is not None:
            self.contacts.friction_scale[None] = 1.0 if on else 0.0

    def reset(self) -> ModelChange:
        """Back to the pieces as placed, apart, gravity off while sewing: the model is refilled with the garment
        as built (also before a join: the ramp has shortened the seam springs' rest lengths in the fields)."""
        self._start()
        data = self.garment.data
        return ModelChange(data=data, rest=True,
                           topology=self.model.data is not data)

    def model_changed(self, change: ModelChange, t: float, dt: float) -> None:
        """A level switch of a garment run coarse to fine: the seams and pieces of the new level."""
        if self.levels is not None and change.level is not None and self.joined:
            level = change.garment if change.garment is not None else self.levels.levels[change.level]
            self.garment, self.current_of = level.garment, level.current_of

    # ------------------------------------------------------------------ per step
    def before_step(self, t: float, dt: float) -> None:
        if self.active and self._wall0 is None:
            self._wall0 = time.perf_counter()

    def after_step(self, t: float, dt: float) -> None:
        """Shrink the seam springs' rest lengths (ramp and force cap)."""
        if self.active:
            o = self.options
            reach, max_force = (self.REACH * o.close_speed * dt, math.inf) if o.max_force is None else \
                (math.inf, o.max_force)
            self._ramp(self.first, self.count, o.close_speed * dt, reach, max_force)

    @ti.kernel
    def _ramp(self, first: ti.i32, count: ti.i32, shrink: ti.f64, reach: ti.f64, max_force: ti.f64):
        """Shorten every seam spring's rest length by `shrink` [m], but never below its length less `reach` [m], nor
        below its length less max_force / k (one of the two is inf)."""
        m = self.model
        ti.loop_config(serialize=self.model.serial)
        for k in range(count):
            s = first + k
            l = ti.cast((self.x[m.spring_b[s]] - self.x[m.spring_a[s]]).norm(), ti.f64)
            L0 = ti.max(0.0, ti.cast(m.rest_length[s], ti.f64) - shrink)
            L0 = ti.max(L0, l - ti.min(reach, max_force / ti.cast(m.stiffness[s], ti.f64)))
            m.rest_length[s] = ti.cast(L0, self.model.fp)

    # ------------------------------------------------------------------ per frame
    report_slots = 2  # the largest and mean seam gap, read with the frame's measurement

    @ti.kernel
    def report(self, out: ti.template(), offset: ti.i32):
        """out[offset], out[offset + 1] = the largest and the mean distance [m] between the particles of a seam pair
        (0 once merged)."""
        largest = ti.cast(0.0, ti.f64)
        total = ti.cast(0.0, ti.f64)
        ti.loop_config(serialize=self.model.serial)
        for k in range(ti.select(self.merged[None] != 0, 0, self.count)):
            e = self.pair_ends[k]
            gap = (ti.cast(self.x[e[1]], ti.f64) - ti.cast(self.x[e[0]], ti.f64)).norm()
            ti.atomic_max(largest, gap)
            total += gap
        out[offset] = largest
        out[offset + 1] = total / ti.static(max(self.count, 1))

    def reported(self, values) -> None:
        self._gap = (float(values[0]), float(values[1]))

    def gaps(self, x: np.ndarray | None = None) -> np.ndarray:
        """(K,) distance [m] between the two particles of every seam pair now (0 for merged pairs)."""
        x = self.state.positions() if x is None else x
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

    def after_frame(self, frame: FrameInfo) -> ModelChange | None:
        """Record the seam gap, and join the seams once they are closed and the elastic energy has settled
        (changed by less than energy_tolerance of itself, or of one seam pair's energy at the closing gap)."""
        if self._gap is None:  # (no measurement carried it: read the positions)
            g = self.gaps()
            self._gap = (float(g.max()), float(g.mean())) if len(g) else (0.0, 0.0)
        largest, mean = self._gap
        self._gap = None
        self.history.append(SeamGap(frame.t, largest, mean))
        if not self.active:
            return None
        m = frame.measurement
        previous, self._energy = self._energy, m.elastic
        settled = previous is not None and abs(m.elastic - previous) <= self.options.energy_tolerance * max(
            abs(m.elastic), self.energy_floor)
        stalled = largest < self.stall_gap and self._stalled(frame.t, largest)
        if self.count and (largest < self.options.epsilon or stalled) and settled:
            self.closed_at = frame.t
            return self._join(frame, largest, stalled=largest >= self.options.epsilon)
        if frame.t >= self.options.max_time:
            self.gave_up = True
            self.active = False
            self.forces.set_gravity(self.gravity)
            self._body_friction(True)
            g = self.gaps()
            opened = ", ".join(f"{k} ({1e3 * v:.1f} mm)" for k, v in self.open_seams(g).items())
            return ModelChange(warning=f"sewing gave up after {self.options.max_time:g} s: open seams "
                                       f"{opened or 'none'} (largest gap {1e3 * g.max():.1f} mm, epsilon "
                                       f"{1e3 * self.options.epsilon:g} mm); the seam springs stay")
        return None

    def _stalled(self, t: float, largest: float) -> bool:
        """Whether the largest gap [m] shrank by less than STALL_SHRINK of itself since STALL_TIME ago (False
        before sewing has run that long)."""
        past = [h.max for h in self.history[self._sewing_from:] if h.t <= t - self.STALL_TIME + 1e-9]
        return bool(past) and largest >= (1.0 - self.STALL_SHRINK) * past[-1]

    # ------------------------------------------------------------------ joining
    def _join(self, frame: FrameInfo, gap: float, stalled: bool = False) -> ModelChange:
        self.wall = time.perf_counter() - self._wall0 if self._wall0 is not None else 0.0
        self.active = False
        self.joined = True
        self.forces.set_gravity(self.gravity)
        self._body_friction(True)
        join = self.options.join
        data = self.model.data
        x, v = self.state.positions(), self.state.velocities()
        if join == "spring":
            seam = data.kind == int(SpringKind.SEAM)
            k = self.options.join_stiffness or 10.0 * float(data.stiffness[seam].max())
            data = ClothData(x, data.mass, data.springs, np.where(seam, 0.0, data.rest_length),
                             np.where(seam, k, data.stiffness),
                             np.where(seam, self.garment.material.damping * k, data.damping), data.kind, data.triangles,
                             viscosity=data.viscosity)
        elif join == "merge":
            data, x, v, self.current_of = merge_seams(data, self.garment, x, v)
            self.merged[None] = 1
        what = {"merge": "pairs merged", "spring": "pairs joined by stiff springs", "none": "seam springs kept"}[join]
        how = (f"stalled at a largest gap of {1e3 * gap:.2f} mm, below {self.options.stall_gap:g} of the seam spacing"
               if stalled else f"largest gap {1e3 * gap:.2f} mm")
        event = (f"seams closed at t = {self.closed_at:.3f} s after {frame.steps} steps and {self.wall:.2f} s of wall "
                 f"time, compiles included ({how}): {what}; {data.n_particles} particles now")
        if join == "none":
            return ModelChange(event=event)
        # merged on a garment's levels, the model is its start level (the numbering is the same merge's)
        level = self.levels.start_level if self.levels is not None and join == "merge" else None
        return ModelChange(data=data, x=x, v=v, topology=join == "merge", level=level, event=event)

    # ------------------------------------------------------------------ what a recording shows
    def layout(self, layout) -> None:
        layout.series["seam_gap"] = ["max [mm]", "mean [mm]"]
        layout.garment = True

    @property
    def busy(self) -> str | None:
        return "sewing" if self.active else None

    def record(self, frame) -> None:
        gaps = self.gaps(frame.positions.astype(np.float64))
        frame.scalars["seam_gap"] = [1e3 * gaps.max(), 1e3 * gaps.mean()] if len(gaps) else [0.0, 0.0]
        g = self.garment
        if not (self.joined and self.options.join == "merge"):  # the pieces are apart: each its own entity
            frame.pieces = {name: np.arange(g.offsets[k], g.offsets[k + 1]) for k, name in enumerate(g.piece_names)}
        if self.active:  # the seams as lines between their pairs, while they close: one entity, one call a frame
            p = self.current_of[g.seam_pairs]
            frame.segments["seams"] = np.stack([frame.positions[p[:, 0]], frame.positions[p[:, 1]]], 1)


def seam_spacing(garment) -> float:
    """The seams' particle spacing [m]: the median distance between the same side's particles of neighbouring seam
    pairs, as placed (0 for a garment without seams)."""
    pairs, seam = garment.seam_pairs, garment.seam_of_pair
    if len(pairs) < 2:
        return 0.0
    x = garment.data.positions
    same = seam[1:] == seam[:-1]
    steps = np.linalg.norm(x[pairs[1:]] - x[pairs[:-1]], axis=2)[same]
    return float(np.median(steps)) if len(steps) else 0.0


def merge_seams(data: ClothData, garment, x: np.ndarray, v: np.ndarray):
    """Merge every seam pair of `garment` into one particle (connected components: a corner on two seams merges
    with all its partners). Mass adds up; position and velocity are mass-weighted means (momentum is conserved).
    Seam springs go; springs whose ends merged go; new bend springs span every seam edge, with the rest length
    of the two pattern triangles unfolded flat (with quadratic bending, its pairs are rebuilt on the merged mesh).
    Returns (ClothData, x, v, current_of (P0,) int64)."""
    roots = connected_components(data.n_particles, garment.seam_pairs)
    _, current_of = np.unique(roots, return_inverse=True)
    n = int(current_of.max()) + 1
    mass = np.bincount(current_of, data.mass, minlength=n)
    mx = np.stack([np.bincount(current_of, data.mass * x[:, c], minlength=n) for c in range(3)], 1) / mass[:, None]
    mv = np.stack([np.bincount(current_of, data.mass * v[:, c], minlength=n) for c in range(3)], 1) / mass[:, None]

    keep = data.kind != int(SpringKind.SEAM)
    springs = current_of[data.springs[keep]]
    alive = springs[:, 0] != springs[:, 1]
    springs = springs[alive]
    rest, k, kd, kind = (arr[keep][alive] for arr in (data.rest_length, data.stiffness, data.damping, data.kind))
    tris = current_of[data.triangles]

    mat = garment.material
    if mat.bending == "quadratic":
        # the quadratic energy is a sum over hinges whose pairs the merge joined: rebuilt on the merged mesh from
        # the pattern triangles (across a seam, the two pieces' triangles unfolded flat)
        bending = kind == int(SpringKind.QUADRATIC_BEND)
        springs, rest, k, kd, kind = (arr[~bending] for arr in (springs, rest, k, kd, kind))
        pairs, kb = quadratic_bending(tris, garment.rest_uv()[data.triangles], mat.bend)
        new = np.ones(len(pairs), bool)
        L0, kind_new = np.zeros(len(pairs)), SpringKind.QUADRATIC_BEND
    else:
        # bend springs across the new (seam) edges: the hinges of the merged mesh not bent before
        pairs, L0 = hinges(tris, garment.rest_uv()[data.triangles])
        bent = np.sort(springs[kind == int(SpringKind.BEND)], axis=1)
        new = ~rows_in(pairs, bent)
        kb = mat.bend / np.maximum(L0, 1e-9) ** 2
        kind_new = SpringKind.BEND
    if new.any():
        springs = np.concatenate([springs, pairs[new]])
        rest = np.concatenate([rest, L0[new]])
        k = np.concatenate([k, kb[new]])
        kd = np.concatenate([kd, mat.damping * kb[new]])
        kind = np.concatenate([kind, np.full(int(new.sum()), int(kind_new), np.int64)])
    merged = ClothData(mx, mass, springs, rest, k, kd, kind, tris, viscosity=data.viscosity)
    return merged, mx, mv, current_of


def hinges(triangles: np.ndarray, tri_uv: np.ndarray):
    """For every edge shared by two triangles: the two apexes (K, 2) int64 (sorted), and their rest distance
    (K,) [m] with both triangles unfolded into one plane, each keeping its own pattern side lengths (tri_uv:
    (T, 3, 2) [m], the pattern coordinates of each triangle's corners; the two may come from different pieces)."""
    edges, face_edge, counts = edges_of(triangles)
    entry = np.argsort(face_edge.reshape(-1), kind="stable")  # (triangle, corner k) entries grouped by edge
    first = np.searchsorted(face_edge.reshape(-1)[entry], np.nonzero(counts == 2)[0])
    e1, e2 = entry[first], entry[first + 1]

    def side_lengths(e):
        t, k = e // 3, e % 3  # edge k runs from corner k to k + 1; the apex is corner k + 2
        p, q, c = k, (k + 1) % 3, (k + 2) % 3
        uv = tri_uv[t]
        rows = np.arange(len(t))
        L = lambda i, j: np.linalg.norm(uv[rows, i] - uv[rows, j], axis=1)  # noqa: E731
        return triangles[t, c], triangles[t, p], L(c, p), L(c, q), L(p, q)

    r, p1, rp, rq, L1 = side_lengths(e1)
    s, p2, sp, sq, L2 = side_lengths(e2)
    same = p1 == p2  # match the second triangle's sides to the first's edge ends
    sp, sq = np.where(same, sp, sq), np.where(same, sq, sp)
    L = 0.5 * (L1 + L2)
    u1 = (rp**2 - rq**2 + L**2) / (2 * L)
    u2 = (sp**2 - sq**2 + L**2) / (2 * L)
    h1 = np.sqrt(np.maximum(rp**2 - u1**2, 0.0))
    h2 = np.sqrt(np.maximum(sp**2 - u2**2, 0.0))
    pairs = np.sort(np.stack([r, s], 1), axis=1)
    return pairs, np.hypot(u1 - u2, h1 + h2)  # the apexes on opposite sides of the edge
