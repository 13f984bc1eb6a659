"""Scene glue for collision: collider specs (scene-file tables or dicts) -> collision package objects.

Spec keys (SI units):
  {"type": "sphere",  "center": [x, y, z], "radius": r}
  {"type": "capsule", "a": [x, y, z], "b": [x, y, z], "radius": r}
  {"type": "plane",   "point": [x, y, z], "normal": [nx, ny, nz]}
  {"type": "mesh",    "path": "body.obj" | "mannequin", "scale": 1.0, "translate": [0, 0, 0],
                      (or "vertices": (V,3) [m] and "triangles": (T,3) arrays, "path" then only names it)
                      "cell_size": None (1.5 x mean edge), "mode": "fuzzy" | "exact",
                      "repulsion": None | {"stiffness": N, "distance": m, "max_force": N}}
  {"type": "standin"}: Zhang et al. 2017's sphere-collider body, a sphere-and-capsule stand-in for the mannequin
  every type also takes "thickness" [m] (default 0.003) and "friction" (default 0.3), and may move: "keyframes":
  [[t, dx, dy, dz], ...] (translation [s, m]) and "rotation": [[t, ax, ay, az], ...] (degrees about the x, y, z axes
  through "pivot" [m]), linear between keys and held outside them (clothbase.keyframes). A moving collider is
  posed before every step, and its contact tests run in its own frame on each particle's relative motion.
A dict is checked as a scene file's [[colliders]] table is (taichi_cloth.specs): a misspelled or unknown key, a
missing one, a value of the wrong kind are refused with one SceneError line naming "[[colliders]] #k" and the key.
Still analytic shapes with the same thickness and friction share one PrimitiveColliders (one kernel).
`Colliders` is the scene's collision stage (and a controller for what it shows, counts and refills): `begin`
remembers where the particles start a step; `collide`, after the step and the controllers' after_step, pushes them
out and writes the contact normals the next step's integrator filters (Scene.substep).
"""
from __future__ import annotations

import inspect
from pathlib import Path

import numpy as np

from clothbase.keyframes import RigidMotion
from clothbase.meshes import load_triangle_mesh, open_mesh_warning
from clothbase.sequences import MeshSequence, load_mesh_sequence
from collision import MeshCollider, PrimitiveColliders
from collision.mannequin import load_mannequin
from collision.primitives import STANDIN_CAPSULES, STANDIN_SPHERES
from collision.self_collision import SelfCollision

from .contacts import require_bound
from .control import Controller
from .errors import SceneError
from .guards import check_voxel_grid
from .specs import collider_table


def body_mesh(path: str, scale: float = 1.0, translate=(0.0, 0.0, 0.0), base_dir: Path | None = None):
    """(vertices [m], triangles) of a body: "mannequin" for the shipped CC0 body, else a mesh file."""
    if path == "mannequin":
        m = load_mannequin()
        return m.vertices * scale + np.asarray(translate, dtype=np.float64), m.triangles
    p = Path(path)
    if not p.is_absolute() and base_dir is not None:
        p = base_dir / p
    return load_triangle_mesh(p, scale, translate)


def body_sequence(spec: dict, base_dir: Path | None = None) -> MeshSequence:
    """The MeshSequence of a mesh collider's `sequence` (a MeshSequence, or a .npz or folder of frames relative to
    base_dir, read with its fps, scale and translate); MeshError names the file when it is unusable."""
    seq = spec["sequence"]
    if isinstance(seq, MeshSequence):
        return seq
    p = Path(seq)
    if not p.is_absolute() and base_dir is not None:
        p = base_dir / p
    return load_mesh_sequence(p, spec.get("fps"), spec.get("scale", 1.0), spec.get("translate", (0.0, 0.0, 0.0)))


#: [m] the motion per step a mesh collider's voxel grid leaves room for (MeshCollider's max_step)
MAX_STEP = inspect.signature(MeshCollider).parameters["max_step"].default


