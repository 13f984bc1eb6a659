"""Fabric measurements (Kawabata KES-F, SiroFAST) turned into the mass-spring model's Material, and the two tests
that check the result: the cantilever bending length (calibrates `bend`) and the Cusick drape coefficient.

Conversions (docs/fabrics.md):

- density [kg/m^2]  = weight [g/m^2] / 1000
- stretch [N/m]     = secant modulus at the measured load: load [N/m] / strain (FAST: 100 gf/cm = 98.07 N/m over E100;
                      KES EMT is the strain at 500 gf/cm = 490.3 N/m)
- shear [N/m]       = G [gf/cm/degree] x 9.807e-3 N/gf / 0.01 m/cm x 180/pi
- bending rigidity  = B [gf cm^2/cm] x 9.807e-5 [N m]; bending length c = (B / (w g))^(1/3), w the weight [kg/m^2]

The model's bend springs (k = bend / L^2 across every interior edge) are not a continuum bending rigidity, so `bend`
is calibrated: a simulated Peirce cantilever strip (the FAST-2 / BS 3356 bending-length test) is given the fabric's
bending length at the garments' spacing (`calibrate_bend`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .cloth import mesh_cloth
from .garment.mesh import mesh_piece
from .garment.pattern import PatternPiece
from .material import Material
from .perturb import perturb_start
from .scene import Scene

#: standard gravity [m/s^2] (the gram-force)
G0 = 9.80665
#: one gram-force [N]
GF = G0 * 1e-3
#: the Peirce cantilever's tip line: a strip whose overhang is l drops to this angle [deg] when l = 2 c
CANTILEVER_ANGLE = 41.5


def shear_from_kes(g_gf_cm_deg: float) -> float:
    """Shear stiffness [N/m] from KES-F (or FAST) shear rigidity G [gf/cm/degree]."""
    return g_gf_cm_deg * GF / 0.01 * 180.0 / math.pi


def bending_rigidity_from_kes(b_gf_cm2_cm: float) -> float:
    """Bending rigidity [N m] from KES-F B [gf cm^2/cm] (= 9.807e-5 N m per gf cm^2/cm)."""
    return b_gf_cm2_cm * GF * 1e-4 / 1e-2


def stretch_secant(load_n_per_m: float, strain: float) -> float:
    """Secant tensile modulus [N/m]: the load per width [N/m] over the strain [-] it gives."""
    return load_n_per_m / strain


def bending_length(rigidity: float, density: float, g: float = G0) -> float:
    """Peirce bending length c [m] = (B / (w g))^(1/3) for bending rigidity B [N m] and areal density w [kg/m^2]."""
    return (rigidity / (density * g)) ** (1.0 / 3.0)


@dataclass(frozen=True)
class Fabric:
    """One fabric's published measurements (means of warp and weft where the source gives both) and its source.

    weight [g/m^2]; extension [-] the strain at `load` [N/m] (FAST E100 at 98.07 N/m, or KES EMT at 490.3 N/m);
    G [gf/cm/deg]; B [gf cm^2/cm]; source: who measured it; notes: what was averaged or taken from a typical range.
    """

    name: str
    weight: float
    extension: float
    load: float
    G: float
    B: float
    source: str
    notes: str = ""

    @property
    def density(self) -> float:
        return self.weight / 1000.0

    @property
    def stretch(self) -> float:
        return stretch_secant(self.load, self.extension)

    @property
    def shear(self) -> float:
        return shear_from_kes(self.G)

    @property
    def rigidity(self) -> float:
        return bending_rigidity_from_kes(self.B)

    @property
    def bending_length(self) -> float:
        return bending_length(self.rigidity, self.density)

    def material(self, bend: float, damping: float = 2e-5, viscosity: float = 2e-3) -> Material:
        """The model's Material, with the calibrated `bend` [N m] (calibrate_bend)."""
        return Material(density=self.density, stretch=self.stretch, shear=self.shear, bend=bend, damping=damping,
                        viscosity=viscosity)


#: KES-F strain load: EMT is the strain at 500 gf/cm [N/m]
KES_EMT_LOAD = 500.0 * GF / 0.01
#: FAST-3 load: E100 is the strain at 100 gf/cm [N/m]
FAST_E100_LOAD = 100.0 * GF / 0.01

