"""Pins (Hsiao 2006 "fixed points"): particles held in place, or moved along a scripted path.

Selection is a predicate on rest positions (indices, nearest-to-points, or a box), so it can be
re-applied to a refined mesh. A fixed pin is just inverse mass 0 and costs nothing per step; only a
scene with a moving pin builds the PinDriver and compiles its kernel. `Pins` is the scene's controller: it pins
the selected particles of whatever cloth the model holds (again after a level switch or a seam merge) and moves
the moving groups after every step.
"""

import warnings
from dataclasses import InitVar, dataclass
from typing import Callable, Sequence

import numpy as np
import taichi as ti

from clothbase.fields import FieldBlock
from clothbase.keyframes import KeyframePath

from .control import Controller
from .specs import pin_table


@dataclass
class PinSpec:
    """A group of pinned particles.

    indices:   particle indices;
    near:      points [m]; each pins the particle whose rest position is nearest to it;
    box:       ((xmin, ymin, zmin), (xmax, ymax, zmax)) [m]; pins every particle whose rest position is inside;
    keyframes: None (fixed), keyframes [[t, dx, dy, dz], ...] or any callable t [s] -> offset (3,) [m]: the
               group's motion (a scene file's [[pins]] keyframes); `path=`, its old name, still works with a
               DeprecationWarning;
    where:     what names the group in an error message (a scene file's "[[pins]] #2"), or "".
    A dict for Scene(pins=[...]) is checked as a scene file's [[pins]] table is (pin_spec, taichi_cloth.specs).
    """

    indices: Sequence[int] = ()
    near: Sequence[Sequence[float]] = ()
    box: tuple | None = None
    keyframes: Callable[[float], np.ndarray] | Sequence | None = None
    where: str = ""
    path: InitVar[Callable[[float], np.ndarray] | Sequence | None] = None  # the old name of keyframes

    def __post_init__(self, path):
        if path is not None:
            if self.keyframes is not None:
                raise ValueError("PinSpec: give keyframes, not both keyframes and path (its old name)")
            warnings.warn("PinSpec(path=...) is now PinSpec(keyframes=...) (as in a scene file's [[pins]])",
                          DeprecationWarning, stacklevel=3)
            self.keyframes = path
        if self.keyframes is not None and not callable(self.keyframes):
            self.keyframes = KeyframePath(self.keyframes)

    def select(self, rest_positions: np.ndarray) -> np.ndarray:
        """Indices (sorted, unique) of the particles this spec pins."""
        try:
            return self._select(rest_positions)
        except ValueError as exc:
            raise ValueError(f"{self.where}: {exc}" if self.where else str(exc)) from None

    def _select(self, rest_positions: np.ndarray) -> np.ndarray:
        P = len(rest_positions)
        chosen = [np.asarray(self.indices, dtype=np.int64).reshape(-1)]
        if len(chosen[0]) and (chosen[0].min() < 0 or chosen[0].max() >= P):
            raise ValueError(f"pin indices must lie in 0..{P - 1}")
        if len(self.near):
            pts = np.asarray(self.near, dtype=np.float64).reshape(-1, 3)
            d2 = ((rest_positions[None, :, :] - pts[:, None, :]) ** 2).sum(-1)
            chosen.append(np.argmin(d2, axis=1))
        if self.box is not None:
            lo, hi = (np.asarray(b, dtype=np.float64) for b in self.box)
            inside = np.all((rest_positions >= lo) & (rest_positions <= hi), axis=1)
            if not inside.any():
                raise ValueError(f"pin box {lo.tolist()}..{hi.tolist()} contains no particle")
            chosen.append(np.nonzero(inside)[0])
        idx = np.unique(np.concatenate(chosen))
        if len(idx) == 0:
            raise ValueError("a pin selects no particle (give indices, near or box)")
        return idx


