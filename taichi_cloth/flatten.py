"""3D -> 2D flattening of a garment piece (Fan et al. 1998 section 3.2) and its error metrics.

A 3D piece (a draped garment piece, or any triangle mesh with disc topology) is flattened in three steps:

1. Initial planar layout: the triangles are unfolded across shared edges, breadth first from the triangle
   nearest the piece's middle. Each new vertex is placed by trilateration from the two placed ends of the
   shared edge, with the triangle's 3D side lengths, on the side its winding asks for (so every triangle of
   a consistently wound disc lands counter-clockwise). One BFS wave is one vectorised numpy step.
2. Planar spring relaxation with the engine's own mass-spring model, as Fan et al. 1998 do ("the same model and
   computation, without gravity, sewing or collision forces"): one structural spring per triangle edge with the
   3D edge length as rest length (the isotropic constants of `taichi_cloth.cloth.mesh_cloth`), masses from the 3D
   areas, no bend springs (a planar sheet has nothing to bend). It runs the implicit (BW98) integrator in
   float64 quasi-statically: velocities are zeroed before every step, so each step is a Newton step on the
   elastic energy regularised by the mass matrix (h is set so that h^2 k / m ~ 1e3 on the stiffest particle).
   It stops when the relative energy change of a step falls below `tolerance` (Fan et al. 1998: "when the change of
   the elastic energy between two iterations is below a given error"). All forces lie in the plane, so the
   piece stays at z = 0.
3. Checks and metrics (Fan et al. 1998 table 1, 3D values as the denominators): area error |S3 - S2| / S3, boundary
   length error |L3 - L2| / L3, per-edge length error (l2 - l3) / l3 (the error map), flipped triangles
   (signed 2D area <= 0; none is allowed).

A developable piece (a cylinder or cone patch) unfolds exactly in step 1 and needs no relaxation; a doubly curved
one (a sphere cap) cannot reach zero error, and its errors grow with its curvature.
"""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clothbase.meshes import connected_components, edges_of, triangle_areas, validate_triangle_mesh

from .cloth import ClothData, SpringKind, mesh_cloth
from .errors import MeshError
from .garment.pattern import PatternPiece, Segment
from .model import Model
from .scene import Scene

__all__ = ["FlatPiece", "disc_boundary", "unfold", "flatten", "flatten_pieces", "write_flat_dxf", "plot_flat",
           "format_table"]


# ------------------------------------------------------------------------------------------- topology

