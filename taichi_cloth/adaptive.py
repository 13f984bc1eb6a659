"""Automatic time-step selection, `Scene(dt="auto")` (docs/algorithms.md, step limits, "Adaptive step"; Fan et al. 1998 cites
Desbrun-Gascuel 1996).

The rule, re-evaluated before every frame (and before every `Scene.step` call):

    cap    = clamp(safety x stable step, dt_min, dt_max)
             stable step: the integrator's damped closed form at the estimated highest frequency
             (stability.stable_dt, the step guard's bound); an unconditionally stable integrator (approx-implicit,
             implicit) has none, so its cap is dt_max: one step per frame by default
    h      = min(cap, motion step, rollback limit)
             motion step: only with colliders. When a particle moved more than `motion` x the thinnest collider's
             thickness in one step (frame-end max speed x dt), h is halved (as often as that takes); after
             `calm_steps` calm steps it regrows x `growth`, and once it is back at the cap the motion limit goes
    frame  substeps = ceil(frame time / h), dt = frame time / substeps: frames stay on the fps clock and
             dt <= h <= safety x the stable step

The bound is recomputed whenever the model changes: a multilevel level switch, a garment's seam springs being
joined or merged, Model.set_stiffness / set_mass / pin, a new air drag. They all replace one of the arrays (or
the value) that `AdaptiveStep._model_key` holds, so one identity check per frame notices every one of them; the
key holds the arrays themselves, so an id cannot be recycled.

safety = 0.8 by default. The frequency estimate (stability.omega_max_estimate, the step guard's) lies within 1-2 %
above the exact highest linear frequency (the Gershgorin bound it replaced was 1.4-1.8x above it on cloth sheets).
0.8 keeps a 20 % margin for what the linear theory leaves out (stretched springs, collision and stretch-limit
corrections, float32), at 1/0.8 = 1.25x the steps of the bound; the customary C ~ 0.5 would cost 2x everywhere for
a margin the rollback below provides anyway.

Rollback (`rollback = True`, the default; in Scene.run, while Scene.step raises as before): the clock keeps a copy
of x and v at the start of every frame (two capacity-sized fields, allocated once). A frame that blows up anyway
is rolled back, h is halved and capped there until the model changes, and the frame is run again; the run stops
with the BlowUpError only when the halved step would fall below dt_min. Each rollback is an event in the run
summary and the recording. It is a copy, not a swap of two state buffers (warp.sim's state_in/state_out): a Taichi
kernel binds the fields it reads when it compiles, so swapping buffers would compile every kernel of the scene twice
and double the compile time of every run, where the copy costs one kernel launch per frame. A rollback does not
undo what controllers did during the frame (a sewing ramp's shortened seams, a body morph's progress).
"""

import math
from dataclasses import dataclass, fields

import taichi as ti

from clothbase.fields import FieldBlock

from .clock import frame_steps
from .stability import stable_dt


@dataclass(frozen=True)
class AdaptiveOptions:
    """The rule's parameters (`Scene(..., dt="auto", adaptive={...})`, scene file `[integrator] adaptive`).

    safety:     C, the fraction of the stable step used (0 < C <= 1)
    dt_min:     [s] the smallest step; the run stops with a BlowUpError when a rollback would go below it, and a
                cap clamped up to it (a bound below dt_min) is reported as a warning
    dt_max:     [s] the largest step (default: one frame, 1/fps; never more than a frame)
    growth:     regrowth factor after calm_steps calm steps (> 1)
    calm_steps: steps without fast motion before the step regrows (>= 1)
    motion:     the largest move per step, as a fraction of the thinnest collider's thickness (> 0)
    rollback:   on a blow-up, roll the frame back and halve the step instead of stopping
    """

    safety: float = 0.8
    dt_min: float = 1e-6
    dt_max: float | None = None
    growth: float = 1.25
    calm_steps: int = 50
    motion: float = 0.5
    rollback: bool = True

    def __post_init__(self):
        def bad(key, what):
            raise ValueError(f"adaptive {key} {what}, got {getattr(self, key)!r}")

        num = lambda v: isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)  # noqa: E731
        if not (num(self.safety) and 0 < self.safety <= 1):
            bad("safety", "must lie in (0, 1]")
        if not (num(self.dt_min) and self.dt_min > 0):
            bad("dt_min", "must be > 0 s")
        if self.dt_max is not None and not (num(self.dt_max) and self.dt_max > self.dt_min):
            bad("dt_max", f"must be > dt_min = {self.dt_min:g} s")
        if not (num(self.growth) and self.growth > 1):
            bad("growth", "must be > 1")
        if not (isinstance(self.calm_steps, int) and not isinstance(self.calm_steps, bool) and self.calm_steps >= 1):
            bad("calm_steps", "must be a whole number >= 1")
        if not (num(self.motion) and self.motion > 0):
            bad("motion", "must be > 0")
        if not isinstance(self.rollback, bool):
            bad("rollback", "must be true or false")

    @classmethod
    def keys(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls))


