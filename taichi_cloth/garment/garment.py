"""A garment: pattern pieces, seams, placements and fixed points (GarmentSpec), and the cloth built from it
(GarmentCloth): every piece meshed with seam-compatible boundary counts, placed around the body, with one
zero-rest-length seam spring per seam pair appended after the cloth's own springs.

Rest lengths, masses and spring constants come from the 2D pattern (the isotropic rule of
taichi_cloth.cloth.mesh_cloth), never from the placed 3D shape, so a piece bent around the body starts with the
strain of its placement and relaxes toward its pattern.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..body.landmarks import Body
from ..cloth import ClothData, SpringKind, mesh_cloth
from ..errors import MeshError, PatternError
from ..guards import check_memory, sheet_particles
from ..material import Material
from ..material import material as as_material
from .mesh import level_mesh, mesh_piece
from .pattern import PatternPiece
from .placement import place
from .seams import pair_sides, plan_counts, side_vertices


@dataclass(frozen=True)
class FreePlacement:
    """A piece laid flat anywhere, without a body: its point `at` (u, v) [m] goes to `origin` (3,) [m], its +u
    along `u_axis` and its +v along `v_axis` (3D directions, normalised here; they must not be parallel)."""

    origin: tuple
    u_axis: tuple = (1.0, 0.0, 0.0)
    v_axis: tuple = (0.0, 1.0, 0.0)
    at: tuple = (0.0, 0.0)

    def __post_init__(self):
        """PatternError naming the key and its value: an origin, axis or `at` that is not finite numbers, a zero
        axis (it has no direction: the piece would be placed at NaN), or parallel axes."""
        _vector("origin", self.origin, 3)
        _vector("at", self.at, 2)
        for key in ("u_axis", "v_axis"):
            if not np.linalg.norm(_vector(key, getattr(self, key), 3)) > 0:
                raise PatternError(f"free placement {key} must be a non-zero direction, got {getattr(self, key)!r}")
        if np.linalg.norm(self._frame()[1]) < 1e-9:
            raise PatternError(f"free placement: u_axis {self.u_axis!r} and v_axis {self.v_axis!r} are parallel")

    def _frame(self) -> tuple[np.ndarray, np.ndarray]:
        """(unit u_axis, v_axis less its part along u_axis): an orthonormal frame once the second is normalised,
        so the piece is laid without stretch."""
        eu = np.asarray(self.u_axis, dtype=np.float64)
        eu = eu / np.linalg.norm(eu)
        ev = np.asarray(self.v_axis, dtype=np.float64)
        return eu, ev - ev.dot(eu) * eu

    def place(self, uv: np.ndarray) -> np.ndarray:
        """(n, 3) [m] positions of pattern points uv (n, 2) [m]."""
        eu, ev = self._frame()
        ev = ev / np.linalg.norm(ev)
        d = np.asarray(uv, dtype=np.float64) - np.asarray(self.at, dtype=np.float64)
        return np.asarray(self.origin, dtype=np.float64) + d[:, :1] * eu + d[:, 1:2] * ev


def _vector(key: str, value, n: int) -> np.ndarray:
    """`value` as n finite floats, else PatternError naming the key and the value."""
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        v = None
    if v is None or v.shape != (n,) or not np.all(np.isfinite(v)):
        raise PatternError(f"free placement {key} must be {n} finite numbers, got {value!r}")
    return v


def place_piece(uv: np.ndarray, placement, body) -> np.ndarray:
    """(n, 3) [m]: a FreePlacement lays the piece flat; a Placement wraps it around the body's anchor."""
    if isinstance(placement, FreePlacement):
        return placement.place(uv)
    return place(uv, placement, body)


@dataclass(frozen=True)
class FixedPoint:
    """A particle held still (Hsiao 2006's fixed points): the particle of `piece` nearest to `point` (a corner
    name or index, or (u, v) [m] in the piece's plane). With `anchor`, it is held at that body anchor's surface
    point moved `offset` [m] outward; otherwise where the placement put it."""

    piece: str
    point: str | int | tuple
    anchor: str | None = None
    offset: float = 0.005


#: garment resolution presets: name -> (particle spacing [m], 4-8 levels coarse to fine). Garment tools draft at
#: about 2 cm and fit at about 1 cm. An odd number of levels ends on a square-lattice level at the spacing (an even
#: one on the diagonal level below it, with twice the particles); the first level is at 2 ** ((levels - 1) // 2)
#: times the spacing: 4 cm, 4 cm and 2 cm.
RESOLUTIONS = {"draft": (0.02, 3), "fit": (0.01, 5), "fine": (0.005, 5)}


