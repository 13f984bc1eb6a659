"""NVIDIA Warp on the CPU as a peer (warp.sim of warp-lang 1.9.1: it was removed in 1.10).

Two things are measured:
  - `ShippedExample`: warp's own `warp/examples/sim/example_cloth.py` as shipped (an FEM/spring cloth of
    (n-1) x (n-1) cells, pinned on one side, dropped on the bunny mesh, 32 substeps per 1/60 s frame), with each
    integrator the file offers (euler = SemiImplicitIntegrator, xpbd, vbd), headless (stage_path=None: no USD
    output), timed per simulated second. Its physics is not ours, so it has a cost and no error. It needs usd-core
    (`pxr`) for the bunny. Building the cloth is pure Python in warp (add_cloth_grid: 20-100 s at 128 x 128), so
    the builder's state after add_cloth_grid is cached on disk (pickle, keyed by warp's version and the call's
    arguments) and reused by later runs: the model is then finalised exactly as shipped.
  - `WarpSamePhysics`: the Taichi example's scene (peer_taichi_example.ExamplePhysics) built with warp.sim's
    ModelBuilder from the same ClothData (particles, springs with ke = k and kd = kd, gravity -9.8, no ground),
    stepped by warp's SemiImplicitIntegrator or XPBDIntegrator, so its error can be measured against our reference.
    What had to be added or chosen, since warp.sim has no such terms:
      * air drag: warp.sim has no linear particle drag, so one extra warp kernel adds -drag m v to the particle
        forces before each step (both integrators read them: semi-implicit as force, XPBD in its prediction).
      * the ball: a static warp sphere shape. Contacts are regenerated every step (wp.sim.collide; the shipped
        example does it once per frame). The semi-implicit integrator resolves them with its penalty force
        (stiffness CONTACT_KE, damping CONTACT_KD on the approaching velocity, friction 0); XPBD projects the
        penetration (relaxation 0.9) and has no stiffness. Neither is our projection, nor the example's velocity
        projection. Particle radius 0, so no particle-particle contacts.
Warp's compiled kernels are cached on disk by warp itself (wp.config.kernel_cache_dir, ~/.cache/warp by default).
Warp runs single-threaded on the CPU.
"""
from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib
import importlib.util
import io
import pickle
import time
import warnings
from pathlib import Path

import numpy as np

from .accuracy import Trajectory
from .peer_taichi_example import ExamplePhysics, sample_peer

WARP_VERSION = "1.9.1"
INSTALL_HINT = "pip install 'taichi-cloth[peers]'"
#: the shipped example's integrators (its IntegratorType values)
EXAMPLE_INTEGRATORS = ("euler", "xpbd", "vbd")
#: penalty contact of the semi-implicit same-physics scene: stiffness [N/m] (1 kg particles: an impact at 2.5 m/s
#: sinks 2.5 mm, the contact frequency 1000 rad/s stays below the springs') and damping [N s/m] (critical: the
#: contact is inelastic, like ours and the example's)
CONTACT_KE, CONTACT_KD = 1.0e6, 2.0e3


def warp_status() -> tuple[str | None, str | None]:
    """(why warp.sim cannot run, why the shipped example cannot run): None where it can. Imports nothing heavy
    beyond warp itself."""
    try:
        import warp  # noqa: F401
    except ImportError:
        return (f"warp-lang is not installed ({INSTALL_HINT})",) * 2
    try:
        if importlib.util.find_spec("warp.sim") is None:
            raise ImportError
    except ImportError:
        msg = f"warp {warp.__version__} has no warp.sim (removed in 1.10; {INSTALL_HINT} installs {WARP_VERSION})"
        return msg, msg
    try:
        import pxr  # noqa: F401
    except ImportError:
        return None, f"usd-core is not installed: the shipped example loads the bunny from USD ({INSTALL_HINT})"
    return None, None


@functools.lru_cache(maxsize=None)
def warp_module():
    """warp, initialised quietly on the CPU, with warp.sim imported (its deprecation notice silenced)."""
    import warp as wp

    wp.config.quiet = True
    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        wp.init()
        import warp.sim  # noqa: F401
        import warp.sim.render  # noqa: F401  (the example imports it)
    return wp


@functools.lru_cache(maxsize=None)
def _drag_kernel():
    """The warp kernel f[i] -= rate m[i] v[i] (air drag [N], rate [1/s]), compiled once and cached by warp."""
    wp = warp_module()

    @wp.kernel(module="unique")
    def air_drag(v: wp.array(dtype=wp.vec3), mass: wp.array(dtype=float), rate: float,
                 f: wp.array(dtype=wp.vec3)):
        i = wp.tid()
        f[i] = f[i] - rate * mass[i] * v[i]

    return air_drag