def step_cap(bound: float | None, options: AdaptiveOptions, dt_max: float) -> float:
    """clamp(safety x bound, dt_min, dt_max) [s] for a stable step `bound` [s]; dt_max when bound is None (an
    unconditionally stable integrator)."""
    if bound is None:
        return dt_max
    return min(max(options.safety * bound, options.dt_min), dt_max)


@ti.data_oriented
class AdaptiveStep:
    """The automatic step clock (see the module docstring and taichi_cloth.clock for the interface). Built for
    dt = "auto" only.

    model, state, forces: the scene's; integrator_cls: the integrator class (its stable step); fps: frames per
    simulated second; thickness: the thinnest collider's thickness [m] (None: no colliders, no motion rule).
    bound:      the current stable step [s] (None: unconditionally stable)
    cap:        clamp(safety x bound, dt_min, dt_max) [s]
    dt, substeps: the current plan: dt [s] = frame time / substeps
    halvings, regrowths, rollbacks: how often each rule fired since the last reset
    warnings:   lines for the run summary (a bound below dt_min)
    """

    auto = True

    def __init__(self, model, state, forces, integrator_cls, fps: float, options: AdaptiveOptions,
                 thickness: float | None = None):
        self.model, self.state, self.forces = model, state, forces
        self.cls, self.options = integrator_cls, options
        self.frame_time = 1.0 / fps
        self.dt_max = min(options.dt_max or self.frame_time, self.frame_time)
        if self.dt_max <= options.dt_min:
            raise ValueError(f"adaptive dt_min = {options.dt_min:g} s must be below the frame time "
                             f"{self.frame_time:.4g} s (and dt_max)")
        #: [m] the largest move per step the motion rule allows (None: no colliders, no motion rule)
        self.max_move = options.motion * thickness if thickness else None
        self.warnings: list[str] = []
        self._key = None
        self._x0 = self._v0 = None
        self._n = model.n_particles  # 0-d i32 field: the live particle count
        self.reset()

    # ------------------------------------------------------------------ the bound
    def _model_key(self) -> tuple:
        """What the bound depends on. Holding the arrays themselves (not ids) makes `is` exact."""
        m = self.model
        d = m.data
        return (d, d.stiffness, d.damping, d.mass, m.pinned, int(m.pinned.sum()), self.forces.air_damping_value)

    def _same_model(self, key) -> bool:
        return self._key is not None and all(a is b if not isinstance(a, (int, float)) else a == b
                                             for a, b in zip(key, self._key))

    def _refresh_bound(self) -> bool:
        """Recompute the bound if the model changed since the last call; True if it did. A new model also drops
        the rollback limit (it was about the old model)."""
        key = self._model_key()
        if self._same_model(key):
            return False
        self._key = key
        self.bound = stable_dt(self.cls, self.model, self.forces.air_damping_value)
        self.cap = self.step_for(self.bound)
        self.limit = math.inf
        if self.bound is not None and self.options.safety * self.bound < self.options.dt_min:
            msg = (f"dt = auto: {self.options.safety:g} x the stable step {self.bound:.3g} s is below dt_min = "
                   f"{self.options.dt_min:.3g} s; stepping at dt_min, above the linear-theory bound")
            if msg not in self.warnings:
                self.warnings.append(msg)
        return True

    def step_for(self, bound: float | None) -> float:
        """The cap [s] for a stable step `bound` [s] (None: unconditionally stable)."""
        return step_cap(bound, self.options, self.dt_max)

    # ------------------------------------------------------------------ planning and observing
    def reset(self) -> None:
        """Forget the motion history and the rollback limit (the scene was reset)."""
        self._key = None
        self.motion_dt = math.inf
        self.limit = math.inf
        self.calm = 0
        self.halvings = self.regrowths = self.rollbacks = 0
        self.refresh()

    def refresh(self) -> None:
        """Plan dt for the next frame (or Scene.step call); cheap unless the model changed."""
        self._refresh_bound()
        h = max(min(self.cap, self.motion_dt, self.limit), self.options.dt_min)
        self.substeps, self.dt = frame_steps(h, self.frame_time)

    def frame(self) -> tuple[int, float]:
        self.refresh()
        return self.substeps, self.dt

    def set_dt(self, dt: float) -> None:
        """The step is managed: a request only re-plans it."""
        self.refresh()

    def model_changed(self, scale: float | None) -> None:
        """A new model: re-plan (the bound follows the model, not a level's scale)."""
        self.refresh()

    def observe(self, max_speed: float, steps: int) -> None:
        """After `steps` steps ending at frame-end max speed `max_speed` [m/s]: the motion rule (halve when a
        step moved a particle more than max_move, regrow after calm_steps calm steps)."""
        if self.max_move is None:
            return
        h = self.dt
        if max_speed * h > self.max_move:
            while max_speed * h > self.max_move and h > self.options.dt_min:
                h *= 0.5
                self.halvings += 1
            self.motion_dt = h
            self.calm = 0
            return
        if self.motion_dt == math.inf:
            return
        self.calm += steps
        while self.calm >= self.options.calm_steps and self.motion_dt < math.inf:
            self.calm -= self.options.calm_steps
            self.motion_dt *= self.options.growth
            self.regrowths += 1
            if self.motion_dt >= self.cap:
                self.motion_dt, self.calm = math.inf, 0

    # ------------------------------------------------------------------ rollback
    def start_frame(self) -> None:
        """Keep x, v and t of the frame start (capacity-sized fields, allocated on first use)."""
        if not self.options.rollback:
            return
        s = self.state
        if self._x0 is None:
            blk = FieldBlock()
            self._x0 = blk.vector(3, self.model.fp, self.model.capacity[0])
            self._v0 = blk.vector(3, self.model.fp, self.model.capacity[0])
            blk.finalize(self)
        self._copy(self._x0, s.x, self._v0, s.v)
        self._t0 = s.t

    @ti.kernel
    def _copy(self, x_to: ti.template(), x_from: ti.template(), v_to: ti.template(), v_from: ti.template()):
        ti.loop_config(serialize=self.model.serial)
        for i in range(self._n[None]):
            x_to[i] = x_from[i]
            v_to[i] = v_from[i]

    def roll_back(self) -> bool:
        """Restore the frame start (x, v, t) and halve the step (it stays at most that until the model changes).
        False when rollback is off or the halved step would fall below dt_min: the blow-up stands."""
        if not self.options.rollback or self._x0 is None or self.dt * 0.5 < self.options.dt_min:
            return False
        s = self.state
        self._copy(s.x, self._x0, s.v, self._v0)
        s.t = self._t0
        self.limit = 0.5 * self.dt
        self.calm = 0
        self.rollbacks += 1
        return True

    def counters(self) -> tuple[int, int, int]:
        """(halvings, regrowths, rollbacks) so far."""
        return self.halvings, self.regrowths, self.rollbacks

    def describe(self, dt_min: float | None, dt_max: float | None, since=(0, 0, 0)) -> str:
        """One line for the run summary: the rule, the smallest and largest step [s] a run took, and what the
        rules did since `since` (a `counters()` tuple taken at the start of the run)."""
        rule = (f"{self.options.safety:g} x the stable step" if self.bound is not None
                else f"unconditionally stable: up to {self.dt_max:.3g} s")
        used = f"{dt_min:.3g} .. {dt_max:.3g} s" if dt_max is not None else "none yet"
        extra = "".join(f", {now - then} {what}" for now, then, what in zip(
            self.counters(), since, ("halvings on fast motion", "regrowths", "rollbacks")) if now > then)
        return f"dt = auto ({rule}): steps {used}{extra}"