#: The measured fabrics behind the presets (docs/fabrics.md gives the sources and the ranges the values are taken
#: from): typical mid-range KES-F values of each fabric type, warp and weft averaged. Not single quoted measurements.
FABRICS: dict[str, Fabric] = {
    "silk": Fabric("silk", weight=60.0, extension=0.05, load=KES_EMT_LOAD, G=0.4, B=0.03,
                   source="silk crepe de chine / habotai, KES-F typical values", notes="ranges in docs/fabrics.md"),
    "jersey": Fabric("jersey", weight=160.0, extension=0.25, load=FAST_E100_LOAD, G=0.5, B=0.04,
                     source="cotton single jersey, KES-F B and G, extension at 100 gf/cm", notes="course/wale mean"),
    "shirting": Fabric("shirting", weight=120.0, extension=0.04, load=KES_EMT_LOAD, G=1.0, B=0.10,
                       source="cotton poplin shirting, KES-F typical values"),
    "wool": Fabric("wool", weight=230.0, extension=0.06, load=KES_EMT_LOAD, G=0.6, B=0.09,
                   source="worsted men's suiting, KES-F typical values (Kawabata & Niwa)"),
    "denim": Fabric("denim", weight=400.0, extension=0.05, load=KES_EMT_LOAD, G=4.0, B=1.5,
                    source="cotton denim 12 oz, KES-F typical values"),
    "leather": Fabric("leather", weight=900.0, extension=0.15, load=KES_EMT_LOAD, G=10.0, B=10.0,
                      source="garment leather about 1 mm, KES-F typical values (wide range)"),
}


#: Published Cusick drape-coefficient ranges per fabric type (docs/fabrics.md says where each comes from)
DC_RANGES: dict[str, tuple[float, float]] = {
    "silk": (0.20, 0.40), "jersey": (0.20, 0.45), "shirting": (0.40, 0.65), "wool": (0.40, 0.70),
    "denim": (0.60, 0.90), "leather": (0.80, 0.95),
}


# -- the Cusick drape test ---------------------------------------------------------------------------------------------

#: BS 5058 / ISO 9073-9: a 30 cm specimen between two 18 cm disks
CUSICK_SPECIMEN = 0.30
CUSICK_PEDESTAL = 0.18


def disk_piece(diameter: float, name: str = "disk"):
    """A circular PatternPiece of `diameter` [m] centred on the origin: four exact quarter arcs."""
    r, b = 0.5 * diameter, math.tan(math.pi / 8.0)  # bulge = tan(sweep / 4)
    return PatternPiece.from_corners(name, [{"at": [r, 0.0], "bulge": b}, {"at": [0.0, r], "bulge": b},
                                            {"at": [-r, 0.0], "bulge": b}, {"at": [0.0, -r], "bulge": b}])


