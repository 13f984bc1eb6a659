"""Cloth materials in SI units, and the presets users pick by name.

A mass-spring sheet has no exact continuum equivalent, so the moduli below are the spring
constants of a *square* grid; builders scale them by the local geometry so that refining a
uniform mesh keeps the same sheet response (docs/algorithms.md, materials):

- structural spring:  k = stretch * (attributed width / rest length)   -> `stretch` on a square grid
- shear (diagonal):   k = shear * 2 * cell area / rest length^2         -> `shear` on a square grid
- bend (skip-one):    k = bend / rest length^2                          (approximation; bending = "springs")
- bend (quadratic):   the bending rigidity B of Bergou et al.'s hinge energy (bending = "quadratic";
                      taichi_cloth.bending): a measured rigidity is used as it is
- every spring:       damping coefficient kd = damping * k              (stiffness-proportional)
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass


#: the bending models a Material can name (Material.bending)
BENDING_MODELS = ("springs", "quadratic")
#: the membranes a triangle mesh of the material can have (Material.membrane; grids are always the square grid's)
MEMBRANE_MODELS = ("isotropic", "orthotropic")


@dataclass(frozen=True)
class Material:
    """A cloth material.

    density: areal mass density [kg/m^2] (cotton shirting ~0.12).
    stretch: in-plane stretch modulus [N/m]; the structural spring constant on a square grid.
    shear:   in-plane shear modulus [N/m]; the diagonal spring constant on a square grid.
    bend:    bending coefficient [N*m]: with bending = "springs" a bend spring of rest length L gets k = bend / L^2;
             with bending = "quadratic" it is the bending rigidity B (a cylindrical bend of curvature kappa holds
             B / 2 kappa^2 per unit area; KES-F's B x 9.807e-5).
    damping: stiffness-proportional spring damping [s]; a spring of constant k gets kd = damping * k [N*s/m].
    viscosity: internal (membrane) viscosity [m^2/s]: neighbouring particles' velocities are pulled together
             (ClothData.viscous_damping), so a sway or a wrinkle of wavelength lambda loses its speed at about
             viscosity * (2 pi / lambda)^2 per second, while a rigid motion and the rest shape are untouched.
    bending: the bending model, "springs" (across every hinge, resisting a bend of angle theta with a force of
             order theta^2) or "quadratic" (Bergou et al. 2006: linear in the positions, first order in theta).
    membrane: a triangle mesh's in-plane springs (taichi_cloth.cloth.mesh_cloth, the "isotropic" rule of the
             garments, 4-8 levels and drape tests): "isotropic" (Young's modulus sheet_modulus, Poisson 1/3, so the
             shear modulus is 3/8 of it whatever `shear` says) or "orthotropic" (the square grid's sheet along the
             pattern's axes: `stretch` along warp and weft, `shear` on the bias, as a woven fabric).
    """

    density: float
    stretch: float
    shear: float
    bend: float
    damping: float = 0.0
    viscosity: float = 0.0
    bending: str = "springs"
    membrane: str = "isotropic"

    def __post_init__(self):
        if self.bending not in BENDING_MODELS:
            raise ValueError(f"material bending must be one of {', '.join(BENDING_MODELS)}, got {self.bending!r}")
        if self.membrane not in MEMBRANE_MODELS:
            raise ValueError(f"material membrane must be one of {', '.join(MEMBRANE_MODELS)}, got {self.membrane!r}")
        for f in dataclasses.fields(self):
            if f.name in ("bending", "membrane"):
                continue
            v = getattr(self, f.name)
            if not isinstance(v, (int, float)) or v != v:
                raise ValueError(f"material {f.name} must be a number, got {v!r}")
        if self.density <= 0:
            raise ValueError(f"material density must be > 0 kg/m^2, got {self.density}")
        for name in ("stretch", "shear", "bend", "damping", "viscosity"):
            if getattr(self, name) < 0:
                raise ValueError(f"material {name} must be >= 0, got {getattr(self, name)}")

    @property
    def sheet_modulus(self) -> float:
        """Young's modulus of the sheet [N/m] under uniaxial stress along a grid axis, for the square grid's
        springs (stretch on the edges, shear on both diagonals): C11 - C12^2 / C11 with C11 = stretch + shear,
        C12 = shear. Isotropic meshes (4-8 levels, ClothBuilder.triangle_mesh(..., stiffness_rule="isotropic"))
        are given this modulus, so the same material responds alike on a grid and on a 4-8 level."""
        c11 = self.stretch + self.shear
        return c11 - self.shear ** 2 / c11 if c11 > 0 else 0.0

    def replace(self, **changes) -> "Material":
        return dataclasses.replace(self, **changes)


#: Presets. `cotton` is the engine's original cotton (not from measurements; the demo and many tests are tuned on
#: it). The others are published KES-F measurements converted to the model (taichi_cloth.fabrics.FABRICS has the
#: measured values, docs/fabrics.md the sources, the conversion and the Cusick drape test): density from the weight,
#: stretch the secant modulus at the measured load, shear from KES G, isotropic (warp and weft averaged). `bend` is
#: calibrated (taichi_cloth.fabrics.calibrate_bend) so that a simulated cantilever strip at the garments' 2 cm spacing
#: has the fabric's measured bending length; damping and viscosity are the engine's usual values.
MATERIALS: dict[str, Material] = {
    "silk": Material(density=0.06, stretch=9806.6, shear=22.48, bend=5.22e-4, damping=2e-5, viscosity=2e-3),
    "cotton": Material(density=0.15, stretch=2000.0, shear=200.0, bend=2e-4, damping=2e-5, viscosity=2e-3),
    "jersey": Material(density=0.16, stretch=392.27, shear=28.09, bend=3.23e-4, damping=2e-5, viscosity=2e-3),
    "shirting": Material(density=0.12, stretch=12258.3, shear=56.19, bend=4.17e-3, damping=2e-5,
                         viscosity=2e-3),
    "wool": Material(density=0.23, stretch=8172.2, shear=33.71, bend=1.34e-3, damping=2e-5, viscosity=2e-3),
    "denim": Material(density=0.40, stretch=9806.6, shear=224.75, bend=2.14e-2, damping=2e-5, viscosity=2e-3),
    "leather": Material(density=0.90, stretch=3268.9, shear=561.88, bend=1.39, damping=2e-5, viscosity=2e-3),
}


def material(name_or_material: str | Material) -> Material:
    """A Material from a preset name, or the Material itself."""
    if isinstance(name_or_material, Material):
        return name_or_material
    try:
        return MATERIALS[name_or_material]
    except KeyError:
        raise ValueError(
            f"unknown material {name_or_material!r}: choose one of {', '.join(MATERIALS)}"
        ) from None
