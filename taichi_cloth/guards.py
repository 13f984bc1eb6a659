"""Guards that refuse a scene before it costs anything: memory it cannot have, a run of more steps than anyone
means to wait for, a precision that cannot resolve a step. Each raises SceneError with one line that says the
figure it estimated and what to change.

Figures (measured on x86-64 Linux, ti.cpu, 2 cores; they are bounds to refuse by, not predictions):
- memory: building and running a grid cloth took 5.2-6.5 KB per particle of peak resident memory over the
  interpreter's (200x200: 260 MB, 400x400: 830 MB, explicit or implicit), hence BYTES_PER_PARTICLE = 6 KB;
- time: an explicit step costs about 70 ns per particle and an implicit (Newton + CG) step about 8 us per
  particle at 128x128 (runtime's measurements), never less than about 50 us a step (kernel launches);
- precision: the implicit solve's matrix is M + h^2 K. Where a spring's h^2 k / m exceeds 0.1 / epsilon the mass
  term keeps less than one significant digit in f32 (epsilon 1.19e-7): inertia and gravity are lost in the sum
  and the sheet freezes or falls short (a 16x16 sheet, h = 1/60 s: from k = 1e7 N/m, h^2 k / m = 4e3, the f32 run
  falls short of the f64 one; at 1e9 N/m and above it does not move). f64 (epsilon 2.2e-16) resolves it.
"""
from __future__ import annotations

import math
import os

import numpy as np

from .errors import SceneError

#: peak resident bytes per particle of a built and running cloth (see the module docstring)
BYTES_PER_PARTICLE = 6 * 1024
#: a run of more steps than this is refused unless confirmed (`run --yes`)
MAX_STEPS = 10_000_000
#: a run estimated to take longer than this [s] has its step count and time printed before it starts
ANNOUNCE_SECONDS = 60.0
#: [s] per particle and step, and the least a step costs (see the module docstring)
SECONDS_PER_PARTICLE_STEP = {"implicit": 8e-6}
SECONDS_PER_PARTICLE_STEP_DEFAULT = 7e-8
SECONDS_PER_STEP_MIN = 5e-5
#: the largest h^2 k / m times the precision's epsilon a step resolves (the mass term keeps one digit)
MASS_DIGITS = 0.1
EPSILON = {"f32": float(np.finfo(np.float32).eps), "f64": float(np.finfo(np.float64).eps)}


def available_memory() -> int:
    """Bytes this machine can give a new process now: MemAvailable of /proc/meminfo, else physical memory."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 1 << 62  # unknown: refuse nothing


def human_bytes(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if n < 1024 or unit == "PiB":
            return f"{n:.3g} {unit}"
        n /= 1024
    return f"{n:.3g} PiB"  # unreachable


def human_seconds(s: float) -> str:
    for unit, size in (("years", 365 * 86400), ("days", 86400), ("h", 3600), ("min", 60)):
        if s >= size:
            return f"{s / size:.3g} {unit}"
    return f"{s:.2g} s"


def check_memory(n_particles: int, what: str, available: int | None = None, error: type[Exception] = SceneError,
                 advice: str = "use a coarser resolution") -> None:
    """Refuse (`error`, SceneError by default) a cloth of `n_particles` whose estimated memory exceeds what the
    machine has. `what` names the source and its key in the message (e.g. "[cloth.grid] resolution 30000 x 30000",
    "garment 'skirt' spacing 1e-05 m"); `advice` says what to change."""
    need = float(n_particles) * BYTES_PER_PARTICLE
    have = available_memory() if available is None else available
    if need > have:
        raise error(f"{what}: {n_particles:,} particles need about {human_bytes(need)} of memory (estimate, "
                    f"{BYTES_PER_PARTICLE // 1024} KiB a particle) and this machine has {human_bytes(have)} "
                    f"available; {advice}")


def multilevel_particles(base_cells, levels: int) -> int:
    """Particles of a 4-8 hierarchy of `levels` levels over (nx, ny) base cells, every level kept (a multilevel
    cloth keeps them all): each level roughly doubles the vertices of the one below it."""
    nx, ny = (int(c) for c in base_cells)
    return 2 * (nx + 1) * (ny + 1) * 2 ** (int(levels) - 1)


def check_grid(resolution, what: str, available: int | None = None) -> None:
    """The memory guard of a grid cloth of (nu, nv) particles (ClothBuilder.grid calls it before it allocates, and
    the scene-file reader before Taichi starts)."""
    nu, nv = (int(r) for r in resolution)
    check_memory(nu * nv, f"{what} {nu} x {nv}", available)


def check_multilevel_grid(base_cells, levels: int, what: str, available: int | None = None) -> None:
    """The memory guard of a multilevel grid (ClothBuilder.multilevel_grid and the scene-file reader)."""
    nx, ny = (int(c) for c in base_cells)
    check_memory(multilevel_particles(base_cells, levels), f"{what} base_cells {nx} x {ny}, levels {levels}",
                 available, advice="use fewer levels")


def sheet_particles(area: float, perimeter: float, spacing: float, levels: int = 1) -> int:
    """Particles of pattern pieces of total `area` [m^2] and outline `perimeter` [m] meshed at `spacing` [m]: a
    square lattice inside (area / spacing^2) plus the outline's samples; a hierarchy of several 4-8 levels keeps
    about as many again below its finest (each level halves the one above)."""
    finest = area / spacing ** 2 + perimeter / spacing
    return int(math.ceil(finest * (2.0 if levels > 1 else 1.0)))


#: [bytes] of a dense voxel grid (collision.grid.VoxelGrid): two i32 counts per cell, one i32 per (triangle, cell)
#: pair with room to grow by its factor 1.25 in extent (1.25^2 in pairs)
BYTES_PER_VOXEL = 8
BYTES_PER_VOXEL_PAIR = 4 * 1.25 ** 2
#: a field of more entries than this cannot be indexed by Taichi's 32-bit indices
MAX_FIELD_ENTRIES = 2 ** 31 - 1


def voxel_grid_size(vertices: np.ndarray, triangles: np.ndarray, cell_size: float, pad: float,
                    margin: float) -> tuple[float, float]:
    """(cells, triangle-cell pairs) of the dense voxel grid a mesh collider builds over a body (the formulas of
    collision.grid.VoxelGrid: its box grown by 1.25 plus 2 cells per axis, each triangle's box widened by `pad`
    [m]), as floats: a tiny cell can make them too large for an integer."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    extent = v.max(0) - v.min(0) + 2 * margin
    cells = float(np.prod(np.ceil(1.25 * extent / cell_size) + 2))
    lo, hi = v[t].min(1) - pad, v[t].max(1) + pad
    pairs = float(np.sum(np.prod(np.floor(hi / cell_size) - np.floor(lo / cell_size) + 1, axis=1)))
    return cells, pairs


