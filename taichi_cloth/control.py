"""The controllers' protocol: what a feature of a scene may do around the integrator's steps.

A Scene holds a model, a state, an integrator, a step clock and a list of controllers (pins, sewing, the level
refiner, the body morph, the stretch limit, the colliders...). The colliders' per-step work is no hook: it is the
scene's collision stage (taichi_cloth.colliders), around the integrator's step. Its loop calls, in list order:

    before_step(t, dt)       before every integrator step (t: the time the step starts at)
    after_step(t, dt)        after every integrator step (t: the time it ended at), before the collision stage
    after_frame(frame)       after every frame's measurement; returns a ModelChange, or None
    reset()                  when the scene goes back to t = 0; returns a ModelChange, or None

A controller never reaches into the scene. It gets the objects it works on (model, state, forces...) when it is
built, and says what it changed by returning a ModelChange; the scene applies every change in one place
(Scene.apply: refill the model's fields and live counts, write or prolong the state, re-plan the step, tell the
integrator, then every controller through model_changed, and count a new topology for the recorder). Adding a
feature adds a controller; the loop stays as it is.

What a controller shows in a recording goes through `layout(layout)` once (the names of its scalar series, its
colliders) and `record(frame)` for every recorded frame (scalars, vertex colours, points, a moving collider's
vertices); the recorder gets that plain data and never sees a controller.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Callable, ClassVar, Mapping

import numpy as np

from .cloth import ClothData
from .diagnostics import Measurement


@dataclass(frozen=True)
class FrameInfo:
    """One finished frame: its index (1-based), the simulated time t [s], the steps taken since the scene started
    (or was reset), and the frame's measurement."""

    frame: int
    t: float
    steps: int
    measurement: Measurement


@dataclass
class ModelChange:
    """What a controller changed, for the scene to apply (every field optional).

    data:      a new cloth (ClothData) for the model's fields: a level switch, merged seams, new spring constants;
               it must fit the model's capacity
    x, v:      (P,3) positions [m] and velocities [m/s] to write after the refill
    rest:      or put every particle at its (new) rest position, at rest
    prolong:   or a callable prolong(state, n_before) that fills the state in place after the refill (a level
               switch: the new vertices from their parents); n_before is the particle count before it
    level:     the 4-8 level now simulated (0-based), for integrators that keep per-level data (a level switch,
               or a garment's seams merged on its start level)
    garment:   a garment's locally refined level (taichi_cloth.garment.levels.GarmentLevel) when `data` is one
               (the sewing follows it instead of the hierarchy's level)
    dt_scale:  the step on this model as a multiple of the scene's base step (coarse levels may step larger)
    topology:  the triangles changed: the recorder logs them again
    event:     a line for the run summary and the recording (what happened)
    warning:   a line for the run summary's warnings
    """

    data: ClothData | None = None
    x: np.ndarray | None = None
    v: np.ndarray | None = None
    rest: bool = False
    prolong: Callable | None = None
    level: int | None = None
    garment: object = None
    dt_scale: float | None = None
    topology: bool = False
    event: str | None = None
    warning: str | None = None

    @property
    def refills(self) -> bool:
        """Whether the model's particles and springs are replaced."""
        return self.data is not None


class Controller:
    """Base class of the controllers: every hook does nothing by default, and the scene calls only the hooks a
    controller overrides.

    name:             how Scene.controller(name) finds it
    changes_topology: whether it may change the cloth's triangles during a run (the recorder then logs the
                      topology on the timeline instead of once)
    stats:            cumulative counters (e.g. stretch-limit passes); a run reports their mean per step
    """

    name: ClassVar[str] = ""
    changes_topology: bool = False
    stats: Mapping[str, float] = MappingProxyType({})  # a controller with counters sets its own dict

    @property
    def busy(self) -> str | None:
        """What this controller is still doing that a drape at rest must wait for (e.g. "sewing"), or None."""
        return None

    @property
    def per_step(self) -> bool:
        """Whether this controller's before_step/after_step have work in this scene (the scene skips them when
        not; e.g. pins without a path)."""
        return True

    def inline_step(self) -> tuple | None:
        """The per-step work of this controller in a form an integrator can run inside its own particle loop
        (objects with a @ti.func resolve_particle(i, start), each touching particle i only), or None. When every
        per-step controller has one, an integrator that fuses substeps runs a frame's steps in few kernel launches."""
        return None

    def before_step(self, t: float, dt: float) -> None:
        """Before an integrator step from time t [s] over dt [s]."""

    def after_step(self, t: float, dt: float) -> None:
        """After an integrator step of dt [s] that ended at time t [s]."""

    def after_frame(self, frame: FrameInfo) -> ModelChange | None:
        """After a frame (the state is measured and sane); a change is applied by the scene."""
        return None

    #: device values this controller needs every frame, carried by the frame's one read (the measurement): a
    #: controller with report_slots > 0 implements report(out, offset), a kernel writing them into out[offset:
    #: offset + report_slots] (float64), and reported(values), which gets them back as a numpy array before
    #: after_frame. Reading its own fields in after_frame would cost the frame a second round trip.
    report_slots: int = 0

    def report(self, out, offset: int) -> None:
        """Write this controller's report_slots values into out[offset:] (a Taichi kernel)."""

    def reported(self, values) -> None:
        """The values report wrote, read with the frame's measurement."""

    def model_changed(self, change: ModelChange, t: float, dt: float) -> None:
        """After the scene applied `change` (from this controller or another) at time t [s]; dt [s] is the step
        from now on. Refill what depends on the model (limited springs, pinned particles...)."""

    def reset(self) -> ModelChange | None:
        """Back to the start of a run (the state is already at rest, t = 0)."""
        return None

    def layout(self, layout) -> None:
        """Add what this controller shows for the whole run to a SceneLayout (taichi_cloth.frame): the names of
        the scalar series its `record` writes, collider descriptions."""

    def record(self, frame) -> None:
        """Add what this controller shows of one frame to a FrameSnapshot (taichi_cloth.frame): scalars, vertex
        colours, points, a moved collider's vertices."""


def overrides(controller: Controller, hook: str) -> bool:
    """Whether `controller` implements `hook` itself (the scene skips the base class's empty ones)."""
    return getattr(type(controller), hook) is not getattr(Controller, hook)