@dataclass
class GarmentSpec:
    """Everything a garment file holds (our equivalent of Hsiao 2006's .gar file). Lengths in metres.

    name; pieces: PatternPiece list; seams: Seam list; placements: piece name -> Placement (around the body)
    or FreePlacement (every piece needs one); fixed: FixedPoint list; material: preset name or Material;
    spacing: particle spacing on the piece boundaries [m] (the interior lattice has the same cell); levels: 4-8
    levels meshed per piece (the finest is simulated; the spacing is that of the finest level); resolution: the
    RESOLUTIONS preset that set the spacing, if one did (None: the file's spacing).
    """

    name: str
    pieces: list
    seams: list = field(default_factory=list)
    placements: dict = field(default_factory=dict)
    fixed: list = field(default_factory=list)
    material: str | Material = "cotton"
    spacing: float = 0.02
    levels: int = 1
    resolution: str | None = None

    def at_resolution(self, name: str) -> None:
        """Mesh at the preset `name` of RESOLUTIONS (its spacing; its levels when run coarse to fine)."""
        if name not in RESOLUTIONS:
            raise PatternError(f"garment {self.name!r}: resolution must be one of {', '.join(RESOLUTIONS)}, got "
                               f"{name!r}")
        self.spacing, self.resolution = RESOLUTIONS[name][0], name

    @property
    def coarse_to_fine_levels(self) -> int:
        """The levels to run coarse to fine on: the file's `levels` where it names several, else its resolution's
        (else 1: the caller refuses)."""
        if self.levels > 1 or self.resolution is None:
            return self.levels
        return RESOLUTIONS[self.resolution][1]

    def piece(self, name: str) -> PatternPiece:
        for p in self.pieces:
            if p.name == name:
                return p
        raise PatternError(f"garment {self.name!r}: unknown piece {name!r} (pieces: "
                           f"{', '.join(p.name for p in self.pieces)})")

    def validate(self) -> None:
        """PatternError naming the first problem: no pieces, duplicate names, a piece without placement,
        a placement, seam or fixed point naming an unknown piece, a non-positive spacing."""
        g = f"garment {self.name!r}"
        if not self.pieces:
            raise PatternError(f"{g} has no pieces")
        names = [p.name for p in self.pieces]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise PatternError(f"{g}: duplicate piece names {', '.join(dup)}")
        if not (isinstance(self.spacing, (int, float)) and np.isfinite(self.spacing) and self.spacing > 0):
            raise PatternError(f"{g}: spacing must be a positive length, got {self.spacing!r}")
        if not (isinstance(self.levels, int) and 1 <= self.levels <= 6):
            raise PatternError(f"{g}: levels must be an integer in 1..6, got {self.levels!r}")
        for name in self.placements:
            self.piece(name)
        for p in self.pieces:
            if p.name not in self.placements:
                raise PatternError(f"{g}: piece {p.name!r} has no placement")
        seam_names = [s.name for s in self.seams]
        dup = sorted({n for n in seam_names if seam_names.count(n) > 1})
        if dup:
            raise PatternError(f"{g}: duplicate seam names {', '.join(dup)}")
        for s in self.seams:
            for side in (s.a, s.b):
                if side.piece not in names:
                    raise PatternError(f"seam {s.name!r}: unknown piece {side.piece!r} (pieces: {', '.join(names)})")
        for f in self.fixed:
            self.piece(f.piece)


@dataclass
class GarmentCloth:
    """A garment built and placed (the original particle numbering: piece after piece).

    spec:        the GarmentSpec; body: the Body it was placed on (None if every piece was placed freely);
                 material: Material
    data:        ClothData: placed positions [m], the pieces' springs from their 2D rest shape, then one SEAM
                 spring per seam pair (zero rest length; the sewing ramps its rest length down from the
                 initial gap, stored here)
    meshes:      PieceMesh per piece; offsets: (n_pieces + 1,) first particle of each piece
    seam_pairs:  (K, 2) int64 particle pairs, pick-ordered; seam_of_pair: (K,) int64 index into spec.seams
    seam_flags:  seam name -> (forward a, forward b): the recorded pick directions
    fixed:       (F,) int64 fixed particles; fixed_targets: (F, 3) [m] where they are held
    """

    spec: GarmentSpec
    body: Body | None
    material: Material
    data: ClothData
    meshes: list
    offsets: np.ndarray
    seam_pairs: np.ndarray
    seam_of_pair: np.ndarray
    seam_flags: dict
    fixed: np.ndarray
    fixed_targets: np.ndarray
    first_seam_spring: int

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def piece_names(self) -> list[str]:
        return [m.piece.name for m in self.meshes]

    def piece_of_particle(self) -> np.ndarray:
        """(P,) int64 piece index of each original particle."""
        return np.repeat(np.arange(len(self.meshes)), np.diff(self.offsets))

    def triangle_pieces(self) -> np.ndarray:
        """(T,) int64 piece index of each triangle."""
        return np.repeat(np.arange(len(self.meshes)), [len(m.triangles) for m in self.meshes])

    def rest_uv(self) -> np.ndarray:
        """(P, 2) float64 [m] pattern coordinates of each original particle (in its own piece's plane)."""
        return np.concatenate([m.uv for m in self.meshes])

    def boundary_edges(self, k: int) -> np.ndarray:
        """(E, 2) int64 original particle pairs along piece k's outline, in loop order."""
        loop = self.meshes[k].boundary_loop + self.offsets[k]
        return np.stack([loop, np.roll(loop, -1)], 1)


