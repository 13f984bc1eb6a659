"""Taichi's shipped 3D mass-spring example, run headless, and the same physics as a taichi-cloth scene.

The example is `taichi/examples/ggui_examples/mass_spring_3d_ggui.py` in the installed taichi wheel. It is
read as text, its `arch = ...` and `ti.init(...)` lines are dropped (Taichi is started once, by
taichi_cloth.runtime.init), `n = 128` and `dt = 4e-2 / n` are replaced by the size and step asked for, and the
rest is executed unchanged in a fresh namespace without calling main() (no window). We then drive its own
`substep()` kernel. If a substitution does not find its target (another taichi version), `ExampleUnavailable`
says which, and the bench skips the example.

`ExamplePhysics` is that scene in SI units, and `ExamplePhysics.cloth()` / `.scene()` reproduce it in our
engine: n x n particles of 1 kg spaced quad_size = 1/n m in the plane y = 0.6 m, a spring to every neighbour at a
grid offset (di, dj) with |di| + |dj| <= 2 (structural, diagonal and skip-one "bending" links; the example's
`bending_springs = False` selects exactly these, True would keep only the 8-neighbourhood), rest length
L0 = quad_size |(di, dj)|, stiffness k = spring_Y / L0 [N/m] (its force is spring_Y (l / L0 - 1)), damping
kd = dashpot_damping x quad_size [N s/m] on every spring, gravity (0, -9.8, 0), air drag at rate drag_damping
[1/s], and the ball (radius 0.3 m at the origin) as a frictionless sphere collider of zero thickness.

Differences that cannot be removed (and what they cost, measured in tests/test_peers.py):
  - the example updates v[i] in place inside its parallel spring loop, so the dashpot term of a particle reads
    some neighbours' velocities before and some after their update in that step (a data race: in order within
    a chunk of the parallel loop, arbitrary between chunks). Ours reads every velocity from the start of the
    step. The difference is first order in dt, like the scheme's own error, but large: on a 12 x 12 sheet
    dropped on the ball (dt = 5e-5 s), the example ends 46 mm from a converged float64 run at t = 0.5 s, the same
    kernel with a separate force buffer 0.5 mm, our explicit integrator 0.2 mm. The race also makes it stable at
    steps 1.5-3x above our linear bound (its dashpot update is partly Gauss-Seidel).
  - the example applies gravity to v before the spring loop; gravity is uniform, so the relative velocities
    the dashpot sees are unchanged (only round-off differs).
  - drag: the example multiplies v by exp(-drag dt) after the force update; ours adds -drag m v_old to the force
    (a difference of order drag dt per step: 1e-4 relative at our steps).
  - the ball: the example removes the approaching normal velocity of particles inside or on the ball, before
    moving them, and never moves positions (particles may sink by about one step's travel); ours pushes a
    particle that ended inside back to the surface (Zhang et al. 2017) and removes its approaching normal velocity.
  - the example has no pins, no wind and no checks; its start has a random offset of up to 5 cm in x and z
    (ti.random), which we replace by a deterministic start (`start_positions`).
"""
from __future__ import annotations

import linecache
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import taichi
import taichi as ti

from taichi_cloth import runtime
from taichi_cloth.cloth import ClothData, SpringKind
from taichi_cloth.scene import Scene

from .accuracy import UNSTABLE, Trajectory

EXAMPLE_RELPATH = ("examples", "ggui_examples", "mass_spring_3d_ggui.py")

#: blow-up limits of the peers' runs, the Scene defaults (speed [m/s], structural strain [-])
MAX_SPEED, MAX_STRAIN = 200.0, 10.0


class ExampleUnavailable(RuntimeError):
    """The shipped example cannot be found or no longer has the lines we substitute."""


def example_path() -> Path:
    """Path of mass_spring_3d_ggui.py in the installed taichi package (it may not exist)."""
    return Path(taichi.__file__).parent.joinpath(*EXAMPLE_RELPATH)


#: the example's lines we touch: (what, pattern, replacement template or None to drop the line)
_SUBSTITUTIONS = (
    ("the `arch = ...` line", r"^arch\s*=.*$", None),
    ("the `ti.init(...)` line", r"^ti\.init\(.*\)\s*$", None),
    ("`n = 128`", r"^n\s*=\s*\d+\s*$", "n = {n}"),
    ("`dt = 4e-2 / n`", r"^dt\s*=\s*4e-2\s*/\s*n\s*$", "dt = {dt!r}"),
)


