"""Guards that refuse a scene before it costs anything: memory it cannot have, a run of more steps than anyone
means to wait for, a precision that cannot resolve a step. Each raises SceneError with one line that says the
figure it estimated and what to change.

Figures (measured on x86-64 Linux, ti.cpu, 2 cores; they are bounds to refuse by, not predictions):
- memory: building and running a grid cloth took 5.2-6.5 KB per particle of peak resident memory over the
  interpreter's (200x200: 260 MB, 400x400: 830 MB, explicit or implicit), hence BYTES_PER_PARTICLE = 6 KB;
- time: see "How long a run takes" below;
- precision: the implicit solve's matrix is M + h^2 K. Where a spring's h^2 k / m exceeds 0.1 / epsilon the mass
  term keeps less than one significant digit in f32 (epsilon 1.19e-7): inertia and gravity are lost in the sum
  and the sheet freezes or falls short (a 16x16 sheet, h = 1/60 s: from k = 1e7 N/m, h^2 k / m = 4e3, the f32 run
  falls short of the f64 one; at 1e9 N/m and above it does not move). f64 (epsilon 2.2e-16) resolves it.

How long a run takes (check_run_length; a bound to announce by, meant to be at or somewhat above the truth, never
far below it). steps = frames x the steps of a frame on the finest level the run reaches: a fixed dt's frame
steps; with dt = "auto" those of the clock's rule (taichi_cloth.adaptive: safety x the stable step of
stability.stable_dt, here at the highest frequency of the finest level, where a coarse-to-fine cloth's step is the
shortest; one step a frame for an unconditionally stable integrator). The adaptive clock may take more (halved on
fast motion near a collider, rolled back on a blow-up), never fewer, so this is the least it takes. seconds =
steps x (fixed cost + P x cost per particle), P the most particles the run reaches (the model's capacity: the
finest level of a coarse-to-fine cloth, a garment's pieces before their seams merge):
- explicit family 70 ns a particle (the bench sheets: 37-75 ns); approx-implicit 100 ns (32-101 ns);
- implicit: 0.5 us a particle plus I CG iterations of c each, and 10 us of launches a CG iteration: Jacobi
  (auto below 2,000 particles off 4-8 levels) I = 20 + 2 sqrt(P), c = 30 ns (CG iterations grow with the size: 43,
  79, 133, 200 = the cap on the bench sheets of 10^2, 32^2, 64^2, 128^2 particles at 1/60 s; 112 on a 24^2 sheet
  falling from two corners at 1/120 s, where the other terms still put the step at 1.05x the 2.2 ms measured);
  aggregation (auto from 2,000 particles off 4-8 levels, or preconditioner = multigrid there) I = 25, c = 130 ns;
  the 4-8 level cycle I = 6, c = 250 ns; at most cg_max_iterations, three times as many with newton_converge;
- per step, per particle: a mesh collider 0.8 us (3.1 ms a step at 64x64, 13 ms at 128x128: docs/collision.md),
  self-collision 2 us (2.15 ms a step on the 1,370-particle T-shirt), the stretch limit 30 ns a pass (at most
  min(iterations, 20) passes);
- fixed, per step: 50 us fused (kernel launches), 100 us unfused, 150 us more per mesh collider (its launches: a
  small explicit sheet over the mannequin takes 0.19 ms a step whatever its size), 100 us an implicit step.
Compiling the kernels on a first run (15-25 s for a garment) is not counted.

Against measured runs (2-core CPU; estimate / measured ms a step): the implicit bench sheets of
docs/performance.md, Jacobi 0.95-1.9x (10^2 to 256^2 particles), aggregation 1.6-2.1x, the 4-8 cycle 1.2-1.8x;
the demos hanging_cloth 4.1 / 2.9, drape_on_mannequin 11.3 / 6.1, sew_tshirt 8.3 / 7.4; the 1 cm T-shirt (`run
demos/scenes/sew_tshirt.toml --resolution fit --frames 900`: 5,541 particles, aggregation) 29 / 11.8-30, about
52 s for its 1,800 steps (44-80 s of wall time measured, 15-25 s of it the first frame's compiles); the 5 mm
T-shirt coarse to fine (`sew_tshirt_multilevel.toml --resolution fine --frames 900`, 21,176 particles on its finest
level) 110 / 69-91, about 3.3 min (2.7-2.8 min of wall time). The rule before this one announced both T-shirts
as "about 1.33 min": it took the particles of the level the run starts on (the 5 mm T-shirt starts on 5,541, the
1 cm T-shirt's count, and refines to four times as many), one cost per particle measured on one 128x128 Jacobi
sheet (8 us) whatever the size, the preconditioner or the iteration cap, and no collision stage (an explicit sheet
over the mannequin costs 10x its own step); with dt = "auto" it said nothing (a stiff fine scene at --quality
accurate, 0.9 x the stable step of central differences, ran for hours unannounced).
"""
from __future__ import annotations

