"""Runs sampled at fixed simulated times, their errors against a reference run, and the Pareto front.

Shared by the speed/accuracy study (`bench tradeoff`) and the comparison with other engines (`bench peers`):
every configuration is run on the same scene, sampled at the same simulated times, and compared with one
reference trajectory (the implicit integrator in float64 at a small step and a tight CG tolerance).
A run on a coarser 4-8 level is compared on the vertices it shares with the reference's finest level: the
hierarchy is nested, so they are its first P vertices.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from collision.distance import unsigned_distance
from taichi_cloth.errors import BlowUpError

#: the status of a run: finished, or stopped by the blow-up check (NaN, runaway speed or strain)
OK, UNSTABLE = "ok", "unstable"


@dataclass
class Trajectory:
    """A run sampled at fixed simulated times.

    times:      (S,) float64 [s]       the simulated times of the samples (whole steps: within dt of the asked ones)
    positions:  (S, P, 3) float64 [m]  particle positions at each sample (NaN after a blow-up)
    energy:     (S,) float64 [J]       total energy (kinetic + elastic + gravity) at each sample
    max_strain: float [-]              peak structural strain over every frame of the run
    wall:       float [s]              wall time of the stepping (compiles excluded: see run_sampled)
    sim_time:   float [s]              simulated time reached
    steps:      int                    steps taken
    status:     OK or UNSTABLE; message: the blow-up report when UNSTABLE
    start_energy: float [J]            total energy at the start (the scene's state when run_sampled began)
    """

    times: np.ndarray
    positions: np.ndarray
    energy: np.ndarray
    max_strain: float = 0.0
    wall: float = 0.0
    sim_time: float = 0.0
    steps: int = 0
    status: str = OK
    message: str = ""
    start_energy: float = float("nan")
    extra: dict = field(default_factory=dict)

    @property
    def wall_per_sim_s(self) -> float:
        """Wall seconds per simulated second (the cost); NaN for a run that simulated nothing."""
        return self.wall / self.sim_time if self.sim_time > 0 else float("nan")

    @property
    def stable(self) -> bool:
        return self.status == OK

    def save(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, times=self.times, positions=self.positions, energy=self.energy,
                            scalars=np.array([self.max_strain, self.wall, self.sim_time, self.steps,
                                              self.start_energy]),
                            status=np.array(self.status), message=np.array(self.message))
        return path

    @classmethod
    def load(cls, path) -> "Trajectory":
        with np.load(path) as z:
            max_strain, wall, sim_time, steps, *rest = z["scalars"]  # files before start_energy have 4
            start_energy = rest[0] if rest else float("nan")
            return cls(z["times"], z["positions"], z["energy"], float(max_strain), float(wall), float(sim_time),
                       int(steps), str(z["status"]), str(z["message"]), float(start_energy))


def run_sampled(scene, times, warm_up: bool = True, progress=None) -> Trajectory:
    """Run `scene` from its current state and sample it at the simulated `times` [s] (increasing).

    The scene steps frame by frame (scene.substeps steps of scene.dt, with the blow-up check after each frame),
    so an unstable configuration stops within a frame of going wrong. With `warm_up`, one step is taken first
    and the scene reset, so the kernels are compiled (or loaded) before the clock starts. `progress`, when
    given, is called with the simulated time after every frame."""
    times = np.asarray(times, dtype=np.float64)
    if warm_up:
        try:
            scene.step(1)
        except BlowUpError:
            pass
        scene.reset()
    dt = scene.dt
    P = scene.model.data.n_particles
    positions = np.full((len(times), P, 3), np.nan)
    energy = np.full(len(times), np.nan)
    reached = np.full(len(times), np.nan)
    traj = Trajectory(reached, positions, energy, start_energy=scene.measure().total)
    t0 = time.perf_counter()
    try:
        for k, t in enumerate(times):
            target = int(round(t / dt))
            while scene.steps_taken < target:
                m = scene.step(min(scene.substeps, target - scene.steps_taken))
                traj.max_strain = max(traj.max_strain, m.max_strain)
                if progress is not None:
                    progress(scene.state.t)
            traj.wall += time.perf_counter() - t0
            reached[k] = scene.state.t
            positions[k] = scene.positions()
            energy[k] = scene.measure().total
            t0 = time.perf_counter()  # reading the samples back is not stepping
    except BlowUpError as err:
        traj.wall += time.perf_counter() - t0
        traj.status, traj.message = UNSTABLE, str(err)
    traj.sim_time, traj.steps = scene.state.t, scene.steps_taken
    return traj


def sample_errors(run: Trajectory, reference: Trajectory) -> np.ndarray:
    """(S,) float64 [m]: the RMS vertex distance of `run` to `reference` at each sample, on the reference's first
    P vertices (NaN after a blow-up)."""
    P = run.positions.shape[1]
    d = np.linalg.norm(run.positions - reference.positions[:, :P], axis=2)
    return np.sqrt(np.mean(d ** 2, axis=1))


def surface_distance(xa: np.ndarray, tri_a: np.ndarray, xb: np.ndarray, tri_b: np.ndarray,
                     cutoff: float = 2.0) -> tuple[float, float]:
    """RMS and max [m] of the symmetric vertex-to-surface distance between two triangle meshes (positions
    (n,3) [m], triangles (t,3)): every vertex of each against the other's surface. Unlike a vertex distance it
    needs no common vertices and does not count cloth sliding along itself; exact up to `cutoff` [m]."""
    d = np.r_[unsigned_distance(xa, xb[tri_b], cutoff), unsigned_distance(xb, xa[tri_a], cutoff)]
    return float(np.sqrt(np.mean(d ** 2))), float(d.max())


def compare(run: Trajectory, reference: Trajectory, energy_scale: float, window: int | None = None,
            triangles: tuple | None = None) -> dict:
    """Errors of `run` against `reference`, sampled at the same times, on the reference's first P vertices.

    Returns rms_error and max_error [m]: the vertex distance over the first `window` samples (default all) and
    every vertex; final_rms and final_max [m]: the shape at the last sample, as the symmetric surface distance
    when `triangles` = (the run's, the reference's) (T,3) arrays are given, else the vertex distance;
    energy_drift: max over all samples of |E - E_ref|, divided by `energy_scale` [J] (e.g. the cloth's weight
    times its size); energy_growth: how far the total energy rose above its start, max(0, max E - E_start), in the
    same unit (a passive cloth started at rest only loses energy: a growth is energy the scheme or a constraint
    put in); max_strain [-] (the run's peak) and wall_per_sim_s. NaN errors for an unstable run."""
    P = run.positions.shape[1]
    d = np.linalg.norm(run.positions - reference.positions[:, :P], axis=2)
    out = {"wall_per_sim_s": run.wall_per_sim_s, "max_strain": run.max_strain, "stable": run.stable}
    if not run.stable or not np.isfinite(d).all():
        return out | {k: float("nan") for k in ("rms_error", "max_error", "final_rms", "final_max", "energy_drift",
                                                "energy_growth")}
    w = d[:window]
    if triangles is not None:
        final = surface_distance(run.positions[-1], triangles[0], reference.positions[-1], triangles[1])
    else:
        final = float(np.sqrt(np.mean(d[-1] ** 2))), float(d[-1].max())
    return out | {"rms_error": float(np.sqrt(np.mean(w ** 2))), "max_error": float(w.max()),
                  "final_rms": final[0], "final_max": final[1],
                  "energy_drift": float(np.max(np.abs(run.energy - reference.energy)) / energy_scale),
                  "energy_growth": max(0.0, float(np.max(run.energy) - run.start_energy)) / energy_scale}


def pareto_front(cost, error) -> np.ndarray:
    """(N,) bool: the points no other point beats on both cost and error (both minimised). NaN points (unstable
    runs) are never on the front; of equal points, only the first."""
    cost, error = np.asarray(cost, float), np.asarray(error, float)
    ok = np.isfinite(cost) & np.isfinite(error)
    front = np.zeros(len(cost), dtype=bool)
    order = np.lexsort((error, cost))  # by cost, ties by error
    best = np.inf
    for i in order:
        if ok[i] and error[i] < best:
            front[i] = True
            best = error[i]
    return front
