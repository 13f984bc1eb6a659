"""Coarse-to-fine simulation (Hsiao 2006 section 2.2): run a coarse 4-8 level until the drape settles, then
switch to the next level, until the finest.

A switch is a ModelChange (taichi_cloth.control) that the scene applies: the Model's fields (allocated at the
finest capacity) are refilled with the next level's particles and springs, positions and velocities are prolonged
to the new vertices in one Taichi kernel (multilevel.prolong), and the pins, the integrator and the constraints
follow. Nothing is recompiled. Built only when the scene's cloth is a MultilevelCloth.

Refinement is global (every triangle bisected: the next level of the hierarchy) or local: only the
triangles whose dihedral angle across the hypotenuse exceeds `angle` degrees, or that touch a collider,
are bisected (with the 4-8 forced splits that keep the mesh conforming, multilevel.hierarchy.refine_local),
never deeper than the hierarchy's finest level, so the fields' capacity still holds. A garment (its merged
outline levels are not bisections of each other) refines locally by taichi_cloth.garment.local: the marked
triangles get the next level's vertices, the pieces are re-triangulated on them and merged again.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from multilevel.hierarchy import refine_local
from multilevel.prolong import Prolongation

from .control import Controller, FrameInfo, ModelChange


@dataclass(frozen=True)
class SettleCriterion:
    """When a level counts as settled (all must hold, checked once per frame):

    max_speed:     every particle slower than this [m/s];
    energy_change: |E(now) - E(window frames ago)| below this fraction of the energy scale M |g| D
                   (total mass [kg] x gravity [m/s^2] x the cloth's rest diameter [m]);
    window:        frames in the energy comparison (also the fewest frames spent on a level);
    max_time:      simulated seconds after which a level is refined even if not settled (None: never).
    (A garment has its own criterion for when sewing stops: taichi_cloth.garment.sewing.)
    """

    max_speed: float = 0.05
    energy_change: float = 1e-4
    window: int = 10
    max_time: float | None = 3.0

    def __post_init__(self):
        if not self.max_speed > 0:
            raise ValueError(f"settle max_speed must be > 0 m/s, got {self.max_speed}")
        if not self.energy_change > 0:
            raise ValueError(f"settle energy_change must be > 0, got {self.energy_change}")
        if int(self.window) != self.window or self.window < 1:
            raise ValueError(f"settle window must be a whole number of frames >= 1, got {self.window}")
        if self.max_time is not None and not self.max_time > 0:
            raise ValueError(f"settle max_time must be > 0 s (or None), got {self.max_time}")


@dataclass
class LevelSwitch:
    """One level change: the level (0-based) entered, at simulated time t [s], after `steps` steps."""

    level: int
    t: float
    steps: int


class Refiner(Controller):
    """The level schedule of a scene whose cloth is a MultilevelCloth (a controller).

    model, state: the scene's; contacts: its Contacts (or None: no colliders); cloth: the MultilevelCloth;
    gravity: (3,) [m/s^2] for the energy scale of the settle criterion; ready: a callable that says when the level
    schedule may begin (a garment: once its seams are joined; None: at once). Until then no frame counts toward
    the settle criterion, and a reset leaves the model to the controller it waits for. garment: the
    MultilevelGarment whose merged levels `cloth` holds (local refinement needs it).
    level:    the current level (0-based; the first paper's N = level + 1)
    switches: the LevelSwitch history (the start level first)
    settled:  whether the settle criterion held at the last observed frame
    """

    name = "refiner"
    changes_topology = True

    def __init__(self, model, state, contacts, cloth, settle: SettleCriterion | None = None,
                 refine: bool | str = True, dt_growth: float = 1.0, angle: float = 20.0, gravity=(0.0, -9.81, 0.0),
                 ready: Callable[[], bool] | None = None, garment=None):
        self.model, self.state, self.contacts, self.cloth = model, state, contacts, cloth
        self.ready = ready
        self.settle = settle or SettleCriterion()
        mode = {True: "global", False: "none"}.get(refine, refine)
        if mode not in ("global", "local", "none"):
            raise ValueError(f"multilevel refine must be 'global', 'local' or 'none', got {refine!r}")
        self.mode = mode
        self.local = None
        if mode == "local" and garment is not None:
            from .garment.local import LocalGarmentRefinement  # scipy.spatial (0.6 s): a garment refined locally

            self.local = LocalGarmentRefinement(garment)
        elif mode == "local" and getattr(cloth.hierarchy.levels[0], "regular", None) is not None:
            raise ValueError("local refinement needs a 4-8 hierarchy of a rectangle (an outline's boundary band "
                             "is re-triangulated per level, not bisected)")
        self.refine_enabled = mode != "none"
        if not 0 < angle < 180:
            raise ValueError(f"multilevel angle must lie in (0, 180) degrees, got {angle}")
        self.angle = float(angle)
        if not 1.0 <= dt_growth <= 2.0:
            raise ValueError(f"multilevel dt_growth must lie in [1, 2], got {dt_growth}")
        # the scene's dt belongs to the finest level; a coarser level may step dt_growth times larger per
        # level (the edge length grows by sqrt(2) per level, and with it the explicit step limit)
        self.dt_growth = float(dt_growth)
        self.prolongation = Prolongation(cloth.capacity[0], model.fp, model.serial)
        finest = cloth.levels[-1]
        diameter = float(np.linalg.norm(np.ptp(finest.positions, axis=0)))
        self.energy_scale = max(float(finest.mass.sum()) * float(np.linalg.norm(gravity)) * diameter, 1e-12)
        # levels whose tables do not carry momentum over exactly (an outline's band: the coarse masses are not the
        # fine masses restricted); a switch onto one adds the difference back as a uniform velocity
        self.lossy = [k > 0 and not _keeps_momentum(cloth.hierarchy.levels[k], cloth.levels[k - 1].mass,
                                                    cloth.levels[k].mass) for k in range(cloth.n_levels)]
        self._steps = 0
        self._restart()

    def _restart(self) -> None:
        self.level = self.cloth.start_level
        self.mesh = self.cloth.hierarchy.levels[self.level]  # the current Level (uv, triangles)
        if self.local is not None:
            self.local.reset()
        self.depth = np.full(self.mesh.n_triangles, self.level, np.int64)
        self._exhausted = False
        self._energies: list[float] = []
        self._level_t0 = 0.0
        self._steps = 0
        self.settled = False
        self.switches = [LevelSwitch(self.level, 0.0, 0)]

    def reset(self) -> ModelChange | None:
        """Back to the start level (the model is refilled with it, the state at its rest shape; with `ready`, the
        controller it waits for refills the model)."""
        self._restart()
        if self.ready is not None:
            return None
        data = self.cloth.levels[self.level]
        if self.model.data is data:
            return None
        return ModelChange(data=data, rest=True, level=self.level,
                           dt_scale=self.dt_scale(self.level), topology=True)

    def dt_scale(self, level: int) -> float:
        """The step on `level` as a multiple of the finest level's step: dt_growth per level below the finest."""
        return self.dt_growth ** (self.cloth.n_levels - 1 - level)

    @property
    def at_finest(self) -> bool:
        """No further refinement: the finest level (global), or nothing left to refine (local)."""
        return self.level == self.cloth.n_levels - 1 or self._exhausted

    @property
    def busy(self) -> str | None:
        return "refinement to the finest level" if self.refine_enabled and not self.at_finest else None

    def after_frame(self, frame: FrameInfo) -> ModelChange | None:
        """Feed one frame's measurement; refine when the level has settled (or used its time budget)."""
        m = frame.measurement
        self._steps = frame.steps
        if self.ready is not None and not self.ready():
            self._level_t0 = frame.t  # the level's time budget starts when the schedule does
            return None
        self._energies.append(m.total)
        w = self.settle.window
        calm = len(self._energies) > w and abs(self._energies[-1] - self._energies[-1 - w]) < (
            self.settle.energy_change * self.energy_scale)
        self.settled = calm and m.max_speed < self.settle.max_speed
        if self.at_finest or not self.refine_enabled:
            return None
        overdue = (self.settle.max_time is not None
                   and frame.t - self._level_t0 >= self.settle.max_time - 1e-12)
        if self.settled or overdue:
            return self.refine()
        return None

    def refine(self) -> ModelChange | None:
        """The switch to the next level, now (apply it with Scene.apply): the next level's cloth, x and v prolonged
        to the new vertices. None when a local refinement found nothing to refine (this is the finest the drape
        needs)."""
        if self.at_finest:
            raise ValueError("the cloth is already at its finest level")
        n_old = self.model.data.n_particles
        old = self.model.data
        garment = None
        if self.local is not None:
            step = self.local.refine(self.marked())
            fits = step is not None and all(
                n <= c for n, c in zip(_size(step[0].level.merged), self.model.capacity))
            if not fits:  # nothing left to refine (or, never seen, more than the finest level's fields hold)
                self._exhausted = True
                return None
            local, mesh = step
            self.local.accept(local)
            data, garment = local.level.merged, local.level
        elif self.mode == "local":
            mesh, depth = refine_local(self.mesh.uv, self.mesh.triangles, self.marked(), self.depth,
                                       self.cloth.n_levels - 1)
            if mesh.n_vertices == n_old:
                self._exhausted = True
                return None
            self.depth = depth
            data = self.cloth.build(mesh)
        else:
            mesh = self.cloth.hierarchy.levels[self.level + 1]
            data = self.cloth.levels[self.level + 1]
        self.level += 1
        self.mesh = mesh
        t = self.state.t
        self._energies = []
        self._level_t0 = t
        self.settled = False
        self.switches.append(LevelSwitch(self.level, t, self._steps))

        lossy = (self.mode == "global" and self.lossy[self.level]) or garment is not None
        momentum = (old.mass[:, None] * self.state.velocities()).sum(0) if lossy else None

        def prolong(state, n_before):
            self.prolongation.apply(mesh, state.x, state.v, n_before)
            if lossy:
                v = state.velocities()
                state.set(v=v + (momentum - (data.mass[:, None] * v).sum(0)) / data.mass.sum())

        return ModelChange(data=data, prolong=prolong, level=self.level, garment=garment,
                           dt_scale=self.dt_scale(self.level), topology=True,
                           event=f"level {self.level + 1} at t = {t:.3f} s: {data.n_particles} particles, "
                                 f"{data.n_springs} springs")

    def record(self, frame) -> None:
        frame.scalars["level"] = self.level + 1

    def layout(self, layout) -> None:
        layout.series["level"] = "level"

    def marked(self) -> np.ndarray:
        """(t,) bool: the current triangles that call for refinement: a dihedral angle across the hypotenuse
        above `angle` degrees (curvature), or a vertex in contact with a collider in the last step. A garment
        refined locally: the dihedral angle across any edge (its triangles have no hypotenuse)."""
        x = self.state.positions()
        if self.local is not None:
            from .garment.local import fold_marks  # scipy.spatial (0.6 s): a garment refined locally

            return fold_marks(x, self.model.data.triangles, self.angle) | self._touching(self.model.data.triangles, x)
        tri = self.mesh.triangles
        n = np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
        key = np.sort(tri[:, :2], axis=1)
        _, inverse, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        inverse = inverse.reshape(-1)
        order = np.argsort(inverse, kind="stable")
        marked = np.zeros(len(tri), dtype=bool)
        # triangles sharing a hypotenuse come in pairs (a diamond); boundary hypotenuses have no partner
        first = np.searchsorted(inverse[order], np.arange(len(count)))
        two = count == 2
        a, b = order[first[two]], order[first[two] + 1]
        bent = np.degrees(np.arccos(np.clip((n[a] * n[b]).sum(axis=1), -1.0, 1.0))) > self.angle
        marked[a[bent]] = marked[b[bent]] = True
        return marked | self._touching(tri, x)

    def _touching(self, tri: np.ndarray, x: np.ndarray) -> np.ndarray:
        """(t,) bool: the triangles with a vertex in contact with a collider in the last step."""
        if self.contacts is None:
            return np.zeros(len(tri), bool)
        touching = np.linalg.norm(self.contacts.normal.to_numpy()[: len(x)], axis=1) > 0
        return touching[tri].any(axis=1)


def _size(data) -> tuple[int, int, int]:
    return data.n_particles, data.n_springs, len(data.triangles)


def _keeps_momentum(level, coarse_mass: np.ndarray, fine_mass: np.ndarray) -> bool:
    """Whether prolonging velocities onto `level` keeps the momentum exactly: every coarse mass is the sum of the
    fine masses it contributes to, weighted (the restriction of the fine masses), to round-off."""
    restricted = np.zeros(len(coarse_mass))
    live = level.parents >= 0
    np.add.at(restricted, level.parents[live], (level.weights * fine_mass[:, None])[live])
    return bool(np.abs(restricted - coarse_mass).max() <= 1e-12 * coarse_mass.max())
