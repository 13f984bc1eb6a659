"""Step-size theory (ALGORITHMS.md 1.4): the largest stable step of an explicit integrator on a model.

omega_max is bounded by Gershgorin, sqrt(max_i 2 sum_j k_ij / m_i) over free particles (cheap, always
valid, used by the engine); `omega_max_exact` computes it from the linearised stiffness at the rest
shape (dense eigenvalues, for small models: tests and the stability study). Damping enters through each
integrator's closed-form condition (`Integrator.is_stable`).

The probes measure the same thing by simulation, for the tests and `python -m taichi_cloth bench stability`:
`probe_scene` (a small sheet with a checkerboard of light and heavy particles, reused across a sweep: the
stiffness goes through Model.set_stiffness and dt is an argument, so nothing recompiles), `probe_run` (a
perturbed run of it), and `critical_step` (bisection on dt between a run that stays bounded and one that grows,
started on the highest mode, `highest_mode`).
"""
from __future__ import annotations

import numpy as np


def stable_dt(integrator_cls, model, air_damping: float, safety: float = 1.0, omega: float | None = None) -> float | None:
    """The largest step [s] the linear theory guarantees stable for `integrator_cls` on `model`, times
    `safety`; None for an unconditionally stable integrator. `omega` [rad/s] defaults to the Gershgorin bound."""
    omega = model.omega_max_bound() if omega is None else omega
    dt = integrator_cls.max_stable_dt(omega, air_damping, model.damping_ratio_max())
    return None if dt is None else safety * dt


def stiffness_matrix(positions: np.ndarray, springs: np.ndarray, stiffness: np.ndarray, rest_length: np.ndarray) -> np.ndarray:
    """Dense (3P,3P) stiffness matrix K = -df/dx of a spring network at `positions` (BW98 Jacobians,
    with the geometric term clamped at 0 for compressed springs)."""
    P = len(positions)
    K = np.zeros((3 * P, 3 * P))
    d = positions[springs[:, 1]] - positions[springs[:, 0]]
    length = np.linalg.norm(d, axis=1)
    u = d / np.maximum(length, 1e-300)[:, None]
    geo = np.maximum(0.0, 1.0 - rest_length / np.maximum(length, 1e-300))
    blocks = stiffness[:, None, None] * (np.einsum("si,sj->sij", u, u) * (1 - geo)[:, None, None]
                                         + geo[:, None, None] * np.eye(3))
    a, b = springs[:, 0], springs[:, 1]
    c = np.arange(3)
    for i, j, sign in ((a, a, 1.0), (b, b, 1.0), (a, b, -1.0), (b, a, -1.0)):
        rows = (3 * i)[:, None, None] + c[None, :, None]
        cols = (3 * j)[:, None, None] + c[None, None, :]
        np.add.at(K, (np.broadcast_to(rows, blocks.shape), np.broadcast_to(cols, blocks.shape)), sign * blocks)
    return K


def _mass_scaled_free(model, positions):
    """(free dof mask (3P,) bool, M^-1/2 on the free dofs, M^-1/2 K M^-1/2 on the free dofs)."""
    d = model.data
    x = d.positions if positions is None else positions
    K = stiffness_matrix(x, d.springs, d.stiffness, d.rest_length)
    free = np.repeat(~model.pinned, 3)
    s = 1.0 / np.sqrt(np.repeat(d.mass, 3))[free]
    return free, s, s[:, None] * K[np.ix_(free, free)] * s[None, :]


def highest_mode(model, positions: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """The highest linear mode of the free particles at `positions` (default: rest shape): its frequency
    [rad/s] and its shape, a (P,3) float64 displacement scaled to a largest entry of 1 (zero on pinned
    particles). Dense, as omega_max_exact."""
    free, s, A = _mass_scaled_free(model, positions)
    lam, vec = np.linalg.eigh(A)
    shape = np.zeros(len(free))
    shape[free] = s * vec[:, -1]  # back from mass-scaled coordinates: x = M^-1/2 y
    shape /= np.abs(shape).max()
    return float(np.sqrt(max(lam[-1], 0.0))), shape.reshape(-1, 3)


def omega_max_exact(model, positions: np.ndarray | None = None) -> float:
    """Highest linear frequency [rad/s] of the free particles at `positions` (default: rest shape), from
    the generalised eigenproblem K v = w^2 M v with pinned particles removed. Dense: use for P < ~1000."""
    lam = np.linalg.eigvalsh(_mass_scaled_free(model, positions)[2])
    return float(np.sqrt(max(lam.max(), 0.0)))


# ---------------------------------------------------------------------- probes (tests, bench stability)
PROBE_AIR = 0.1    # [1/s] the probes' air drag: "a little damping"
PROBE_BETA = 1e-6  # [s] the probes' stiffness-proportional spring damping kd / k


def probe_scene(integrator: str, mass_ratio: float = 1.0, n: int = 6, air_damping: float = PROBE_AIR,
                beta: float = PROBE_BETA, precision: str = "f64", integrator_options: dict | None = None,
                dt: float | str = 1e-3):
    """The stability probe: a 0.3 m square sheet of n x n particles (xy plane, material density 0.2 kg/m^2,
    stretch 1, shear 0.3, bend 0.01 N/m, spring damping ratio `beta` [s]), no gravity, two top corners pinned,
    and a checkerboard of light and heavy particles: neighbours differ by `mass_ratio` (ALGORITHMS.md 5). The
    step guard is off (the caller decides what the guard would say: `Scene._check_step`). Scale the stiffness
    with `probe_run` or Model.set_stiffness; the implicit integrator gets cg_max_iterations = 50 unless
    `integrator_options` say otherwise."""
    from .builder import ClothBuilder
    from .material import Material
    from .scene import Scene

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
    from .errors import BlowUpError

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
