"""Which preconditioner the implicit step's CG uses (its option `preconditioner`), and how the choice follows the
model's changes (a seam merge that names a level, a level switch, a reset that takes a garment's pieces apart
again, new spring constants: Integrator.topology_changed).

  jacobi     block Jacobi (linear.jacobi);
  multigrid  V-cycles over the cloth's nested 4-8 levels where it has them (linear.level_cycle; a garment's from
             the seam merge on, aggregation or Jacobi before), else over aggregates of its particles
             (linear.aggregation); Jacobi, with a warning, where neither can be built;
  auto       V-cycles over 4-8 levels where the cloth has nested ones and is not a garment, over aggregates on a
             cloth of at least AGGREGATION_FROM particles, else Jacobi.
Why these thresholds: docs/performance.md, preconditioners.
"""
from __future__ import annotations

from dataclasses import dataclass

import taichi as ti

from clothbase.errors import warn

from .aggregation import AggregationMultigrid
from .jacobi import Jacobi
from .level_cycle import SERIAL_BELOW, SpringMultigrid

PRECONDITIONERS = ("auto", "jacobi", "multigrid")
#: `auto` aggregates a cloth without 4-8 levels from this many particles (below, the cycle's kernels cost more to
#: compile than they save)
AGGREGATION_FROM = 2000
#: whether `auto` uses a garment's own 4-8 levels once its seams are merged (no: slower per step than Jacobi on a
#: CPU); "multigrid" asks for them
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
    option `choice`; `levels` (4-8 V-cycles) and `apart` (aggregation) are built once, when the cloth allows them."""

    def __init__(self, choice: str, model):
        self.choice, self.model = choice, model
        self.jacobi = Jacobi(model)
        self.levels: SpringMultigrid | None = None
        self.apart: AggregationMultigrid | None = None  # while off the levels, or the cloth's only multigrid
        self.starts_off_levels = False
        self.current = self.jacobi

    def attach(self, nested: NestedLevels | None, why: str | None) -> str | None:
        """Choose for a cloth with these nested levels (None: it has none, `why` says so). Returns (and warns) a
        note for the run when "multigrid" was asked for and Jacobi serves instead."""
        named = self.choice == "multigrid"
        if self.choice == "jacobi":
            return None
        if nested is not None and nested.garment and not (named or GARMENT_LEVELS):
            why = "is used on a garment's levels only when asked for by name"
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
        if named or self.model.data.n_particles >= AGGREGATION_FROM:
            try:
                apart = AggregationMultigrid(self.model.capacity[:2], fp=self.model.fp,
                                             serial=ti.lang.impl.current_cfg().arch == ti.cpu)
                apart.rebuild(self.model.data.springs, self.model.data.n_particles)
                self.apart = self.current = apart
                return None
            except ValueError as err:
                why = f"{why}, and aggregation failed: {err}"
        if named and self.levels is None:
            note = f"the multigrid preconditioner {why}; integrator 'implicit' uses Jacobi instead"
            warn(note)
            return note
        return None

    def _level_cycle(self, nested: NestedLevels) -> SpringMultigrid:
        """Raises ValueError when the levels are not nested or the coarsest is too large."""
        d = nested.cloth
        return SpringMultigrid(
            nested.hierarchy, [c.springs for c in d], [c.stiffness for c in d], [c.damping for c in d],
            [c.rest_length for c in d], [c.mass for c in d], fp=self.model.fp, viscous=[c.viscous_damping() for c in d],
            # every loop serial for a cloth the CPU runs serially; on a GPU none (the CPU's threshold would run
            # every loop in one GPU thread)
            serial_below=1 << 62 if self.model.serial else
            (SERIAL_BELOW if ti.lang.impl.current_cfg().arch == ti.cpu else 0))

    def topology_changed(self, level: int | None) -> None:
        """The model was refilled: on the 4-8 level `level`, or with none named on the level it was on when its
        particle count is that level's (new spring constants), else off the levels (a garment's pieces apart)."""
        if self.levels is not None:
            if level is not None:
                self.levels.set_active_level(level)
                self.current = self.levels
            elif self.model.data.n_particles != self.levels.sizes[self.levels.active]:
                self.current = self.apart or self.jacobi
        if self.current is self.apart:
            self.apart.rebuild(self.model.data.springs, self.model.data.n_particles)

    @property
    def detail(self) -> str:
        """The run summary's words for the preconditioner in use."""
        if self.current is self.jacobi:
            return "Jacobi-preconditioned CG"
        before = ""
        if self.current is self.levels and self.starts_off_levels:
            before = " once on them (before: " + ("aggregation levels)" if self.apart is not None else "Jacobi)")
        return f"CG preconditioned by {self.current.detail}{before}"