# ------------------------------------------------------------------------------------ the example as shipped
@contextlib.contextmanager
def cached_cloth_grid(cache_dir: Path | None):
    """While active, ModelBuilder.add_cloth_grid on a fresh builder restores the builder's state from
    cache_dir/warp_cloth_grid_KEY.pkl when present, else runs warp's own code and saves that state. The key is
    warp's version and the call's arguments, so the model is the one warp would build."""
    wp = warp_module()
    cls = wp.sim.ModelBuilder
    original = cls.add_cloth_grid
    if cache_dir is None:
        yield
        return

    def add_cloth_grid(self, *args, **kwargs):
        if self.particle_count or self.shape_count:  # only a fresh builder's whole state is the grid's
            return original(self, *args, **kwargs)
        text = repr((wp.__version__, [repr(a) for a in args], sorted((k, repr(v)) for k, v in kwargs.items())))
        path = Path(cache_dir) / f"warp_cloth_grid_{hashlib.sha1(text.encode()).hexdigest()[:16]}.pkl"
        if path.exists():
            with open(path, "rb") as fh:
                self.__dict__.update(pickle.load(fh))
            return None
        out = original(self, *args, **kwargs)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp")
        with open(tmp, "wb") as fh:
            pickle.dump(self.__dict__, fh, protocol=pickle.HIGHEST_PROTOCOL)
        tmp.replace(path)
        return out

    cls.add_cloth_grid = add_cloth_grid
    try:
        yield
    finally:
        cls.add_cloth_grid = original


class ShippedExample:
    """warp/examples/sim/example_cloth.py's Example with `integrator` (euler | xpbd | vbd) on n x n particles
    ((n-1) x (n-1) cells, its width and height), on the CPU, headless. build_s: wall seconds to build (from the
    builder cache when warm); frame_dt [s] = 1/60, substeps per frame as shipped."""

    def __init__(self, n: int, integrator: str, cache_dir: Path | None = None):
        if integrator not in EXAMPLE_INTEGRATORS:
            raise ValueError(f"warp example integrator must be one of {', '.join(EXAMPLE_INTEGRATORS)}, "
                             f"got {integrator!r}")
        wp = warp_module()

        mod = importlib.import_module("warp.examples.sim.example_cloth")
        t0 = time.perf_counter()
        with wp.ScopedDevice("cpu"), cached_cloth_grid(cache_dir), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            self.example = mod.Example(stage_path=None, integrator=mod.IntegratorType(integrator),
                                       height=n - 1, width=n - 1)
        self.build_s = time.perf_counter() - t0
        self.n, self.integrator = n, integrator
        self.particles = self.example.model.particle_count

    def time_frames(self, frames: int = 3) -> dict:
        """Wall time of `frames` frames after one warm-up frame (the compile or the kernel-cache load):
        ms_per_frame, wall_per_sim_s, ms_per_step (per substep), dt [s] (its substep), first_frame_s."""
        wp = warp_module()
        ex = self.example
        with wp.ScopedDevice("cpu"):
            t0 = time.perf_counter()
            ex.simulate()  # what Example.step() times, without its printing ScopedTimer
            wp.synchronize()
            first = time.perf_counter() - t0
            t0 = time.perf_counter()
            for _ in range(frames):
                ex.simulate()
            wp.synchronize()
            wall = (time.perf_counter() - t0) / frames
        x = ex.state_0.particle_q.numpy()
        return {"ms_per_frame": 1e3 * wall, "wall_per_sim_s": wall / ex.frame_dt, "dt": ex.sim_dt,
                "ms_per_step": 1e3 * wall / ex.sim_substeps, "first_frame_s": first, "build_s": self.build_s,
                "particles": self.particles, "finite": bool(np.isfinite(x).all())}


# ------------------------------------------------------------------------------------ the same physics in warp
SAME_PHYSICS_INTEGRATORS = ("semi-implicit", "xpbd")