def disc_boundary(vertices, triangles, source: str = "piece") -> np.ndarray:
    """The boundary loop (m,) int64 of a triangle mesh with disc topology, in the direction of the triangles'
    winding (counter-clockwise around the piece seen from the side the winding faces).

    Raises MeshError naming `source` and the problem: an invalid mesh (validate_triangle_mesh), unused
    vertices, inconsistent winding, several pieces, no boundary (a closed surface), several boundary loops (a
    tube, or holes), a vertex where the boundary touches itself, or a handle (Euler characteristic != 1)."""
    v, t = np.asarray(vertices), np.asarray(triangles, dtype=np.int64)
    validate_triangle_mesh(v, t, source)
    n = len(v)
    unused = n - len(np.unique(t))
    if unused:
        raise MeshError(f"{source}: {unused} vertices belong to no triangle")
    directed = t[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    _, dcount = np.unique(directed, axis=0, return_counts=True)
    if (dcount > 1).any():
        raise MeshError(f"{source}: the triangles are not consistently wound ({int((dcount > 1).sum())} edges are "
                        f"walked the same way by both their triangles)")
    edges, face_edge, counts = edges_of(t)
    pieces = len(np.unique(connected_components(n, edges)))
    if pieces > 1:
        raise MeshError(f"{source}: the mesh has {pieces} separate pieces; flatten one disc at a time")
    on_boundary = counts[face_edge.reshape(-1)] == 1
    bnd = directed[on_boundary]  # boundary half-edges, in winding direction
    if len(bnd) == 0:
        raise MeshError(f"{source}: a closed surface has no boundary; cut it open into a disc first")
    out_degree = np.bincount(bnd[:, 0], minlength=n)
    if out_degree.max() > 1:
        raise MeshError(f"{source}: the boundary touches itself at {int((out_degree > 1).sum())} vertices")
    loops = len(np.unique(connected_components(n, bnd)[bnd[:, 0]]))
    if loops > 1:
        raise MeshError(f"{source}: the mesh has {loops} boundary loops (a tube or a piece with holes); a disc has "
                        f"one: cut it open first")
    euler = n - len(edges) + len(t)
    if euler != 1:
        raise MeshError(f"{source}: Euler characteristic {euler}, a disc has 1 (the piece has handles)")
    nxt = np.full(n, -1, np.int64)
    nxt[bnd[:, 0]] = bnd[:, 1]
    loop = np.empty(len(bnd), np.int64)
    loop[0] = bnd[0, 0]
    for k in range(1, len(bnd)):  # a walk along the outline (m ~ sqrt(V) steps), once per piece
        loop[k] = nxt[loop[k - 1]]
    return loop


# ------------------------------------------------------------------------------------------- unfolding

def unfold(vertices, triangles) -> np.ndarray:
    """Initial planar layout (V, 2) float64 [m] of a consistently wound disc (see disc_boundary), by unfolding
    triangles across shared edges breadth first. Every triangle keeps its 3D side lengths exactly when it is
    placed; the error of a doubly curved piece gathers where unfolding fronts meet."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    uv = np.zeros((len(v), 2))
    placed = np.zeros(len(v), bool)
    done = np.zeros(len(t), bool)
    centre = v.mean(axis=0)
    t0 = int(np.argmin(np.linalg.norm(v[t].mean(axis=1) - centre, axis=1)))
    a, b, c = t[t0]
    uv[b] = [np.linalg.norm(v[b] - v[a]), 0.0]
    uv[c] = _apex(uv[a][None], uv[b][None], v[[a]], v[[b]], v[[c]])[0]
    placed[[a, b, c]] = True
    done[t0] = True
    while not done.all():
        n_placed = placed[t].sum(axis=1)
        closing = ~done & (n_placed == 3)  # all three corners already placed from other sides
        done |= closing
        grow = np.flatnonzero(~done & (n_placed == 2))
        if len(grow) == 0:
            if not done.all():
                raise MeshError(f"unfold: {int((~done).sum())} triangles are not reachable across shared edges")
            break
        k = np.argmin(placed[t[grow]], axis=1)  # the missing corner; the edge opposite it is placed
        rows = t[grow]
        c = rows[np.arange(len(grow)), k]
        p = rows[np.arange(len(grow)), (k + 1) % 3]
        q = rows[np.arange(len(grow)), (k + 2) % 3]
        c_unique, first = np.unique(c, return_index=True)  # two triangles may reach the same corner in one wave
        sel = first
        uv[c_unique] = _apex(uv[p[sel]], uv[q[sel]], v[p[sel]], v[q[sel]], v[c[sel]])
        placed[c_unique] = True
        done[grow[sel]] = True
    return uv


def _apex(up, uq, p, q, c) -> np.ndarray:
    """2D position (n, 2) of apex c of the counter-clockwise triangle (p, q, c) given p, q in 2D (n, 2) and all
    three in 3D (n, 3): c keeps its 3D distances to p and to q (measured along the 2D edge direction from p)."""
    d = uq - up
    e = d / np.linalg.norm(d, axis=1, keepdims=True)
    normal = np.stack([-e[:, 1], e[:, 0]], axis=1)  # left of p -> q: counter-clockwise
    L = np.linalg.norm(q - p, axis=1)
    rp2 = ((c - p) ** 2).sum(axis=1)
    rq2 = ((c - q) ** 2).sum(axis=1)
    along = (rp2 - rq2 + L**2) / (2 * L)
    height = np.sqrt(np.maximum(rp2 - along**2, 0.0))
    return up + along[:, None] * e + height[:, None] * normal


# ------------------------------------------------------------------------------------------- the piece

@dataclass
class FlatPiece:
    """A flattened piece.

    name: str; vertices: (V,3) float64 [m] the 3D piece; triangles: (T,3) int64; uv: (V,2) float64 [m] the
    flattened layout (counter-clockwise triangles); boundary: (m,) int64 the outline in loop order;
    edges: (E,2) int64; edge_error: (E,) float64 (l2 - l3) / l3 per edge; corners: name -> vertex index on the
    outline (named corners of the DXF export; empty: one closed polyline);
    iterations: relaxation steps taken; energy: (iterations + 1,) float64 [J] elastic energy before and after
    each step; initial_area_error / initial_boundary_error: the metrics of the unfolded layout before relaxing.
    """

    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray
    boundary: np.ndarray
    edges: np.ndarray
    edge_error: np.ndarray
    iterations: int
    energy: np.ndarray
    initial_area_error: float
    initial_boundary_error: float
    corners: dict = field(default_factory=dict)

    @property
    def area_3d(self) -> float:
        return float(triangle_areas(self.vertices, self.triangles).sum())

    @property
    def area_2d(self) -> float:
        return float(signed_areas(self.uv, self.triangles).sum())

    @property
    def boundary_3d(self) -> float:
        return _loop_length(self.vertices, self.boundary)

    @property
    def boundary_2d(self) -> float:
        return _loop_length(self.uv, self.boundary)

    @property
    def area_error(self) -> float:
        """|S3 - S2| / S3 (Fan et al. 1998 table 1)."""
        return abs(self.area_3d - self.area_2d) / self.area_3d

    @property
    def boundary_error(self) -> float:
        """|L3 - L2| / L3 of the outline (Fan et al. 1998 table 1)."""
        return abs(self.boundary_3d - self.boundary_2d) / self.boundary_3d

    @property
    def flipped(self) -> int:
        """Triangles whose 2D signed area is not positive (must be 0)."""
        return int(np.count_nonzero(signed_areas(self.uv, self.triangles) <= 0))

    def vertex_error(self) -> np.ndarray:
        """(V,) float64: the mean |edge length error| of each vertex's edges (the error map on vertices)."""
        total = np.zeros(len(self.uv))
        count = np.zeros(len(self.uv))
        for side in (0, 1):
            np.add.at(total, self.edges[:, side], np.abs(self.edge_error))
            np.add.at(count, self.edges[:, side], 1.0)
        return total / np.maximum(count, 1.0)

    def aligned_to(self, reference_uv) -> np.ndarray:
        """The layout (V,2) moved rigidly (rotation and translation, no reflection or scaling) to best match
        reference_uv (V,2) in the least-squares sense (Kabsch), e.g. the original pattern of a draped piece."""
        ref = np.asarray(reference_uv, dtype=np.float64)
        a = self.uv - self.uv.mean(axis=0)
        b = ref - ref.mean(axis=0)
        u, _, wt = np.linalg.svd(a.T @ b)
        d = np.sign(np.linalg.det(u @ wt))
        rot = u @ np.diag([1.0, d]) @ wt
        return a @ rot + ref.mean(axis=0)

    def pattern_piece(self):
        """The flattened outline as a PatternPiece (metres): polylines between the named corners, or one closed
        polyline when there are none."""
        pts = self.uv[self.boundary]
        if self.boundary_2d and signed_polygon_area(pts) < 0:
            raise MeshError(f"{self.name}: the flattened outline runs clockwise")
        where = {int(v): k for k, v in enumerate(self.boundary)}
        marks = sorted((where[int(v)], name) for name, v in self.corners.items() if int(v) in where) or [(0, "c0")]
        segments, names = [], []
        for j, (start, name) in enumerate(marks):
            end = marks[(j + 1) % len(marks)][0]
            stop = end if end > start else end + len(pts)
            idx = np.arange(start, stop + 1) % len(pts)
            segments.append(Segment("polyline" if len(idx) > 2 else "line", pts[idx]))
            names.append(name)
        return PatternPiece(self.name, segments, names)

    def summary(self) -> dict:
        return {"piece": self.name, "triangles": len(self.triangles), "area_error": self.area_error,
                "boundary_error": self.boundary_error, "max_edge_error": float(np.abs(self.edge_error).max()),
                "flipped": self.flipped, "iterations": self.iterations}


def signed_areas(uv: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(T,) signed areas [m^2] of 2D triangles: positive when counter-clockwise."""
    p = uv[triangles]
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])


def signed_polygon_area(points: np.ndarray) -> float:
    """Shoelace area [m^2] of a closed 2D polygon (n, 2): positive when counter-clockwise."""
    x, y = points[:, 0], points[:, 1]
    return 0.5 * float((x * np.roll(y, -1) - np.roll(x, -1) * y).sum())


def _loop_length(points: np.ndarray, loop: np.ndarray) -> float:
    p = points[loop]
    return float(np.linalg.norm(p - np.roll(p, -1, axis=0), axis=1).sum())


# ------------------------------------------------------------------------------------------- flattening

#: h^2 k / m on the stiffest particle for the quasi-static Newton steps (module docstring)
NEWTON_STIFFNESS_RATIO = 1.0e3


def flatten(vertices, triangles, name: str = "piece", tolerance: float = 1e-6, max_iterations: int = 500,
            material="cotton", corners: dict | None = None) -> FlatPiece:
    """Flatten one 3D piece (vertices (V,3) [m], triangles (T,3) int, a consistently wound disc) into the plane.

    tolerance: stop when |E_k - E_(k-1)| <= tolerance * E_(k-1) (relative elastic energy change of one step) or
    when the energy is below 1e-12 of its scale (a developable piece); max_iterations caps the steps.
    material: the cloth whose stiffness and density weigh the springs (it only sets the relative weights).
    corners: optional name -> vertex index on the outline (kept as named corners in the DXF export).
    Needs the Taichi runtime (taichi_cloth.init). Raises MeshError for a mesh that is not a disc.
    """
    return flatten_pieces([(name, vertices, triangles, corners)], tolerance, max_iterations, material)[0]


def flatten_pieces(pieces, tolerance: float = 1e-6, max_iterations: int = 500, material="cotton") -> list:
    """Flatten several pieces, each a tuple (name, vertices (V,3) [m], triangles (T,3), corners or None), with
    one set of fields sized for the largest (so the relaxation kernels compile once). Options as `flatten`."""
    if not tolerance > 0:
        raise ValueError(f"flatten: tolerance must be > 0, got {tolerance}")
    if int(max_iterations) != max_iterations or max_iterations < 0:
        raise ValueError(f"flatten: max_iterations must be a whole number >= 0, got {max_iterations}")
    prepared = [_prepare(*piece, material) for piece in pieces]
    relax = _Relaxation([p[-1] for p in prepared])
    out = []
    for name, v, t, boundary, corners, data in prepared:
        edges, _, _ = edges_of(t)
        l3 = np.linalg.norm(v[edges[:, 1]] - v[edges[:, 0]], axis=1)
        uv0 = data.positions[:, :2]
        initial = FlatPiece(name, v, t, uv0, boundary, edges, np.zeros(len(edges)), 0, np.zeros(1), 0.0, 0.0)
        uv, energy = relax.run(data, tolerance, int(max_iterations))
        l2 = np.linalg.norm(uv[edges[:, 1]] - uv[edges[:, 0]], axis=1)
        out.append(FlatPiece(name, v, t, uv, boundary, edges, (l2 - l3) / l3, len(energy) - 1, energy,
                             initial.area_error, initial.boundary_error, corners))
    return out


def _prepare(name, vertices, triangles, corners, material):
    """Checks, the unfolded layout and the planar spring system (ClothData at z = 0) of one piece."""
    v = np.asarray(vertices, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.int64)
    boundary = disc_boundary(v, t, name)
    corners = {str(k): int(i) for k, i in (corners or {}).items()}
    on_outline = set(boundary.tolist())
    for k, i in corners.items():
        if i not in on_outline:
            raise MeshError(f"{name}: corner {k!r} (vertex {i}) is not on the piece's outline")
    uv0 = unfold(v, t)
    cloth = mesh_cloth(v, t, material, source=name, stiffness_rule="isotropic")
    keep = cloth.kind == SpringKind.STRUCTURAL  # edges only: rest lengths from 3D, constants from 3D areas
    data = ClothData(np.column_stack([uv0, np.zeros(len(uv0))]), cloth.mass, cloth.springs[keep],
                     cloth.rest_length[keep], cloth.stiffness[keep], np.zeros(int(keep.sum())), cloth.kind[keep], t)
    return name, v, t, boundary, corners, data


class _Relaxation:
    """The planar spring relaxation (module docstring, step 2): one Scene whose fields fit every piece."""

    def __init__(self, datas):
        capacity = tuple(max(n) for n in zip(*((d.n_particles, d.n_springs, len(d.triangles)) for d in datas)))
        model = Model(datas[0], "f64", capacity)
        self.scene = Scene(model, integrator="implicit", dt=1.0, gravity=(0.0, 0.0, 0.0), air_damping=0.0,
                           integrator_options={"cg_tolerance": 1e-8, "cg_max_iterations": 2000}, step_guard="off",
                           max_strain=1e6, max_speed=1e30)

    def run(self, data, tolerance: float, max_iterations: int):
        """((V,2) relaxed layout [m], (steps + 1,) elastic energy [J])."""
        scene = self.scene
        scene.model.load(data)
        scene.state.reset()
        k_sum = np.zeros(data.n_particles)
        np.add.at(k_sum, data.springs.reshape(-1), np.repeat(data.stiffness, 2))
        scene.dt = float(np.sqrt(NEWTON_STIFFNESS_RATIO * (data.mass / k_sum).min()))
        scale = float((0.5 * data.stiffness * data.rest_length**2).sum())  # the energy of a fully collapsed sheet
        energy = [scene.measure().elastic]
        for _ in range(max_iterations):
            if energy[-1] <= 1e-12 * scale:
                break
            scene.state.v.fill(0.0)
            energy.append(scene.step(1).elastic)
            if abs(energy[-2] - energy[-1]) <= tolerance * energy[-2]:
                break
        return scene.positions()[:, :2].copy(), np.array(energy)


# ------------------------------------------------------------------------------------------- export

def write_flat_dxf(pieces, path, units: str = "mm") -> Path:
    """Write flattened pieces (FlatPiece) to a DXF (one layer per piece, see garment.dxf.write_dxf)."""
    from .garment.dxf import write_dxf  # ezdxf (0.5 s to import): only when a DXF is written

    return write_dxf([p.pattern_piece() for p in pieces], path, units)


def plot_flat(pieces, path, full_scale: float | None = None, references=None, layouts=None) -> Path:
    """A PNG of the flattened pieces side by side, each edge coloured by its length error (l2 - l3) / l3 in
    per cent (blue: shorter than in 3D, red: longer), with the per-piece area and boundary errors in the title.
    references: optional list (one per piece, or None) of 2D outlines (m, 2) [m] drawn dashed behind (e.g. the
    original pattern). layouts: optional (V,2) arrays drawn instead of each piece's uv (e.g. aligned to the pattern).
    full_scale: colour range in per cent (default: the largest |error|)."""
    import matplotlib  # 0.5 s with pyplot: only when a picture is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    pieces = list(pieces)
    references = list(references) if references is not None else [None] * len(pieces)
    layouts = list(layouts) if layouts is not None else [p.uv for p in pieces]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    worst = max(float(np.abs(p.edge_error).max()) for p in pieces) * 100
    scale = full_scale or max(worst, 1e-6)
    fig, axes = plt.subplots(1, len(pieces), figsize=(4.2 * len(pieces), 5.0), squeeze=False)
    for ax, piece, ref, uv in zip(axes[0], pieces, references, layouts):
        segs = uv[piece.edges]
        lines = LineCollection(segs, array=100 * piece.edge_error, cmap="coolwarm", linewidths=0.8)
        lines.set_clim(-scale, scale)
        ax.add_collection(lines)
        outline = uv[np.append(piece.boundary, piece.boundary[0])]
        ax.plot(outline[:, 0], outline[:, 1], color="black", linewidth=1.0)
        if ref is not None:
            r = np.vstack([ref, ref[:1]])
            ax.plot(r[:, 0], r[:, 1], color="0.4", linewidth=0.8, linestyle="--")
        ax.set_aspect("equal")
        ax.autoscale_view()
        ax.set_title(f"{piece.name}\narea {100 * piece.area_error:.2f} %, boundary {100 * piece.boundary_error:.2f} %",
                     fontsize=9)
        ax.set_xlabel("m")
    fig.colorbar(lines, ax=axes[0].tolist(), shrink=0.8, label="edge length error [%] (2D vs 3D)")
    fig.savefig(path, dpi=130, bbox_inches="tight")
    plt.close(fig)
    return path


def format_table(pieces) -> str:
    """A markdown table of the flattening errors per piece."""
    head = "| piece | triangles | area error | boundary error | max edge error | flipped | steps |"
    rule = "|---|---|---|---|---|---|---|"
    rows = []
    for p in pieces:
        rows.append(f"| {p.name} | {len(p.triangles)} | {100 * p.area_error:.3f} % | {100 * p.boundary_error:.3f} % | "
                    f"{100 * float(np.abs(p.edge_error).max()):.2f} % | {p.flipped} | {p.iterations} |")
    return "\n".join([head, rule] + rows)