import math
import os

import numpy as np

from collision.grid import hashed_cells, pairs_bound
from collision.self_collision import REUSE_MARGIN, default_thickness

from .clock import DIVIDES, frame_steps
from .errors import SceneError
from .linear.policy import AGGREGATION_FROM
from .pins import pinned_mask
from .stability import omega_max_estimate, stable_dt

#: peak resident bytes per particle of a built and running cloth (see the module docstring)
BYTES_PER_PARTICLE = 6 * 1024
#: a run of more steps than this is refused unless confirmed (`run --yes`)
MAX_STEPS = 10_000_000
#: a run estimated to take longer than this [s] has its step count and time printed before it starts
ANNOUNCE_SECONDS = 60.0
#: [s] per particle and step of the explicit integrators and approx-implicit (see the module docstring)
SECONDS_PER_PARTICLE_STEP = {"approx-implicit": 1e-7}
SECONDS_PER_PARTICLE_STEP_DEFAULT = 7e-8
#: the implicit step: [s] per particle and step besides CG; per CG iteration, its launches [s], and by
#: preconditioner (CG iterations a step, [s] per particle and iteration); Jacobi's iterations grow with the size
IMPLICIT_SECONDS_PER_PARTICLE = 5e-7
IMPLICIT_SECONDS_PER_ITERATION = 1e-5
CG_ITERATIONS = {"jacobi": lambda p: 20 + 2 * math.sqrt(p), "aggregation": lambda p: 25, "levels": lambda p: 6}
CG_SECONDS_PER_PARTICLE_ITERATION = {"jacobi": 3e-8, "aggregation": 1.3e-7, "levels": 2.5e-7}
#: with newton_converge a step takes this many times the CG iterations (2-4 times the cost per step)
NEWTON_CONVERGE = 3
#: [s] per particle and step: a mesh collider, self-collision, one pass of the stretch limit (at most STRETCH_PASSES)
MESH_COLLIDER_SECONDS_PER_PARTICLE = 8e-7
SELF_COLLISION_SECONDS_PER_PARTICLE = 2e-6
STRETCH_PASS_SECONDS_PER_PARTICLE = 3e-8
STRETCH_PASSES = 20
#: [s] fixed per step: fused steps (the least a step costs), unfused ones, more per mesh collider, an implicit step
SECONDS_PER_STEP_MIN = 5e-5
SECONDS_PER_STEP_UNFUSED = 1e-4
SECONDS_PER_STEP_MESH_COLLIDER = 1.5e-4
SECONDS_PER_STEP_IMPLICIT = 1e-4
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
    _check_cells_and_pairs(cells, pairs, BYTES_PER_VOXEL_PAIR, what, available)


def check_self_collision_grid(shapes, cell_size: float, thickness: float | None, what: str,
                              available: int | None = None) -> None:
    """The same for self-collision's hashed grid (collision.self_collision): sized for every mesh in `shapes`
    ((positions (P,3) [m], triangles (T,3)) each) in any pose, its triangles' boxes padded by their reach."""
    pairs = max(pairs_bound(np.asarray(x, np.float64), np.asarray(t, np.int64), cell_size,
                            (1 + REUSE_MARGIN) * (thickness or default_thickness(x, t))) for x, t in shapes)
    _check_cells_and_pairs(hashed_cells(pairs), pairs, 4, what, available)  # sized to the bound: no growth


def _check_cells_and_pairs(cells: float, pairs: float, pair_bytes: float, what: str, available: int | None) -> None:
    need = cells * BYTES_PER_VOXEL + pairs * pair_bytes
    have = available_memory() if available is None else available
    grid = f"a voxel grid of {cells:,.0f} cells and {pairs:,.0f} triangle-cell pairs"
    if need > have:
        raise SceneError(f"{what}: {grid} needs about {human_bytes(need)} of memory (estimate) and this machine has "
                         f"{human_bytes(have)} available; use a larger cell_size (or none: 1.5 x the mean edge)")
    if max(cells, pairs) > MAX_FIELD_ENTRIES:
        raise SceneError(f"{what}: {grid} is more than Taichi's 32-bit indices address ({MAX_FIELD_ENTRIES:,}); "
                         "use a larger cell_size (or none: 1.5 x the mean edge)")


