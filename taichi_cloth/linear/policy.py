"""Which preconditioner the implicit step's CG uses (its option `preconditioner`), and how the choice follows the
model's changes (a seam merge that names a level, a level switch, a reset that takes a garment's pieces apart
again, new spring constants: Integrator.topology_changed).

  jacobi     block Jacobi (linear.jacobi);
  multigrid  on a garment (its pieces apart, sewn, on every 4-8 level it has): V-cycles over aggregates of its
             particles with their rotations (linear.aggregation); on another cloth with nested 4-8 levels: V-cycles
             over them (linear.level_cycle); else aggregation; Jacobi, with a warning, where neither can be built;
  auto       the same, except that a cloth off 4-8 levels (a garment on every level) is aggregated only from
             AGGREGATION_FROM particles (Jacobi below: a draft garment's 1,370 particles take less time per step
             with Jacobi's 80 iterations than with 28 cycles).
The choice between aggregation and Jacobi is made again at every topology change (a garment's coarse level has a
few hundred particles, its finest thousands). Why: docs/performance.md, preconditioners.
"""
from __future__ import annotations

from dataclasses import dataclass

from clothbase.errors import warn

from ..runtime import one_thread_loops

from .aggregation import AggregationMultigrid
from .jacobi import Jacobi
from .level_cycle import SERIAL_BELOW, SpringMultigrid

PRECONDITIONERS = ("auto", "jacobi", "multigrid")
#: `auto` aggregates a cloth off 4-8 levels (a garment on any level) from this many particles: below, Jacobi costs
#: less per step (the 2 cm T-shirt: 5.1 ms against 7.7) and the cycle's kernels are not compiled
AGGREGATION_FROM = 2000
#: whether a garment's own 4-8 levels precondition it once its seams are merged, instead of the aggregation cycle
#: (no: the aggregation cycle with rotations takes fewer iterations and less time per step there)
GARMENT_LEVELS = False


@dataclass
class NestedLevels:
    """A cloth's nested 4-8 levels (global refinement).

    hierarchy: the multilevel Level list (0 = coarsest); cloth: the ClothData of every level; start: the level the
    model is on (None: on none of them, a garment's pieces apart before their seams merge); garment: whether the
    cloth is a garment (the pins are read from the model's inverse masses at every prepare)."""

    hierarchy: list
    cloth: list
    start: int | None
    garment: bool


class PreconditionerPolicy:
    """The preconditioner in use (`current`, a linear.Preconditioner) for a model (taichi_cloth.model.Model) and the
    option `choice`; `levels` (4-8 V-cycles) is built once, when the cloth allows them, `apart` (aggregation) the
    first time the cloth wants it."""

    def __init__(self, choice: str, model):
        self.choice, self.model = choice, model
        self.jacobi = Jacobi(model)
        self.levels: SpringMultigrid | None = None
        self.apart: AggregationMultigrid | None = None  # off the 4-8 levels, or the cloth's only multigrid
        self.apart_failed: str | None = None             # why aggregation could not be built, once it failed
        self.garment = False
        self.starts_off_levels = False
        self.current = self.jacobi

    def attach(self, nested: NestedLevels | None, why: str | None, garment: bool = False) -> str | None:
        """Choose for a cloth with these nested levels (None: it has none, `why` says so); garment: the cloth is a
        garment (its pieces apart, then sewn). Returns (and warns) a note for the run when "multigrid" was asked for
        and Jacobi serves instead."""
        named = self.choice == "multigrid"
        if self.choice == "jacobi":
            return None
        self.garment = garment or (nested is not None and nested.garment)
        if nested is not None and nested.garment and not GARMENT_LEVELS:
            why = "is not used on a garment's 4-8 levels (GARMENT_LEVELS)"
        elif nested is not None:
            try:
                self.levels = self._level_cycle(nested)
            except ValueError as err:  # e.g. a coarsest level too large for its dense factorisation
                why = str(err)
            else:
                self.starts_off_levels = nested.start is None
                if nested.start is not None:
                    self.levels.set_active_level(nested.start)
                    self.current = self.levels
                if not nested.garment:
                    return None
        if self._wants_aggregation():
            if self._aggregation() is not None:
                self.current = self.apart
                return None
            why = f"{why}, and aggregation failed: {self.apart_failed}"
        if named and self.levels is None:
            note = f"the multigrid preconditioner {why}; integrator 'implicit' uses Jacobi instead"
            warn(note)
            return note
        return None

    def _wants_aggregation(self) -> bool:
        """Whether the cloth as it is now (off 4-8 levels) is preconditioned by aggregation rather than Jacobi."""
        return self.choice == "multigrid" or self.model.data.n_particles >= AGGREGATION_FROM

    def _aggregation(self) -> AggregationMultigrid | None:
        """The aggregation cycle rebuilt for the model's cloth (built the first time), or None where it cannot be
        (apart_failed says why)."""
        try:
            if self.apart is None:
                self.apart = AggregationMultigrid(self.model.capacity[:2], fp=self.model.fp,
                                                  serial=one_thread_loops())
            self.apart.rebuild(self.model.data.springs, self.model.data.n_particles, self.model.data.kind)
            return self.apart
        except ValueError as err:
            self.apart_failed = str(err)
            return None

    def _level_cycle(self, nested: NestedLevels) -> SpringMultigrid:
        """Raises ValueError when the levels are not nested or the coarsest is too large."""
        d = nested.cloth
        return SpringMultigrid(
            nested.hierarchy, [c.springs for c in d], [c.stiffness for c in d], [c.axial_damping() for c in d],
            [c.rest_length for c in d], [c.mass for c in d], fp=self.model.fp, viscous=[c.viscous_damping() for c in d],
            # every loop serial for a cloth the CPU runs serially; on a GPU none (the CPU's threshold would run
            # every loop in one GPU thread)
            serial_below=1 << 62 if self.model.serial else
            (SERIAL_BELOW if one_thread_loops() else 0))

    def topology_changed(self, level: int | None) -> None:
        """The model was refilled: on the 4-8 level `level`, or with none named on the level it was on when its
        particle count is that level's (new spring constants), else off the levels (a garment's pieces apart). Off
        the 4-8 levels, aggregation or Jacobi is chosen again for the cloth as it is now."""
        if self.choice == "jacobi":
            return
        if self.levels is not None:
            if level is not None:
                self.levels.set_active_level(level)
                self.current = self.levels
                return
            if self.model.data.n_particles == self.levels.sizes[self.levels.active] and self.current is self.levels:
                return
        self.current = self.jacobi
        if self._wants_aggregation() and self._aggregation() is not None:
            self.current = self.apart

    @property
    def detail(self) -> str:
        """The run summary's words for the preconditioner in use."""
        if self.current is self.jacobi:
            return "Jacobi-preconditioned CG"
        before = ""
        if self.current is self.levels and self.starts_off_levels:
            before = " once on them (before: " + ("aggregation levels)" if self.apart is not None else "Jacobi)")
        return f"CG preconditioned by {self.current.detail}{before}"
