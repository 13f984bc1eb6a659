"""The one small contract every integrator honours: `step(state, contacts, dt)` advances the state by dt seconds,
with the contacts the collision stage left (taichi_cloth.colliders)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, ClassVar

import taichi as ti

from ..contacts import require_bound
from ..runtime import PARALLEL_FROM_CPU


@dataclass(frozen=True)
class Option:
    """An integrator option as the scene file and the Python API see it."""

    type: type
    default: Any
    doc: str
    check: Callable[[Any], str | None] = lambda v: None  # returns an error text or None


def positive(v):
    return None if v > 0 else "must be > 0"


def at_least_one(v):
    return None if v >= 1 else "must be >= 1"


def one_of(choices):
    """A check that the value is one of `choices`."""
    return lambda v: None if v in choices else f"must be one of {', '.join(choices)}"


@ti.data_oriented
class Integrator:
    """Base class. Subclasses set `name`, `OPTIONS`, `unconditionally_stable` and implement `_advance(dt)`.

    An explicit integrator also implements `is_stable(h, omega, gamma, beta)`: the closed-form linear
    stability condition for a mode of frequency omega [rad/s] with air drag rate gamma [1/s] and
    stiffness-proportional spring damping beta [s] (docs/algorithms.md, step limits).
    """

    name: ClassVar[str] = ""
    OPTIONS: ClassVar[dict[str, Option]] = {}
    unconditionally_stable: ClassVar[bool] = False
    #: True when positions alone carry the motion (velocity derived from history): Verlet, central difference
    position_based: ClassVar[bool] = False
    #: True when v is the motion over the last step, (x - x_prev) / h: half a step behind the positions, so a
    #: measurement adds half a step of acceleration to read the velocity at the positions' time (the explicit family)
    staggered_velocity: ClassVar[bool] = False
    #: particles from which a cloth stepped by this integrator runs its loops in parallel on the CPU
    #: (runtime.serial_loops; the model is built with it)
    parallel_from_cpu: ClassVar[int] = PARALLEL_FROM_CPU

    def __init__(self, model, state, forces, contacts=None, **options):
        self.model, self.state, self.forces = model, state, forces
        unknown = set(options) - set(self.OPTIONS)
        if unknown:
            raise ValueError(f"integrator {self.name!r} has no option {sorted(unknown)[0]!r}"
                             f" (options: {', '.join(self.OPTIONS) or 'none'})")
        self.options = {k: opt.default for k, opt in self.OPTIONS.items()}
        for k, v in options.items():
            problem = self.OPTIONS[k].check(v)
            if problem:
                raise ValueError(f"integrator {self.name!r} option {k!r} {problem} (got {v!r})")
            self.options[k] = v
        #: cumulative counters worth reporting (e.g. CG iterations); a run reports their mean per step
        self.stats: dict[str, float] = {}
        self.contacts = contacts  # a Contacts (taichi_cloth.contacts) when the scene has colliders
        self.has_contacts = contacts is not None  # compile-time: no colliders, no contact code

    @ti.func
    def contact_filter(self, i, vec):
        """vec without its component along particle i's last contact normal (BW98's constraint filter);
        vec itself when the scene has no colliders or i touched none."""
        out = vec
        if ti.static(self.has_contacts):
            out = self.contacts.filter(i, vec)
        return out

    def step(self, state, contacts, dt: float) -> None:
        """Advance `state` (a State) by dt [s] with `contacts` (the Contacts of the last collision stage, or None
        without colliders): forces are prepared for time t, then the scheme's own update. They must be the state
        and contacts this integrator was built for (its kernels bind their fields): another raises ValueError."""
        require_bound(self, state, contacts)
        self.forces.prepare(state.t)
        self._advance(dt)
        state.t += dt

    def _advance(self, dt: float) -> None:
        raise NotImplementedError

    def fuse(self, colliders: tuple) -> bool:
        """Whether this integrator runs several steps per kernel launch (advance_fused) in this scene, with the
        per-particle resolve of `colliders` inlined; the scene asks when its controllers change. False by default."""
        return False

    def advance_fused(self, state, contacts, n: int, dt: float) -> None:
        """n steps of dt [s] of `state` in few kernel launches (only after fuse() said yes); the state and contacts
        as for step."""
        raise NotImplementedError

    def reset(self) -> None:
        """Forget any history (called when the state is reset or overwritten)."""

    def topology_changed(self, level: int | None = None) -> None:
        """The particles and springs were refilled (a multilevel switch to `level`, 0-based) and x, v
        prolonged: by default forget any history."""
        self.reset()

    @property
    def detail(self) -> str | None:
        """How this integrator solves its step, for the run summary (None: nothing to add to its name)."""
        return None

    def unstable_advice(self) -> str | None:
        """A hint for the blow-up message beyond "a smaller step" (e.g. an option known to be unstable), or None."""
        return None

    @classmethod
    def is_stable(cls, h: float, omega: float, gamma: float, beta: float) -> bool:
        return True

    @classmethod
    def max_stable_dt(cls, omega: float, gamma: float, beta: float) -> float | None:
        """Largest h [s] with is_stable(h, ...) for a mode of frequency omega (bisection on the closed form);
        None for an unconditionally stable integrator or omega = 0."""
        if cls.unconditionally_stable or omega <= 0:
            return None
        lo, hi = 0.0, 4.0 / omega
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if cls.is_stable(mid, omega, gamma, beta) else (lo, mid)
        return lo