class WarpSamePhysics:
    """The Taichi example's physics in warp.sim on the CPU: `integrator` "semi-implicit" (SemiImplicitIntegrator)
    or "xpbd" (XPBDIntegrator with `iterations`), step dt [s]. Build once per size; set dt, reset and rerun.

    State: particle_q, particle_qd (P,) vec3 f32 [m], [m/s]; particle i is our particle i.
    """

    def __init__(self, physics: ExamplePhysics, integrator: str = "semi-implicit", dt: float = 1e-4,
                 iterations: int = 1, start: np.ndarray | None = None):
        if integrator not in SAME_PHYSICS_INTEGRATORS:
            raise ValueError(f"warp integrator must be one of {', '.join(SAME_PHYSICS_INTEGRATORS)}, "
                             f"got {integrator!r}")
        wp = warp_module()
        self.wp, self.physics, self.dt, self.integrator_name = wp, physics, float(dt), integrator
        data = physics.cloth(start)
        P = data.n_particles
        g = np.asarray(physics.gravity, dtype=np.float64)
        # warp's gravity vector is up_vector x gravity
        b = wp.sim.ModelBuilder(up_vector=tuple(-g / np.linalg.norm(g)), gravity=-float(np.linalg.norm(g)))
        # the builder's own lists, filled from numpy (add_particle / add_spring are one Python call each)
        b.particle_q = data.positions.tolist()
        b.particle_qd = np.zeros((P, 3)).tolist()
        b.particle_mass = data.mass.tolist()
        b.particle_radius = [0.0] * P  # no particle-particle contacts; the ball is met at its surface
        b.particle_flags = [wp.sim.model.PARTICLE_FLAG_ACTIVE] * P
        b.spring_indices = data.springs.reshape(-1).tolist()
        b.spring_rest_length = data.rest_length.tolist()
        b.spring_stiffness = data.stiffness.tolist()
        b.spring_damping = data.damping.tolist()
        b.spring_control = [0.0] * data.n_springs
        b.add_shape_sphere(body=-1, pos=wp.vec3(*physics.ball_center), radius=physics.ball_radius,
                           ke=CONTACT_KE, kd=CONTACT_KD, kf=0.0, mu=0.0, thickness=0.0)
        with wp.ScopedDevice("cpu"):
            self.model = m = b.finalize("cpu")
            m.ground = False
            # warp averages particle and shape contact parameters: make both ours
            m.soft_contact_ke, m.soft_contact_kd = CONTACT_KE, CONTACT_KD
            m.soft_contact_kf, m.soft_contact_mu = 0.0, 0.0
            self.states = [m.state(), m.state()]
            self.integrator = (wp.sim.SemiImplicitIntegrator() if integrator == "semi-implicit"
                               else wp.sim.XPBDIntegrator(iterations=iterations))
        self.x0 = data.positions.astype(np.float32)
        self.drag = _drag_kernel()
        self.steps_taken = 0

    def reset(self, start: np.ndarray | None = None) -> None:
        """Back to `start` (P,3) [m] (default: the build's start), zero velocity."""
        x = self.x0 if start is None else np.asarray(start, np.float32)
        s = self.states[0]
        s.particle_q.assign(x)
        s.particle_qd.zero_()
        self.steps_taken = 0

    def advance(self, steps: int) -> None:
        """`steps` steps of dt: contacts, forces cleared, air drag, the integrator; then synchronise."""
        wp, m = self.wp, self.model
        rate = float(self.physics.drag_damping)
        with wp.ScopedDevice("cpu"):
            for _ in range(steps):
                s0, s1 = self.states
                wp.sim.collide(m, s0)
                s0.clear_forces()
                wp.launch(self.drag, dim=m.particle_count, inputs=[s0.particle_qd, m.particle_mass, rate],
                          outputs=[s0.particle_f])
                self.integrator.simulate(m, s0, s1, self.dt)
                self.states = [s1, s0]
            wp.synchronize()
        self.steps_taken += steps

    def read(self) -> tuple[np.ndarray, np.ndarray]:
        """(positions, velocities) (P,3) float64 [m], [m/s]."""
        s = self.states[0]
        return s.particle_q.numpy().astype(np.float64), s.particle_qd.numpy().astype(np.float64)


def run_same_physics(sim: WarpSamePhysics, times, start: np.ndarray | None = None, progress=None) -> Trajectory:
    """Sample `sim` from `start` at `times` [s] (one warm-up step first, so compiles are not timed).
    extra: ms_per_step."""
    sim.reset(start)
    sim.advance(1)
    sim.reset(start)
    traj = sample_peer(sim.physics, sim.advance, sim.read, sim.dt, times, progress=progress)
    traj.extra["ms_per_step"] = 1e3 * traj.wall / max(traj.steps, 1)
    return traj