def build_garment(spec: GarmentSpec, body: Body | None = None, seam_stiffness: float | None = None) -> GarmentCloth:
    """Mesh, pair, place and assemble a garment on its finest level. body: the Body to place on (default: the
    shipped mannequin). seam_stiffness [N/m]: the seam springs' constant (default: the material's sheet modulus / 2,
    about the constant of one interior spring of the pieces)."""
    return build_garment_levels(spec, body, seam_stiffness, levels=[spec.levels - 1])[0]


def build_garment_levels(spec: GarmentSpec, body: Body | None = None, seam_stiffness: float | None = None,
                         levels=None) -> list[GarmentCloth]:
    """A GarmentCloth per 4-8 level of the garment (0-based `levels`, default all, coarsest first): the pieces are
    meshed once as hierarchies, so the levels share their outlines and their seam counts (a seam pairs its sides
    on every level). Every level carries the finest level's total mass (the outlines are resampled per level, so
    their areas differ slightly), so that a level switch keeps the mass."""
    plan = plan_garment_levels(spec, body, seam_stiffness)
    wanted = range(spec.levels) if levels is None else levels
    return [plan.assemble([level_mesh(m, k) for m in plan.finest]) for k in wanted]


@dataclass
class GarmentLevelPlan:
    """What every level of a garment is assembled from (build_garment_levels; a local refinement assembles its own
    piece meshes the same way: taichi_cloth.garment.local).

    finest:     PieceMesh per piece on the finest level (their hierarchies hold the other levels)
    total_mass: [kg] what the finest level's triangles weigh; every assembled cloth is rescaled to it
    """

    spec: GarmentSpec
    finest: list
    routes: dict
    material: Material
    body: Body | None
    seam_stiffness: float
    total_mass: float

    def assemble(self, meshes: list) -> GarmentCloth:
        """The GarmentCloth of one mesh per piece (in spec.pieces order; seam sides with equal counts), its mass
        rescaled to total_mass."""
        g = _assemble(self.spec, meshes, self.routes, self.material, self.body, self.seam_stiffness)
        if any(m is not f for m, f in zip(meshes, self.finest)):
            g.data.mass *= self.total_mass / g.data.mass.sum()
        return g