@ti.data_oriented
class PinDriver:
    """Moves the particles of the pin groups that have keyframes. Built only when one does.

    pin_index (N,) i32, pin_origin (N,) vec3 [m], pin_group (N,) i32; group_offset / group_velocity (G,) vec3.
    N is a capacity (`capacity`, default the groups' size) with a live count, so that a refined level can
    reload larger groups in place (`load`) without recompiling.
    """

    def __init__(self, model, state, groups: list[tuple[np.ndarray, Callable]], capacity: int | None = None):
        self.model, self.state = model, state
        self.paths = [path for _, path in groups]
        N = max(int(capacity or 0), sum(len(g) for g, _ in groups))
        G = len(groups)
        blk = FieldBlock()
        self.pin_index = blk.scalar(ti.i32, N)
        self.pin_group = blk.scalar(ti.i32, N)
        self.pin_origin = blk.vector(3, model.fp, N)
        self.group_offset = blk.vector(3, model.fp, G)
        self.group_velocity = blk.vector(3, model.fp, G)
        blk.finalize(self)
        self.capacity = N
        self.load([g for g, _ in groups])

    def load(self, indices: list[np.ndarray]) -> None:
        """(Re)fill the groups' particle indices (one array per group, same order as the paths); the
        origins are the model's current rest positions."""
        if len(indices) != len(self.paths):
            raise ValueError(f"expected {len(self.paths)} pin groups, got {len(indices)}")
        idx = np.concatenate(indices).astype(np.int32)
        if len(idx) > self.capacity:
            raise ValueError(f"{len(idx)} moving pins exceed the driver's capacity {self.capacity}")
        grp = np.concatenate([np.full(len(g), k, np.int32) for k, g in enumerate(indices)])
        self.n = len(idx)
        pad = self.capacity - self.n
        self.pin_index.from_numpy(np.pad(idx, (0, pad)))
        self.pin_group.from_numpy(np.pad(grp, (0, pad)))
        origin = self.model.data.positions[idx].astype(self.model.np_dtype)
        self.pin_origin.from_numpy(np.pad(origin, ((0, pad), (0, 0))))

    def apply(self, t: float, dt: float | None) -> None:
        """Place the moving pins at their offset for time t [s]; their velocity is the path's finite
        difference over the last step dt [s] (zero when dt is None)."""
        for g, path in enumerate(self.paths):
            off = np.asarray(path(t), dtype=np.float64)
            vel = (off - np.asarray(path(t - dt), dtype=np.float64)) / dt if dt else np.zeros(3)
            self.group_offset[g] = off.tolist()
            self.group_velocity[g] = vel.tolist()
        self._place(self.n)

    @ti.kernel
    def _place(self, n: ti.i32):
        ti.loop_config(serialize=self.model.serial)
        for p in range(n):
            i = self.pin_index[p]
            g = self.pin_group[p]
            self.state.x[i] = self.pin_origin[p] + self.group_offset[g]
            self.state.v[i] = self.group_velocity[g]

    def positions(self) -> np.ndarray:
        """(N,3) current positions of the moving pins [m]."""
        return self.state.positions()[self.pin_index.to_numpy()[: self.n]]


def _old_path(self):
    warnings.warn("PinSpec.path is now PinSpec.keyframes (as in a scene file's [[pins]])", DeprecationWarning,
                  stacklevel=2)
    return self.keyframes


# the old name reads the motion too (as an InitVar it would read the class's default, None, for every group)
PinSpec.path = property(_old_path, doc="The old name of keyframes (DeprecationWarning).")


def pin_spec(spec, k: int) -> "PinSpec":
    """The PinSpec of Scene(pins=[...])'s entry k (0-based): a PinSpec passes through; a dict is checked as a
    scene file's [[pins]] table is (taichi_cloth.specs: SceneError naming "[[pins]] #k+1" and the key), and the
    group is named so in later messages (a box that holds no particle)."""
    if isinstance(spec, PinSpec):
        return spec
    where = f"[[pins]] #{k + 1}"
    return PinSpec(**pin_table(spec, where), where=where)


def pinned_mask(specs: Sequence[PinSpec], rest_positions: np.ndarray) -> np.ndarray:
    """(P,) bool: the particles (of a cloth with these rest positions [m]) that any of `specs` pins."""
    pinned = np.zeros(len(rest_positions), dtype=bool)
    for spec in specs:
        pinned[spec.select(rest_positions)] = True
    return pinned


class Pins(Controller):
    """The scene's pins: every PinSpec selects particles on the current cloth's rest positions; their inverse mass
    is 0. Groups with keyframes move after every step (a PinDriver, built only when one has them). `capacity`: the
    most moving particles any cloth of the scene may select (a multilevel cloth's finest level).

    indices: (N,) int64 the pinned particles of the current cloth
    """

    name = "pins"

    def __init__(self, model, state, specs: Sequence[PinSpec], capacity: int | None = None):
        self.model, self.state = model, state
        self.specs = list(specs)
        moving = [s for s in self.specs if s.keyframes is not None]
        self.driver = None
        if moving:
            groups = [(s.select(model.data.positions), s.keyframes) for s in moving]
            self.driver = PinDriver(model, state, groups, capacity)
        self._select()
        self._place(0.0, None)

    @property
    def moving(self) -> bool:
        return self.driver is not None

    def _select(self) -> None:
        rest = self.model.data.positions
        groups = [(spec.select(rest), spec) for spec in self.specs]
        self.model.pin(np.concatenate([idx for idx, _ in groups]) if groups else [])
        if self.driver is not None:
            self.driver.load([idx for idx, spec in groups if spec.keyframes is not None])
        self.indices = np.nonzero(self.model.pinned)[0]

    def _place(self, t: float, dt: float | None) -> None:
        if self.driver is not None:
            self.driver.apply(t, dt)

    @property
    def per_step(self) -> bool:
        return self.driver is not None  # fixed pins are set once, in the inverse masses

    def after_step(self, t: float, dt: float) -> None:
        if self.driver is not None:
            self.driver.apply(t, dt)

    def model_changed(self, change, t: float, dt: float) -> None:
        if change.refills:
            self._select()
        self._place(t, dt)

    def reset(self):
        self._place(0.0, None)
        return None

    def record(self, frame) -> None:
        if len(self.indices):
            (frame.points if self.driver is not None else frame.fixed_points)["pins"] = frame.positions[self.indices]
