"""Stability probes: the step-size theory of taichi_cloth.stability measured by simulation, for the tests and
`python -m taichi_cloth bench stability`.

`probe_scene` is a small sheet with a checkerboard of light and heavy particles, reused across a sweep (the
stiffness goes through Model.set_stiffness and dt is an argument, so nothing recompiles); `probe_run` is a
perturbed run of it; `critical_step` bisects on dt between a run that stays bounded and one that grows, started
on the highest linear mode (taichi_cloth.stability.highest_mode).
"""
from __future__ import annotations

import numpy as np

from .builder import ClothBuilder
from .errors import BlowUpError
from .material import Material
from .scene import Scene
from .stability import highest_mode

PROBE_AIR = 0.1    # [1/s] the probes' air drag: "a little damping"
PROBE_BETA = 1e-6  # [s] the probes' stiffness-proportional spring damping kd / k


def probe_scene(integrator: str, mass_ratio: float = 1.0, n: int = 6, air_damping: float = PROBE_AIR,
                beta: float = PROBE_BETA, precision: str = "f64", integrator_options: dict | None = None,
                dt: float | str = 1e-3):
    """The stability probe: a 0.3 m square sheet of n x n particles (xy plane, material density 0.2 kg/m^2,
    stretch 1, shear 0.3, bend 0.01 N/m, spring damping ratio `beta` [s]), no gravity, two top corners pinned,
    and a checkerboard of light and heavy particles: neighbours differ by `mass_ratio` (docs/algorithms.md). The
    step guard is off (the caller decides what the guard would say: `Scene._check_step`). Scale the stiffness
    with `probe_run` or Model.set_stiffness; the implicit integrator gets cg_max_iterations = 50 unless
    `integrator_options` say otherwise."""

    mat = Material(density=0.2, stretch=1.0, shear=0.3, bend=0.01, damping=beta)
    cloth = ClothBuilder.grid((0.3, 0.3), (n, n), mat, center=(0.0, 1.0, 0.0), plane="xy")
    i, j = np.meshgrid(np.arange(n), np.arange(n))
    cloth.mass = np.where(((i + j) % 2 == 0).ravel(), cloth.mass, cloth.mass * mass_ratio)
    options = dict(integrator_options or {})
    if integrator == "implicit":
        options.setdefault("cg_max_iterations", 50)
    return Scene(cloth, integrator=integrator, dt=dt, gravity=(0, 0, 0), air_damping=air_damping,
                 step_guard="off", pins=[{"indices": [n * (n - 1), n * n - 1]}], precision=precision,
                 integrator_options=options or None)


def set_max_stiffness(model, k: float) -> None:
    """Scale every spring constant so that the stiffest is k [N/m] (the probes' stiffness axis)."""
    model.set_stiffness(k * model.data.stiffness / model.data.stiffness.max())


def probe_amplitude(model) -> float:
    """The probes' perturbation [m]: 1 mm, less on stiff cloth, min(1e-3, 10 / omega) with omega [rad/s] the
    Gershgorin bound, so that the physical oscillation it starts stays near 10 m/s, far below the 200 m/s at
    which a scene declares a blow-up (at k = 1e7 N/m a 1 mm kick alone reaches ~300 m/s)."""
    omega = model.omega_max_bound()
    return min(1e-3, 10.0 / omega) if omega > 0 else 1e-3


def probe_run(scene, k: float, dt: float, rng: np.random.Generator, steps: int = 300, amplitude: float | None = None,
              check_every: int | None = None, initial: list | None = None):
    """Reset `scene`, make its stiffest spring k [N/m], perturb every free particle by `amplitude` [m] (default
    `probe_amplitude`) x a standard normal (excites every mode), take `steps` steps of dt [s], checking for a
    blow-up every `check_every` steps (None: once, at the end). Returns the last Measurement; raises
    BlowUpError (its .step is the step the check caught it at). The energy [J] right after the perturbation is
    appended to `initial`."""
    scene.reset()
    set_max_stiffness(scene.model, k)
    scene.dt = dt
    x0 = scene.model.data.positions
    a = probe_amplitude(scene.model) if amplitude is None else amplitude
    scene.state.set(x=x0 + a * rng.standard_normal(x0.shape) * ~scene.model.pinned[:, None])
    if initial is not None:
        initial.append(scene.measure().total)
    chunk = check_every or steps
    done, m = 0, None
    while done < steps:
        n = min(chunk, steps - done)
        m = scene.step(n)
        done += n
    return m


def grows(scene, dt: float, shape: np.ndarray, amplitude: float = 1e-6, steps: int = 2000,
          growth: float = 1e3, check_every: int = 250) -> bool:
    """Whether a run of `steps` steps of dt [s] from rest + amplitude x shape ((P,3), [m]), at rest velocity,
    grows: its largest displacement from the rest shape exceeds growth x amplitude at a check, or it blows up
    (BlowUpError). The scene is reset first; its stiffness is left as it is."""
    scene.reset()
    scene.dt = dt
    x0 = scene.model.data.positions
    scene.state.set(x=x0 + amplitude * shape)
    done = 0
    try:
        while done < steps:
            n = min(check_every, steps - done)
            scene.step(n)
            done += n
            if np.abs(scene.positions() - x0).max() > growth * amplitude:
                return True
    except BlowUpError:
        return True
    return False


def critical_step(scene, lo: float, hi: float, rel_tol: float = 1e-4, **grows_options) -> float:
    """The measured critical step [s] of `scene`'s integrator: bisection on dt between lo (a run that stays
    bounded) and hi (one that grows; see `grows`), starting on the highest linear mode, until the bracket is
    narrower than rel_tol relative; returns its middle. Raises ValueError when lo grows or hi does not."""
    shape = highest_mode(scene.model)[1]
    if grows(scene, lo, shape, **grows_options):
        raise ValueError(f"critical_step: the lower end dt = {lo:.6g} s already grows")
    if not grows(scene, hi, shape, **grows_options):
        raise ValueError(f"critical_step: the upper end dt = {hi:.6g} s stays bounded")
    while hi - lo > rel_tol * lo:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if grows(scene, mid, shape, **grows_options) else (mid, hi)
    return 0.5 * (lo + hi)
