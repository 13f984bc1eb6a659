"""The linear algebra of the implicit step: one block system, one preconditioned CG, three preconditioners and the
policy that picks one.

  system       the Newton system's blocks (3x3 per particle, one per spring: the spring-block formula) and the
               constraint filter of pins and contacts
  pcg          the preconditioned CG loop on the filtered system, decided on the device
  jacobi       block Jacobi, inline in the CG kernels
  level_cycle  V-cycles over the cloth's nested 4-8 levels (multilevel.hierarchy's tables)
  aggregation  V-cycles over levels made by aggregating particles (any cloth)
  dense        the coarsest level's Cholesky factorisation
  policy       auto / jacobi / multigrid, and how the choice follows the model's changes

A Preconditioner is built once at the model's capacity and, per system, `prepare(system, filt)`; then CG calls
`apply(r, z)` (z = P r on (P,) vec3 fields) once per iteration, or, where `inline` is True, evaluates its Taichi
function `precondition(i, r)` inside its own kernels; where `in_thread` is True (every loop of its cycle serial),
CG runs its Taichi function `cycle_in_thread(r, z)` inside CG's own one-thread kernel, so that a solve on the CPU is
one launch. `warm_start` says whether CG may start from the last step's
solution (the V-cycles start from 0, where r = b gives b.z_b for free); `detail` names it for the run summary.
"""
from typing import Protocol

from .pcg import PCG
from .policy import PRECONDITIONERS, NestedLevels, PreconditionerPolicy
from .system import BlockSystem, ConstraintFilter


class Preconditioner(Protocol):
    inline: bool
    in_thread: bool
    warm_start: bool
    detail: str

    def prepare(self, system: BlockSystem, filt: ConstraintFilter) -> None: ...

    def apply(self, r, z) -> None: ...


__all__ = ["PCG", "PRECONDITIONERS", "BlockSystem", "ConstraintFilter", "NestedLevels", "Preconditioner",
           "PreconditionerPolicy"]
