"""When a drape is at rest: one criterion for `run --until-rest`, the run summary and the garment quality table.

A cloth is at rest at a frame when, with no controller still at work (sewing, refining to the finest level):
  * every free particle moves slower than `max_speed` [m/s], measured by its motion since the last frame
    (displacement / simulated time), and its velocity (what the integrator carries) is below `max_speed` too, so a
    velocity that is noise from the contact response does not pass for rest, nor does a creep the velocity hides;
  * at least 99 % of the free particles move slower than `p99_speed` [m/s];
  * both speed conditions have held at every frame for the last `hold` seconds: a hem swinging to and fro slows
    to nothing at each turn, and one slow frame must not pass for rest;
  * the total energy (kinetic + elastic + gravity) has not risen over the last `window` seconds of simulated time:
    no frame in the window has more energy than an earlier frame in it, beyond `energy_tolerance` x the cloth's
    weight x its size (round-off: float32 positions jitter by about 1e-7 m, a resting sheet's energy by 1e-7 J).
The defaults are the targets of a drape a garment designer waits for: 5 mm/s, 1 mm/s, held half a second, and
one second of energy.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from .diagnostics import Measurement


@dataclass(frozen=True)
class RestCriterion:
    """max_speed, p99_speed [m/s]; hold [s] the speeds must have stayed below them; window [s] of simulated time
    for the energy; energy_tolerance relative to the cloth's weight times its size (the RestMonitor's
    energy_scale)."""

    max_speed: float = 5e-3
    p99_speed: float = 1e-3
    window: float = 1.0
    energy_tolerance: float = 1e-6
    hold: float = 0.5

    def __post_init__(self):
        for name in ("max_speed", "p99_speed", "window", "energy_tolerance", "hold"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
                raise ValueError(f"rest {name} must be a positive number, got {v!r}")
        if self.p99_speed > self.max_speed:
            raise ValueError(f"rest p99_speed ({self.p99_speed} m/s) must not exceed max_speed ({self.max_speed} m/s)")

    def describe(self) -> str:
        return (f"every particle under {1e3 * self.max_speed:g} mm/s (motion and velocity), 99 % under "
                f"{1e3 * self.p99_speed:g} mm/s, both for {self.hold:g} s, energy not rising over {self.window:g} s")


@dataclass(frozen=True)
class RestStatus:
    """The criterion at one frame: at_rest; since [s] (when the current stretch of rest began, None if not at rest);
    motion_speed [m/s] (the fastest free particle's motion over the last frame, inf before a first frame); fast
    (fraction of free particles above p99_speed); velocity [m/s] (the largest velocity); energy_rise [J] (the largest
    rise within the window, None while the window is not yet covered); energy_allowed [J] (the rise the tolerance
    allows); busy (the controller still at work, or None); slow_for [s] (how long the speed conditions have held,
    None while they do not)."""

    at_rest: bool
    since: float | None
    motion_speed: float
    fast: float
    velocity: float
    energy_rise: float | None
    energy_allowed: float
    busy: str | None
    slow_for: float | None = None

    def describe(self, criterion: RestCriterion) -> str:
        if self.at_rest:
            return f"at rest since t = {self.since:.3f} s ({criterion.describe()})"
        why = []
        if self.busy:
            why.append(f"{self.busy} not finished")
        if not self.motion_speed < criterion.max_speed:
            why.append(f"fastest particle {1e3 * self.motion_speed:.3g} mm/s")
        if not self.velocity < criterion.max_speed:
            why.append(f"largest velocity {1e3 * self.velocity:.3g} mm/s")
        if not self.fast <= 0.01:
            why.append(f"{100 * self.fast:.3g} % of the particles above {1e3 * criterion.p99_speed:g} mm/s")
        if self.slow_for is not None and self.slow_for < criterion.hold - 1e-9:
            why.append(f"slow for {self.slow_for:.3g} s only (of {criterion.hold:g} s)")
        if self.energy_rise is None:
            why.append(f"less than {criterion.window:g} s observed")
        elif self.energy_rise > self.energy_allowed:
            why.append(f"energy rose {self.energy_rise:.3g} J within the last {criterion.window:g} s")
        return "not at rest: " + ", ".join(why)


class RestMonitor:
    """Feeds the criterion one frame at a time (observe) and keeps the energy of the last window. energy_scale [J]:
    the cloth's weight times its size (the energy tolerance is a fraction of it)."""

    def __init__(self, criterion: RestCriterion | None = None, energy_scale: float = 1.0):
        self.criterion = criterion or RestCriterion()
        self.energy_scale = float(energy_scale)
        self.reset()

    def reset(self) -> None:
        """Forget the history (a new run from the start, or a change of the cloth's particles)."""
        self._energy: deque[tuple[float, float]] = deque()
        self._since: float | None = None
        self._slow_since: float | None = None
        self.status: RestStatus | None = None

    def observe(self, t: float, m: Measurement, busy: str | None = None) -> RestStatus:
        """The status after a frame ending at simulated time t [s] with measurement m."""
        c = self.criterion
        self._energy.append((t, m.total))
        while self._energy and self._energy[0][0] < t - c.window - 1e-9:
            self._energy.popleft()
        rise = None
        if self._energy[0][0] <= t - c.window + 1e-9:  # the window is covered
            rise, low = -math.inf, math.inf
            for _, e in self._energy:
                rise = max(rise, e - low)
                low = min(low, e)
            rise = max(rise, 0.0) if len(self._energy) > 1 else 0.0
        slow = m.motion_speed < c.max_speed and m.max_speed < c.max_speed and m.motion_fast <= 0.01 and busy is None
        if not slow:
            self._slow_since = None
        elif self._slow_since is None:
            self._slow_since = t
        # a frame's speeds stand for the frame before it: a stretch of slow frames from t0 has been slow since t0 - dt
        slow_for = t - self._slow_since + self._frame_dt(t) if slow else None
        quiet = (slow and slow_for >= c.hold - 1e-9 and rise is not None
                 and rise <= c.energy_tolerance * self.energy_scale)
        if not quiet:
            self._since = None
        elif self._since is None:
            self._since = t
        self.status = RestStatus(quiet, self._since, m.motion_speed, m.motion_fast, m.max_speed, rise,
                                 c.energy_tolerance * self.energy_scale, busy, slow_for)
        return self.status

    def _frame_dt(self, t: float) -> float:
        """The length [s] of the frame ending at t (0 for the first frame seen)."""
        return t - self._energy[-2][0] if len(self._energy) > 1 else 0.0
