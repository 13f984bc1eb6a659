"""The step clock of a scene: which step dt the next steps take, and how a frame of 1/fps is filled with steps.

Two clocks share one small interface (the scene's loop calls nothing else):

    dt                      the step [s] of Scene.step calls
    frame() -> (n, dt)      the steps of the next frame: n steps of dt fill exactly one frame of 1/fps
    start_frame()           a frame begins (the adaptive clock keeps the state for a rollback)
    observe(max_speed, n)   a frame of n steps ended at that max speed [m/s]
    roll_back() -> bool     undo the frame that just blew up, if the clock can
    model_changed(scale)    the model changed; scale: its step as a multiple of the base step (a coarse 4-8 level)
    reset(), describe(...), counters(), warnings

FixedStep (here) steps a given dt; AdaptiveStep (taichi_cloth.adaptive) chooses it from the stable step.
"""
from __future__ import annotations

import math

#: how far a requested step may sit off a frame's divisor and still count as dividing it (0.008333333 s is 1/120 s)
DIVIDES = 1e-6


def frame_steps(h: float, frame_time: float, tolerance: float = 1e-9) -> tuple[int, float]:
    """(substeps, dt): the fewest equal steps dt <= h [s] that fill one frame of frame_time [s]. A step that divides
    the frame to within `tolerance` (relative) keeps its count (no extra substep from rounding)."""
    n = max(1, math.ceil(frame_time / h * (1.0 - tolerance)))
    return n, frame_time / n


class FixedStep:
    """A fixed step: `dt` [s] times the model's step scale (1, except on coarse 4-8 levels with dt_growth > 1).

    In a run, every frame of 1/fps is filled with equal steps no longer than that: n = ceil(frame / dt) steps of
    frame / n, so the frame clock stays true when dt does not divide a frame (dt = 0.01 s at 60 fps takes two
    steps of 1/120 s per frame). Scene.step(n) takes steps of exactly dt.
    """

    auto = False

    def __init__(self, dt: float, fps: float):
        self.base = float(dt)
        self.scale = 1.0
        self.frame_time = 1.0 / float(fps)
        self.warnings: list[str] = []

    @property
    def dt(self) -> float:
        """The step [s] of Scene.step calls: the base step times the model's scale."""
        return self.base * self.scale

    def set_dt(self, dt: float) -> None:
        """A new base step [s] (the step of the finest level of a multilevel cloth)."""
        self.base = float(dt)

    def refresh(self) -> None:
        """Nothing to re-plan: the step is fixed."""

    def frame(self) -> tuple[int, float]:
        return frame_steps(self.dt, self.frame_time, DIVIDES)

    @property
    def substeps(self) -> int:
        """Steps per frame in a run."""
        return self.frame()[0]

    def start_frame(self) -> None:
        """Nothing to keep: a fixed step has no rollback."""

    def observe(self, max_speed: float, steps: int) -> None:
        """Nothing to adapt."""

    def roll_back(self) -> bool:
        return False

    def model_changed(self, scale: float | None) -> None:
        if scale is not None:
            self.scale = float(scale)

    def reset(self) -> None:
        """Nothing to forget."""

    def counters(self) -> tuple:
        return ()

    def describe(self, dt_min: float | None, dt_max: float | None, since=()) -> str | None:
        """A line for the run summary when the run's steps differ from the requested dt (aligned to the frames, or
        scaled on coarse levels); None when every step was dt."""
        if dt_min is None:
            return None
        if abs(dt_min - self.base) <= DIVIDES * self.base and abs(dt_max - self.base) <= DIVIDES * self.base:
            return None
        used = f"{dt_min:.3g} s" if dt_max <= dt_min * (1 + 1e-9) else f"{dt_min:.3g} .. {dt_max:.3g} s"
        return (f"steps: {used} ({self.base:.3g} s requested; each frame of {self.frame_time:.4g} s is filled with "
                f"equal steps no longer than that)")