def check_voxel_grid(vertices, triangles, cell_size: float, pad: float, margin: float, what: str,
                     available: int | None = None) -> None:
    """Refuse (SceneError) a collider voxel grid whose cells or pairs outgrow the machine's memory or Taichi's
    32-bit field indices, before it is allocated. `what` names the collider and its cell_size key."""
    cells, pairs = voxel_grid_size(vertices, triangles, cell_size, pad, margin)
    need = cells * BYTES_PER_VOXEL + pairs * BYTES_PER_VOXEL_PAIR
    have = available_memory() if available is None else available
    grid = f"a voxel grid of {cells:,.0f} cells and {pairs:,.0f} triangle-cell pairs"
    if need > have:
        raise SceneError(f"{what}: {grid} needs about {human_bytes(need)} of memory (estimate) and this machine has "
                         f"{human_bytes(have)} available; use a larger cell_size (or none: 1.5 x the mean edge)")
    if max(cells, pairs) > MAX_FIELD_ENTRIES:
        raise SceneError(f"{what}: {grid} is more than Taichi's 32-bit indices address ({MAX_FIELD_ENTRIES:,}); "
                         "use a larger cell_size (or none: 1.5 x the mean edge)")


def run_steps(scene, frames: int) -> int | None:
    """Steps a run of `frames` frames will take at the scene's step (None with dt = "auto": the clock decides)."""
    if scene.clock.auto:
        return None
    return int(frames) * int(scene.substeps)


def estimated_seconds(scene, steps: int) -> float:
    """A rough wall-clock estimate [s] of `steps` steps of this scene on the CPU (see the module docstring)."""
    per = SECONDS_PER_PARTICLE_STEP.get(scene.integrator.name, SECONDS_PER_PARTICLE_STEP_DEFAULT)
    return steps * max(SECONDS_PER_STEP_MIN, per * scene.model.data.n_particles)


def check_run_length(scene, frames: int, confirmed: bool = False, label: str = "scene", announce=print) -> None:
    """Before a run: say its step count and estimated time when it is long (through `announce`), and refuse
    (SceneError) more than MAX_STEPS steps unless `confirmed`."""
    steps = run_steps(scene, frames)
    if steps is None:
        return
    seconds = estimated_seconds(scene, steps)
    line = (f"{frames} frames of {scene.substeps:,} steps (dt = {scene.dt:.3g} s) = {steps:,} steps, "
            f"about {human_seconds(seconds)} on this CPU (estimate)")
    if steps > MAX_STEPS and not confirmed:
        raise SceneError(f"{label}: the run is too long: {line}; more than {MAX_STEPS:,} steps needs --yes "
                         "(or raise dt)")
    if seconds > ANNOUNCE_SECONDS or steps > MAX_STEPS:
        announce(f"this run takes {line}")


def stiffness_ratio(scene) -> float:
    """The largest h^2 k / m over the cloth's springs (k the spring constant [N/m], m the lighter end's mass
    [kg], h the scene's step [s]): how much the stiffness term outweighs the mass term of M + h^2 K."""
    d = scene.model.data
    if d.n_springs == 0:
        return 0.0
    m = np.minimum(d.mass[d.springs[:, 0]], d.mass[d.springs[:, 1]])
    return float(np.max(scene.dt ** 2 * d.stiffness / np.maximum(m, 1e-300)))


def check_precision(scene, precision: str, label: str = "scene") -> None:
    """Refuse (SceneError) an implicit step that the precision cannot resolve (h^2 k / m above MASS_DIGITS /
    epsilon), advising f64. Explicit integrators are left to the step guard (their stable step keeps h^2 k / m
    below ~4)."""
    if not type(scene.integrator).unconditionally_stable:
        return
    ratio = stiffness_ratio(scene)
    limit = MASS_DIGITS / EPSILON[precision]
    if ratio > limit:
        raise SceneError(f"{label}: {precision} cannot resolve this step: h^2 k / m = {ratio:.3g} (dt = "
                         f"{scene.dt:.3g} s, the stiffest spring against the lightest particle) exceeds "
                         f"{limit:.3g} = {MASS_DIGITS} / {precision} epsilon, so inertia and gravity are lost "
                         "in the solve and the cloth would freeze; use precision = \"f64\" (--precision f64), a "
                         "smaller dt or a softer material")