def frame_plan(scene) -> tuple[int, float, str]:
    """(steps a frame, dt [s], how dt was chosen) on the finest level the run reaches (module docstring: how long a
    run takes). A fixed dt: the base step (a coarse level's may be dt_growth times longer); dt = "auto": the
    adaptive clock's rule at the stable step of the finest level."""

    clock = scene.clock
    if not clock.auto:
        n, dt = frame_steps(clock.base, clock.frame_time, DIVIDES)
        return n, dt, f"dt = {dt:.3g} s"
    cls = type(scene.integrator)
    bound = clock.bound
    refiner = scene.controller("refiner")
    if bound is not None and refiner is not None:  # the finest level's highest frequency sets its shortest step
        finest = refiner.cloth.levels[-1]
        pins = scene.controller("pins")
        mask = pinned_mask(pins.specs, finest.positions) if pins is not None else np.zeros(finest.n_particles, bool)
        fine = stable_dt(cls, scene.model, scene.forces.air_damping_value, omega=omega_max_estimate(finest, mask))
        bound = bound if fine is None else min(bound, fine)
    n, dt = frame_steps(clock.step_for(bound), clock.frame_time)
    if bound is None:
        rule = "one step a frame: unconditionally stable"
    else:
        rule = f"{clock.options.safety:g} x the stable step {bound:.3g} s" + (" of the finest level" if refiner else "")
        if clock.options.safety * bound < clock.options.dt_min:
            rule = f"dt_min: {rule} is below it"
    return n, dt, f"dt = auto: {dt:.3g} s, {rule}"


def run_steps(scene, frames: int) -> int:
    """Steps a run of `frames` frames takes on the finest level it reaches (frame_plan; with dt = "auto" at least
    that many)."""
    return int(frames) * frame_plan(scene)[0]


def implicit_cost(scene, particles: int) -> tuple[float, float]:
    """([s] a step and a particle, [s] a step) of the implicit integrator's Newton step and CG at `particles`
    (module docstring): the preconditioner auto or the option picks there, its iterations, at most the cap."""

    opts = scene.integrator.options
    policy = getattr(scene.integrator, "policy", None)
    if opts.get("preconditioner") == "jacobi":
        kind = "jacobi"
    elif policy is not None and policy.levels is not None and not policy.garment:
        kind = "levels"
    elif opts.get("preconditioner") == "multigrid" or particles >= AGGREGATION_FROM:
        kind = "aggregation"
    else:
        kind = "jacobi"
    iterations = CG_ITERATIONS[kind](particles) * (NEWTON_CONVERGE if opts.get("newton_converge") else 1)
    iterations = min(iterations, opts.get("cg_max_iterations", 200))
    return (IMPLICIT_SECONDS_PER_PARTICLE + iterations * CG_SECONDS_PER_PARTICLE_ITERATION[kind],
            SECONDS_PER_STEP_IMPLICIT + iterations * IMPLICIT_SECONDS_PER_ITERATION)


def seconds_per_step(scene) -> float:
    """A step's wall time [s] on the CPU at the most particles the run reaches (module docstring: how long a run
    takes): the integrator's, the collision stage's and the stretch limit's, and the launches of a step."""
    particles = max(int(scene.model.capacity[0]), int(scene.model.data.n_particles))
    name = scene.integrator.name
    fixed = SECONDS_PER_STEP_MIN if scene.fused else SECONDS_PER_STEP_UNFUSED
    if name == "implicit":
        per, extra = implicit_cost(scene, particles)
        fixed += extra
    else:
        per = SECONDS_PER_PARTICLE_STEP.get(name, SECONDS_PER_PARTICLE_STEP_DEFAULT)
    colliders = scene.controller("colliders")
    if colliders is not None:
        bodies = len(colliders.bodies)
        per += bodies * MESH_COLLIDER_SECONDS_PER_PARTICLE
        fixed += bodies * SECONDS_PER_STEP_MESH_COLLIDER
        if colliders.self_collision is not None:
            per += SELF_COLLISION_SECONDS_PER_PARTICLE
    limit = scene.controller("stretch_limit")
    if limit is not None:
        per += min(int(limit.iterations), STRETCH_PASSES) * STRETCH_PASS_SECONDS_PER_PARTICLE
    return fixed + particles * per


def estimated_seconds(scene, steps: int) -> float:
    """A rough wall-clock estimate [s] of `steps` steps of this scene on the CPU (see the module docstring)."""
    return steps * seconds_per_step(scene)


def check_run_length(scene, frames: int, confirmed: bool = False, label: str = "scene", announce=print) -> None:
    """Before a run: say its step count and estimated time when it is long (through `announce`), and refuse
    (SceneError) more than MAX_STEPS steps unless `confirmed`. With dt = "auto" the steps come from the clock's rule
    on the finest level (frame_plan): a stiff or fine cloth's short stable step is counted as a fixed dt is."""
    n, _, how = frame_plan(scene)
    steps = int(frames) * n
    seconds = estimated_seconds(scene, steps)
    line = (f"{frames} frames of {n:,} steps ({how}) = {steps:,} steps{' at least' if scene.clock.auto else ''}, "
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
