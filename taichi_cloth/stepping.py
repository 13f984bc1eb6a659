"""The step of a run (Scene.advance, Scene.substep): the integrator's step with the per-step work of the scene's
controllers and its collision stage around it.

One step of dt: every per-step controller's before_step, the collision stage's begin, the integrator's
step(state, contacts, dt), every per-step controller's after_step, then the collision stage (taichi_cloth.colliders),
which pushes the particles out and writes the contacts the next step reads. When every piece of that per-step work
has an inline form (Controller.inline_step) and the integrator can fuse it, a frame's steps run inside the
integrator's own particle loop in few kernel launches instead: nothing between two steps needs the host.
"""
from __future__ import annotations

from .control import overrides


class Stepper:
    """Steps of `integrator` on `state` with the per-step hooks of `controllers` (a list of
    taichi_cloth.control.Controller, in the order their hooks run) and the collision stage `collision` (a Colliders
    writing `contacts`; both None without colliders). Built again when the scene's controllers change.

    fused: whether `advance` runs its steps fused (Integrator.fuse accepted the inline per-step work).
    """

    def __init__(self, integrator, state, contacts, collision, controllers):
        self.integrator, self.state, self.contacts, self.collision = integrator, state, contacts, collision
        stepping = [c for c in controllers if c.per_step]  # a hook without work in this scene costs no call
        self._before = [c.before_step for c in stepping if overrides(c, "before_step")]
        self._after = [c.after_step for c in stepping if overrides(c, "after_step")]
        inline = [c.inline_step() for c in stepping if overrides(c, "before_step") or overrides(c, "after_step")]
        if collision is not None:
            inline.append(collision.inline_step())
        self.fused = all(x is not None for x in inline) and integrator.fuse(tuple(o for x in inline for o in x))

    def advance(self, n: int, dt: float) -> None:
        """n steps of dt [s]: fused when the integrator can, else one `step` after another."""
        if self.fused:
            self.integrator.advance_fused(self.state, self.contacts, n, dt)
            return
        for _ in range(n):
            self.step(dt)

    def step(self, dt: float, observe=None) -> None:
        """One step of dt [s], unfused. observe: a callable of no argument, called right after the integrator's
        step (what the integrator alone did), or None."""
        state, contacts, collision = self.state, self.contacts, self.collision
        for hook in self._before:
            hook(state.t, dt)
        if collision is not None:
            # speculative contacts for the long steps of the implicit integrators (an explicit step's push is short,
            # and its fused steps resolve inline)
            collision.begin(state, contacts, dt if type(self.integrator).unconditionally_stable else None)
        self.integrator.step(state, contacts, dt)
        if observe is not None:
            observe()
        for hook in self._after:
            hook(state.t, dt)
        if collision is not None:
            collision.collide(state, contacts, dt)
