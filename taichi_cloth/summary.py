"""RunSummary: what one Scene.run did, and its text for a terminal."""
from __future__ import annotations

from dataclasses import dataclass, field

from .diagnostics import Measurement


@dataclass
class RunSummary:
    """What a run did. Times in seconds of wall clock unless named sim_.

    dt: the step [s] the run started with; dt_min, dt_max: the smallest and largest step taken (they differ with
    dt = "auto", on 4-8 levels with dt_growth, or when the frames were filled with shorter steps); steps_line: the
    clock's line about them (None when every step was dt).
    sim_time: simulated seconds of this run (from its start, not from t = 0).
    wall_step: stepping and per-frame checks over frames 2.. (frame 1 compiles the kernels: first_frame_wall);
    timed_steps, timed_sim: the steps and simulated seconds inside wall_step; wall_record: recorder calls, frames 2..
    host_reads_steps, host_reads_frames: the host's reads of device data (taichi_cloth.hostreads) inside the steps,
    and in the frames' own work (the measurement, the controllers' frame hooks), over frames 2..; the outputs (a
    recording's snapshots, the quarter-second intersection counts) are not counted.
    """

    name: str
    integrator: str
    dt: float
    auto: bool
    n_particles: int
    n_springs: int
    frames: int = 0
    steps: int = 0
    sim_time: float = 0.0
    wall_step: float = 0.0
    timed_steps: int = 0
    wall_record: float = 0.0
    rest: str | None = None  # the rest criterion at the last frame (taichi_cloth.rest), in words
    stopped_at_rest: bool = False  # the run ended early because the cloth was at rest
    agreement: str | None = None  # whether the stretch limit and the colliders both hold at the end, in words
    intersections: int | None = None  # intersecting triangle pairs at the end (taichi_cloth.self_intersection)
    intersections_max: int | None = None  # the largest count over the run's counts
    self_intersection: str | None = None  # both, in words
    first_frame_wall: float = 0.0
    final: Measurement | None = None
    max_strain_seen: float = 0.0
    stats: dict = field(default_factory=dict)
    blowup: str | None = None   # the BlowUpError's message, when the run blew up
    blowup_short: str | None = None  # what the summary's instability line says of it
    dt_min: float | None = None
    dt_max: float | None = None
    timed_sim: float = 0.0
    host_reads_steps: int = 0
    host_reads_frames: int = 0
    steps_line: str | None = None
    solver: str | None = None  # how the integrator solves its step (e.g. its preconditioner)
    events: list[str] = field(default_factory=list)  # what happened on the way (seams joined, level switches...)
    outputs: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    @property
    def steps_per_s(self) -> float:
        return self.timed_steps / self.wall_step if self.wall_step > 0 else float("nan")

    @property
    def realtime_factor(self) -> float:
        """Simulated seconds per wall second of stepping (> 1 is faster than real time)."""
        return self.timed_sim / self.wall_step if self.wall_step > 0 else float("nan")

    def count_frame(self, frame: int, steps: int, wall: float, simulated: float, compiling: bool) -> None:
        """A frame of `steps` steps took `wall` seconds for `simulated` seconds; `compiling`: it compiled the kernels
        (the first frame of a run longer than one frame), so it stays out of the speed figures."""
        self.frames, self.steps = frame, self.steps + steps
        if compiling:
            self.first_frame_wall = wall
        else:
            self.wall_step += wall
            self.timed_steps += steps
            self.timed_sim += simulated

    def measured(self, m: Measurement) -> None:
        """The frame's final measurement."""
        self.final = m
        self.max_strain_seen = max(self.max_strain_seen, m.max_strain)

    def blew_up(self, frame: int, err) -> None:
        """The run stopped at `frame` with a BlowUpError; the error carries this summary."""
        self.frames = frame
        self.blowup = str(err)
        self.blowup_short = f"blew up by step {err.step} ({err.reason}); the error says what to change"
        err.summary = self

    def took_step(self, dt: float) -> None:
        """Count dt [s] into the range of steps taken."""
        self.dt_min = dt if self.dt_min is None else min(self.dt_min, dt)
        self.dt_max = dt if self.dt_max is None else max(self.dt_max, dt)

    def format(self) -> str:
        lines = [f"scene {self.name!r}: {self.n_particles} particles, {self.n_springs} springs, "
                 f"integrator {self.integrator}{f' ({self.solver})' if self.solver else ''}, "
                 f"dt = {'auto' if self.auto else f'{self.dt:.3g} s'}",
                 f"  ran {self.frames} frames, {self.steps} steps, {self.sim_time:.3f} s simulated"]
        if self.steps_line is not None:
            lines.append(f"  {self.steps_line}")
        if self.wall_step > 0:
            ms = 1e3 * self.wall_step / max(self.timed_steps, 1)
            lines.append(f"  speed: {self.steps_per_s:,.0f} steps/s, {ms:.3f} ms/step, {self.realtime_factor:.2f}x "
                         f"real time (frames 2..; frame 1 with compiles took {self.first_frame_wall:.2f} s)")
            frames = max(self.frames - 1, 1)
            lines.append(f"  host reads: {self.host_reads_steps / max(self.timed_steps, 1):.2g} per step inside the "
                         f"steps, {self.host_reads_frames / frames:.2g} per frame besides (frames 2..)")
            if self.wall_record > 0:
                lines.append(f"  recording: {1e3 * self.wall_record / max(self.frames - 1, 1):.2f} ms/frame, "
                             f"{100 * self.wall_record / (self.wall_step + self.wall_record):.1f} % of the loop")
        if self.final is not None:
            f = self.final
            lines.append(f"  energy: kinetic {f.kinetic:.4g} J, potential {f.potential:.4g} J "
                         f"(elastic {f.elastic:.4g}, gravity {f.gravity:.4g}), total {f.total:.4g} J")
            lines.append(f"  max strain: {100 * f.max_strain:.2f} % now, {100 * self.max_strain_seen:.2f} % peak; "
                         f"max speed {f.max_speed:.3g} m/s")
        if self.rest is not None:
            lines.append(f"  {self.rest}" + ("; the run stopped there" if self.stopped_at_rest else ""))
        if self.agreement is not None:
            lines.append(f"  {self.agreement}")
        if self.self_intersection is not None:
            lines.append(f"  {self.self_intersection}")
        for e in self.events:
            lines.append(f"  {e}")
        for k, v in self.stats.items():
            lines.append(f"  {k}: {v:.4g}")
        for w in self.warnings:
            lines.append(f"  warning: {w}")
        lines.append(f"  instability: {(self.blowup_short or self.blowup) if self.blowup else 'none detected'}")
        for o in self.outputs:
            lines.append(f"  wrote {o}")
        return "\n".join(lines)
