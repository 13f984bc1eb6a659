"""The five integrators, selected by name. Importing them compiles nothing: kernels compile on first step."""
from __future__ import annotations

from .approx_implicit import ApproxImplicit
from .base import Integrator, Option
from .central_difference import CentralDifference
from .explicit import SymplecticEuler
from .implicit import Implicit
from .verlet import Verlet

#: name -> class, in order from cheapest/least stable to the accurate reference
INTEGRATORS: dict[str, type[Integrator]] = {
    cls.name: cls for cls in (SymplecticEuler, Verlet, CentralDifference, ApproxImplicit, Implicit)
}


def integrator_class(name: str) -> type[Integrator]:
    try:
        return INTEGRATORS[name]
    except KeyError:
        raise ValueError(f"unknown integrator {name!r}: choose one of {', '.join(INTEGRATORS)}") from None


__all__ = ["INTEGRATORS", "Integrator", "Option", "integrator_class", "ApproxImplicit", "CentralDifference",
           "Implicit", "SymplecticEuler", "Verlet"]