def headless_source(n: int, dt: float, source: str | None = None) -> str:
    """The example's source with the arch/init lines dropped and n, dt [s] substituted (each must match once).
    Raises ExampleUnavailable naming the first line it cannot find."""
    if source is None:
        path = example_path()
        if not path.is_file():
            raise ExampleUnavailable(f"{path} is not in the installed taichi package")
        source = path.read_text()
    for what, pattern, repl in _SUBSTITUTIONS:
        matches = re.findall(pattern, source, flags=re.M)
        if len(matches) != 1:
            raise ExampleUnavailable(f"the example's {what} was found {len(matches)} times (expected once): "
                                     f"this taichi version's example differs from 1.7.4's")
        new = "# (removed for a headless run)" if repl is None else repl.format(n=int(n), dt=float(dt))
        source = re.sub(pattern, new, source, count=1, flags=re.M)
    return source


_LOADED = [0]  # a counter for unique pseudo file names


class TaichiExample:
    """The shipped example at n x n particles and step dt [s], headless, Taichi already initialised.

    ns: the example's namespace (its fields x, v: (n, n) vec3 f32 [m], [m/s]; its kernel substep()).
    Particle (i, j) of the example is our particle i n + j.
    """

    NEEDED = ("substep", "x", "v", "n", "dt", "quad_size", "spring_Y", "dashpot_damping", "drag_damping",
              "ball_radius", "ball_center", "gravity", "spring_offsets")

    def __init__(self, n: int, dt: float):
        runtime.ensure_initialized()
        src = headless_source(n, dt)
        _LOADED[0] += 1
        # Taichi reads a kernel's source back through inspect/linecache: register the text under a pseudo name
        filename = f"<taichi example mass_spring_3d_ggui headless #{_LOADED[0]}>"
        linecache.cache[filename] = (len(src), None, src.splitlines(keepends=True), filename)
        ns = {"__name__": "mass_spring_3d_ggui_headless", "__file__": filename}
        exec(compile(src, filename, "exec"), ns)  # defines fields and kernels; main() is not called
        missing = [k for k in self.NEEDED if k not in ns]
        if missing:
            raise ExampleUnavailable(f"the example no longer defines {', '.join(missing)}")
        self.ns = ns
        self.n, self.dt = int(ns["n"]), float(ns["dt"])
        self.physics = ExamplePhysics.from_example(ns)
        self.steps_taken = 0

    def set_state(self, x: np.ndarray, v: np.ndarray | None = None) -> None:
        """Positions (P,3) [m] (our order, P = n^2) and velocities (default 0) [m/s]; t = 0."""
        n = self.n
        self.ns["x"].from_numpy(np.asarray(x, np.float32).reshape(n, n, 3))
        self.ns["v"].from_numpy(np.zeros((n, n, 3), np.float32) if v is None
                                else np.asarray(v, np.float32).reshape(n, n, 3))
        self.steps_taken = 0

    def advance(self, steps: int) -> None:
        """`steps` calls of the example's substep() (each one step of dt), then ti.sync()."""
        substep = self.ns["substep"]
        for _ in range(steps):
            substep()
        ti.sync()
        self.steps_taken += steps

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions (P,3), velocities (P,3)) float64 [m], [m/s] in our particle order."""
        return (self.ns["x"].to_numpy().reshape(-1, 3).astype(np.float64),
                self.ns["v"].to_numpy().reshape(-1, 3).astype(np.float64))


@dataclass(frozen=True)
class ExamplePhysics:
    """The shipped example's scene in SI units (defaults: taichi 1.7.4's file).

    n: particles per side; quad_size [m] = 1/n; spring_Y [N] (force spring_Y (l/L0 - 1), so k = spring_Y / L0);
    dashpot_damping [N s/m^2] (kd = dashpot_damping x quad_size); drag_damping [1/s]; ball_radius [m];
    ball_center (3,) [m]; gravity (3,) [m/s^2]; height [m] of the start plane; offsets: the grid offsets (di, dj)
    of the springs (both signs, as the example lists them); mass [kg] per particle (the example's force is its
    acceleration: 1 kg).
    """

    n: int
    spring_Y: float = 3e4
    dashpot_damping: float = 1e4
    drag_damping: float = 1.0
    ball_radius: float = 0.3
    ball_center: tuple = (0.0, 0.0, 0.0)
    gravity: tuple = (0.0, -9.8, 0.0)
    height: float = 0.6
    offsets: tuple = field(default=tuple((i, j) for i in range(-2, 3) for j in range(-2, 3)
                                         if (i, j) != (0, 0) and abs(i) + abs(j) <= 2))
    mass: float = 1.0

    @property
    def quad_size(self) -> float:
        return 1.0 / self.n

    @classmethod
    def from_example(cls, ns: dict) -> "ExamplePhysics":
        """The physics read from a loaded example's namespace (whatever its constants are)."""
        offsets = tuple((int(o[0]), int(o[1])) for o in ns["spring_offsets"])
        return cls(n=int(ns["n"]), spring_Y=float(ns["spring_Y"]), dashpot_damping=float(ns["dashpot_damping"]),
                   drag_damping=float(ns["drag_damping"]), ball_radius=float(ns["ball_radius"]),
                   ball_center=tuple(float(c) for c in ns["ball_center"].to_numpy()[0]),
                   gravity=tuple(float(g) for g in ns["gravity"].to_numpy()), offsets=offsets)

    def key(self) -> dict:
        """Everything that defines the scene (for cache keys)."""
        return {k: getattr(self, k) for k in ("n", "spring_Y", "dashpot_damping", "drag_damping", "ball_radius",
                                              "ball_center", "gravity", "height", "offsets", "mass")}

    def start_positions(self, offset=(0.0, 0.0)) -> np.ndarray:
        """(P,3) float64 [m]: the example's initialize_mass_points() with its random offset replaced by `offset`
        [m] (x, z): particle (i, j) at (i q - 0.5 + ox, height, j q - 0.5 + oz), our index i n + j."""
        n, q = self.n, self.quad_size
        i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        x = np.stack([i * q - 0.5 + offset[0], np.full(i.shape, self.height), j * q - 0.5 + offset[1]], axis=-1)
        return x.reshape(-1, 3).astype(np.float64)

    def springs(self) -> tuple[np.ndarray, np.ndarray]:
        """(S,2) int64 particle pairs (each unordered pair once) and (S,2) int64 their grid offsets (di, dj)."""
        n = self.n
        idx = np.arange(n * n).reshape(n, n)
        pairs, offs = [], []
        for di, dj in self.offsets:
            if (di, dj) <= (0, 0):  # the example visits each pair from both ends; keep one direction
                continue
            a = idx[max(0, -di):n - max(0, di), max(0, -dj):n - max(0, dj)]
            b = idx[max(0, di):n + min(0, di), max(0, dj):n + min(0, dj)]
            pairs.append(np.stack([a.ravel(), b.ravel()], 1))
            offs.append(np.tile([di, dj], (a.size, 1)))
        return np.concatenate(pairs).astype(np.int64), np.concatenate(offs).astype(np.int64)

    def cloth(self, positions: np.ndarray | None = None):
        """The example as ClothData: start `positions` (P,3) [m] (default start_positions()), rest lengths from
        the grid (not from the start, which may be deformed), k = spring_Y / L0, kd = dashpot_damping x
        quad_size, 1 kg particles, the example's triangles."""
        n, q = self.n, self.quad_size
        x = self.start_positions() if positions is None else np.asarray(positions, np.float64)
        springs, offs = self.springs()
        rest = q * np.linalg.norm(offs.astype(np.float64), axis=1)
        l1 = np.abs(offs).sum(axis=1)
        diagonal = (np.abs(offs[:, 0]) == 1) & (np.abs(offs[:, 1]) == 1)
        kind = np.where(l1 == 1, SpringKind.STRUCTURAL, np.where(diagonal, SpringKind.SHEAR, SpringKind.BEND))
        idx = np.arange(n * n).reshape(n, n)
        c00, c10, c01, c11 = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()
        tri = np.concatenate([np.stack([c00, c10, c01], 1), np.stack([c11, c01, c10], 1)])  # the example's indices
        return ClothData(x.copy(), np.full(n * n, self.mass), springs, rest, self.spring_Y / rest,
                         np.full(len(springs), self.dashpot_damping * q), kind.astype(np.int64), tri.astype(np.int64),
                         None)

    def collider(self) -> dict:
        """The ball as our collider spec: frictionless (the example only removes the normal velocity), no
        thickness (it tests |x - c| <= r)."""
        return {"type": "sphere", "center": tuple(self.ball_center), "radius": self.ball_radius,
                "thickness": 0.0, "friction": 0.0}

    def scene(self, integrator: str, dt: float, precision: str = "f32", options: dict | None = None,
              positions: np.ndarray | None = None, ball: bool = True, name: str = "peers"):
        """Our Scene of the example: `integrator` at step dt [s], drag rate drag_damping as our linear
        air_damping, the ball as a sphere collider (unless ball=False), step guard off (the caller chooses)."""
        return Scene(self.cloth(positions), name=name, integrator=integrator, dt=dt,
                     integrator_options=dict(options or {}), gravity=self.gravity, air_damping=self.drag_damping,
                     colliders=[self.collider()] if ball else [], precision=precision, step_guard="off")

    # ------------------------------------------------------------------ measuring a peer's state (numpy)
    def energy(self, x: np.ndarray, v: np.ndarray) -> float:
        """Total energy [J] of positions x and velocities v ((P,3) [m], [m/s]): kinetic + elastic + gravity
        (-sum m g.x), as taichi_cloth.diagnostics measures ours."""
        springs, offs = self.springs()
        rest = self.quad_size * np.linalg.norm(offs.astype(np.float64), axis=1)
        length = np.linalg.norm(x[springs[:, 1]] - x[springs[:, 0]], axis=1)
        g = np.asarray(self.gravity)
        return float(0.5 * self.mass * np.sum(v * v) + 0.5 * np.sum(self.spring_Y / rest * (length - rest) ** 2)
                     - self.mass * np.sum(x @ g))

    def max_strain(self, x: np.ndarray) -> float:
        """Largest structural strain [-] of positions x (P,3) [m]."""
        springs, offs = self.springs()
        s = np.abs(offs).sum(axis=1) == 1
        length = np.linalg.norm(x[springs[s, 1]] - x[springs[s, 0]], axis=1)
        return float(np.max(length / self.quad_size - 1.0))