def plan_garment_levels(spec: GarmentSpec, body: Body | None = None,
                        seam_stiffness: float | None = None) -> GarmentLevelPlan:
    """Mesh the pieces of `spec` as hierarchies and plan their seams (see build_garment_levels). A spacing that would
    mesh more particles than the machine has memory for is refused first (PatternError naming the spacing)."""
    spec.validate()
    check_memory(sheet_particles(sum(p.area() for p in spec.pieces), sum(p.perimeter() for p in spec.pieces),
                                 spec.spacing, spec.levels),
                 f"garment {spec.name!r}: spacing {spec.spacing:.3g} m" + (f" ({spec.levels} levels)"
                                                                         if spec.levels > 1 else ""),
                 error=PatternError, advice="use a larger spacing (or resolution = \"draft\", \"fit\", \"fine\")")
    mat = as_material(spec.material)
    needs_body = any(not isinstance(p, FreePlacement) for p in spec.placements.values()) or any(
        f.anchor for f in spec.fixed)
    if body is None and needs_body:
        try:
            body = Body.from_mannequin()
        except MeshError as exc:  # its message names the body's file
            raise MeshError(f"garment {spec.name!r}: placing its pieces on the {exc}") from None
    pieces = {p.name: p for p in spec.pieces}
    tol = spec.spacing / 200.0
    lengths = {n: np.array([s.length(tol / 10) for s in p.segments]) for n, p in pieces.items()}
    base_spacing = spec.spacing * 2 ** ((spec.levels - 1) // 2)
    counts, routes = plan_counts(pieces, spec.seams, base_spacing, lengths)
    finest = [mesh_piece(p, base_spacing, counts[p.name], levels=spec.levels, tolerance=tol) for p in spec.pieces]
    k_s = mat.sheet_modulus / 2 if seam_stiffness is None else float(seam_stiffness)
    if not k_s > 0:
        raise PatternError(f"garment {spec.name!r}: seam stiffness must be > 0 N/m, got {seam_stiffness!r}")
    total = mat.density * sum(m.area for m in finest)
    return GarmentLevelPlan(spec, finest, routes, mat, body, k_s, total)


def _assemble(spec: GarmentSpec, meshes: list, routes: dict, mat: Material, body, k_s: float) -> GarmentCloth:
    """The GarmentCloth of one level's piece meshes: springs from the 2D rest shape, placed, seams paired."""
    offsets = np.concatenate([[0], np.cumsum([m.n_vertices for m in meshes])]).astype(np.int64)
    index = {m.piece.name: k for k, m in enumerate(meshes)}

    # the cloth's own springs from the 2D rest shape: all pieces side by side in z = 0 (they share no vertex)
    uv3 = np.zeros((offsets[-1], 3))
    uv3[:, :2] = np.concatenate([m.uv for m in meshes])
    tris = np.concatenate([m.triangles + offsets[k] for k, m in enumerate(meshes)])
    data = mesh_cloth(uv3, tris, mat, source=f"garment {spec.name!r}", stiffness_rule="isotropic")

    placed = np.concatenate([place_piece(m.uv, spec.placements[m.piece.name], body) for m in meshes])

    pairs, owner, flags = [], [], {}
    for s_idx, seam in enumerate(spec.seams):
        ra, rb = routes[seam.name]
        ka, kb = index[seam.a.piece], index[seam.b.piece]
        a = side_vertices(meshes[ka].boundary_segments, ra) + offsets[ka]
        b = side_vertices(meshes[kb].boundary_segments, rb) + offsets[kb]
        p = pair_sides(a, ra, b, rb, seam.name)
        p = p[p[:, 0] != p[:, 1]]  # a self-seam's shared corner pairs with itself
        pairs.append(p)
        owner.append(np.full(len(p), s_idx, np.int64))
        flags[seam.name] = (ra.forward, rb.forward)
    seam_pairs = np.concatenate(pairs) if pairs else np.zeros((0, 2), np.int64)
    seam_of_pair = np.concatenate(owner) if owner else np.zeros(0, np.int64)

    gap = np.linalg.norm(placed[seam_pairs[:, 1]] - placed[seam_pairs[:, 0]], axis=1)
    K = len(seam_pairs)
    cloth = ClothData(
        positions=placed, mass=data.mass,
        springs=np.concatenate([data.springs, seam_pairs]),
        rest_length=np.concatenate([data.rest_length, gap]),
        stiffness=np.concatenate([data.stiffness, np.full(K, k_s)]),
        damping=np.concatenate([data.damping, np.full(K, mat.damping * k_s)]),
        kind=np.concatenate([data.kind, np.full(K, int(SpringKind.SEAM), np.int64)]),
        triangles=data.triangles, viscosity=data.viscosity)

    fixed, targets = _fixed_points(spec, meshes, offsets, index, placed, body)
    cloth.positions[fixed] = targets
    return GarmentCloth(spec, body, mat, cloth, meshes, offsets, seam_pairs, seam_of_pair, flags, fixed, targets,
                        data.n_springs)


def _fixed_points(spec, meshes, offsets, index, placed, body):
    idx, targets = [], []
    for f in spec.fixed:
        k = index[f.piece]
        mesh = meshes[k]
        if isinstance(f.point, (str, int)) and not isinstance(f.point, bool):
            uv = mesh.piece.corners[mesh.piece.corner_index(f.point)]
        else:
            uv = np.asarray(f.point, dtype=np.float64).reshape(2)
        i = int(np.argmin(((mesh.uv - uv) ** 2).sum(1))) + int(offsets[k])
        idx.append(i)
        targets.append(body.surface_point(f.anchor, f.offset) if f.anchor else placed[i])
    if not idx:
        return np.zeros(0, np.int64), np.zeros((0, 3))
    return np.array(idx, np.int64), np.array(targets, np.float64)