def build_colliders(specs, base_dir: Path | None = None) -> list:
    """Collider objects for a list of spec dicts (see the module docstring); objects pass through. Each dict is
    checked as a scene file's [[colliders]] table is (taichi_cloth.specs: SceneError naming "[[colliders]] #k" and
    the key), and a mesh's voxel grid against the machine's memory before it is allocated (guards)."""
    out, groups = [], {}
    for k, spec in enumerate(specs):
        if not isinstance(spec, dict):
            out.append(spec)
            continue
        where = f"[[colliders]] #{k + 1}"
        spec = collider_table(spec, where)
        kind = spec["type"]
        thickness, friction = spec["thickness"], spec["friction"]
        motion = None
        if spec.get("keyframes") is not None or spec.get("rotation") is not None:
            motion = RigidMotion(spec.get("keyframes"), spec.get("rotation"), spec.get("pivot", (0.0, 0.0, 0.0)))
        sequence = None
        if kind == "mesh":
            if "vertices" in spec:  # a body given as arrays (e.g. a fitted taichi_cloth.body morph)
                v, t = spec["vertices"], spec["triangles"]
            elif "sequence" in spec:  # a deforming body
                sequence = body_sequence(spec, base_dir)
                v, t = sequence.frames[0], sequence.triangles
            else:
                v, t = body_mesh(spec["path"], spec.get("scale", 1.0), spec.get("translate", (0.0, 0.0, 0.0)),
                                 base_dir)
            name = str(spec.get("path") or sequence.source)
            open_mesh_warning(t, name)
            cell = spec.get("cell_size")
            if cell is not None:  # the default (1.5 x the mean edge) bins each triangle into a few cells
                check_voxel_grid(v, t, cell, thickness, thickness + MAX_STEP, f"{where} cell_size {cell:g} m "
                                 f"(mesh {name})")
            if motion is not None and spec.get("repulsion"):
                raise SceneError(f"{where}: a moving body has no repulsion force (give it keyframes or repulsion)")
            out.append(MeshCollider(v, t, thickness=thickness, friction=friction, cell_size=cell,
                                    mode=spec.get("mode", "fuzzy"), repulsion=spec.get("repulsion"),
                                    source=name, motion=motion, sequence=sequence, start=spec.get("start", 0.0)))
        elif kind in ("sphere", "capsule", "plane", "standin"):
            # still shapes of equal thickness and friction share one object; a moving one has its own (its motion)
            key = (thickness, friction) if motion is None else (thickness, friction, k)
            g = groups.setdefault(key, {"sphere": [], "capsule": [], "plane": [], "motion": motion})
            if kind == "standin":
                g["sphere"] += STANDIN_SPHERES
                g["capsule"] += STANDIN_CAPSULES
            elif kind == "sphere":
                g["sphere"].append((spec["center"], spec["radius"]))
            elif kind == "capsule":
                g["capsule"].append((spec["a"], spec["b"], spec["radius"]))
            else:
                g["plane"].append((spec["point"], spec["normal"]))
        else:
            raise ValueError(f"unknown collider type {kind!r} (sphere, capsule, plane, mesh, standin)")
    for (thickness, friction, *_), g in groups.items():
        out.append(PrimitiveColliders(g["sphere"], g["capsule"], g["plane"], thickness=thickness, friction=friction,
                                      motion=g["motion"]))
    return out