def sample_peer(physics: ExamplePhysics, advance, read, dt: float, times, fps: float = 60.0,
                progress=None) -> Trajectory:
    """Run a peer engine and sample it like accuracy.run_sampled samples our scenes.

    advance(k): take k steps of dt [s] and wait for the device; read(): (x, v) (P,3) float64 in our particle
    order. The peer steps in frames of round(1 / (fps dt)) steps; after each frame the clock stops while the
    state is read and checked (NaN, speed > 200 m/s, strain > 10: a blow-up ends the run as UNSTABLE). Wall
    time counts only advance()."""
    times = np.asarray(times, dtype=np.float64)
    frame = max(1, round(1.0 / (fps * dt)))
    P = physics.n ** 2
    traj = Trajectory(np.full(len(times), np.nan), np.full((len(times), P, 3), np.nan), np.full(len(times), np.nan))
    steps = 0
    try:
        for k, t in enumerate(times):
            target = int(round(t / dt))
            while steps < target:
                m = min(frame, target - steps)
                t0 = time.perf_counter()
                advance(m)
                traj.wall += time.perf_counter() - t0
                steps += m
                x, v = read()
                speed = np.sqrt(np.max(np.sum(v * v, axis=1))) if np.isfinite(v).all() else np.inf
                strain = physics.max_strain(x) if np.isfinite(x).all() else np.inf
                traj.max_strain = max(traj.max_strain, strain)
                if not (np.isfinite(x).all() and speed <= MAX_SPEED and strain <= MAX_STRAIN):
                    raise FloatingPointError(f"blow-up by step {steps} (t = {steps * dt:.4g} s, dt = {dt:.3g} s): "
                                             f"max speed {speed:.3g} m/s, max strain {strain:.3g}")
                if progress is not None:
                    progress(steps * dt)
            x, v = read()
            traj.times[k], traj.positions[k], traj.energy[k] = steps * dt, x, physics.energy(x, v)
    except FloatingPointError as err:
        traj.status, traj.message = UNSTABLE, str(err)
    traj.sim_time, traj.steps = steps * dt, steps
    return traj


def run_example(n: int, dt: float, times, start: np.ndarray | None = None, example: TaichiExample | None = None,
                progress=None) -> tuple[Trajectory, TaichiExample]:
    """The shipped example at n, dt [s] from `start` (P,3) [m] (default: the deterministic start), sampled at
    `times` [s]. One warm-up substep compiles the kernel before the clock starts. Returns the Trajectory
    (extra: ms_per_step) and the loaded example (pass it back to reuse the compiled kernel at the same n, dt)."""
    ex = example if example is not None else TaichiExample(n, dt)
    x0 = ex.physics.start_positions() if start is None else start
    ex.set_state(x0)
    ex.advance(1)  # compile (or load from the offline cache) before timing
    ex.set_state(x0)
    traj = sample_peer(ex.physics, ex.advance, ex.read, ex.dt, times, progress=progress)
    traj.extra["ms_per_step"] = 1e3 * traj.wall / max(traj.steps, 1)
    return traj, ex
