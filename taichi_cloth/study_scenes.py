"""The study scenes: three standard sheets on a 4-8 hierarchy that the speed/accuracy study (`bench tradeoff`),
the quality presets it derives and the energy tests of the implicit step all run.

  hanging   1 m cotton sheet held level by one edge, released: it swings down and hangs (one rest shape)
  sphere    1 m cotton sheet dropped 15 cm onto a 0.3 m ball on the floor
  mannequin 1.2 x 1.0 m silk sheet dropped over the shipped mannequin's head and shoulders (voxel collision,
            stretch limit 10 %, as demos/scenes/drape_on_mannequin.toml)
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

from .material import material
from .multilevel_cloth import multilevel_grid
from .scene import Scene

__all__ = ["SCENES", "StudyScene", "energy_scale"]


@dataclass(frozen=True)
class StudyScene:
    """A standard scene of the study: a sheet of `size` [m] centred at `center` [m] in the xz plane."""

    name: str
    doc: str
    material: str
    size: tuple
    center: tuple
    air_damping: float  # [1/s]
    pins: tuple = ()
    colliders: tuple = ()
    stretch_limit: dict | None = None

    def build(self, base: int, level: int, integrator: str, dt: float, precision: str = "f32",
              options: dict | None = None):
        """The Scene on 4-8 `level` (0-based) of a hierarchy with `base` x `base` cells, staying on that level, with
        `integrator` (a name) and its `options`, at the step dt [s]. Every warning is silenced: a study records
        what a known-unstable configuration does."""
        opts = dict(options or {})
        cloth = multilevel_grid(self.size, (base, base), level + 1, self.material, center=self.center, plane="xz",
                                start_level=level)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return Scene(cloth.levels[level], name=self.name, integrator=integrator, dt=dt,
                         integrator_options=dict(opts), air_damping=self.air_damping,
                         pins=[dict(p) for p in self.pins], colliders=[dict(c) for c in self.colliders],
                         stretch_limit=self.stretch_limit, precision=precision, step_guard="off")


SCENES = {s.name: s for s in (
    StudyScene("hanging", "1 m cotton sheet held level by one edge, released", "cotton", (1.0, 1.0), (0.0, 1.0, 0.0),
               0.3, pins=({"box": ((-0.6, 0.99, -0.51), (0.6, 1.01, -0.49))},)),
    StudyScene("sphere", "1 m cotton sheet dropped 15 cm onto a 0.3 m ball", "cotton", (1.0, 1.0), (0.0, 0.75, 0.0),
               0.3, colliders=({"type": "sphere", "center": (0.0, 0.3, 0.0), "radius": 0.3, "friction": 0.4},
                               {"type": "plane", "point": (0.0, 0.0, 0.0), "normal": (0.0, 1.0, 0.0)})),
    StudyScene("mannequin", "1.2 x 1.0 m silk sheet dropped over the mannequin", "silk", (1.2, 1.0),
               (0.0, 1.73, 0.06), 0.3,
               colliders=({"type": "mesh", "path": "mannequin", "thickness": 0.004, "friction": 0.4},
                          {"type": "plane", "point": (0.0, 0.0, 0.0), "normal": (0.0, 1.0, 0.0)}),
               stretch_limit={"max_strain": 0.1, "iterations": 20}),
)}


def energy_scale(spec: StudyScene) -> float:
    """The cloth's weight times its diagonal [J]: the unit of the energy drift."""
    mass = material(spec.material).density * spec.size[0] * spec.size[1]
    return mass * 9.81 * math.hypot(*spec.size)