class Colliders(Controller):
    """The scene's collision stage: its colliders, resolved after every step in order (self-collision last: it never
    pushes a particle that a body holds into that body, so a body does not undo it). objects: collision objects
    (MeshCollider, PrimitiveColliders, SelfCollision); contacts: the scene's Contacts, whose normals they write.

    moving: indices of the objects whose surface moves during a run (a morphing body): the recorder logs them on
    the timeline instead of once
    """

    name = "colliders"

    def __init__(self, model, state, objects: list, contacts):
        self.objects, self.state, self.contacts = list(objects), state, contacts
        # a deforming body is drawn anew every frame
        self.moving: set[int] = {k for k, c in enumerate(self.objects) if getattr(c, "deforming", False)}
        self._drawn: dict[int, tuple] = {}  # a deforming body: its (frame, weight) last recorded
        for c in self.objects:
            c.attach(state.x, state.v, model.inv_mass, model.n_particles, contacts.normal, model.serial,
                     contacts.friction, contacts.before, contacts.velocity)

    @property
    def thickness(self) -> float | None:
        """The thinnest collider's thickness [m] (None if none has one)."""
        values = [c.thickness for c in self.objects if getattr(c, "thickness", None)]
        return min(values) if values else None

    @property
    def stats(self) -> dict:
        """The collision counters of the colliders that keep them (mesh bodies: candidate triangles, crossing
        tests, crossings, proximity contacts...; self-collision: candidates, point-triangle and edge-edge
        contacts), summed by name."""
        out: dict[str, int] = {}
        for c in self.objects:
            if hasattr(c, "counter_values"):
                prefix = "self-collision" if isinstance(c, SelfCollision) else "collision"
                for key, value in c.counter_values().items():
                    out[f"{prefix} {key}"] = out.get(f"{prefix} {key}", 0) + value
        return out

    @property
    def self_collision(self) -> SelfCollision | None:
        """The cloth's self-collision, if the scene has it."""
        return next((c for c in self.objects if isinstance(c, SelfCollision)), None)

    @property
    def _reporters(self) -> list:
        return [c for c in self.objects if getattr(c, "report_slots", 0)]

    @property
    def report_slots(self) -> int:
        """The per-frame values of self-collision and of deforming bodies (their grids' capacity checks) travel with
        the frame's measurement."""
        return sum(c.report_slots for c in self._reporters)

    def report(self, out, offset: int) -> None:
        for c in self._reporters:
            c.report(out, offset)
            offset += c.report_slots

    def reported(self, values) -> None:
        k = 0
        for c in self._reporters:
            c.reported(values[k:k + c.report_slots])
            k += c.report_slots

    @property
    def bodies(self) -> list:
        """The mesh colliders (bodies)."""
        return [c for c in self.objects if isinstance(c, MeshCollider)]

    @property
    def repulsions(self) -> list:
        """The force sources of the mesh colliders that push the cloth off from a distance."""
        return [r for r in (getattr(c, "repulsion", None) for c in self.objects) if r is not None]

    def inline_step(self) -> tuple | None:
        """The primitive colliders (spheres, capsules, planes), whose resolve touches one particle at a time; None
        when a body mesh or self-collision is among the colliders, or one moves (its pose changes every step)."""
        if any(c.animated for c in self.objects):
            return None
        return tuple(self.objects) if all(isinstance(c, PrimitiveColliders) for c in self.objects) else None

    @property
    def per_step(self) -> bool:
        """A scripted motion poses its collider before every step."""
        return any(c.animated for c in self.objects)

    def before_step(self, t: float, dt: float) -> None:
        """The poses of the moving colliders at the start and the end of the step from t over dt [s]."""
        for c in self.objects:
            c.move(t, t + dt)

    def reset(self) -> None:
        """Back to t = 0: the moving colliders where they start."""
        self._drawn.clear()
        for c in self.objects:
            c.rewind()

    def begin(self, state, contacts, dt: float | None = None) -> None:
        """A step of `state` begins: every collider remembers where the particles start (its crossing tests run
        from there); with the step dt [s], the primitive colliders also cut the approach of the particles that would
        reach them within it (speculative contacts, collision.primitives). state and contacts: those the colliders
        were built for (another raises ValueError)."""
        require_bound(self, state, contacts)
        for c in self.objects:
            if isinstance(c, PrimitiveColliders):
                c.begin_step(dt)
            else:
                c.begin_step()

    def collide(self, state, contacts, dt: float) -> None:
        """After a step of dt [s]: push the particles of `state` out of every collider and write `contacts` afresh
        (the next step's integrator filters them)."""
        require_bound(self, state, contacts)
        contacts.clear()
        for c in self.objects:
            c.resolve(dt)

    def model_changed(self, change, t: float, dt: float) -> None:
        """A refill (seam merge, level switch, reset): self-collision follows the new triangles."""
        if change.data is not None:
            for c in self.objects:
                if isinstance(c, SelfCollision):
                    c.topology_changed(change.data.positions, change.data.triangles)

    def layout(self, layout) -> None:
        for k, c in enumerate(self.objects):
            layout.colliders.append(dict(c.describe(), moving=k in self.moving))

    def record(self, frame) -> None:
        """The pose of each collider on a scripted path, and the surface of each deforming body that moved, now."""
        for k, c in enumerate(self.objects):
            if c.moving:
                frame.poses[k] = c.pose_now()
            elif getattr(c, "deforming", False) and self._drawn.get(k) != c.sequence.position(c.t_pose):
                self._drawn[k] = c.sequence.position(c.t_pose)
                frame.meshes[k] = c.vertices_np.astype(np.float32)
