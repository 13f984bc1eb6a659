"""A batch's jobs: one garment on one body in one material, as a scene dict ready for taichi_cloth.run, and its key.

A job's key is a hash of everything that decides its result: its scene (the template, the garment, the body's
girths, the material, the run settings) and the bytes of the files it reads (the garment file and the DXF it
names, the template scene). A rerun of the batch finds a job finished when its folder holds a row with its key;
change a girth, a material or the garment file, and the job's key (so its folder) is new.
"""
from __future__ import annotations

import copy
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

from ..schema import read_toml
from ..scenefile import parse_scene
from .spec import MANNEQUIN, BatchError, BatchSpec

#: the scene every job starts from unless [run] scene names one: the shipped garment scenes' settings
#: (demos/scenes/sew_tshirt.toml, sew_skirt.toml): implicit at 1/120 s, sewn with gravity off, the mannequin; but the
#: stretch limit holds the pieces while they are sewn only (after_join = false): on the garment matrix 63 of 75 jobs
#: came to rest within 5 s so, 45 with the limit on after the join (docs/garments.md, the garment matrix)
TEMPLATE = {
    "fps": 60.0,
    "air_damping": 1.0,
    "integrator": {"name": "implicit", "dt": 0.008333333, "cg_tolerance": 1e-3},
    "sewing": {"close_speed": 0.5, "epsilon": 0.002, "energy_tolerance": 0.05, "gravity": False},
    "colliders": [{"type": "mesh", "path": "mannequin", "thickness": 0.004, "friction": 0.4}],
    "stretch_limit": {"max_strain": 0.1, "iterations": 20, "after_join": False},
}
#: the key's length in hex digits (48 bits: no two jobs of a batch of millions share one)
KEY_DIGITS = 12
#: a job's folder, below the batch's output folder
JOBS_DIR = "jobs"


@dataclass
class Job:
    """label: "<garment>_<body>_<material>" (names its files); key: the hash (module docstring); scene: the
    scene dict (taichi_cloth.run.run_scene_file); base_dir: where the scene's relative paths start; run: the
    job's [run] settings; garment, body, material: the names; girths: the body's {girth: cm} (empty: the
    mannequin); dir: the job's folder."""

    label: str
    key: str
    scene: dict
    base_dir: str
    run: dict
    garment: str
    body: str
    material: str
    girths: dict
    dir: str

    def as_dict(self) -> dict:
        """Plain data, to hand to a worker process or a Ray task."""
        return dict(self.__dict__)


def make_jobs(spec: BatchSpec) -> list[Job]:
    """The spec's jobs, in order: its [[jobs]] list, else every garment x material x body (garments outermost,
    bodies innermost; a garment that names its bodies only on those). Bodies vary fastest because the jobs running
    at once then differ in their body: a garment on one body compiles the kernels whose fields the body sizes (the
    collision grid), and the job of the same garment and body in the next material, started later, finds them in
    the offline cache the first one wrote at its end (two jobs of one body started together would both compile
    them)."""
    combos = spec.jobs if spec.jobs is not None else [
        (g, b, m, {}) for g in spec.garments for m in spec.materials for b in spec.bodies
        if g.bodies is None or b.name in g.bodies]
    jobs = []
    for g, b, m, overrides in combos:
        run = dict(spec.run, **overrides)
        if run.get("seeds") is not None and run.get("perturb") is None:
            raise BatchError(f"{spec.path}: [run] seeds {run['seeds']}: nothing to seed without perturb (metres)")
        seeds = run.get("seeds") or ([0] if run.get("perturb") is not None else [None])
        jobs += [make_job(spec, g, b, m, dict(run, seed=seed)) for seed in seeds]
    for job in jobs:  # a mistake in [run] (an integrator option, a rest key) fails here, once, not in every job
        parse_scene(job.scene, Path(job.base_dir), label=f"{spec.path}: [run] (job {job.label})")
    seen = {}
    for job in jobs:
        if job.key in seen:
            raise BatchError(f"{spec.path}: [[jobs]]: {seen[job.key]} and {job.label} are the same job")
        seen[job.key] = job.label
    return jobs


def make_job(spec: BatchSpec, garment, body, material, run: dict) -> Job:
    seed = run.get("seed")
    label = f"{garment.name}_{body.name}_{material.name}" + ("" if seed is None or run.get("seeds") is None
                                                            else f"_seed{seed}")
    if run["scene"] is not None:
        template_path = Path(run["scene"])
        template_path = template_path if template_path.is_absolute() else spec.path.parent / template_path
        scene = read_toml(template_path, str(template_path), "scene", error=BatchError)
        base_dir, template_bytes = template_path.parent, template_path.read_bytes()
    else:
        scene, base_dir, template_bytes = copy.deepcopy(TEMPLATE), spec.path.parent, b""
    cloth = {"garment": str(garment.path)}
    if material.table is not None:
        cloth["material"] = material.table
    if run["resolution"] is not None:
        cloth["resolution"] = run["resolution"]
    scene.update(name=label, frames=run["frames"], cloth=cloth)
    scene.pop("body", None)
    if body.name != MANNEQUIN:  # girths in cm (the `body` command's), the scene's in metres
        scene["body"] = {**{g: cm / 100.0 for g, cm in body.girths.items()}, "tolerance": body.tolerance / 100.0,
                         "morph": "before"}
    if run["quality"] is not None:
        scene["quality"] = run["quality"]
    if run.get("integrator"):  # merged into the scene's; another integrator's name starts from its dt alone
        integrator = scene.get("integrator", {})
        if run["integrator"].get("name", integrator.get("name")) != integrator.get("name"):
            integrator = {k: integrator[k] for k in ("dt",) if k in integrator}
        scene["integrator"] = dict(integrator, **run["integrator"])
    if run.get("rest"):
        scene["rest"] = dict(scene.get("rest", {}), **run["rest"])
    settings = {k: run[k] for k in ("until_rest", "max_inside", "png", "record", "timeout")}
    if run.get("perturb") is not None:  # the start moved (taichi_cloth.perturb): part of the job's key
        settings.update(perturb=float(run["perturb"]), seed=int(seed or 0))
    files = [garment.path, *_garment_files(garment.path)]
    hashed = dict(scene, cloth=dict(cloth, garment=garment.path.name))  # the file by its bytes, not where it lies
    digest = hashlib.sha256(json.dumps({"scene": hashed, "template": _hash_bytes(template_bytes),
                                        "run": {k: v for k, v in settings.items() if k != "timeout"},
                                        "files": [_hash_bytes(Path(f).read_bytes()) for f in files]},
                                       sort_keys=True, default=str).encode())
    key = digest.hexdigest()[:KEY_DIGITS]
    folder = spec.out / JOBS_DIR / f"{label}_{key}"
    scene["output"] = {"dir": str(folder), "record": run["record"], "mesh": True}
    return Job(label, key, scene, str(base_dir), settings, garment.name, body.name, material.name,
               dict(body.girths), str(folder))


def _garment_files(path: Path) -> list[Path]:
    """The files a garment file reads besides itself: its DXF, if it names one."""
    try:
        data = read_toml(path, str(path), "garment", error=BatchError)
    except BatchError:
        return []
    dxf = data.get("dxf")
    return [path.parent / dxf] if isinstance(dxf, str) and (path.parent / dxf).is_file() else []


def _hash_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()