def disk_mesh(diameter: float, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """(uv (n,2) [m], triangles (t,3)) of a disk meshed by the garment mesher at `spacing` [m]."""
    m = mesh_piece(disk_piece(diameter), spacing)
    return m.uv, m.triangles


def _raster_cell_centres(lo: np.ndarray, cell: float, shape) -> tuple[np.ndarray, np.ndarray]:
    return lo[0] + cell * (np.arange(shape[0]) + 0.5), lo[1] + cell * (np.arange(shape[1]) + 0.5)


def projected_area(vertices: np.ndarray, triangles: np.ndarray, cell: float = 5e-4, up: int = 1) -> float:
    """Area [m^2] of the union of the triangles' projections along axis `up` (the shadow cast from above), by
    rasterising them on a grid of `cell` [m] squares: a cell counts when its centre lies in a projected triangle
    (edges included). The error is at most the perimeter of the shadow (holes' included) times cell / sqrt(2) and is
    usually a small fraction of that: over- and under-counted cells along the outline largely cancel."""
    v = np.asarray(vertices, dtype=np.float64)
    axes = [a for a in range(v.shape[1]) if a != up] if v.shape[1] == 3 else [0, 1]
    p = v[:, axes]
    t = np.asarray(triangles, dtype=np.int64)
    lo = p.min(axis=0) - cell
    shape = tuple(int(n) for n in np.ceil((p.max(axis=0) + cell - lo) / cell))
    covered = np.zeros(shape, dtype=bool)
    a, b, c = p[t[:, 0]], p[t[:, 1]], p[t[:, 2]]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    keep = np.abs(cross) > 0  # a triangle seen edge-on casts no area
    a, b, c, cross = a[keep], b[keep], c[keep], cross[keep]
    flip = cross < 0
    b, c = np.where(flip[:, None], c, b), np.where(flip[:, None], b, c)  # counter-clockwise
    tri_lo = np.floor((np.minimum(np.minimum(a, b), c) - lo) / cell - 0.5).astype(np.int64)
    tri_hi = np.ceil((np.maximum(np.maximum(a, b), c) - lo) / cell - 0.5).astype(np.int64)
    xs, ys = _raster_cell_centres(lo, cell, shape)
    # triangles in batches of equal bounding-box size, so each batch is one vectorised test
    span = np.maximum(tri_hi - tri_lo + 1, 1)
    size = int(span.max())
    batch = max(1, 2_000_000 // (size * size))
    for start in range(0, len(a), batch):
        sl = slice(start, start + batch)
        i = tri_lo[sl, 0, None, None] + np.arange(size)[None, :, None]
        j = tri_lo[sl, 1, None, None] + np.arange(size)[None, None, :]
        i, j = np.broadcast_arrays(i, j)
        valid = (i >= 0) & (i < shape[0]) & (j >= 0) & (j < shape[1])
        i, j = np.clip(i, 0, shape[0] - 1), np.clip(j, 0, shape[1] - 1)
        x, y = xs[i], ys[j]
        inside = valid
        for (p0, p1) in ((a[sl], b[sl]), (b[sl], c[sl]), (c[sl], a[sl])):
            e = ((p1[:, 0] - p0[:, 0])[:, None, None] * (y - p0[:, 1, None, None])
                 - (p1[:, 1] - p0[:, 1])[:, None, None] * (x - p0[:, 0, None, None]))
            inside &= e >= 0
        covered[i[inside], j[inside]] = True
    return float(covered.sum()) * cell * cell


#: the pedestal's (support disk's) area [m^2]
PEDESTAL_AREA = math.pi * (0.5 * CUSICK_PEDESTAL) ** 2


def drape_coefficient(shadow: float, specimen: float = CUSICK_SPECIMEN, pedestal: float = CUSICK_PEDESTAL) -> float:
    """Cusick's DC = (shadow - pedestal area) / (specimen area - pedestal area) for a shadow [m^2] and the specimen's
    and pedestal's diameters [m]."""
    return drape_coefficient_areas(shadow, math.pi * (0.5 * specimen) ** 2, math.pi * (0.5 * pedestal) ** 2)


def drape_coefficient_areas(shadow: float, specimen_area: float, pedestal_area: float = PEDESTAL_AREA) -> float:
    """Cusick's DC from areas [m^2]: (shadow - pedestal) / (specimen - pedestal)."""
    return (shadow - pedestal_area) / (specimen_area - pedestal_area)


# -- the cantilever bending-length test (calibrates `bend`) -----------------------------------------------------------

def cantilever_angle(overhang_over_c: float) -> float:
    """The chord angle [deg] below the horizontal from the ledge's edge to the tip of an inextensible elastica strip
    overhanging by `overhang_over_c` bending lengths under its own weight (exact, not Peirce's small-angle formula:
    d^2 phi / ds^2 = -(l - s) cos(phi) / c^3 with phi(0) = 0, phi'(l) = 0). At l = 2 c it is 41.5 degrees, the line
    of the FAST-2 and BS 3356 bending-length tests."""
    from scipy.integrate import solve_bvp
    lam = float(overhang_over_c)
    s = np.linspace(0.0, 1.0, 201)  # arc length over l

    def rhs(s, y):  # y = (phi, phi', x, z) with lengths in units of l
        return np.vstack([y[1], -lam ** 3 * (1.0 - s) * np.cos(y[0]), np.cos(y[0]), np.sin(y[0])])

    def bc(ya, yb):
        return np.array([ya[0], yb[1], ya[2], ya[3]])

    guess = np.zeros((4, len(s)))
    guess[2] = s
    sol = solve_bvp(rhs, bc, s, guess, tol=1e-8, max_nodes=100000)
    if not sol.success:
        raise RuntimeError(f"the elastica at l/c = {lam} did not converge: {sol.message}")
    x, z = sol.sol(1.0)[2:]
    return math.degrees(math.atan2(z, x))


#: the tip angle [deg] of an overhang of 3 bending lengths, the longest bending_length_from_angle inverts
MAX_ANGLE = 66.9


def bending_length_from_angle(overhang: float, angle_deg: float) -> float:
    """The bending length c [m] of a strip whose tip, `overhang` [m] past the ledge, lies `angle_deg` below the
    horizontal (the inverse of cantilever_angle)."""
    from scipy.optimize import brentq
    if not 0.1 < angle_deg < MAX_ANGLE:
        raise ValueError(f"a cantilever's tip angle must lie between 0.1 and {MAX_ANGLE} degrees (overhangs up to 3 "
                         f"bending lengths), got {angle_deg}")
    lam = brentq(lambda q: cantilever_angle(q) - angle_deg, 0.3, 3.0, xtol=1e-6)
    return overhang / lam


@dataclass(frozen=True)
class Cantilever:
    """One simulated cantilever: `overhang` [m] past the ledge at mesh `spacing` [m], its tip's chord angle [deg]
    below the horizontal once at rest, and the bending length [m] that angle gives (bending_length_from_angle)."""

    spacing: float
    overhang: float
    angle: float
    bending_length: float
    rest_time: float


def cantilever_overhang(target_c: float, spacing: float) -> float:
    """The overhang [m] the calibration uses: the standards' 2 c, but at least two mesh spacings (a strip of one
    spacing has no interior hinge to bend at)."""
    return max(2.0 * target_c, 2.0 * spacing)


def simulate_cantilever(material: Material, spacing: float, overhang: float, width: float = 0.05,
                        max_time: float = 8.0) -> Cantilever:
    """The FAST-2 / BS 3356 bending test in the model: a strip `width` [m] wide (at least two spacings) meshed by the
    garment mesher at `spacing` [m], held flat on a ledge (the particles at x <= 0: a clamp two spacings long) and
    overhanging by `overhang` [m], settles under gravity with the garment scenes' implicit settings (dt 1/120 s, CG
    tolerance 1e-3, air damping 1/s) until at rest (the scenes' rest criterion, at most `max_time` [s]). The tip is
    the mean of the particles at the free end."""
    width = max(width, 2.0 * spacing)
    ledge = 2.0 * spacing
    piece = PatternPiece.from_polygon("strip", [[-ledge, 0.0], [overhang, 0.0], [overhang, width], [-ledge, width]])
    m = mesh_piece(piece, spacing)
    uv, tri = m.uv, m.triangles
    height = 1.0
    x0 = np.c_[uv[:, 0], np.full(len(uv), height), uv[:, 1]]
    cloth = mesh_cloth(x0, tri, material, source="cantilever", stiffness_rule="isotropic", uv=uv)
    held = np.nonzero(uv[:, 0] <= 1e-9)[0]
    tip = np.nonzero(uv[:, 0] >= overhang - 1e-9)[0]
    scene = Scene(cloth, integrator="implicit", dt=1.0 / 120.0, integrator_options={"cg_tolerance": 1e-3},
                  air_damping=1.0, pins=[{"indices": held.tolist()}], fps=60.0, rest={"stop": True})
    summary = scene.run(int(round(max_time * 60.0)), progress=False)
    x = scene.positions()[tip]
    angle = math.degrees(math.atan2(height - x[:, 1].mean(), x[:, 0].mean()))
    rest_time = float(scene.state.t)
    c = bending_length_from_angle(overhang, angle) if 0.1 < angle < MAX_ANGLE else float("nan")
    del summary
    return Cantilever(spacing, overhang, angle, c, rest_time)


def calibrate_bend(fabric: Fabric, spacing: float, tolerance: float = 0.5, max_tries: int = 12,
                   start: float | None = None, bending: str = "springs",
                   membrane: str = "isotropic") -> tuple[float, list[tuple[float, Cantilever]]]:
    """The model's `bend` [N m] for which a simulated cantilever at `spacing` [m], overhanging by
    cantilever_overhang(c, spacing), has its tip at the angle an elastica of the fabric's measured bending length c
    has there (41.5 degrees at the standards' overhang of 2 c), within `tolerance` [deg]; and the (bend, cantilever)
    pairs tried. The model's bend springs resist a hinge's fold angle theta with a force ~ theta^2 (their length
    changes to second order), so the strip's tip angle falls slowly with bend: the search brackets it by factors of
    4 from the measured rigidity (or `start`), then narrows the bracket by regula falsi on log(bend) (Illinois).
    bending, membrane: the Material's models (with "quadratic" bending, `bend` is a rigidity and lands near B)."""
    target_c = fabric.bending_length
    overhang = cantilever_overhang(target_c, spacing)
    target = cantilever_angle(overhang / target_c)
    tries: list[tuple[float, Cantilever]] = []

    def miss(bend: float) -> float:
        result = simulate_cantilever(fabric.material(bend).replace(bending=bending, membrane=membrane), spacing,
                                     overhang)
        tries.append((bend, result))
        return result.angle - target  # > 0: too soft

    b0 = fabric.rigidity if start is None else start
    f0 = miss(b0)
    lo = hi = None
    b, f = b0, f0
    while len(tries) < max_tries and abs(f) > tolerance:
        if f > 0:
            lo = (math.log(b), f)
        else:
            hi = (math.log(b), f)
        if lo is None or hi is None:
            b = b * (4.0 if f > 0 else 0.25)
            f = miss(b)
            continue
        x = lo[0] - lo[1] * (hi[0] - lo[0]) / (hi[1] - lo[1])
        b = math.exp(x)
        f_new = miss(b)
        # Illinois: halve the value kept at the side that did not move, so the bracket shrinks from both ends
        if f_new > 0 and lo is not None and f > 0:
            hi = (hi[0], 0.5 * hi[1])
        elif f_new <= 0 and hi is not None and f <= 0:
            lo = (lo[0], 0.5 * lo[1])
        f = f_new
    best = min(tries, key=lambda bt: abs(bt[1].angle - target))
    return best[0], tries


# -- the Cusick drape test in the model --------------------------------------------------------------------------------

@dataclass(frozen=True)
class Drape:
    """One simulated Cusick test: the drape coefficient, the shadow [m^2], the flat specimen's area [m^2] (the meshed
    disk's, a polygon inscribed in the circle), the simulated time [s], whether the scene's rest criterion ended it,
    the final positions (P,3) [m] and the triangles."""

    dc: float
    shadow: float
    specimen: float
    time: float
    at_rest: bool
    positions: np.ndarray
    triangles: np.ndarray


def cusick_scene(material: Material, spacing: float, height: float = 1.0, **options):
    """(Scene, triangles, flat area [m^2]) of the Cusick test in the model: a 30 cm disk meshed by the garment mesher
    at `spacing` [m], flat at `height` [m] in the xz plane, the particles within the 18 cm clamp (r <= 9 cm) held, the
    rest free, with the garment scenes' settings (implicit, dt 1/120 s, CG tolerance 1e-3, air damping 1/s, stretch
    limit 10 %, 20 iterations) and the rest criterion ending the run; `options` override Scene options."""
    uv, tri = disk_mesh(CUSICK_SPECIMEN, spacing)
    x0 = np.c_[uv[:, 0], np.full(len(uv), height), uv[:, 1]]
    cloth = mesh_cloth(x0, tri, material, source="cusick disk", stiffness_rule="isotropic", uv=uv)
    held = np.nonzero(np.hypot(uv[:, 0], uv[:, 1]) <= 0.5 * CUSICK_PEDESTAL + 1e-9)[0]
    settings = dict(integrator="implicit", dt=1.0 / 120.0, integrator_options={"cg_tolerance": 1e-3},
                    air_damping=1.0, stretch_limit={"max_strain": 0.1, "iterations": 20},
                    pins=[{"indices": held.tolist()}], fps=60.0, rest={"stop": True})
    settings.update(options)
    flat = float(projected_area_exact(uv, tri))
    return Scene(cloth, **settings), tri, flat


def projected_area_exact(uv: np.ndarray, triangles: np.ndarray) -> float:
    """Area [m^2] of a flat, non-overlapping triangle mesh (uv (n,2)): the sum of its triangles' areas."""
    a, b, c = (uv[triangles[:, k]] for k in range(3))
    return float(0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])).sum())


def cusick_drape(material: Material, spacing: float, max_time: float = 10.0, perturb: float = 0.0, seed: int = 0,
                 cell: float = 5e-4) -> Drape:
    """Run the Cusick test (cusick_scene) until at rest or `max_time` [s]; with `perturb` [m] > 0, the free
    particles' start moved first by that much (taichi_cloth.perturb, `seed`). The DC's specimen area is the meshed
    disk's own flat area, so a disk that does not drape at all gives DC = 1 up to the rasterisation (cell [m])."""
    scene, tri, flat = cusick_scene(material, spacing)
    if perturb > 0:
        perturb_start(scene, perturb, seed)
    summary = scene.run(int(round(max_time * 60.0)), progress=False)
    x = scene.positions()
    shadow = projected_area(x, tri, cell)
    return Drape(drape_coefficient_areas(shadow, flat), shadow, flat, float(scene.state.t),
                 bool(summary.stopped_at_rest), x, tri)
